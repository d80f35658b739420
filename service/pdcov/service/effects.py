"""What ``ServiceCore`` decided, done (core.Actions, in its order): MAVLink messages sent on
every link, the recording written, tiles, detections and status published, the candidates
journal appended (before the detections message it protects), checkpoints and re-tasking
nonces written, re-tasking queries answered, lines logged; each outcome the core must know
reported back. On the loop's thread, with no event loop of its own: the journal's append
and fsync (one short line at most once every DETECTIONS_PERIOD_S) is done where the put must
wait for it. A checkpoint is taken on the loop's thread (nothing copied: its tiles are
frozen, copy on write) and written by a thread of its own (service/checkpoint.py); its
outcome is reported when ``act`` or ``do`` next finds it done, a checkpoint decided
meanwhile started then.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

from pdcov.bus.status import StatusEncoder
from pdcov.errors import PdcovError
from pdcov.service.actions import Actions
from pdcov.service.bus_endpoints import BusEndpoints
from pdcov.service.checkpoint import CheckpointJob, CheckpointWriter
from pdcov.service.checkpoint_meta import CheckpointContents, CheckpointMeta
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
        self._checkpoints = CheckpointWriter(checkpoint_path)
        self._writer = ThreadPoolExecutor(max_workers=1, thread_name_prefix="checkpoint")
        self._writing: tuple[CheckpointJob, Future[None], CheckpointContents] | None = None
        self._checkpoint_due = False  # decided while one was written: started after it
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
        self._check_writing()
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
            self._start_checkpoint(a.checkpoint)
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
        """Write a checkpoint of the grid now, waiting for it (at the stop)."""
        self.wait_checkpoint()
        self._start_checkpoint(self.core.checkpoint_meta(time.time()))
        self.wait_checkpoint()

    def wait_checkpoint(self) -> None:
        """Wait for the checkpoint being written, if any, and report it."""
        if self._writing is not None:
            self._writing[1].exception()  # waits; the outcome is read by _check_writing
            self._check_writing()

    def _start_checkpoint(self, meta: CheckpointMeta) -> None:
        """The grid's changed tiles copied with ``meta`` (of the grid now), written by the
        checkpoint thread; after the one being written when there is one."""
        if self._writing is not None:
            self._checkpoint_due = True
            return
        live = self.core.coverage
        job = self._checkpoints.prepare(live.grid, meta, live.checkpoint_cameras,
                                        self.core.candidates_checkpoint())
        self._writing = (job, self._writer.submit(job.write), self.core.checkpoint_contents())

    def _check_writing(self) -> None:
        """Report the checkpoint written or failed, and start the one decided meanwhile."""
        if self._writing is None or not self._writing[1].done():
            return
        (job, done, contents), self._writing = self._writing, None
        job.release()
        exc = done.exception()
        if exc is not None and not isinstance(exc, (OSError, PdcovError, ValueError)):
            raise exc  # a bug, not the disk: the daemon stops as on any other
        if exc is None:
            self._checkpoints.written(job)
        assert job.meta is not None  # the core's metadata (a mapping only from tests)
        self.core.checkpoint_written(job.meta, None if exc is None else str(exc), contents)
        if self._checkpoint_due:
            self._checkpoint_due = False
            self._start_checkpoint(self.core.checkpoint_meta(time.time()))
        self.act()  # the outcome adds only log lines

    def close(self) -> None:
        """At the stop: the checkpoint thread ended, the recording closed."""
        self._writer.shutdown(wait=True)
        if self.recorder is not None:
            self.recorder.close()
