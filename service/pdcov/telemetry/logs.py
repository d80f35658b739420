"""Flight logs -> one ``FlightLog`` of time-sorted telemetry arrays in the autopilot clock.

Formats: MAVLink telemetry logs (.tlog: ``telemetry.tlog``), ArduPilot DataFlash (.bin:
pymavlink DFReader) and PX4 ULog (.ulg: pyulog, the optional ``ulog`` extra), told apart by
their first bytes. Times are the autopilot's boot clock (time_boot_ms, TimeUS, ULog
timestamps), made monotonic across restarts by ``telemetry.BootClock``; a tlog's wall-clock
stamps are never used (a log may have been recorded faster than real time). Every failure to
read becomes a ``TelemetryError`` that names the file; a damaged log is read up to and past
its damage, which ``FlightLog.damage`` describes.
"""

from __future__ import annotations

import math
import os
import struct
import sys
from array import array
from collections import Counter, defaultdict
from collections.abc import Iterator, Mapping
from contextlib import contextmanager, redirect_stderr, redirect_stdout
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from pdcov.errors import TelemetryError
from pdcov.telemetry.clocks import COMPONENT_CLOCK_WINDOW_S, VehicleClock
from pdcov.telemetry.frame_policy import AUTOPILOT_ONLY, AttitudeSource
from pdcov.telemetry.gimbal import preferred_gimbal_source
from pdcov.telemetry.recorded_frames import (
    MARK,
    NOT_TAKEN,
    RECORDED_FRAME_COMPONENT,
    NotTakenCaptures,
    recorded_mark,
)
from pdcov.telemetry.recorded_frames import SOURCE as RECORDED_SOURCE
from pdcov.telemetry.samples import (
    CONST_POS_MODE,
    DATAFLASH_TYPES,
    ESTIMATOR_GPS_GLITCH,
    MAV_AUTOPILOT_INVALID,
    POS_HORIZ_ABS,
    REBOOT_GAP_S,
    AttitudeSample,
    AttitudeSeries,
    BootClock,
    CaptureSample,
    EstimatorSample,
    EstimatorSeries,
    GimbalSample,
    GimbalSeries,
    HeartbeatSample,
    HomeSample,
    MountTargetSample,
    MountTargetSeries,
    ParamSample,
    PositionSample,
    PositionSeries,
    dataflash_boot_time_s,
    mavlink_boot_time_s,
    sample_from_mavlink,
    samples_from_dataflash,
)
from pdcov.telemetry.tlog import LogDamage, TlogScanner

DATAFLASH_MAGIC = b"\xa3\x95"
ULOG_MAGIC = b"ULog\x01\x12\x35"

_Series = TypeVar("_Series", AttitudeSeries, PositionSeries, GimbalSeries, MountTargetSeries,
                   EstimatorSeries)


@dataclass(frozen=True, slots=True)
class FlightLog:
    """What pdcov uses of one flight log, for one vehicle (``system_id``).

    All times are seconds in the autopilot's boot clock (monotonic across restarts). gimbal
    holds the chosen source (``gimbal_source`` = (system, component, gimbal_device_id)) only;
    homes are in log order; params hold each parameter's last value. notes say, in words,
    which clock, sources and fallbacks were used (for summaries); damage says what was
    skipped or cut while reading (also among the notes). estimator: the position
    estimator's verdicts (empty when the log carries none); estimator_source names the
    messages they came from.
    """

    path: str
    format: str
    system_id: int | None
    attitude: AttitudeSeries
    position: PositionSeries
    gimbal: GimbalSeries
    gimbal_source: tuple[int, int, int] | None
    homes: tuple[HomeSample, ...]
    captures: tuple[CaptureSample, ...]
    params: Mapping[str, float]
    mount_targets: MountTargetSeries
    restarts_t_s: tuple[float, ...] = ()
    notes: tuple[str, ...] = ()
    damage: tuple[str, ...] = ()
    estimator: EstimatorSeries = field(
        default_factory=lambda: EstimatorSeries.from_samples([]))
    estimator_source: str = ""


