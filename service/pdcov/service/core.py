"""Everything ``pdcov serve`` decides, in one object with no I/O (the aioquic / h11 shape).

``ServiceCore`` is fed events and the time: MAVLink messages as parsed
(``receive_mavlink``), a detector's frames payloads (``receive_frames``), the end of a loop
pass (``process``), the timer (``tick``) and the outcome of what the shell did
(``checkpoint_written``, ``journal_written``, ``put_failed``, ``snapshot_sent``) and
snapshot queries (``admit_snapshot``). It never reads a clock, a socket or a file:
``now_s`` is the shell's one monotonic clock (s), and the only wall-clock time it sees is a
value the shell passes for the checkpoint's ``written_unix_s``. What to do comes out of
``actions()`` (messages to send on every link, bytes to record, tiles to publish, whether a
status is due, a checkpoint to write, lines to log); ``status(now_s, report)`` builds the
status once the shell has flushed its recording; ``get_timer()`` says when ``tick`` is next
needed. The shell (daemon.py) does the I/O; tests and benchmarks drive this object directly
(tests/support/link_feed.py).

What it decides, delegating to the decision classes beside it: the MAVLink conversation
(``LinkProtocol``: which autopilot, what intervals and parameters to ask for), the frames
and the grid (``LiveCoverage``), and here: detector frames held until the autopilot is
known (at most EARLY_FRAMES, oldest dropped; their boxes at most MAX_HELD_BOXES) and those
beyond a recordable time refused; the boxes of the frames taken recorded after them;
a capture event that came too late to be taken (its not-taken mark in the recording);
the checkpoint's metadata and error state; the candidates across restarts (restored at
start, a journal line before each detections message, the journal emptied after each
checkpoint: service/candidate_store.py); the kernel-drop warning's rate limit; the
link's state in the status; which snapshot queries are answered (query_limit).
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from pdcov.bus.errors import BusPayloadError
from pdcov.bus.faults import Fault, FaultFamily
from pdcov.bus.frames import decode_frames
from pdcov.bus.keys import VehicleKeys
from pdcov.core.detections import Box
from pdcov.core.grid import CoverageGrid
from pdcov.ids import candidate_uid_prefix, new_epoch
from pdcov.service import candidate_store, frame_admission
from pdcov.service.actions import Actions
from pdcov.service.candidate_store import MAX_JOURNAL_BYTES, Restored
from pdcov.service.checkpoint_meta import (
    CheckpointContents,
    CheckpointMeta,
    CheckpointState,
    finite_or_none,
)
from pdcov.service.coverage import LiveCoverage
from pdcov.service.detections import MAX_HELD_BOXES
from pdcov.service.link_setup import LinkReport, link_requests, link_state
from pdcov.service.query_limit import QueryLimiter
from pdcov.service.retask import Retasker, RetaskPolicy
from pdcov.service.retask_auth import NonceBook, RetaskAuthority
from pdcov.telemetry.frame_policy import FrameSource
from pdcov.telemetry.link_protocol import LinkProtocol
from pdcov.telemetry.recorded_frames import MAX_BOOT_MS, FrameEncoder, boot_ms, boot_s
from pdcov.telemetry.samples import CaptureSample

if TYPE_CHECKING:  # a value handed in: the decisions never load a config or open the bus
    from pdcov.service.settings import ServeConfig

EARLY_FRAMES = 100_000
"""Detector frame times kept while the autopilot is not known yet (then the oldest go)."""
DROPS_WARNING_PERIOD_S = 60.0
"""The kernel-drop warning is logged at most once in this long (the count is always in the
status)."""


class ServiceCore:
    """The decisions of one ``pdcov serve`` (module docstring). ``grid``: a new grid
    (``Mission.new_mission_grid``), or the resumed one with its ``resumed`` metadata (and,
    with several cameras, each camera's resumed grid, ``camera_grids``); ``checkpoint``: the
    checkpoint's state to report (its path, whether it resumed or was set aside);
    ``now_s``: the shell's monotonic clock at start; ``nonces``: the re-tasking nonces seen
    before (read back from the state dir); ``epoch``: the state dir's token in every
    candidate uid (ids.valid_epoch; None: a fresh one, a run without a state dir)."""

    def __init__(self, cfg: ServeConfig, grid: CoverageGrid, now_s: float, *,
                 mission_hash: str, resumed: CheckpointMeta | None = None,
                 checkpoint: CheckpointState | None = None,
                 camera_grids: dict[str, CoverageGrid] | None = None,
                 nonces: NonceBook | None = None, epoch: str | None = None) -> None:
        m = cfg.mission
        self.cfg = cfg
        self.mission_hash = mission_hash
        self.keys = VehicleKeys(m.vehicle_id)
        self.started_s = now_s
        self.record = cfg.service.record
        intervals, names, complete = link_requests(cfg)
        self.protocol = LinkProtocol(mavlink.MAVLink(None, srcSystem=cfg.link.system_id or 1),
                                     system_id=cfg.link.system_id or m.system_id,
                                     intervals=intervals, param_names=names,
                                     param_timeout_s=cfg.link.param_timeout_s,
                                     estimator_hz=cfg.link.estimator_hz
                                     if m.estimator_status else None,
                                     params_complete=complete)
        self.coverage = LiveCoverage(
            cfg, grid, now_s, tiles_seq=resumed.tiles_seq + 1 if resumed is not None else 0,
            camera_grids=camera_grids,
            uid_prefix=candidate_uid_prefix(m.vehicle_id, epoch or new_epoch()))
        self._journal_seq = 0  # the last journal line decided
        self._journal_bytes = 0  # in the journal file now
        self._journal_error: str | None = None
        if resumed is not None:
            self._resume(resumed)
        self.checkpoint = checkpoint or CheckpointState(path="")
        self._frame_encoder = FrameEncoder()
        # Detector frames (boot ms, boxes) before a HEARTBEAT.
        self._early_frames: deque[tuple[int, tuple[Box, ...]]] = deque()
        self._early_boxes = 0  # boxes in _early_frames (at most MAX_HELD_BOXES)
        self._classes = frame_admission.known_classes(m.first_camera.detector)
        self._status_seq = 0
        self._next_drops_warning_s = -math.inf
        self._kernel_drops = 0
        self.snapshot_limiter = QueryLimiter()
        svc = cfg.service
        authority = RetaskAuthority(m.vehicle_id, {k.id: k for k in cfg.operator_keys},
                                    svc.retask_window_s) if cfg.operator_keys else None
        self.retasker = Retasker(m.vehicle_id, RetaskPolicy(
            svc.retask, authority, svc.retask_limits, m.domain.boundary), now_s, nonces)
        self.candidates_limiter = QueryLimiter()
        self._out = Actions()

    def _resume(self, meta: CheckpointMeta) -> None:
        live = self.coverage
        if meta.cameras is not None:
            live.resume_cameras(meta.cameras)
        elif meta.last_frame_t_s is not None:
            live.resume_lattice(meta.t0_s, meta.last_frame_t_s)
        if meta.clock_offset_s is not None and meta.clock_boot_s is not None:
            self.protocol.prime_clock(meta.clock_offset_s, meta.clock_boot_s)
        live.counters.used = meta.frames_used

    # --- events in ------------------------------------------------------------------------

    def receive_mavlink(self, msgs: Iterable[Any], now_s: float) -> None:
        """Messages as pymavlink parsed them from a link (BAD_DATA too: counted), in
        arrival order."""
        live, proto = self.coverage, self.protocol
        capture = live.frame_source == FrameSource.CAPTURE
        record = self.record
        for msg in msgs:
            samples = proto.receive(msg, now_s)
            mtype = msg.get_type()
            if mtype == "BAD_DATA":
                continue
            # The message's own capture event (the last sample), not taken: late.
            late = (capture and mtype == "CAMERA_IMAGE_CAPTURED" and bool(samples)
                    and isinstance(samples[-1], CaptureSample)
                    and live.is_late(samples[-1].t_s))
            for sample in samples:
                live.add_sample(sample)
            if proto.from_autopilot(msg):
                self._out.send += self.retasker.receive(msg, now_s, proto)
            if record:  # all of it: even what came before a HEARTBEAT
                self._out.record.append(msg.get_msgbuf())
                if late and proto.system_id is not None:  # recorded_frames: not taken
                    self._out.record.append(
                        self._frame_encoder.not_taken(proto.system_id, msg))

    def receive_frames(self, payload: bytes) -> None:
        """A detector's frames message (version 1 or 2): its times to the millisecond (what
        the recording keeps) and boxes, held until the autopilot is known (its system and
        clock). A message refused (bus.frames: a box outside the picture, NaN, a flood of
        boxes, another vehicle's) is counted by reason and logged."""
        faults = self.coverage.counters.faults
        camera = self.cfg.mission.first_camera.camera  # whose boxes the frames carry
        try:
            frames = decode_frames(payload, self.keys.frames,
                                   (camera.width_px, camera.height_px), self.keys.vehicle_id)
        except BusPayloadError as exc:
            faults[Fault.BAD_FRAMES_MESSAGES] += 1
            faults[FaultFamily.FRAMES_REFUSED.key(exc.reason)] += 1
            self._out.logs.append((logging.WARNING, str(exc)))
            return
        ms = []
        for f in frames:
            boxes, unknown = frame_admission.split_by_class(f.boxes, self._classes)
            if unknown:
                faults[frame_admission.FrameRefusal.UNKNOWN_CLASS.value] += unknown
            ms.append((boot_ms(f.t_boot_s), boxes))
        if any(v > MAX_BOOT_MS for v, _b in ms):
            faults[Fault.FRAMES_OUT_OF_RANGE] += sum(v > MAX_BOOT_MS for v, _b in ms)
            ms = [(v, b) for v, b in ms if v <= MAX_BOOT_MS]
        if not self._clock_known:
            for v, boxes in ms:
                if len(self._early_frames) >= EARLY_FRAMES:
                    self._early_boxes -= len(self._early_frames.popleft()[1])
                    faults[Fault.FRAMES_DROPPED_WAITING] += 1
                if self._early_boxes + len(boxes) > MAX_HELD_BOXES:
                    faults[Fault.BOXES_DROPPED_WAITING] += len(boxes)
                    boxes = ()
                self._early_boxes += len(boxes)
                self._early_frames.append((v, boxes))
            return
        self._take_frames(ms)

    @property
    def _clock_known(self) -> bool:
        """The autopilot and its clock are known: frame times can be placed and judged."""
        return self.protocol.autopilot_known and math.isfinite(self.protocol.clock_now_s)

    def _take_frames(self, frames: list[tuple[int, tuple[Box, ...]]]) -> None:
        """Give the grid the frames (autopilot boot ms, boxes) and record, in the order
        taken, those it took and their boxes (recorded_frames: ``pdcov evaluate`` of the
        recording uses them); the boxes of a frame not taken (a duplicate, or late) are
        counted."""
        proto, live = self.protocol, self.coverage
        t_s: dict[float, tuple[int, tuple[Box, ...]]] = {}
        faults, history_s = live.counters.faults, live.first.history_s
        for v, boxes in frames:
            t = proto.autopilot_boot_s(boot_s(v))
            refusal = frame_admission.refusal_of_time(t, proto.clock_now_s, history_s)
            if refusal is not None:  # frame_admission: outside the clock's window
                faults[refusal.value] += 1
                faults[Fault.BOXES_OF_FRAMES_NOT_TAKEN] += len(boxes)
            elif t in t_s:  # a duplicate within the message: the first is the one taken
                live.counters.faults[Fault.BOXES_OF_FRAMES_NOT_TAKEN] += len(boxes)
            else:
                t_s[t] = (v, boxes)
        taken = live.add_frame_times(list(t_s))
        not_taken = sum(len(t_s[t][1]) for t in set(t_s) - set(taken))
        if not_taken:
            live.counters.faults[Fault.BOXES_OF_FRAMES_NOT_TAKEN] += not_taken
        record = self.record and proto.system_id is not None
        for t in taken:
            v, boxes = t_s[t]
            live.detections.hold(t, boot_s(v), boxes)
            if record and proto.system_id is not None:
                enc = self._frame_encoder
                self._out.record.append(enc.encode(proto.system_id, v))
                self._out.record += [enc.box(proto.system_id, v, b) for b in boxes]

    def process(self) -> None:
        """Decide what the messages and frames received so far allow (once per loop pass,
        after every readable link)."""
        proto = self.protocol
        if self._early_frames and self._clock_known:
            early, self._early_frames = list(self._early_frames), deque()
            self._early_boxes = 0
            self._take_frames(early)
        self.coverage.set_params(proto.params, proto.params_done)
        self.coverage.process()

    def tick(self, now_s: float, unix_s: float) -> None:
        """The timer: what is due at ``now_s`` (monotonic s). ``unix_s``: the wall clock,
        written into a checkpoint's metadata only."""
        live, proto = self.coverage, self.protocol
        out = self._out
        out.send += proto.poll(now_s)
        out.send += self.retasker.poll(now_s, proto)
        live.set_params(proto.params, proto.params_done)  # a parameter read may time out
        live.process()
        due = live.poll(now_s)
        out.logs += [(logging.WARNING, note) for note in due.notes]
        if due.tiles is not None:
            out.tiles = due.tiles
        self._publish_detections(now_s)
        if due.status:
            out.status_due = True
        if due.checkpoint:
            out.checkpoint = self.checkpoint_meta(unix_s)
        if due.named_value is not None or due.statustext is not None:
            t_ms = int(max(live.last_frame_t_s, 0.0) * 1000)
            out.send += proto.coverage_messages(due.named_value, due.statustext, t_ms)
            if due.statustext:
                out.logs.append((logging.INFO, due.statustext))

    def _publish_detections(self, now_s: float, force: bool = False) -> None:
        """The detections messages due (``force``: all pending), after one journal line
        holding every candidate they carry."""
        live = self.coverage
        pubs = []
        while (p := live.detections.poll(now_s, live.origin, force)) is not None:
            pubs.append(p)
            if not force:
                break
        if not pubs:
            return
        ids = {i for p in pubs for i in p.candidate_ids}
        line = candidate_store.journal_line(live.detections.tracker, ids,
                                            self._journal_seq + 1, self.mission_hash)
        if self._journal_bytes + len(line) > MAX_JOURNAL_BYTES:
            self.journal_written(f"the journal would exceed {MAX_JOURNAL_BYTES} bytes "
                                 "(no checkpoint emptied it)")
        else:
            self._journal_seq += 1
            self._journal_bytes += len(line)
            self._out.journal = (self._out.journal or b"") + line
        self._out.detections += [p.payload for p in pubs]

    def stop(self, now_s: float) -> None:
        """A clean stop: decide what the messages received allow, and publish every pending
        detection now (whatever DETECTIONS_PERIOD_S says). Frames the telemetry has not
        reached yet stay undecided: their boxes are not published."""
        self.process()
        self._publish_detections(now_s, force=True)

    def restore_candidates(self, *, resumed: bool, checkpoint: Any,
                           checkpoint_error: str | None, journal: bytes | None,
                           journal_path: str) -> Restored:
        """At start: the candidates from the resumed checkpoint's member and the journal's
        bytes (candidate_store.restore); the shell then keeps the journal's first
        ``keep_bytes`` or sets it aside, and logs ``logs``."""
        r = candidate_store.restore(
            self.coverage.detections.tracker, self.mission_hash, resumed=resumed,
            checkpoint=checkpoint, checkpoint_error=checkpoint_error,
            checkpoint_path=self.checkpoint.path, journal=journal, journal_path=journal_path)
        self.coverage.detections.restored()
        self._journal_seq = r.journal_seq
        self._journal_bytes = 0 if r.set_aside else r.keep_bytes
        self.checkpoint.candidates_restored = r.candidates
        self.checkpoint.candidates_from_journal = r.from_journal
        return r

    def candidates_checkpoint(self) -> dict[str, Any]:
        """The candidates' document for a checkpoint written now (every journal line)."""
        return candidate_store.checkpoint_doc(self.coverage.detections.tracker,
                                              self._journal_seq)

    def journal_written(self, error: str | None) -> None:
        """The shell appended the journal line (``error``: why not; counted, logged once
        until one is written again: the detections are published all the same)."""
        if error is None:
            if self._journal_error is not None:
                self._out.logs.append((logging.WARNING, "candidates journal written again "
                                       f"after: {self._journal_error}"))
            self._journal_error = None
            return
        self.coverage.counters.faults[Fault.CANDIDATES_JOURNAL_ERRORS] += 1
        if self._journal_error is None:
            self._out.logs.append((logging.ERROR, (
                f"candidates journal not written: {error}; the detections are published, "
                "but a kill before the next checkpoint loses their candidates")))
        self._journal_error = error

    def get_timer(self) -> float:
        """When ``tick`` is next needed (monotonic s): the next status, tiles, checkpoint,
        NAMED_VALUE_FLOAT, HEARTBEAT or request retry."""
        return min(self.coverage.next_timer_s(), self.protocol.next_timer_s(),
                   self.retasker.next_timer_s())

    def receive_retask(self, ticket: int, payload: bytes, key_expr: str,
                       session: str | None, now_s: float, unix_s: float) -> None:
        """A re-tasking query's payload on ``key_expr`` (the query's own) from Zenoh
        session ``session``, named ``ticket`` by the shell, at ``now_s`` (monotonic) and
        ``unix_s`` (UTC, for the request's time window): refused or uploaded
        (service/retask.py); its answer comes out in ``Actions.replies`` once known."""
        origin = self.coverage.origin or self.cfg.mission.origin()
        self._out.send += self.retasker.request(ticket, payload, key_expr, session, now_s,
                                                unix_s, self.protocol, origin)
        self._collect_retask()

    def _collect_retask(self) -> None:
        out, retasker = self._out, self.retasker
        out.replies += retasker.replies()
        out.logs += retasker.logs
        retasker.logs = []
        if retasker.nonces.changed:
            out.nonces = retasker.nonces.to_bytes()

    def admit_snapshot(self, requester: str | None, now_s: float) -> str | None:
        """Whether a snapshot query of ``requester`` (its Zenoh session) is answered at
        ``now_s``: None, or why not (over its rate or all replies' bytes/s: query_limit,
        counted in faults.snapshot_queries_refused). ``snapshot_sent`` then takes the reply's
        size."""
        limiter = self.snapshot_limiter
        refusal = limiter.admit(requester, now_s)
        return None if refusal is None else limiter.limits.reason(refusal)

    def snapshot_sent(self, n_bytes: int) -> None:
        self.snapshot_limiter.sent(n_bytes)

    def admit_candidates(self, requester: str | None, now_s: float) -> str | None:
        """Whether a candidates query is answered: as ``admit_snapshot``, with limits of its
        own (counted in faults.candidates_queries_refused); ``candidates_sent`` then takes
        the reply's size."""
        limiter = self.candidates_limiter
        refusal = limiter.admit(requester, now_s)
        return None if refusal is None else limiter.limits.reason(refusal)

    def candidates_sent(self, n_bytes: int) -> None:
        self.candidates_limiter.sent(n_bytes)

    def candidates_payload(self) -> bytes:
        """The candidates query's answer (bus.detections): every candidate now."""
        live = self.coverage
        return live.detections.candidates_payload(live.origin)

    def put_failed(self) -> None:
        """A Zenoh put failed (no peer, a closing session): counted."""
        self.coverage.counters.faults[Fault.ZENOH_PUT_ERRORS] += 1

    # --- actions out ----------------------------------------------------------------------

    def actions(self) -> Actions:
        """What to do since the last call (then forgotten)."""
        self._collect_retask()
        out, self._out = self._out, Actions()
        return out

    def link_description(self, report: LinkReport) -> dict[str, Any]:
        """The status's ``link`` object (docs/protocol.md)."""
        ages = [d["last_message_age_s"] for d in report.links
                if d.get("last_message_age_s") is not None]
        return {"state": str(link_state(report.states, self.protocol.autopilot_known)),
                "url": report.url, "last_message_age_s": min(ages) if ages else None,
                "bad_messages": self.protocol.stats.bad, "links": list(report.links),
                **self.protocol.describe()}

    def status(self, now_s: float, report: LinkReport) -> tuple[dict[str, Any], str]:
        """The status fields to publish (bus.status) and the one-line service status (for
        sd_notify), at ``now_s`` with what the shell's links say."""
        live, proto = self.coverage, self.protocol
        faults = live.counters.faults
        faults[Fault.REBOOTS] = proto.reboots
        if proto.stats.bad:
            faults[Fault.BAD_MESSAGES] = proto.stats.bad
        faults[Fault.LINK_LOSSES] = report.losses
        if report.parse_errors:
            faults[Fault.LINK_PARSE_ERRORS] = report.parse_errors
        drops = report.kernel_drops
        if drops > self._kernel_drops and now_s >= self._next_drops_warning_s:
            self._next_drops_warning_s = now_s + DROPS_WARNING_PERIOD_S
            self._out.logs.append((logging.WARNING, (
                f"MAVLink: the kernel dropped {drops} datagrams so far: the daemon did not "
                "read them in time (overloaded?)")))
        self._kernel_drops = faults[Fault.KERNEL_DROPS] = drops
        faults[Fault.REJECTED_MESSAGES] = sum(proto.stats.rejected.values())
        faults[Fault.OTHER_SYSTEMS_MESSAGES] = proto.stats.other_systems
        faults[Fault.SNAPSHOT_QUERIES_REFUSED] = sum(self.snapshot_limiter.refused.values())
        faults[Fault.RETASK_REFUSED] = sum(self.retasker.refused.values())
        for reason, n in self.retasker.refused.items():
            faults[FaultFamily.RETASK_REFUSED.key(reason)] = n
        if self.candidates_limiter.refused:
            faults[Fault.CANDIDATES_QUERIES_REFUSED] = sum(self.candidates_limiter.refused.values())
        self.checkpoint.recording_error = report.recording_error
        fields = live.status_fields(uptime_s=round(now_s - self.started_s, 3),
                                    seq=self._status_seq, link=self.link_description(report),
                                    checkpoint=self.checkpoint.describe())
        retask = self.retasker.describe()
        if retask is not None:  # only once a request came: other statuses are unchanged
            fields["retask"] = retask
        self._status_seq += 1
        share = live.share_at_target()
        line = (f"coverage {share:.1%} at P_D>={live.target_pd:g}, {live.counters.used} "
                f"frames, link {fields['link']['state']}")
        return fields, line

    # --- checkpoints ----------------------------------------------------------------------

    def checkpoint_meta(self, unix_s: float) -> CheckpointMeta:
        """The metadata of a checkpoint of the grid as it is now, the shell copying the
        grid now."""
        live = self.coverage
        offset, boot = self.protocol.clock_state()
        known = math.isfinite(boot)
        return CheckpointMeta(
            mission_hash=self.mission_hash, vehicle_id=self.cfg.mission.vehicle_id,
            t0_s=live.t0_s, last_frame_t_s=finite_or_none(live.last_frame_t_s),
            clock_offset_s=offset if known else None, clock_boot_s=boot if known else None,
            tiles_seq=live.tiles_seq - 1, frames_used=live.counters.used,
            written_unix_s=unix_s, cameras=live.camera_resume())

    def checkpoint_contents(self) -> CheckpointContents:
        """What a checkpoint copied now holds: the shell keeps it with the write and hands
        it back to ``checkpoint_written`` (another may be decided meanwhile)."""
        return CheckpointContents(frames=self.coverage.grid.frames,
                                  journal_seq=self._journal_seq)

    def checkpoint_written(self, meta: CheckpointMeta, error: str | None,
                           contents: CheckpointContents) -> None:
        """The shell wrote the checkpoint ``meta`` holding ``contents``, or failed with
        ``error`` (computing and publishing go on; the next one is retried in a period)."""
        state, live = self.checkpoint, self.coverage
        if error is not None:
            live.counters.faults[Fault.CHECKPOINT_ERRORS] += 1
            if state.error is None:
                self._out.logs.append((logging.ERROR, (
                    "checkpoint not written (computing and publishing go on; retrying "
                    f"every {self.cfg.service.checkpoint_period_s:g} s): {error}")))
            state.error = error
            return
        if state.error is not None:
            self._out.logs.append((logging.WARNING,
                                   f"checkpoint written again after: {state.error}"))
        frames = contents.frames
        live.checkpointed(frames)
        # Lines decided while it was written are not in it: the journal is kept for them.
        if self._journal_bytes and self._journal_seq == contents.journal_seq:
            self._out.journal_reset, self._journal_bytes = True, 0
        state.last_t_s, state.error = meta.last_frame_t_s, None
        state.written_unix_s, state.frames = meta.written_unix_s, frames
