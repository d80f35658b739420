"""PX4 ULog (.ulg, pyulog: the optional ``ulog`` extra) -> ``FlightLog``.

Times: ULog timestamps (microseconds since PX4 boot, here s). Positions from
vehicle_global_position (lat/lon deg, alt m AMSL), else a GPS topic with a 3D fix; the EKF
verdicts are those of the primary EKF2 instance in force at each report.
"""

from __future__ import annotations

import math
import struct
from collections import Counter
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from pdcov.errors import TelemetryError
from pdcov.telemetry.adapters import CONST_POS_MODE, ESTIMATOR_GPS_GLITCH, POS_HORIZ_ABS
from pdcov.telemetry.logs.choose import choose_gimbal
from pdcov.telemetry.logs.flight_log import FlightLog, armed_changes, estimator_series, gated
from pdcov.telemetry.sample_gate import SampleGate
from pdcov.telemetry.samples import (
    AttitudeSample,
    CaptureSample,
    EstimatorSample,
    GimbalSample,
    GnssAccuracySample,
    HomeSample,
    PositionSample,
    RangefinderSample,
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

_ULOG_GPS_TOPICS = ("vehicle_gps_position", "sensor_gps")
_ULOG_TOPICS = ["vehicle_attitude", "vehicle_global_position", *_ULOG_GPS_TOPICS,
                "gimbal_device_attitude_status", "home_position", "camera_capture",
                "camera_trigger", "estimator_status", "estimator_selector_status",
                "distance_sensor", "vehicle_status"]
_ARMING_STATE_ARMED = 2  # vehicle_status.arming_state (PX4 VehicleStatus.msg)
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


def _ulog_gnss_accuracy(t_s: np.ndarray, fields: Mapping[str, np.ndarray]
                        ) -> list[GnssAccuracySample]:
    """The accuracy a PX4 GPS topic reports (eph, epv: m, the receiver's position accuracy,
    which PX4 sends as GPS_RAW_INT h_acc/v_acc); unknown below a 3D fix, and for a topic
    without them."""
    n = len(t_s)
    eph, epv = (np.asarray(fields.get(k, np.full(n, np.nan)), float) for k in ("eph", "epv"))
    fix = np.asarray(fields.get("fix_type", np.zeros(n)), int) >= _GPS_FIX_3D
    return [GnssAccuracySample(float(t), float(h), float(v)) if ok
            else GnssAccuracySample(float(t), math.nan, math.nan)
            for t, h, v, ok in zip(t_s, eph, epv, fix, strict=True)]


def _ulog_utc(t_s: np.ndarray, fields: Mapping[str, np.ndarray]) -> list[UtcSample]:
    """The GPS topic's UTC beside its timestamps: ``time_utc_usec`` (PX4 SensorGps.msg,
    0 when the receiver has no time; the topic's timestamp is its boot time)."""
    if "time_utc_usec" not in fields:
        return []
    us = np.asarray(fields["time_utc_usec"], float)
    return [UtcSample(float(t), float(t), u * 1e-6 if u > 0 else math.nan)
            for t, u in zip(t_s, us, strict=True)]


def read_ulog(path: Path, gimbal_instance: int) -> FlightLog:
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
    rangefinder: list[RangefinderSample] = []
    for d in ulog.data_list:
        if d.name == "estimator_status":
            ekf_instances[d.multi_id] = d.data
        elif d.name == "distance_sensor":  # every instance: the check takes the downward
            rangefinder += _ulog_rangefinder(d.data, d.multi_id)
        elif d.multi_id == 0:
            topics[d.name] = d.data

    def col(topic: str, name: str) -> np.ndarray:
        return np.asarray(topics[topic][name], float)

    # ULog timestamps: microseconds since boot (PX4 hrt_absolute_time).
    def t_of(topic: str) -> np.ndarray:
        return col(topic, "timestamp") * 1e-6

    def quat(topic: str) -> np.ndarray:
        return np.stack([col(topic, f"q[{i}]") for i in range(4)], axis=1)

    faults: Counter = Counter()  # the daemon's checks (sample_gate), counted as it does
    gate = SampleGate(faults)
    att = AttitudeSeries(np.zeros(0), np.zeros((0, 4)))
    if "vehicle_attitude" in topics:  # q: body FRD -> NED (PX4 vehicle_attitude.msg)
        att = AttitudeSeries.from_samples(gated(gate, [
            AttitudeSample(t, tuple(q)) for t, q in zip(
                t_of("vehicle_attitude"), quat("vehicle_attitude"), strict=True)]))
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
    gnss = next((_ulog_gnss_accuracy(t_of(g), topics[g]) for g in _ULOG_GPS_TOPICS
                 if g in topics), [])
    utc = next((_ulog_utc(t_of(g), topics[g]) for g in _ULOG_GPS_TOPICS if g in topics), [])
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
    gimbal_samples = gated(gate, gimbal_samples)
    gimbal, source, gnote = choose_gimbal(gimbal_samples, 1, gimbal_instance)
    damage = _ulog_damage(path, ulog.file_corruption)
    notes = [*damage, "clock: ULog timestamps (PX4 boot time)"]
    notes += [n for n in (pos_note, gnote) if n]
    return FlightLog(str(path), "ulog", None, att,
                     PositionSeries.from_samples(gated(gate, pos_samples)),
                     gimbal, source, homes, tuple(captures), params,
                     MountTargetSeries.from_samples([]), (), tuple(notes), damage,
                     *_ulog_estimator(ekf_instances, topics.get("estimator_selector_status")),
                     (), tuple(sorted(rangefinder, key=lambda r: r.t_s)),
                     gnss_accuracy=GnssAccuracySeries.from_samples(gnss),
                     faults=dict(sorted(faults.items())),
                     gimbal_reports=tuple(gimbal_samples),
                     armed_states=armed_changes(
                         (float(t), int(a) == _ARMING_STATE_ARMED) for t, a in zip(
                             t_of("vehicle_status"), col("vehicle_status", "arming_state"),
                             strict=True)) if "vehicle_status" in topics else None,
                     utc=tuple(utc))


_PX4_QUALITY_INVALID = 0  # distance_sensor.signal_quality: 0 invalid, -1 unknown, 100 best


def _ulog_rangefinder(fields: Mapping[str, np.ndarray], instance: int
                      ) -> list[RangefinderSample]:
    """Readings of one distance_sensor instance (PX4 DistanceSensor.msg): current_distance,
    min_distance, max_distance m; orientation MAV_SENSOR_ORIENTATION; valid within
    min..max and not of signal quality 0 (invalid)."""
    t_s = np.asarray(fields["timestamp"], float) * 1e-6
    d, lo, hi = (np.asarray(fields[k], float) for k in
                 ("current_distance", "min_distance", "max_distance"))
    quality = np.asarray(fields.get("signal_quality", np.full(len(d), -1)), int)
    valid = (lo <= d) & (d <= hi) & (quality != _PX4_QUALITY_INVALID)
    return [RangefinderSample(float(t), float(x), int(o), bool(v), instance) for t, x, o, v in
            zip(t_s, d, np.asarray(fields["orientation"], int), valid, strict=True)]


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
        return estimator_series([], "")
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
    return estimator_series(samples, "estimator_status solution_status_flags, "
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