def read_flight_log(path: str | Path, *, system_id: int | None = None,
                    gimbal_instance: int = 1) -> FlightLog:
    """Read a .tlog, DataFlash .bin or .ulg file (format from its first bytes).

    system_id: the MAVLink system to follow (tlogs); None = the autopilot announced by
    HEARTBEAT. gimbal_instance: the gimbal to follow where several report (the mount's
    ``instance``, as the live tracker uses it). Raises TelemetryError naming the file when
    it cannot be read or holds no attitude or position.
    """
    path = Path(path)
    try:
        with path.open("rb") as f:
            head = f.read(4096)
    except OSError as exc:
        raise TelemetryError(f"{path}: cannot open log: {exc.strerror or exc}") from None
    if not head:
        raise TelemetryError(f"{path}: empty file, not a flight log")
    if head.startswith(ULOG_MAGIC):
        log = _read_ulog(path, gimbal_instance)
    elif head.startswith(DATAFLASH_MAGIC):
        log = _read_dataflash(path, gimbal_instance)
    elif b"FMT," in head and _mostly_text(head):
        raise TelemetryError(
            f"{path}: a text DataFlash log (.log); pdcov reads binary DataFlash (.bin), "
            "MAVLink .tlog and PX4 .ulg logs only. Use the .bin the autopilot wrote, or "
            "convert this one with a tool that understands its layout")
    else:
        log = _read_tlog(path, system_id, gimbal_instance)
    if len(log.attitude.t_s) == 0:
        raise TelemetryError(f"{path}: no attitude messages (ATTITUDE / ATT / "
                             f"vehicle_attitude) for the followed vehicle")
    if len(log.position.t_s) == 0:
        raise TelemetryError(f"{path}: no position messages (GLOBAL_POSITION_INT / POS / "
                             f"vehicle_global_position) with a valid fix")
    return log


def _mostly_text(head: bytes) -> bool:
    printable = sum(32 <= b < 127 or b in (9, 10, 13) for b in head)
    return printable > 0.95 * len(head)


# --- MAVLink telemetry logs -----------------------------------------------------------------

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


def _read_tlog(path: Path, system_id: int | None, gimbal_instance: int) -> FlightLog:
    comps: dict[tuple[int, int], _Component] = defaultdict(_Component)
    heartbeats: list[HeartbeatSample] = []
    messages = _Messages()
    recorded: dict[int, tuple[int, int]] = {}  # message index -> (system, image_index)
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
        messages.source.append(-1 if mark == NOT_TAKEN else (key[0] << 8) | key[1])
        messages.boot_s.append(math.nan if boot_s is None else boot_s)
        if mark == MARK:  # placed below, once the autopilot is known
            recorded[n_ok - 1] = (key[0], int(msg.image_index))
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
    sysid, ap_comp, why = _choose_system(comps, heartbeats, system_id, path)
    notes.append(why)
    ap = comps[(sysid, ap_comp)]
    notes.append(f"clock: time_boot_ms of the autopilot ({sysid}, {ap_comp}); "
                 "the tlog's wall-clock stamps are not used")
    restarts = tuple(ap.clock.restarts_t_s)
    if restarts:
        notes.append(_restart_note(len(restarts), "time_boot_ms"))
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
    gimbal, source, gnote = _choose_gimbal(gimbals, ap_comp, gimbal_instance)
    if gnote:
        notes.append(gnote)
    params = {p.name: p.value for p in taken(ParamSample)}
    captures = taken(CaptureSample)
    if read_off:
        notes.append(_recorded_frames_note(len(read_off), len(captures)))
        captures = [CaptureSample(times[i], recorded[i][1], RECORDED_SOURCE)
                    for i in sorted(read_off)]
    return _shifted(FlightLog(
        str(path), "tlog", sysid, AttitudeSeries.from_samples(attitude),
        PositionSeries.from_samples(taken(PositionSample)), gimbal, source,
        tuple(taken(HomeSample)), tuple(sorted(captures, key=lambda c: c.t_s)),
        params, MountTargetSeries.from_samples([]), restarts, tuple(notes), tuple(damage),
        *_estimator(taken(EstimatorSample), "EKF_STATUS_REPORT / "
                    "ESTIMATOR_STATUS")), -ap.clock.offset_s)


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


def _estimator(samples: list[EstimatorSample], source: str) -> tuple[EstimatorSeries, str]:
    series = EstimatorSeries.from_samples(samples)
    return series, source if len(series.t_s) else ""


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


