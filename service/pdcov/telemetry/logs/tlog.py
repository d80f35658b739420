"""MAVLink telemetry logs (.tlog) -> ``FlightLog``, replayed through the daemon's protocol.

Every message goes, in log order, through a ``LinkProtocol`` (telemetry/link_protocol.py,
the object the daemon follows its link with: which autopilot, its clock and the other
components' mapped onto it, the attitude source, the autopilot-only samples) and the
``SampleGate`` (telemetry/sample_gate.py: what the daemon counts as bad samples, counted in
``FlightLog.faults``), so that a log gives the samples the link gave. One protocol per
system: the one followed is chosen at the end (logs/choose.py). The tlog's own wall-clock
stamps are never used. Frames the daemon recorded (``recorded_frames``) become the capture
events, at the times it took them.
"""

from __future__ import annotations

import math
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from pdcov.bus.faults import Fault
from pdcov.core.detections import Box
from pdcov.errors import TelemetryError
from pdcov.telemetry.adapters import mavlink_boot_time_s
from pdcov.telemetry.clocks import COMPONENT_CLOCK_WINDOW_S
from pdcov.telemetry.link_protocol import LinkProtocol
from pdcov.telemetry.logs.choose import choose_gimbal, choose_system
from pdcov.telemetry.logs.flight_log import (
    FlightLog,
    armed_changes,
    estimator_series,
    restart_note,
    shifted,
)
from pdcov.telemetry.recorded_frames import (
    BOX,
    MARK,
    NOT_TAKEN,
    RECORDED_FRAME_COMPONENT,
    NotTakenCaptures,
    RecordedBox,
    box_of,
    recorded_mark,
)
from pdcov.telemetry.recorded_frames import SOURCE as RECORDED_SOURCE
from pdcov.telemetry.recorded_frames import boot_s as recorded_boot_s
from pdcov.telemetry.sample_gate import SampleGate
from pdcov.telemetry.samples import (
    AttitudeSample,
    CaptureSample,
    EstimatorSample,
    GimbalSample,
    GnssAccuracySample,
    HeartbeatSample,
    HomeSample,
    LensSample,
    ParamSample,
    PositionSample,
    RangefinderSample,
    TerrainReportSample,
    UtcSample,
)
from pdcov.telemetry.series import (
    AttitudeSeries,
    GnssAccuracySeries,
    MountTargetSeries,
    PositionSeries,
)
from pdcov.telemetry.tlog import TlogScanner


@dataclass(slots=True)
class _Vehicle:
    """One system of the log, its messages replayed through a LinkProtocol of its own (as a
    daemon following that system) and the sample gate; its samples by type in log order, the
    message index of each capture event, per component the samples and those without a time
    in the autopilot clock, and its attitude messages (for choosing the system)."""

    protocol: LinkProtocol
    faults: Counter = field(default_factory=Counter)
    gate: SampleGate = field(init=False)
    samples: dict[type, list] = field(default_factory=lambda: defaultdict(list))
    capture_index: list[int] = field(default_factory=list)
    component_samples: Counter = field(default_factory=Counter)
    component_untimed: Counter = field(default_factory=Counter)
    attitudes: int = 0

    def __post_init__(self) -> None:
        self.gate = SampleGate(self.faults)

    @classmethod
    def following(cls, system_id: int, autopilot_component: int | None = None) -> _Vehicle:
        """A vehicle whose autopilot is known from its HEARTBEAT (None), or named."""
        protocol = LinkProtocol(mavlink.MAVLink(None), system_id=system_id, intervals={},
                                param_names=(), param_timeout_s=0.0)
        if autopilot_component is not None:
            protocol.follow(system_id, autopilot_component)
        return cls(protocol)

    def receive(self, msg: Any, index: int) -> None:
        """``msg``, the log's message ``index``, through the protocol and the gate."""
        comp = msg.get_srcComponent()
        for smp in self.protocol.receive(msg, 0.0):
            self.component_samples[comp] += 1
            if not math.isfinite(smp.t_s):
                self.component_untimed[comp] += 1
            kind = type(smp)
            # A home refused stays in the log: the terrain check takes every sample before
            # the gate, live too (a home needs no autopilot time). So does a parameter: the
            # daemon's LinkProtocol keeps every PARAM_VALUE it reads, timed or not (one read
            # before the autopilot's first timed message is counted untimed, and used).
            if not self.gate.admit(smp) and kind not in (HomeSample, ParamSample):
                continue
            self.samples[kind].append(smp)
            if kind is CaptureSample:
                self.capture_index.append(index)


