"""The asyncio shell of ``pdcov serve``: it owns the MAVLink links, the Zenoh session, the
timers, the signals and the files, and does what ``LiveCoverage`` and ``LinkProtocol``
decide (docs/service.md).

Threads: everything runs on the event loop's thread. MAVLink is read with
``loop.add_reader`` (mavlink_io); Zenoh calls its callbacks on its own threads, which hand
the payload (frames) or the query (snapshot, footprint, mission) to the loop with
``loop.call_soon_threadsafe`` and return at once: no grid is touched off the loop, and no
Zenoh thread waits for the loop (which may be waiting for Zenoh in a put). Checkpoints and
snapshots are encoded on the loop (milliseconds for a mission-sized grid).
"""

from __future__ import annotations

import asyncio
import logging
import math
import signal
import sys
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pdcov.bus.errors import BusPayloadError
from pdcov.bus.footprint import decode_frames, encode_footprint
from pdcov.bus.grid_state import encode_snapshot
from pdcov.bus.keys import VehicleKeys
from pdcov.bus.mission import encode_mission
from pdcov.bus.session import open_session
from pdcov.bus.sources import SourcedPublisher, source_session
from pdcov.bus.status import StatusEncoder
from pdcov.core.mount import GimbalMount
from pdcov.errors import ConfigError, PdcovError
from pdcov.service.checkpoint import CHECKPOINT_NAME, resume, write_checkpoint
from pdcov.service.coverage import LiveCoverage
from pdcov.service.link_protocol import (
    ATTITUDE,
    GIMBAL_DEVICE_ATTITUDE_STATUS,
    GLOBAL_POSITION_INT,
    HOME_POSITION,
    MAV_COMP_ID_ONBOARD_COMPUTER,
    LinkProtocol,
)
from pdcov.service.mavlink_io import Connection, mavlink
from pdcov.service.query_limit import QueryLimiter
from pdcov.service.recorder import TlogRecorder
from pdcov.service.settings import ServeConfig, mission_hash
from pdcov.service.systemd_notify import SystemdNotifier
from pdcov.telemetry.gimbal import MOUNT_TYPE_PARAMS, mount_param_names
from pdcov.telemetry.recorded_frames import MAX_BOOT_MS, FrameEncoder, boot_ms, boot_s
from pdcov.telemetry.samples import CaptureSample

log = logging.getLogger("pdcov.serve")
TICK_S = 0.05
EARLY_FRAMES = 100_000
"""Detector frame times kept while the autopilot is not known yet (then the oldest go)."""
class JournalFormatter(logging.Formatter):
    """``<N>message``: the syslog level as journald reads it from stderr; no time stamp
    (journald adds its own)."""

    LEVELS = {logging.DEBUG: 7, logging.INFO: 6, logging.WARNING: 4, logging.ERROR: 3,
              logging.CRITICAL: 2}

    def format(self, record: logging.LogRecord) -> str:
        level = self.LEVELS.get(record.levelno, 6)
        return f"<{level}>{record.name}: {super().format(record)}"


def setup_logging(level: int = logging.INFO) -> None:
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(JournalFormatter("%(message)s"))
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(level)