def _restart_note(n: int, field_name: str) -> str:
    return (f"{field_name} restarted {n}x (autopilot reboot): t_s is the last boot's own time; "
            f"earlier boots are placed before it with a {REBOOT_GAP_S:.0f} s gap, so no frame "
            "interpolates across a reboot")


def _shifted(log: FlightLog, dt_s: float) -> FlightLog:
    """The same log with every time moved by ``dt_s`` seconds."""
    if dt_s == 0.0:
        return log

    def series(x: _Series) -> _Series:
        return replace(x, t_s=x.t_s + dt_s)

    return replace(log, attitude=series(log.attitude), position=series(log.position),
                   gimbal=series(log.gimbal), mount_targets=series(log.mount_targets),
                   estimator=series(log.estimator),
                   homes=tuple(replace(h, t_s=h.t_s + dt_s) for h in log.homes),
                   captures=tuple(replace(c, t_s=c.t_s + dt_s) for c in log.captures),
                   restarts_t_s=tuple(t + dt_s for t in log.restarts_t_s))


def _choose_system(comps: Mapping[tuple[int, int], _Component],
                   heartbeats: list[HeartbeatSample], system_id: int | None,
                   path: Path) -> tuple[int, int, str]:
    """(system, autopilot component, note): the configured system, else the one whose
    HEARTBEAT names a real autopilot (MAV_AUTOPILOT != INVALID), else the one sending the
    most attitudes; ties and alternatives are named in the note."""
    autopilots: dict[int, int] = {}
    for hb in heartbeats:
        if hb.autopilot != MAV_AUTOPILOT_INVALID:
            autopilots.setdefault(hb.system_id, hb.component_id)
    n_att: Counter[int] = Counter()
    for (s, _c), comp in comps.items():
        n_att[s] += len(comp.samples.get("AttitudeSample", ())) + len(
            comp.samples.get("AttitudeSampleQ", ()))
    seen = sorted({s for s, _c in comps})
    if system_id is not None:
        if system_id not in seen:
            raise TelemetryError(f"{path}: system id {system_id} does not appear in the log; "
                                 f"systems seen: {seen}")
        return system_id, autopilots.get(system_id, 1), (
            f"following system {system_id} (configured); systems seen: {seen}")
    if autopilots:
        sysid = max(autopilots, key=lambda s: (n_att[s], -s))
        how = "its HEARTBEAT names an autopilot"
        if len(autopilots) > 1:
            how += (f"; other autopilots {sorted(set(autopilots) - {sysid})} ignored "
                    "(set the system id to choose)")
        return sysid, autopilots[sysid], f"following system {sysid}: {how}; systems seen: {seen}"
    if not n_att or max(n_att.values()) == 0:
        raise TelemetryError(f"{path}: no autopilot HEARTBEAT and no attitude messages; "
                             f"systems seen: {seen}")
    sysid = max(n_att, key=lambda s: (n_att[s], -s))
    return sysid, 1, (f"following system {sysid}: no autopilot HEARTBEAT, it sends the most "
                      f"attitude messages; systems seen: {seen}")


def _choose_gimbal(samples: list[GimbalSample], ap_comp: int, instance: int
                   ) -> tuple[GimbalSeries, tuple[int, int, int] | None, str]:
    if not samples:
        return GimbalSeries.from_samples([]), None, ""
    flags_seen: dict[tuple[int, int, int], int] = defaultdict(int)
    for s in samples:
        flags_seen[s.source] |= s.flags
    source = preferred_gimbal_source(flags_seen, ap_comp, instance)
    chosen = [s for s in samples if s.source == source]
    note = ""
    if len(flags_seen) > 1:
        note = (f"gimbal status from {sorted(flags_seen)} (system, component, device id); "
                f"following {source}")
    return GimbalSeries.from_samples(chosen), source, note


# --- ArduPilot DataFlash ------------------------------------------------------------------

