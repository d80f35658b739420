"""What ``ServiceCore`` decided, done (core.Actions, in its order): MAVLink messages sent on
every link, the recording written, tiles, detections and status published, the candidates
journal appended (before the detections message it protects), checkpoints and re-tasking
nonces written, re-tasking queries answered, lines logged; each outcome the core must know
reported back. On the loop's thread, with no event loop of its own: the journal's append
and fsync (one short line at most once every DETECTIONS_PERIOD_S) and a checkpoint's
encoding (milliseconds for a mission-sized grid) are done where the put must wait for them.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path

from pdcov.bus.status import StatusEncoder
from pdcov.errors import PdcovError
from pdcov.service.actions import Actions
from pdcov.service.bus_endpoints import BusEndpoints
from pdcov.service.checkpoint import write_checkpoint
from pdcov.service.checkpoint_meta import CheckpointMeta
from pdcov.service.core import ServiceCore
from pdcov.service.link_setup import LinkReport
from pdcov.service.mavlink_link import MavlinkLink
from pdcov.service.recorder import TlogRecorder
from pdcov.service.state_files import StateFiles
from pdcov.service.systemd_notify import SystemdNotifier

__all__ = ["Effects"]

log = logging.getLogger("pdcov.serve")


class Effects:
    """Does ``core``'s actions on ``links``, the ``recorder``, the ``bus``, the state dir's
    ``files`` and ``checkpoint_path``, telling systemd the status line (``notifier``);
    ``clock``: the daemon's monotonic clock (s)."""

    def __init__(self, core: ServiceCore, bus: BusEndpoints, files: StateFiles,
                 checkpoint_path: Path, notifier: SystemdNotifier,
                 clock: Callable[[], float]) -> None:
        self.core = core
        self.bus = bus
        self.files = files
        self.checkpoint_path = checkpoint_path
        self.notifier = notifier
        self._clock = clock
        self.links: list[MavlinkLink] = []
        self.recorder: TlogRecorder | None = None
        self._status_encoder = StatusEncoder()

    def act(self) -> None:
        """Do what the core decided since it was last asked (``core.actions()``)."""
        self.do(self.core.actions())

    def do(self, a: Actions) -> None:
        """Do what the core decided, in its order (core.Actions)."""
        for msg in a.send:
            for link in self.links:
                link.send(msg)
        if a.record and self.recorder is not None:
            unix_s = time.time()
            for data in a.record:
                self.recorder.write(data, unix_s)
        if a.tiles is not None:
            self.bus.put(self.bus.pub_tiles, a.tiles)
        if a.journal is not None:  # before the detections: an id published is kept
            self.core.journal_written(self.files.append_journal(a.journal))
        for payload in a.detections:
            self.bus.put(self.bus.pub_detections, payload)
        if a.status_due:
            if self.recorder is not None:
                self.recorder.flush()
            self._publish_status()
        if a.checkpoint is not None:
            self._write_checkpoint(a.checkpoint)
        if a.journal_reset:
            self.files.reset_journal()
        if a.nonces is not None:  # before the replies: a replay after a crash is refused
            self.files.write_nonces(a.nonces)
        for ticket, payload in a.replies:
            self.bus.reply_retask(ticket, payload)
        for level, text in a.logs:
            log.log(level, "%s", text)

    def _link_report(self, now: float) -> LinkReport:
        return LinkReport(
            links=tuple(c.describe(now) for c in self.links),
            states=tuple(c.state for c in self.links),
            url=", ".join(c.url for c in self.links),
            losses=sum(c.losses for c in self.links),
            kernel_drops=sum(c.kernel_drops for c in self.links),
            parse_errors=sum(c.bad for c in self.links),
            recording_error=self.recorder.error if self.recorder is not None else None)

    def _publish_status(self) -> None:
        now = self._clock()
        fields, line = self.core.status(now, self._link_report(now))
        self.bus.put(self.bus.pub_status, self._status_encoder.encode(fields))
        self.notifier.status(line)
        self.act()  # the status adds only log lines

    def checkpoint(self) -> None:
        """Write a checkpoint of the grid now."""
        self._write_checkpoint(self.core.checkpoint_meta(time.time()))

    def _write_checkpoint(self, meta: CheckpointMeta) -> None:
        error = None
        live = self.core.coverage
        try:
            write_checkpoint(self.checkpoint_path, live.grid, meta, live.checkpoint_cameras,
                             self.core.candidates_checkpoint())
        except (OSError, PdcovError) as exc:  # atomic_write: OutputError (disk full, ...)
            error = str(exc)
        self.core.checkpoint_written(meta, error)
        self.act()  # the outcome adds only log lines

    def close(self) -> None:
        """At the stop: the recording closed."""
        if self.recorder is not None:
            self.recorder.close()
