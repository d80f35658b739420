"""ArduPilot DataFlash logs (.bin, pymavlink DFReader) -> ``FlightLog``.

Times: TimeUS (autopilot boot time, s after conversion, monotonic across restarts). Damage
(bytes that only look like records, a cut last record) is found from the reader's index and
summarised in one line; the EKF verdicts are those of the core the AHRS used.
"""

from __future__ import annotations

import math
import os
import sys
from collections import Counter, defaultdict
from collections.abc import Iterator, Mapping
from contextlib import contextmanager, redirect_stderr, redirect_stdout
from pathlib import Path
from typing import Any

import numpy as np

from pdcov.errors import TelemetryError
from pdcov.telemetry.adapters import DATAFLASH_TYPES, dataflash_boot_time_s, samples_from_dataflash
from pdcov.telemetry.clocks import BootClock
from pdcov.telemetry.logs.choose import choose_gimbal
from pdcov.telemetry.logs.flight_log import (
    FlightLog,
    armed_changes,
    estimator_series,
    gated,
    restart_note,
    shifted,
)
from pdcov.telemetry.sample_gate import SampleGate
from pdcov.telemetry.samples import (
    AttitudeSample,
    CaptureSample,
    EstimatorSample,
    GimbalSample,
    GnssAccuracySample,
    HomeSample,
    MountTargetSample,
    ParamSample,
    PositionSample,
    RangefinderSample,
    TerrainReportSample,
    UtcSample,
)
from pdcov.telemetry.series import (
    AttitudeSeries,
    EstimatorSeries,
    GnssAccuracySeries,
    MountTargetSeries,
    PositionSeries,
)
from pdcov.telemetry.tlog import LogDamage


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


def read_dataflash(path: Path, gimbal_instance: int) -> FlightLog:
    from pymavlink import DFReader

    clock = BootClock()
    by_type: dict[type, list] = defaultdict(list)
    positions: dict[str, list[PositionSample]] = defaultdict(list)
    estimators: dict[str, list[EstimatorSample]] = defaultdict(list)
    armed: list[tuple[float, bool]] = []  # ARM records, else EV ARMED / DISARMED
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
                msg = reader.recv_match(type=[*DATAFLASH_TYPES, *_ARMING_TYPES])
                if msg is None:
                    break
                if reader.offset - reader.formats[reader.name_to_id[msg.get_type()]].len in drop:
                    continue
                boot_s = dataflash_boot_time_s(msg)
                t_s = clock.now_s if boot_s is None else clock.to_s(boot_s)
                if msg.get_type() in _ARMING_TYPES:
                    armed += _armed_state(msg, t_s)
                    continue
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
    faults: Counter = Counter()  # the daemon's checks (sample_gate), counted as it does
    gate = SampleGate(faults)
    gimbals = gated(gate, by_type[GimbalSample])
    gimbal, source, gnote = choose_gimbal(gimbals, 1, gimbal_instance)
    if gnote:
        notes.append(gnote)
    if source is not None:
        notes.append("gimbal attitude from MNT Roll/Pitch/YawB (the angles of the quaternion "
                     "ArduPilot sends in GIMBAL_DEVICE_ATTITUDE_STATUS)")
    if clock.restarts_t_s:
        notes.append(restart_note(len(clock.restarts_t_s), "TimeUS"))
    params = {p.name: p.value for p in by_type[ParamSample]}
    estimator, est_source = _dataflash_estimator(estimators, params)
    return shifted(FlightLog(
        str(path), "dataflash", None,
        AttitudeSeries.from_samples(gated(gate, by_type[AttitudeSample])),
        PositionSeries.from_samples(gated(gate, pos)), gimbal, source,
        tuple(by_type[HomeSample]),
        tuple(sorted(by_type[CaptureSample], key=lambda c: c.t_s)), params,
        MountTargetSeries.from_samples(by_type[MountTargetSample]),
        tuple(clock.restarts_t_s), tuple(notes), tuple(damage_lines), estimator, est_source,
        tuple(by_type[TerrainReportSample]), tuple(by_type[RangefinderSample]),
        gnss_accuracy=GnssAccuracySeries.from_samples(by_type[GnssAccuracySample]),
        faults=dict(sorted(faults.items())), gimbal_reports=tuple(gimbals),
        armed_states=_armed_states(armed), utc=tuple(by_type[UtcSample])), -clock.offset_s)


_ARMING_TYPES = ("ARM", "EV")
_EV_ARMED, _EV_DISARMED = 10, 11  # AP_Logger LogEvent


def _armed_state(msg: Any, t_s: float) -> list[tuple[float, bool]]:
    """The armed state a record gives: ARM (ArmState, ArduPilot 4.0+) or EV ARMED /
    DISARMED (older logs have only these)."""
    if msg.get_type() == "ARM":
        return [(t_s, bool(msg.ArmState))]
    if int(msg.Id) in (_EV_ARMED, _EV_DISARMED):
        return [(t_s, int(msg.Id) == _EV_ARMED)]
    return []


def _armed_states(armed: list[tuple[float, bool]]) -> tuple[tuple[float, bool], ...] | None:
    """The log's armed states (FlightLog.armed_states): before its first arming record
    the vehicle was in the other state, from the log's start."""
    changes = armed_changes(armed)
    if changes is None:
        return None
    return ((-math.inf, not changes[0][1]), *changes)


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
        # ArduCopter 3.4: core 1's records are NKF9 (adapters._CORE_OF_LOG), kept while it
        # was the primary.
        lane1 = estimators.get("NKF9", []) if name == "NKF4" else []
        if estimators.get(name) or lane1:
            return estimator_series([*estimators.get(name, []), *lane1], (
                f"{name}/NKF9 SS ({ekf}, primary core; {len(lane1)} reports of core 1)"
                if lane1 else f"{name} SS ({ekf}, primary core)"))
    return EstimatorSeries.from_samples([]), ""
