"""MAVLink telemetry logs (.tlog) -> ``FlightLog``, stamped as the daemon stamped them live.

Times: time_boot_ms of the followed autopilot (s, monotonic across restarts); the other
components' samples are mapped onto that clock by ``clocks.VehicleClock`` as on the link;
the tlog's own wall-clock stamps are never used. Frames the daemon recorded
(``recorded_frames``) become the capture events.
"""

from __future__ import annotations

import math
from array import array
from collections import defaultdict
from dataclasses import dataclass, field, replace
from pathlib import Path

from pdcov.core.detections import Box
from pdcov.errors import TelemetryError
from pdcov.telemetry.adapters import mavlink_boot_time_s, sample_from_mavlink
from pdcov.telemetry.clocks import COMPONENT_CLOCK_WINDOW_S, BootClock, VehicleClock
from pdcov.telemetry.frame_policy import AUTOPILOT_ONLY, AttitudeSource
from pdcov.telemetry.logs.choose import choose_gimbal, choose_system
from pdcov.telemetry.logs.flight_log import FlightLog, estimator_series, restart_note, shifted
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
from pdcov.telemetry.samples import (
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
)
from pdcov.telemetry.series import (
    AttitudeSeries,
    GnssAccuracySeries,
    MountTargetSeries,
    PositionSeries,
)
from pdcov.telemetry.tlog import TlogScanner


@dataclass(slots=True)
class _Component:
    """Per (system, component): its own boot clock, its samples (stamped in that clock) and
    for each sample the index of its message in the log (``_Messages``)."""

    clock: BootClock = field(default_factory=BootClock)
    samples: dict[str, list] = field(default_factory=lambda: defaultdict(list))
    message_index: dict[str, list[int]] = field(default_factory=lambda: defaultdict(list))


@dataclass(slots=True)
class _Messages:
    """Every message's source (system * 256 + component) and boot time (s, NaN for none),
    in log order: what ``clocks.VehicleClock`` needs, once the autopilot is known, to stamp
    other components' samples exactly as the daemon did on arrival."""

    source: array = field(default_factory=lambda: array("l"))
    boot_s: array = field(default_factory=lambda: array("d"))

    def autopilot_times(self, system_id: int, autopilot_component: int,
                        wanted: set[int], read_off: frozenset[int] = frozenset()
                        ) -> dict[int, float]:
        """{message index: time in the autopilot clock (s)} for the ``wanted`` messages of
        ``system_id``, every message of that system fed to one VehicleClock in order; the
        ``read_off`` messages (frames the daemon recorded) carry a time read off the
        autopilot's boot clock and are placed without feeding the clock
        (VehicleClock.autopilot_boot_s, which LinkProtocol.autopilot_boot_s calls live)."""
        clock = VehicleClock(autopilot_component)
        out: dict[int, float] = {}
        last = max(wanted, default=-1)
        for i, (src, boot) in enumerate(zip(self.source, self.boot_s, strict=True)):
            if i > last:
                break
            if src >> 8 != system_id:
                continue
            if i in read_off:
                out[i] = clock.autopilot_boot_s(boot)
                continue
            t = clock.time_s(src & 0xFF, None if math.isnan(boot) else boot)
            if i in wanted:
                out[i] = t
        return out