@contextmanager
def _silenced_output() -> Iterator[None]:
    """Discard what is printed to fds 1 and 2 meanwhile, by Python or C code: pymavlink's
    DataFlash indexer prints a "bad header" line per damaged byte (tens of thousands);
    pdcov reports the damage in one summary line instead."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 1)
            os.dup2(null.fileno(), 2)
            with redirect_stdout(null), redirect_stderr(null):
                yield
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        os.close(saved[0])
        os.close(saved[1])


def _dataflash_damage(reader: Any, size: int) -> tuple[frozenset[int], LogDamage]:
    """(message starts to drop, damage) from the indexed message starts and lengths of a
    DataFlash reader. Records follow each other with no gap, so a "message" with damage
    on both sides is bytes that happen to look like a header (DataFlash has no checksum)
    and is dropped; a last record running past the end of the file is a cut log."""
    starts, lengths = [], []
    for type_id, offsets in enumerate(reader.offsets):
        if offsets:
            starts.append(np.asarray(offsets, np.int64))
            lengths.append(np.full(len(offsets), reader.formats[type_id].len))
    damage = LogDamage(size=size, kind="DataFlash records")
    if not starts:
        return frozenset(), damage
    start = np.concatenate(starts)
    order = np.argsort(start, kind="stable")
    start, end = start[order], start[order] + np.concatenate(lengths)[order]
    after_prev = np.r_[start[0] == 0, start[1:] == end[:-1]]
    before_next = np.r_[end[:-1] == start[1:], end[-1] >= size]
    isolated = ~after_prev & ~before_next
    start, end = start[~isolated], end[~isolated]
    if len(start) == 0:
        return frozenset(), damage
    prev_end = np.r_[0, end[:-1]]
    for a, b in zip(prev_end[start > prev_end], start[start > prev_end], strict=True):
        damage.junk.append((int(a), int(b - a)))
    if end[-1] > size:
        damage.cut_at = int(start[-1])
    elif end[-1] < size:
        damage.junk.append((int(end[-1]), int(size - end[-1])))
    return frozenset(int(x) for x in np.concatenate(starts)[order][isolated]), damage


def _read_dataflash(path: Path, gimbal_instance: int) -> FlightLog:
    from pymavlink import DFReader

    clock = BootClock()
    by_type: dict[type, list] = defaultdict(list)
    positions: dict[str, list[PositionSample]] = defaultdict(list)
    estimators: dict[str, list[EstimatorSample]] = defaultdict(list)
    error = ""
    try:
        with _silenced_output():
            reader = DFReader.DFReader_binary(str(path), zero_time_base=True)
    except Exception as exc:  # noqa: BLE001 - any parser failure is a bad log, not a crash
        raise TelemetryError(f"{path}: cannot read as a DataFlash log: {exc}") from None
    drop, damage = _dataflash_damage(reader, reader.data_len)
    try:
        with _silenced_output():
            while True:
                msg = reader.recv_match(type=list(DATAFLASH_TYPES))
                if msg is None:
                    break
                if reader.offset - reader.formats[reader.name_to_id[msg.get_type()]].len in drop:
                    continue
                boot_s = dataflash_boot_time_s(msg)
                t_s = clock.now_s if boot_s is None else clock.to_s(boot_s)
                for sample in samples_from_dataflash(msg, t_s):
                    if isinstance(sample, PositionSample):
                        positions[msg.get_type()].append(sample)
                    elif isinstance(sample, EstimatorSample):
                        estimators[msg.get_type()].append(sample)
                    else:
                        by_type[type(sample)].append(sample)
    except Exception as exc:  # noqa: BLE001
        error = f"{type(exc).__name__}: {exc}"
    damage_lines = damage.describe()
    notes = [*damage_lines, "clock: DataFlash TimeUS (autopilot boot time)"]
    if error:
        notes.append(f"reading stopped early at a corrupt record ({error}); "
                     "using the messages before it")
    pos = positions.get("POS") or positions.get("GPS", [])
    if not positions.get("POS") and pos:
        notes.append("no POS messages: positions from GPS (3D fix only)")
    gimbal, source, gnote = _choose_gimbal(by_type[GimbalSample], 1, gimbal_instance)
    if gnote:
        notes.append(gnote)
    if source is not None:
        notes.append("gimbal attitude from MNT Roll/Pitch/YawB (the angles of the quaternion "
                     "ArduPilot sends in GIMBAL_DEVICE_ATTITUDE_STATUS)")
    if clock.restarts_t_s:
        notes.append(_restart_note(len(clock.restarts_t_s), "TimeUS"))
    params = {p.name: p.value for p in by_type[ParamSample]}
    estimator, est_source = _dataflash_estimator(estimators, params)
    return _shifted(FlightLog(
        str(path), "dataflash", None, AttitudeSeries.from_samples(by_type[AttitudeSample]),
        PositionSeries.from_samples(pos), gimbal, source, tuple(by_type[HomeSample]),
        tuple(sorted(by_type[CaptureSample], key=lambda c: c.t_s)), params,
        MountTargetSeries.from_samples(by_type[MountTargetSample]),
        tuple(clock.restarts_t_s), tuple(notes), tuple(damage_lines), estimator, est_source),
        -clock.offset_s)


_EKF_LOGS = {3: ("XKF4", "EKF3"), 2: ("NKF4", "EKF2")}


def _dataflash_estimator(estimators: Mapping[str, list[EstimatorSample]],
                         params: Mapping[str, float]) -> tuple[EstimatorSeries, str]:
    """The verdicts of the EKF the AHRS used (AHRS_EKF_TYPE 3: XKF4, 2: NKF4; without the
    parameter XKF4, else NKF4); none for the other types (0 DCM: no EKF, 1: the EKF1 of
    ArduPilot 3.x, whose EKF4 this reader does not take, 10 SIM, 11 external AHRS)."""
    ekf_type = params.get("AHRS_EKF_TYPE")
    if ekf_type is not None and int(ekf_type) not in _EKF_LOGS:
        return EstimatorSeries.from_samples([]), ""
    order = [_EKF_LOGS[int(ekf_type)]] if ekf_type is not None else list(_EKF_LOGS.values())
    for name, ekf in order:
        # ArduCopter 3.4: core 1's records are NKF9 (samples._CORE_OF_LOG), kept while it
        # was the primary.
        lane1 = estimators.get("NKF9", []) if name == "NKF4" else []
        if estimators.get(name) or lane1:
            return _estimator([*estimators.get(name, []), *lane1], (
                f"{name}/NKF9 SS ({ekf}, primary core; {len(lane1)} reports of core 1)"
                if lane1 else f"{name} SS ({ekf}, primary core)"))
    return EstimatorSeries.from_samples([]), ""


# --- PX4 ULog ------------------------------------------------------------------------------

_ULOG_GPS_TOPICS = ("vehicle_gps_position", "sensor_gps")
_ULOG_TOPICS = ["vehicle_attitude", "vehicle_global_position", *_ULOG_GPS_TOPICS,
                "gimbal_device_attitude_status", "home_position", "camera_capture",
                "camera_trigger", "estimator_status", "estimator_selector_status"]
_GPS_FIX_3D = 3  # fix_type: 0-1 no fix, 2 2D, 3 3D, 4 DGPS, 5 RTK float, 6 RTK fixed


def _ulog_damage(path: Path, pyulog_saw_corruption: bool) -> tuple[str, ...]:
    """Summary lines for a damaged ULog: a last message running past the end of the file
    (a log cut short, e.g. by a power loss; pyulog stops there without a word), found by
    walking the message headers (uint16 size, uint8 type) after the 16-byte file header;
    and pyulog's own corruption flag (data it skipped)."""
    data = path.read_bytes()
    damage = LogDamage(size=len(data), kind="ULog messages")
    offset = 16
    while offset + 3 <= len(data):
        (size,) = struct.unpack_from("<H", data, offset)
        if offset + 3 + size > len(data):
            break
        offset += 3 + size
    if offset != len(data):
        damage.cut_at = offset
    lines = damage.describe()
    if pyulog_saw_corruption:
        lines.append("pyulog skipped corrupt data inside the log; the messages it could read "
                     "are used")
    return tuple(lines)