@dataclass(slots=True)
class _Replay:
    """A log's messages through a ``_Vehicle`` per system (``only``: that system's alone),
    with the frames, boxes and not-taken marks the daemon recorded."""

    only: int | None = None
    named: int | None = None  # the autopilot component, when ``only`` is followed unheard
    vehicles: dict[int, _Vehicle] = field(default_factory=dict)
    messages: Counter = field(default_factory=Counter)  # system -> messages
    recorded: dict[int, tuple[int, int, float]] = field(default_factory=dict)
    boxes: list[tuple[int, float, Box]] = field(default_factory=list)
    bad_boxes: int = 0
    not_taken: NotTakenCaptures = field(default_factory=NotTakenCaptures)

    def vehicle(self, system_id: int) -> _Vehicle:
        v = self.vehicles.get(system_id)
        if v is None:
            v = self.vehicles[system_id] = _Vehicle.following(system_id, self.named)
        return v

    def run(self, scanner: TlogScanner) -> int:
        """Replay every message; returns how many were read."""
        last_mark: dict[tuple[int, int], int] = {}  # (system, image_index) -> latest MARK
        n = 0
        for n, msg in enumerate(scanner.messages(), 1):
            sysid = msg.get_srcSystem()
            self.messages[sysid] += 1
            if self.only is not None and sysid != self.only:
                continue
            mark = recorded_mark(msg)  # the daemon's own (recorded_frames): not the link's
            if mark == MARK:  # its time read off the autopilot's boot clock, as live
                boot_s = mavlink_boot_time_s(msg)
                t_s = self.vehicle(sysid).protocol.autopilot_boot_s(
                    math.nan if boot_s is None else boot_s)
                self.recorded[n - 1] = (sysid, int(msg.image_index), t_s)
                last_mark[(sysid, int(msg.image_index))] = n - 1
            elif mark == BOX:  # its frame's: the MARK of the same system and image_index
                box, frame = box_of(msg), last_mark.get((sysid, int(msg.image_index)))
                if box is None or frame is None:
                    self.bad_boxes += 1
                else:
                    self.boxes.append((frame, recorded_boot_s(msg.time_boot_ms), box))
            elif mark == NOT_TAKEN:
                self.not_taken.mark(msg)
            else:
                v = self.vehicle(sysid)
                if msg.get_type() in ("ATTITUDE", "ATTITUDE_QUATERNION"):
                    v.attitudes += 1
                elif msg.get_type() == "CAMERA_IMAGE_CAPTURED":
                    self.not_taken.capture(msg, n - 1)
                v.receive(msg, n - 1)
        return n


def _scanner(path: Path) -> TlogScanner:
    try:
        return TlogScanner(path.read_bytes())
    except OSError as exc:
        raise TelemetryError(f"{path}: cannot read log: {exc.strerror or exc}") from None