def read_tlog(path: Path, system_id: int | None, gimbal_instance: int) -> FlightLog:
    comps: dict[tuple[int, int], _Component] = defaultdict(_Component)
    heartbeats: list[HeartbeatSample] = []
    messages = _Messages()
    recorded: dict[int, tuple[int, int]] = {}  # message index -> (system, image_index)
    last_mark: dict[tuple[int, int], int] = {}  # (system, image_index) -> its latest MARK
    boxes: list[tuple[int, float, Box]] = []  # (its MARK's message index, t_boot_s, box)
    bad_boxes = 0
    not_taken = NotTakenCaptures()
    first_euler: dict[tuple[int, int], int] = {}  # (system, component) -> first ATTITUDE
    n_ok = 0
    try:
        scanner = TlogScanner(path.read_bytes())
    except OSError as exc:
        raise TelemetryError(f"{path}: cannot read log: {exc.strerror or exc}") from None
    for msg in scanner.messages():
        mtype = msg.get_type()
        n_ok += 1
        key = (msg.get_srcSystem(), msg.get_srcComponent())
        comp = comps[key]
        boot_s = mavlink_boot_time_s(msg)
        if mtype == "ATTITUDE":
            first_euler.setdefault(key, n_ok - 1)
        mark = recorded_mark(msg)  # the daemon's own (recorded_frames): no clock's message
        messages.source.append(-1 if mark in (NOT_TAKEN, BOX) else (key[0] << 8) | key[1])
        messages.boot_s.append(math.nan if boot_s is None else boot_s)
        if mark == MARK:  # placed below, once the autopilot is known
            recorded[n_ok - 1] = (key[0], int(msg.image_index))
            last_mark[recorded[n_ok - 1]] = n_ok - 1
            continue
        if mark == BOX:  # its frame's: the MARK of the same system and image_index before it
            box, frame = box_of(msg), last_mark.get((key[0], int(msg.image_index)))
            if box is None or frame is None:
                bad_boxes += 1
            else:
                boxes.append((frame, recorded_boot_s(msg.time_boot_ms), box))
            continue
        if mark == NOT_TAKEN:
            not_taken.mark(msg)
            continue
        # Stamped in the sender's own clock here; other components than the autopilot
        # are restamped below, once it is known.
        t_s = comp.clock.now_s if boot_s is None else comp.clock.to_s(boot_s)
        sample = sample_from_mavlink(msg, t_s)
        if isinstance(sample, HeartbeatSample):
            heartbeats.append(sample)
        elif sample is not None:
            kind = type(sample).__name__ + ("Q" if mtype == "ATTITUDE_QUATERNION" else "")
            comp.samples[kind].append(sample)
            comp.message_index[kind].append(n_ok - 1)
            if mtype == "CAMERA_IMAGE_CAPTURED":
                not_taken.capture(msg, n_ok - 1)
    if n_ok == 0:
        raise TelemetryError(f"{path}: no MAVLink messages found; not a .tlog, or corrupt")
    damage = scanner.damage.describe()
    notes = list(damage)
    sysid, ap_comp, why = choose_system(comps, heartbeats, system_id, path)
    notes.append(why)
    ap = comps[(sysid, ap_comp)]
    notes.append(f"clock: time_boot_ms of the autopilot ({sysid}, {ap_comp}); "
                 "the tlog's wall-clock stamps are not used")
    restarts = tuple(ap.clock.restarts_t_s)
    if restarts:
        notes.append(restart_note(len(restarts), "time_boot_ms"))
    if not_taken.dropped:
        for comp in comps.values():
            _drop_samples(comp, "CaptureSample", not_taken.dropped)
        notes.append(f"{len(not_taken.dropped)} capture events pdcov serve did not take "
                     f"(late: a later frame was decided; marked {NOT_TAKEN!r}) not used, "
                     "as live")

    # The autopilot's own samples are already in its clock (a BootClock, as VehicleClock
    # keeps it); the other components' are restamped by the rule the daemon applies.
    others = {c: comp for (s, c), comp in comps.items()
              if s == sysid and c != ap_comp and comp.samples}
    wanted = {i for comp in others.values() for idx in comp.message_index.values()
              for i in idx}
    read_off = frozenset(i for i, (s, _n) in recorded.items() if s == sysid)
    wanted |= read_off
    times = messages.autopilot_times(sysid, ap_comp, wanted, read_off) if wanted else {}
    for c, comp in sorted(others.items()):
        n_dropped = 0
        for kind, items in comp.samples.items():
            mapped = [replace(smp, t_s=times[i]) for smp, i in
                      zip(items, comp.message_index[kind], strict=True)]
            comp.samples[kind] = [smp for smp in mapped if math.isfinite(smp.t_s)]
            n_dropped += len(mapped) - len(comp.samples[kind])
        notes.append(f"component {c}'s own clock mapped onto the autopilot's (clocks."
                     f"ComponentClock: largest apparent offset over "
                     f"{COMPONENT_CLOCK_WINDOW_S:g} s)"
                     + (f"; {n_dropped} of its samples before the first autopilot time not "
                        "used" if n_dropped else ""))

    def taken(kind: type) -> list:
        """The samples of ``kind`` the daemon takes too: the autopilot component's own for
        the frame_policy.AUTOPILOT_ONLY kinds, those of any component of the system else."""
        if kind in AUTOPILOT_ONLY:
            return list(ap.samples.get(kind.__name__, []))
        out = []
        for (s, _c), comp in comps.items():
            if s == sysid:
                out.extend(comp.samples.get(kind.__name__, []))
        return out

    attitude = _attitude_as_live(ap, first_euler.get((sysid, ap_comp)))
    gimbals = taken(GimbalSample)
    gimbal, source, gnote = choose_gimbal(gimbals, ap_comp, gimbal_instance)
    if gnote:
        notes.append(gnote)
    params = {p.name: p.value for p in taken(ParamSample)}
    captures = taken(CaptureSample)
    frame_boxes: list[RecordedBox] = []
    if read_off:
        notes.append(_recorded_frames_note(len(read_off), len(captures)))
        captures = [CaptureSample(times[i], recorded[i][1], RECORDED_SOURCE)
                    for i in sorted(read_off)]
        frame_boxes = [RecordedBox(times[i], t_boot_s, box) for i, t_boot_s, box in boxes
                       if i in read_off]
    if bad_boxes:
        notes.append(f"{bad_boxes} recorded boxes ({BOX!r}) unreadable or without their "
                     "frame: not used")
    return shifted(FlightLog(
        str(path), "tlog", sysid, AttitudeSeries.from_samples(attitude),
        PositionSeries.from_samples(taken(PositionSample)), gimbal, source,
        tuple(taken(HomeSample)), tuple(sorted(captures, key=lambda c: c.t_s)),
        params, MountTargetSeries.from_samples([]), restarts, tuple(notes), tuple(damage),
        *estimator_series(taken(EstimatorSample), "EKF_STATUS_REPORT / "
                          "ESTIMATOR_STATUS"),
        tuple(taken(TerrainReportSample)), tuple(taken(RangefinderSample)),
        tuple(frame_boxes), tuple(sorted(taken(LensSample), key=lambda s: s.t_s)),
        GnssAccuracySeries.from_samples(taken(GnssAccuracySample))),
        -ap.clock.offset_s)