def _ulog_gps_positions(t_s: np.ndarray, fields: Mapping[str, np.ndarray]
                        ) -> tuple[list[PositionSample], int]:
    """Positions (lat/lon deg, alt m AMSL) of a PX4 GPS topic's samples with a 3D fix or
    better, and the number of samples without one. Fields: ``latitude_deg``,
    ``longitude_deg``, ``altitude_msl_m`` (PX4 1.14+), else ``lat``/``lon`` (1e-7 deg) and
    ``alt`` (mm)."""
    if "latitude_deg" in fields:
        lat, lon, alt = (np.asarray(fields[k], float) for k in
                         ("latitude_deg", "longitude_deg", "altitude_msl_m"))
    else:
        lat, lon = (np.asarray(fields[k], float) * 1e-7 for k in ("lat", "lon"))
        alt = np.asarray(fields["alt"], float) * 1e-3
    fix = np.asarray(fields["fix_type"]) >= _GPS_FIX_3D
    return ([PositionSample(*row) for row in zip(t_s[fix], lat[fix], lon[fix], alt[fix],
                                                 strict=True)], int(np.count_nonzero(~fix)))


def _read_ulog(path: Path, gimbal_instance: int) -> FlightLog:
    try:
        from pyulog import ULog
    except ImportError:
        raise TelemetryError(f"{path}: a PX4 ULog; reading it needs pyulog "
                             "(pip install 'pdcov[ulog]')") from None
    try:
        ulog = ULog(str(path), _ULOG_TOPICS)
    except Exception as exc:  # noqa: BLE001 - any parser failure is a bad log, not a crash
        raise TelemetryError(f"{path}: cannot read as a ULog: {exc}") from None
    topics: dict[str, dict[str, np.ndarray]] = {}
    ekf_instances: dict[int, dict[str, np.ndarray]] = {}  # estimator_status by multi_id
    for d in ulog.data_list:
        if d.name == "estimator_status":
            ekf_instances[d.multi_id] = d.data
        elif d.multi_id == 0:
            topics[d.name] = d.data

    def col(topic: str, name: str) -> np.ndarray:
        return np.asarray(topics[topic][name], float)

    # ULog timestamps: microseconds since boot (PX4 hrt_absolute_time).
    def t_of(topic: str) -> np.ndarray:
        return col(topic, "timestamp") * 1e-6

    def quat(topic: str) -> np.ndarray:
        return np.stack([col(topic, f"q[{i}]") for i in range(4)], axis=1)

    att = AttitudeSeries(np.zeros(0), np.zeros((0, 4)))
    if "vehicle_attitude" in topics:  # q: body FRD -> NED (PX4 vehicle_attitude.msg)
        att = AttitudeSeries.from_samples([AttitudeSample(t, tuple(q)) for t, q in zip(
            t_of("vehicle_attitude"), quat("vehicle_attitude"), strict=True)])
    pos_samples: list[PositionSample] = []
    pos_note = ""
    if "vehicle_global_position" in topics:  # lat/lon deg, alt m AMSL
        g = "vehicle_global_position"
        pos_samples = [PositionSample(*row) for row in zip(
            t_of(g), col(g, "lat"), col(g, "lon"), col(g, "alt"), strict=True)]
    for g in _ULOG_GPS_TOPICS:  # as the DataFlash reader falls back to GPS
        if pos_samples or g not in topics:
            continue
        pos_samples, n_no_fix = _ulog_gps_positions(t_of(g), topics[g])
        pos_note = (f"no vehicle_global_position: positions from {g} (3D fix or better; "
                    f"{len(pos_samples)} samples used, {n_no_fix} without a fix skipped); "
                    "GPS altitude is coarser than the estimator's")
    gimbal_samples: list[GimbalSample] = []
    g = "gimbal_device_attitude_status"
    if g in topics:
        n = len(t_of(g))
        dev = (col(g, "gimbal_device_id") if "gimbal_device_id" in topics[g] else np.zeros(n))
        fail = col(g, "failure_flags") if "failure_flags" in topics[g] else np.zeros(n)
        gimbal_samples = [GimbalSample(t, tuple(q), int(f), int(e), 1, 154, int(d))
                          for t, q, f, e, d in zip(t_of(g), quat(g), col(g, "device_flags"),
                                                   fail, dev, strict=True)]
    homes: tuple[HomeSample, ...] = ()
    if "home_position" in topics:
        h = "home_position"
        homes = tuple(HomeSample(t, la, lo, al, "home_position") for t, la, lo, al in zip(
            t_of(h), col(h, "lat"), col(h, "lon"), col(h, "alt"), strict=True))
    captures: list[CaptureSample] = []
    for topic in ("camera_capture", "camera_trigger"):
        if topic in topics and not captures:
            captures = [CaptureSample(t, int(s), topic)
                        for t, s in zip(t_of(topic), col(topic, "seq"), strict=True)]
    params = dict(ulog.initial_parameters)
    for _t, name, value in ulog.changed_parameters:
        params[name] = value
    gimbal, source, gnote = _choose_gimbal(gimbal_samples, 1, gimbal_instance)
    damage = _ulog_damage(path, ulog.file_corruption)
    notes = [*damage, "clock: ULog timestamps (PX4 boot time)"]
    notes += [n for n in (pos_note, gnote) if n]
    return FlightLog(str(path), "ulog", None, att, PositionSeries.from_samples(pos_samples),
                     gimbal, source, homes, tuple(captures), params,
                     MountTargetSeries.from_samples([]), (), tuple(notes), damage,
                     *_ulog_estimator(ekf_instances, topics.get("estimator_selector_status")))