def read_tlog(path: Path, system_id: int | None, gimbal_instance: int) -> FlightLog:
    scanner = _scanner(path)
    replay = _Replay(only=system_id)
    if replay.run(scanner) == 0:
        raise TelemetryError(f"{path}: no MAVLink messages found; not a .tlog, or corrupt")
    damage = scanner.damage.describe()
    notes = list(damage)
    autopilots = {s: v.protocol.autopilot_component for s, v in replay.vehicles.items()
                  if v.protocol.autopilot_component is not None}
    sysid, ap_comp, why = choose_system(
        autopilots, Counter({s: v.attitudes for s, v in replay.vehicles.items()}),
        sorted(replay.messages), system_id, path)
    notes.append(why)
    if sysid not in autopilots:  # no HEARTBEAT of its autopilot: followed as named
        replay = _Replay(only=sysid, named=ap_comp)
        replay.run(_scanner(path))
    v = replay.vehicles[sysid]
    proto = v.protocol
    notes.append(f"clock: time_boot_ms of the autopilot ({sysid}, {ap_comp}); "
                 "the tlog's wall-clock stamps are not used")
    restarts = proto.restarts_t_s
    if restarts:
        notes.append(restart_note(len(restarts), "time_boot_ms"))
    captures = v.samples[CaptureSample]
    if replay.not_taken.dropped:
        captures = [c for c, i in zip(captures, v.capture_index, strict=True)
                    if i not in replay.not_taken.dropped]
        notes.append(f"{len(replay.not_taken.dropped)} capture events pdcov serve did not "
                     f"take (late: a later frame was decided; marked {NOT_TAKEN!r}) not used, "
                     "as live")
    for c in sorted(v.component_samples):
        if c == ap_comp:
            continue
        n_dropped = v.component_untimed[c]
        notes.append(f"component {c}'s own clock mapped onto the autopilot's (clocks."
                     f"ComponentClock: largest apparent offset over "
                     f"{COMPONENT_CLOCK_WINDOW_S:g} s)"
                     + (f"; {n_dropped} of its samples before the first autopilot time not "
                        "used" if n_dropped else ""))
    gimbal, source, gnote = choose_gimbal(v.samples[GimbalSample], ap_comp, gimbal_instance)
    if gnote:
        notes.append(gnote)
    read_off = {i: (t_s, image) for i, (s, image, t_s) in replay.recorded.items()
                if s == sysid}
    frame_boxes: list[RecordedBox] = []
    if read_off:
        notes.append(_recorded_frames_note(len(read_off), len(captures)))
        captures = [CaptureSample(read_off[i][0], read_off[i][1], RECORDED_SOURCE)
                    for i in sorted(read_off)]
        frame_boxes = [RecordedBox(read_off[i][0], t_boot_s, box)
                       for i, t_boot_s, box in replay.boxes if i in read_off]
    if replay.bad_boxes:
        notes.append(f"{replay.bad_boxes} recorded boxes ({BOX!r}) unreadable or without "
                     "their frame: not used")
    faults = Counter(v.faults)
    faults[Fault.REJECTED_MESSAGES] = sum(proto.stats.rejected.values())
    faults[Fault.OTHER_SYSTEMS_MESSAGES] = sum(replay.messages.values()) - replay.messages[sysid]
    smp = v.samples
    return shifted(FlightLog(
        str(path), "tlog", sysid, AttitudeSeries.from_samples(smp[AttitudeSample]),
        PositionSeries.from_samples(smp[PositionSample]), gimbal, source,
        tuple(smp[HomeSample]), tuple(sorted(captures, key=lambda c: c.t_s)),
        {p.name: p.value for p in smp[ParamSample]}, MountTargetSeries.from_samples([]),
        restarts, tuple(notes), tuple(damage),
        *estimator_series(smp[EstimatorSample], "EKF_STATUS_REPORT / ESTIMATOR_STATUS"),
        tuple(smp[TerrainReportSample]), tuple(smp[RangefinderSample]),
        tuple(frame_boxes), tuple(sorted(smp[LensSample], key=lambda s: s.t_s)),
        GnssAccuracySeries.from_samples(smp[GnssAccuracySample]),
        {k: n for k, n in sorted(faults.items()) if n}, tuple(v.samples[GimbalSample]),
        ap_comp, armed_changes((h.t_s, h.armed) for h in smp[HeartbeatSample]),
        tuple(smp[UtcSample])),
        -proto.clock_state()[0])


def _recorded_frames_note(n_recorded: int, n_camera: int) -> str:
    """The summary line of a daemon recording whose frames came from its detector: the
    capture events are those frames (what the daemon used), never the camera's."""
    return (f"frames: the log holds {n_recorded} frame times pdcov serve took from its "
            f"detector (CAMERA_IMAGE_CAPTURED of component {RECORDED_FRAME_COMPONENT} marked "
            f"{MARK!r}, time_boot_ms in the autopilot's clock): its capture events, "
            "evaluated as the daemon did unless frame source 'rate' is chosen"
            + (f", not the camera's {n_camera} capture events" if n_camera else ""))