def _attitude_as_live(ap: _Component, first_euler: int | None) -> list:
    """The autopilot's attitude samples by frame_policy.AttitudeSource, the rule
    LinkProtocol.receive applies on the link: its messages fed in log order, its first
    ATTITUDE message (index ``first_euler`` in the log, None: none) included even when it
    gave no sample (the link sees that message too); of equal times the later message
    wins (the series keeps log order)."""
    events = [(i, 1, "ATTITUDE_QUATERNION", smp) for i, smp in zip(
        ap.message_index.get("AttitudeSampleQ", []), ap.samples.get("AttitudeSampleQ", []),
        strict=True)]
    events += [(i, 1, "ATTITUDE", smp) for i, smp in zip(
        ap.message_index.get("AttitudeSample", []), ap.samples.get("AttitudeSample", []),
        strict=True)]
    if first_euler is not None:
        events.append((first_euler, 0, "ATTITUDE", None))
    rule = AttitudeSource()
    return [smp for _i, _k, mtype, smp in sorted(events, key=lambda e: (e[0], e[1]))
            if rule.takes(mtype) and smp is not None]



def _drop_samples(comp: _Component, kind: str, indices: set[int]) -> None:
    """Remove ``comp``'s samples of ``kind`` whose message index is in ``indices``."""
    idx = comp.message_index.get(kind)
    if not idx:
        return
    keep = [j for j, i in enumerate(idx) if i not in indices]
    comp.samples[kind] = [comp.samples[kind][j] for j in keep]
    comp.message_index[kind] = [idx[j] for j in keep]


def _recorded_frames_note(n_recorded: int, n_camera: int) -> str:
    """The summary line of a daemon recording whose frames came from its detector: the
    capture events are those frames (what the daemon used), never the camera's."""
    return (f"frames: the log holds {n_recorded} frame times pdcov serve took from its "
            f"detector (CAMERA_IMAGE_CAPTURED of component {RECORDED_FRAME_COMPONENT} marked "
            f"{MARK!r}, time_boot_ms in the autopilot's clock): its capture events, "
            "evaluated as the daemon did unless frame source 'rate' is chosen"
            + (f", not the camera's {n_camera} capture events" if n_camera else ""))