def _ulog_estimator(instances: Mapping[int, Mapping[str, np.ndarray]],
                    selector: Mapping[str, np.ndarray] | None) -> tuple[EstimatorSeries, str]:
    """The verdicts of the EKF instance PX4 used, and their source in words.

    With several EKF2 instances (EKF2_MULTI_IMU / EKF2_MULTI_MAG) each publishes its own
    estimator_status, the ULog multi_id being the instance (EKF2::multi_init checks the
    uORB instances agree), and the selector names the one whose outputs the vehicle uses in
    estimator_selector_status.primary_instance. A report applies when its instance is the
    primary in force at its timestamp (the latest selection at or before it), so a switch
    changes whose flags apply from then on, as the DataFlash reader follows the primary
    core. Before the first selection, or with no selector topic, instance 0.
    solution_status_flags: ESTIMATOR_STATUS_FLAGS bits (PX4 sends them as the MAVLink
    ESTIMATOR_STATUS flags).
    """
    usable = {i: d for i, d in instances.items() if "solution_status_flags" in d}
    if not usable:
        return _estimator([], "")
    t_sel = np.zeros(0)
    primary = np.zeros(0, int)
    if selector is not None and "primary_instance" in selector:
        t_sel = np.asarray(selector["timestamp"], float) * 1e-6
        primary = np.asarray(selector["primary_instance"], int)
    samples: list[EstimatorSample] = []
    t_first_s = math.inf
    for inst, d in usable.items():
        t = np.asarray(d["timestamp"], float) * 1e-6
        t_first_s = min(t_first_s, float(t[0])) if len(t) else t_first_s
        in_force = np.zeros(len(t), int)
        if len(primary):
            k = np.searchsorted(t_sel, t, side="right") - 1
            in_force = np.where(k >= 0, primary[np.clip(k, 0, None)], 0)
        flags = np.asarray(d["solution_status_flags"], int)
        samples += [EstimatorSample(ts, bool(f & POS_HORIZ_ABS), bool(f & CONST_POS_MODE),
                                    bool(f & ESTIMATOR_GPS_GLITCH))
                    for ts, f in zip(t[in_force == inst], flags[in_force == inst],
                                     strict=True)]
    samples.sort(key=lambda x: x.t_s)
    return _estimator(samples, "estimator_status solution_status_flags, "
                      + _ekf_instances_used(sorted(usable), t_sel, primary, t_first_s))


def _ekf_instances_used(logged: list[int], t_sel: np.ndarray, primary: np.ndarray,
                        t_first_s: float) -> str:
    """Which EKF instance's reports were used when, in words (``_ulog_estimator``)."""
    if len(t_sel) == 0:
        if logged == [0]:
            return "EKF instance 0"
        return (f"EKF instance 0 of instances {logged} logged (no estimator_selector_status: "
                "the primary is not known)")
    changes = np.flatnonzero(np.r_[True, primary[1:] != primary[:-1]])
    runs = [(float(t_sel[i]), int(primary[i])) for i in changes]
    if t_first_s < runs[0][0]:  # reports before the first selection: instance 0's
        runs[:1] = [(t_first_s, 0)] + (runs[:1] if runs[0][1] != 0 else [])
    shown = ", ".join(f"{inst} from {t:.2f} s" for t, inst in runs[:8])
    more = f" and {len(runs) - 8} more switches" if len(runs) > 8 else ""
    missing = sorted({inst for _t, inst in runs} - set(logged))
    gone = f"; primary {missing} not logged: no reports meanwhile" if missing else ""
    return (f"the primary EKF instance (estimator_selector_status.primary_instance): "
            f"{shown}{more}; instances logged {logged}{gone}")