class Daemon:
    """``pdcov serve`` once the config is checked: ``await run()`` until SIGTERM/SIGINT."""

    def __init__(self, cfg: ServeConfig) -> None:
        self.cfg = cfg
        m = cfg.mission
        self.keys = VehicleKeys(m.vehicle_id)
        self.state_dir = Path(cfg.service.state_dir)
        self.started_s = time.monotonic()
        self.stop_event: asyncio.Event | None = None
        self.links: list[Connection] = []
        self.session: Any = None
        self._zenoh_entities: list[Any] = []
        self._status_seq = 0
        self._status_encoder = StatusEncoder()
        self._checkpoint_info: dict[str, Any] = {"path": str(self.state_dir / CHECKPOINT_NAME),
                                                 "last_t_s": None, "resumed": False,
                                                 "set_aside": None, "error": None,
                                                 "recording_error": None}
        self.notifier = SystemdNotifier()
        self._next_watchdog_s = 0.0
        self._next_drops_warning_s = 0.0
        self.recorder: TlogRecorder | None = None
        self._frame_encoder = FrameEncoder()
        self._early_frames: deque[int] = deque()  # detector frames (boot ms) before a HEARTBEAT
        mount = m.mount
        names = (tuple(dict.fromkeys((*mount_param_names(mount.instance), *MOUNT_TYPE_PARAMS)))
                 if isinstance(mount, GimbalMount) else ())
        intervals = {ATTITUDE: cfg.link.attitude_hz, GLOBAL_POSITION_INT: cfg.link.position_hz,
                     HOME_POSITION: 0.2}
        if isinstance(mount, GimbalMount):
            intervals[GIMBAL_DEVICE_ATTITUDE_STATUS] = cfg.link.gimbal_hz
        self.protocol = LinkProtocol(mavlink.MAVLink(None, srcSystem=cfg.link.system_id or 1),
                                     system_id=cfg.link.system_id or m.system_id,
                                     intervals=intervals, param_names=names,
                                     param_timeout_s=cfg.link.param_timeout_s,
                                     estimator_hz=cfg.link.estimator_hz
                                     if m.estimator_status else None)
        self._process_scheduled = False
        self.state_dir.mkdir(parents=True, exist_ok=True)
        self.live = self._start_grid()  # a new or resumed grid: there before the loop runs
        self._mission_reply: tuple[float | None, bytes] | None = None  # (ground alt, bytes)
        self._snapshot: tuple[int, bytes] | None = None  # (grid frames, bytes)
        self._snapshot_limiter = QueryLimiter()

    # --- start ----------------------------------------------------------------------------

    def _start_grid(self) -> LiveCoverage:
        """The grid resumed from the state dir's checkpoint when it belongs to this mission,
        else a new one; primes the link's clock from the checkpoint."""
        m = self.cfg.mission
        grid = m.new_grid()
        mhash = mission_hash(m, grid)
        self.mission_hash = mhash
        r = resume(self.state_dir, mhash, grid)
        (log.warning if r.set_aside else log.info)("%s", r.message)
        meta = r.meta
        live = LiveCoverage(self.cfg, r.grid or grid, time.monotonic(),
                            tiles_seq=int(meta.get("tiles_seq", -1)) + 1)
        if r.grid is not None:
            last = meta.get("last_frame_t_s")
            if isinstance(last, (int, float)):
                live.resume_lattice(meta.get("t0_s"), float(last))
            clock = meta.get("clock")
            if isinstance(clock, list) and len(clock) == 2 and all(
                    isinstance(v, (int, float)) and math.isfinite(v) for v in clock):
                self.protocol.prime_clock(float(clock[0]), float(clock[1]))
            live.counters.used = int(meta.get("frames_used", 0))
        self._checkpoint_info.update(resumed=r.grid is not None,
                                     set_aside=str(r.set_aside) if r.set_aside else None)
        return live

    def _ids(self) -> tuple[int, int]:
        return (self.protocol.system_id or self.cfg.link.system_id or 1,
                MAV_COMP_ID_ONBOARD_COMPUTER)

    async def run(self) -> int:
        loop = asyncio.get_running_loop()
        self.stop_event = asyncio.Event()
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(sig, self.stop_event.set)
        if self.cfg.service.record:
            self.recorder = TlogRecorder(self.state_dir / "recordings",
                                         self.cfg.service.record_max_bytes,
                                         self.cfg.service.record_keep_bytes)
        key = self.cfg.link.signing_key_bytes(self.cfg.base_dir)
        if (self.cfg.link.signing_key or self.cfg.link.signing_key_file) and key is None:
            raise ConfigError("link.signing_key_file: cannot read 64 hex digits from "
                              f"{self.cfg.link.signing_key_file}")
        for url in self.cfg.link.connect:
            c = Connection(url, on_messages=self._on_messages,
                           from_autopilot=self.protocol.from_autopilot, ids=self._ids,
                           signing_key=key, timeout_s=self.cfg.link.timeout_s,
                           reconnect_max_s=self.cfg.link.reconnect_max_s)
            c.start()
            self.links.append(c)
        try:
            self.session = await loop.run_in_executor(None, open_session, self.cfg.bus)
            self._declare(loop)
            log.info("zenoh %s session open (connect %s, listen %s); publishing under "
                     "pdcov/%s/", self.cfg.bus.mode, list(self.cfg.bus.connect),
                     list(self.cfg.bus.listen), self.cfg.mission.vehicle_id)
            self.notifier.ready("pdcov serve: running")
            while not self.stop_event.is_set():
                self._tick()
                try:
                    await asyncio.wait_for(self.stop_event.wait(), TICK_S)
                except asyncio.TimeoutError:
                    pass
            log.info("stopping: writing the checkpoint")
            self.notifier.stopping("pdcov serve: stopping")
        finally:
            self._shutdown()
        return 0

    def _declare(self, loop: asyncio.AbstractEventLoop) -> None:
        s = self.session
        self.pub_status = SourcedPublisher(s.declare_publisher(self.keys.status))
        self.pub_tiles = SourcedPublisher(s.declare_publisher(self.keys.tiles))
        self._zenoh_entities += [
            self.pub_status, self.pub_tiles,
            s.declare_queryable(self.keys.snapshot,
                                lambda q: self._answer(loop, q, self._reply_snapshot)),
            s.declare_queryable(self.keys.footprint, lambda q: self._answer(
                loop, q, lambda q: self._reply(q, self._footprint_bytes))),
            s.declare_queryable(self.keys.mission, lambda q: self._answer(
                loop, q, lambda q: self._reply(q, self._mission_bytes))),
            s.liveliness().declare_token(self.keys.alive),
        ]
        if self.cfg.frame_source == "zenoh":
            self._zenoh_entities.append(s.declare_subscriber(
                self.keys.frames, lambda sample: loop.call_soon_threadsafe(
                    self._on_frames, sample.payload.to_bytes())))

    # --- Zenoh thread -> loop ---------------------------------------------------------------

    @staticmethod
    def _answer(loop: asyncio.AbstractEventLoop, query: Any,
                handle: Callable[[Any], object]) -> None:
        """On a Zenoh thread: hand the query to the loop, never wait for it there (the loop
        may itself be waiting for Zenoh in a put: a deadlock)."""
        loop.call_soon_threadsafe(handle, query)

    @staticmethod
    def _reply(query: Any, make: Callable[[], bytes]) -> int:
        """On the loop: build the reply, send it, finish the query; the bytes sent."""
        try:
            payload = make()
            query.reply(query.key_expr, payload)
            return len(payload)
        except Exception as exc:  # noqa: BLE001 - a failed reply must not stop the daemon
            log.warning("query %s not answered: %s", query.key_expr, exc)
            return 0
        finally:
            query.drop()

    def _reply_snapshot(self, query: Any) -> None:
        """On the loop: the snapshot, or a ``reply_err`` saying why when the requester or
        all snapshot replies together are over their rate (query_limit; counted in
        faults.snapshot_queries_refused)."""
        limiter = self._snapshot_limiter
        refusal = limiter.admit(source_session(query), time.monotonic())
        if refusal is None:
            limiter.sent(self._reply(query, self._snapshot_bytes))
            return
        try:
            query.reply_err(limiter.limits.reason(refusal))
        except Exception as exc:  # noqa: BLE001 - as _reply
            log.debug("query %s: refusal not sent: %s", query.key_expr, exc)
        finally:
            query.drop()

    def _snapshot_bytes(self) -> bytes:
        """The grid's snapshot, encoded again only once the grid took another frame."""
        grid = self.live.grid
        if self._snapshot is None or self._snapshot[0] != grid.frames:
            self._snapshot = (grid.frames, encode_snapshot(grid))
        return self._snapshot[1]

    def _footprint_bytes(self) -> bytes:
        t = self.live.last_pose.t_s if self.live.last_pose is not None else math.nan
        return encode_footprint(self.cfg.mission.vehicle_id, t, self.live.footprint_lonlat())

    def _mission_bytes(self) -> bytes:
        """The mission payload; encoded again only when the ground altitude becomes known."""
        m, origin = self.cfg.mission, self.live.origin
        alt = origin.ground_alt_msl_m if origin is not None else None
        if self._mission_reply is None or self._mission_reply[0] != alt:
            state = self.live.state
            self._mission_reply = (alt, encode_mission(
                m.vehicle_id, m.origin(alt), m.domain, state.geometry, state.hash,
                ground_alt_known=alt is not None, thresholds=m.thresholds,
                target_pd=self.cfg.target_pd))
        return self._mission_reply[1]

    def _on_frames(self, payload: bytes) -> None:
        """A detector's frames message: its times to the millisecond (what the recording
        keeps), held until the autopilot is known (its system and clock)."""
        try:
            t_boot = decode_frames(payload, self.keys.frames)
        except BusPayloadError as exc:
            self.live.counters.faults["bad_frames_messages"] += 1
            log.warning("%s", exc)
            return
        ms = [boot_ms(t) for t in t_boot]
        if any(v > MAX_BOOT_MS for v in ms):
            self.live.counters.faults["frames_out_of_range"] += sum(v > MAX_BOOT_MS for v in ms)
            ms = [v for v in ms if v <= MAX_BOOT_MS]
        if not self.protocol.autopilot_known:
            for v in ms:
                if len(self._early_frames) >= EARLY_FRAMES:
                    self._early_frames.popleft()
                    self.live.counters.faults["frames_dropped_waiting"] += 1
                self._early_frames.append(v)
            return
        self._take_frames(ms)

    def _take_frames(self, t_boot_ms: list[int]) -> None:
        """Give the grid the frames (autopilot boot ms) and record, in the order taken,
        those it took (recorded_frames: ``pdcov evaluate`` of the recording uses them)."""
        proto = self.protocol
        t_s = {proto.autopilot_boot_s(boot_s(v)): v for v in t_boot_ms}
        taken = self.live.add_frame_times(list(t_s))
        if self.recorder is not None and proto.system_id is not None:
            for t in taken:
                self.recorder.write(self._frame_encoder.encode(proto.system_id, t_s[t]),
                                    time.time())

    # --- MAVLink -----------------------------------------------------------------------------

    def _on_messages(self, conn: Connection, msgs: list) -> None:
        now = time.monotonic()
        live, proto = self.live, self.protocol
        for msg in msgs:
            mtype = msg.get_type()
            if mtype == "BAD_DATA":
                live.counters.faults["bad_messages"] += 1
                continue
            samples = proto.receive(msg, now)
            # The message's own capture event (the last sample), not taken: late.
            late = (mtype == "CAMERA_IMAGE_CAPTURED" and live.frame_source == "capture"
                    and bool(samples) and isinstance(samples[-1], CaptureSample)
                    and live.is_late(samples[-1].t_s))
            for sample in samples:
                live.add_sample(sample)
            if self.recorder is not None:  # all of it: even what came before a HEARTBEAT
                self.recorder.write(msg.get_msgbuf(), time.time())
                if late and proto.system_id is not None:  # recorded_frames: not taken
                    self.recorder.write(self._frame_encoder.not_taken(proto.system_id, msg),
                                        time.time())
        if not self._process_scheduled:  # once per loop pass, after every readable link
            self._process_scheduled = True
            asyncio.get_running_loop().call_soon(self._process)

    def _process(self) -> None:
        self._process_scheduled = False
        if self._early_frames and self.protocol.autopilot_known:
            early, self._early_frames = list(self._early_frames), deque()
            self._take_frames(early)
        self.live.set_params(self.protocol.params, self.protocol.params_done)
        self.live.process()

    def _send(self, msgs: list) -> None:
        for msg in msgs:
            for c in self.links:
                c.send(msg)

    # --- timers -----------------------------------------------------------------------------

    def _tick(self) -> None:
        now = time.monotonic()
        live, proto = self.live, self.protocol
        for c in self.links:
            c.check_silence(asyncio.get_running_loop().time())
        self._send(proto.poll(now))
        live.set_params(proto.params, proto.params_done)
        live.process()
        due = live.poll(now)
        if due.note is not None:
            log.warning("%s", due.note)
        if due.tiles is not None:
            self._put(self.pub_tiles, due.tiles)
        if due.status:
            if self.recorder is not None:
                self.recorder.flush()
                self._checkpoint_info["recording_error"] = self.recorder.error
            self._publish_status(now)
        if due.checkpoint:
            self._checkpoint()
        if due.named_value is not None or due.statustext is not None:
            t_ms = int(max(live.last_frame_t_s, 0.0) * 1000)
            self._send(proto.coverage_messages(due.named_value, due.statustext, t_ms))
            if due.statustext:
                log.info("%s", due.statustext)
        if self.notifier.watchdog_interval_s and now >= self._next_watchdog_s:
            self.notifier.watchdog()
            self._next_watchdog_s = now + self.notifier.watchdog_interval_s

    def _put(self, pub: SourcedPublisher, payload: bytes) -> None:
        try:
            pub.put(payload)
        except Exception as exc:  # noqa: BLE001 - no peer or a closing session: keep going
            self.live.counters.faults["zenoh_put_errors"] += 1
            log.debug("zenoh put failed: %s", exc)

    def link_description(self, now: float) -> dict[str, Any]:
        loop_now = asyncio.get_running_loop().time()
        links = [c.describe(loop_now) for c in self.links]
        states = [c.state for c in self.links]
        state = ("connected" if "connected" in states and self.protocol.autopilot_known
                 else "waiting" if "connected" in states or "waiting" in states
                 else states[0] if states else "none")
        ages = [d["last_message_age_s"] for d in links if d["last_message_age_s"] is not None]
        return {"state": state, "url": ", ".join(c.url for c in self.links),
                "last_message_age_s": min(ages) if ages else None,
                "bad_messages": self.live.counters.faults.get("bad_messages", 0),
                "links": links, **self.protocol.describe()}

    def _publish_status(self, now: float) -> None:
        live = self.live
        faults = live.counters.faults
        faults["reboots"] = self.protocol.reboots
        faults["link_losses"] = sum(c.losses for c in self.links)
        drops = sum(c.kernel_drops for c in self.links)
        if drops > faults.get("kernel_drops", 0) and now >= self._next_drops_warning_s:
            self._next_drops_warning_s = now + 60.0
            log.warning("MAVLink: the kernel dropped %d datagrams so far: the daemon did not "
                        "read them in time (overloaded?)", drops)
        faults["kernel_drops"] = drops
        faults["rejected_messages"] = sum(self.protocol.stats.rejected.values())
        faults["other_systems_messages"] = self.protocol.stats.other_systems
        faults["snapshot_queries_refused"] = sum(self._snapshot_limiter.refused.values())
        fields = live.status_fields(uptime_s=round(now - self.started_s, 3),
                                    seq=self._status_seq, link=self.link_description(now),
                                    checkpoint=self._checkpoint_info)
        self._status_seq += 1
        self._put(self.pub_status, self._status_encoder.encode(fields))
        share = live.share_at_target()
        self.notifier.status(f"coverage {share:.1%} at P_D>={live.target_pd:g}, "
                             f"{live.counters.used} frames, link {fields['link']['state']}")

    def _checkpoint(self) -> None:
        live = self.live
        offset, boot = self.protocol.clock_state()
        meta = {"mission_hash": self.mission_hash,
                "vehicle_id": self.cfg.mission.vehicle_id, "t0_s": live.t0_s,
                "last_frame_t_s": live.last_frame_t_s if math.isfinite(live.last_frame_t_s)
                else None,
                "clock": [offset, boot] if math.isfinite(boot) else None,
                "tiles_seq": live.tiles_seq - 1, "frames_used": live.counters.used,
                "written_unix_s": time.time()}
        try:
            write_checkpoint(self.state_dir / CHECKPOINT_NAME, live.grid, meta)
        except (OSError, PdcovError) as exc:  # atomic_write: OutputError (disk full, ...)
            live.counters.faults["checkpoint_errors"] += 1
            if self._checkpoint_info.get("error") is None:
                log.error("checkpoint not written (computing and publishing go on; "
                          "retrying every %g s): %s", self.cfg.service.checkpoint_period_s,
                          exc)
            self._checkpoint_info["error"] = str(exc)
            return
        if self._checkpoint_info.get("error") is not None:
            log.warning("checkpoint written again after: %s", self._checkpoint_info["error"])
        live.checkpointed()
        self._checkpoint_info.update(last_t_s=meta["last_frame_t_s"], error=None,
                                     written_unix_s=meta["written_unix_s"],
                                     frames=live.grid.frames)

    def _shutdown(self) -> None:
        try:
            self.live.process()
            self._checkpoint()
        except Exception as exc:  # noqa: BLE001 - still close everything below
            log.error("final checkpoint failed: %s", exc)
        for c in self.links:
            c.close()
        if self.recorder is not None:
            self.recorder.close()
        for e in reversed(self._zenoh_entities):
            try:
                e.undeclare()
            except Exception:  # noqa: BLE001
                pass
        if self.session is not None:
            self.session.close()
        self.notifier.close()
