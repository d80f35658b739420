"""The offline driver: a whole flight log -> the camera poses at its frames (``poses_of_log``
of a log read once for every camera; ``poses_from_log`` of a file).

Loads the log read (``telemetry.logs``) into one ``PoseTracker`` and decides every frame
time, in chunks, by the daemon's own decision (``frame_decision.decide_frames``: the frames
used, the others counted under the daemon's keys); frames are placed by the rule the daemon
uses (``frame_policy.FrameLattice``) or at the log's capture events; the ground altitude is
the daemon's ``GroundAltitude`` fed the log's homes, armed states and first position in time
order (``ground_alt_of_log``). Times are seconds in the autopilot clock, positions ENU
metres about the resolved origin, the ground altitude m MSL.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np

from pdcov.core.camera import CameraModel
from pdcov.core.detections import Box
from pdcov.core.geodesy import Origin
from pdcov.core.geolocate import PositionAccuracy
from pdcov.core.pose import CameraPose
from pdcov.core.rotations import euler_zyx_from_R_many
from pdcov.core.utc_clock import UtcClock
from pdcov.errors import ConfigError, TelemetryError
from pdcov.flight.frame_decision import FrameCounts, Framing, decide_frames
from pdcov.flight.frame_selection import SelectedFrames
from pdcov.flight.ground_altitude import DEFAULT_HOME_WAIT_S, GroundAltitude
from pdcov.telemetry.estimator import REASONS as ESTIMATOR_REASONS
from pdcov.telemetry.estimator import describe as describe_estimator
from pdcov.telemetry.frame_policy import FrameLattice, FrameSource, untrusted_policy
from pdcov.telemetry.gimbal import GimbalMount, resolve_interpretation
from pdcov.telemetry.gnss_accuracy import describe_accuracy
from pdcov.telemetry.lens_reports import LensReports, describe_lens
from pdcov.telemetry.logs import FlightLog, read_flight_log
from pdcov.telemetry.pose_tracker import FrameBatch, PoseTracker
from pdcov.telemetry.recorded_frames import SOURCE as RECORDED_SOURCE
from pdcov.telemetry.recorded_frames import frame_source_for
from pdcov.telemetry.sample_gate import valid_home
from pdcov.telemetry.samples import PositionSample
from pdcov.telemetry.terrain_check import TerrainCheck, check_flight_log


@dataclass(frozen=True, slots=True)
class LogPoses:
    """The camera poses of a flight log, and how they were obtained.

    poses: one CameraPose per frame used (t_s in the autopilot clock, s). origin: the ENU
    origin as resolved. track_enu (M, 3): vehicle positions in ENU m over the log, for
    plotting the flown track. summary_lines: what was done, in words. The remaining arrays
    are per used frame, for ``write_pose_csv``: q_enu_cam_wxyz (F, 4) the quaternions the
    poses were built from (written as such, so the CSV reads back bit-identical),
    vehicle_rpy_deg (F, 3) roll/pitch/yaw of
    R_ned_body, gimbal_q_wxyz (F, 4) as reported and interpolated (NaN for a fixed mount),
    gimbal_flags (F,) (-1 fixed), interpretation (F,) str, trusted (F,) bool,
    untrusted_reason (F,) str, at_limit (F,) a servo demand at its limit. skipped_t_s:
    frame times skipped by gaps. warnings: what the user should not miss (also among the
    summary lines). frame_boxes: {frame time t_s: (the detector's t_boot_s, its boxes)} of
    the frames ``pdcov serve`` recorded with boxes, when those frames are the ones
    evaluated (recorded_frames). cameras: per used frame, the camera of its zoom report
    (frame_policy.frame_cameras; None: the configured camera), empty without a zoom.
    accuracies: per used frame, the GNSS accuracy the autopilot reported in force at it
    (gnss_accuracy.py; None: unknown). faults: the bad messages and samples counted while
    reading the log (FlightLog.faults: the daemon's fault keys). low: per used frame, the
    camera below min_height_m (frame_selection: added to no grid, as live).
    frames_skipped: the frames not used, by the daemon's reasons (its status's
    frames.skipped: frame_decision.decide_frames, low frames among them). utc: the log's
    real-time clock (``utc_clock_of``); track_unix_s (M,): the UTC of track_enu's
    positions (s since 1970, NaN unknown).
    """

    poses: tuple[CameraPose, ...]
    origin: Origin
    track_enu: np.ndarray
    summary_lines: tuple[str, ...]
    q_enu_cam_wxyz: np.ndarray
    vehicle_rpy_deg: np.ndarray
    gimbal_q_wxyz: np.ndarray
    gimbal_flags: np.ndarray
    interpretation: tuple[str, ...]
    trusted: np.ndarray
    untrusted_reason: tuple[str, ...]
    at_limit: np.ndarray
    skipped_t_s: np.ndarray
    warnings: tuple[str, ...] = ()
    frame_boxes: Mapping[float, tuple[float, tuple[Box, ...]]] = field(default_factory=dict)
    cameras: tuple[CameraModel | None, ...] = ()
    accuracies: tuple[PositionAccuracy | None, ...] = ()
    faults: Mapping[str, int] = field(default_factory=dict)
    low: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    frames_skipped: Mapping[str, int] = field(default_factory=dict)
    utc: UtcClock = field(default_factory=UtcClock)
    track_unix_s: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def export_rows(self) -> Iterable[list[str]]:
        """Rows of the --export-poses CSV (after the header POSE_CSV_COLUMNS +
        EXPORT_EXTRA_COLUMNS); floats printed to round-trip exactly."""
        for i, pose in enumerate(self.poses):
            yield ([repr(float(pose.t_s)), *map(repr, map(float, pose.r_cam_enu)),
                    *map(repr, map(float, self.q_enu_cam_wxyz[i])),
                    *(f"{v:.6f}" for v in self.vehicle_rpy_deg[i]),
                    *("" if math.isnan(v) else repr(float(v)) for v in self.gimbal_q_wxyz[i]),
                    "" if self.gimbal_flags[i] < 0 else str(int(self.gimbal_flags[i])),
                    self.interpretation[i], "1" if self.trusted[i] else "0",
                    self.untrusted_reason[i]])


def utc_clock_of(log: FlightLog) -> UtcClock:
    """The log's real-time clock: a UtcClock fed its UTC samples in log order."""
    clock = UtcClock()
    for u in log.utc:
        clock.add(u.t_s, u.boot_s, u.unix_s)
    return clock


def describe_utc(log: FlightLog, clock: UtcClock, t_s: float) -> str:
    """The summary line of the log's real-time clock: where UTC came from and the UTC of
    autopilot time ``t_s`` (its first frame), or that there is none."""
    source = {"tlog": "SYSTEM_TIME", "dataflash": "GPS GWk/GMS",
              "ulog": "vehicle_gps_position time_utc_usec"}.get(log.format, "")
    if not clock.known:
        return (f"UTC: none, the log carries no real-time clock ({source}: "
                f"{len(log.utc)} messages, none set); time_utc is null in the outputs")
    return (f"UTC: from {source} ({len(log.utc) - clock.unset} of {len(log.utc)} set); "
            f"the first frame at {clock.text(t_s) or 'unknown (none in its boot)'}")


def ground_alt_of_log(log: FlightLog, ground: GroundAltitude) -> tuple[float, str]:
    """The ground altitude (m MSL) ``ground`` (the daemon's rule) gives a whole log, and how
    it was found: told the log's homes (those the daemon's sample gate admits), armed
    states and first position with a height above home in time order, and asked before
    each new time as the daemon asks after every sample (with the newest attitude or
    position before it), then at the log's end."""
    att_t, pos_t = log.attitude.t_s, log.position.t_s

    def newest_before(t_s: float) -> float:
        newest = -math.inf
        for times in (att_t, pos_t):
            i = int(np.searchsorted(times, t_s, side="left"))
            if i:
                newest = max(newest, float(times[i - 1]))
        return newest

    # What a log holds of one instant is told at once (DataFlash logs ORGN's EKF origin and
    # home at the arming's TimeUS; a link delivers such messages in one read).
    events: list[tuple[float, int, Callable[[], None]]] = [
        (t_s, 0, partial(ground.add_armed_state, t_s, armed))
        for t_s, armed in log.armed_states or ()]
    events += [(h.t_s, 1, partial(ground.add_home, h)) for h in log.homes
               if math.isfinite(h.t_s) and valid_home(h)]
    p = log.position
    first = np.flatnonzero(np.isfinite(p.relative_alt_m))
    if len(first):
        i = int(first[0])
        events.append((float(p.t_s[i]), 2, partial(ground.add_position, PositionSample(
            float(p.t_s[i]), float(p.lat_deg[i]), float(p.lon_deg[i]), float(p.alt_msl_m[i]),
            float(p.relative_alt_m[i])))))
    told_t_s = math.nan
    for t_s, _kind, tell in sorted(events, key=lambda e: e[:2]):
        if t_s != told_t_s:
            alt, how = ground.ground_alt(newest_before(t_s))
            if alt is not None:
                return alt, how
            told_t_s = t_s
        tell()
    end_s = max(float(att_t[-1]) if len(att_t) else -math.inf,
                float(pos_t[-1]) if len(pos_t) else -math.inf)
    alt, how = ground.ground_alt(end_s, ended=True)
    if alt is None:
        raise TelemetryError(f"{log.path}: the log gives no home altitude (no HOME_POSITION, "
                             "ORGN or relative altitude); set origin.ground_alt_msl_m in the "
                             "config")
    if (ground.configured_m is None and log.armed_states is not None
            and ground.armed_t_s is None):
        how += "; the vehicle never armed in the log (pdcov serve waits for arming)"
    return alt, how


def _intervals(t: np.ndarray, step_s: float) -> list[tuple[float, float, int]]:
    """Runs of consecutive frame times (start, end, count)."""
    if len(t) == 0:
        return []
    breaks = np.flatnonzero(np.diff(t) > 1.5 * step_s) + 1
    return [(float(r[0]), float(r[-1]), len(r)) for r in np.split(t, breaks)]


def frame_times(tracker: PoseTracker, log: FlightLog, frame_rate_hz: float,
                frame_source: str) -> tuple[np.ndarray, str]:
    """Frame times (s) and a description: every 1/frame_rate_hz over the span all needed
    streams cover ('rate': the frame_policy.FrameLattice the daemon places frames on), or
    the log's capture events ('capture')."""
    if frame_source == FrameSource.CAPTURE:
        if not log.captures:
            raise TelemetryError(f"{log.path}: frame_source 'capture' but the log has no "
                                 "capture events (CAMERA_IMAGE_CAPTURED, CAMERA_FEEDBACK, "
                                 "CAM, TRIG); use frame_source 'rate'")
        t = np.unique([c.t_s for c in log.captures])
        kinds = sorted({c.source for c in log.captures})
        return t, f"{len(t)} capture events ({', '.join(kinds)})"
    if frame_source != FrameSource.RATE:
        raise ConfigError(f"frame_source: expected 'rate' or 'capture', got {frame_source!r}")
    if not (math.isfinite(frame_rate_hz) and frame_rate_hz > 0):
        raise ConfigError(f"camera.frame_rate_hz: expected a positive rate, got {frame_rate_hz!r}")
    t0, t1 = tracker.coverage_s()
    if not math.isfinite(t0) or t1 < t0:
        raise TelemetryError(f"{log.path}: attitude, position and gimbal samples never overlap "
                             "in time; no frame can be placed")
    lattice = FrameLattice(t0, frame_rate_hz)
    return lattice.times(lattice.count_until(t1)), (f"every {1 / frame_rate_hz:g} s "
                                               f"({frame_rate_hz:g} Hz) from {t0:.3f} to "
                                               f"{t1:.3f} s")


_CHUNK = 4096


def poses_from_log(path: str | Path, framing: Framing, *, origin_lat_deg: float,
                   origin_lon_deg: float, ground_alt_msl_m: float | None,
                   system_id: int | None = None, ground_alt_how: str = "configured",
                   home_wait_s: float = DEFAULT_HOME_WAIT_S, progress: bool = False,
                   terrain_check: TerrainCheck | None = None) -> LogPoses:
    """Camera poses of a flight log file (.tlog, DataFlash .bin, PX4 .ulg) at the camera's
    frames: the log read (``read_flight_log``: ``system_id`` the MAVLink system to follow,
    None: the autopilot announced by HEARTBEAT) and ``poses_of_log`` with the other
    arguments."""
    mount = framing.mount
    log = read_flight_log(path, system_id=system_id,
                          gimbal_instance=mount.instance if isinstance(mount, GimbalMount)
                          else 1)
    return poses_of_log(log, framing, origin_lat_deg=origin_lat_deg,
                        origin_lon_deg=origin_lon_deg, ground_alt_msl_m=ground_alt_msl_m,
                        ground_alt_how=ground_alt_how, home_wait_s=home_wait_s,
                        progress=progress, terrain_check=terrain_check)


def poses_of_log(log: FlightLog, framing: Framing, *, origin_lat_deg: float,
                 origin_lon_deg: float, ground_alt_msl_m: float | None,
                 ground_alt_how: str = "configured", home_wait_s: float = DEFAULT_HOME_WAIT_S,
                 progress: bool = False, terrain_check: TerrainCheck | None = None
                 ) -> LogPoses:
    """Camera poses of a flight log read (``read_flight_log``; for a camera of another
    gimbal device, ``logs.for_gimbal``) at the frames of ``framing`` (frame_decision).

    origin_*_deg: the ENU origin; ground_alt_msl_m: ground altitude there (m MSL), None =
    the autopilot's home at arming, as the daemon finds it (``ground_alt_of_log``, waiting
    home_wait_s of autopilot time for it); ground_alt_how: where a given one came from
    ('configured', 'the DEM at the origin'), for the summary. framing.frame_source 'rate'
    places frames every 1/frame_rate_hz s; 'capture' at the log's capture events; None (the
    user chose none): at the detector frames ``pdcov serve`` recorded in the log if it holds
    any, else 'rate' (recorded_frames.frame_source_for; a chosen 'rate' over such a log
    warns). Frames are decided by ``frame_decision.decide_frames`` (gaps longer than
    max_gap_s, untrusted gimbal frames by mount.untrusted, the estimator's verdicts, the
    zoom report in force, ``low``: below min_height_m). terrain_check: fed the log's
    samples (terrain_check.check_flight_log), when given. Raises TelemetryError /
    ConfigError with a message naming the file.
    """
    mount, zoom = framing.mount, framing.zoom
    if terrain_check is not None:
        check_flight_log(terrain_check, log)
    ground_alt, ground_how = ground_alt_of_log(
        log, GroundAltitude(ground_alt_msl_m, home_wait_s, ground_alt_how))
    origin = Origin(origin_lat_deg, origin_lon_deg, ground_alt)
    interp = None
    if isinstance(mount, GimbalMount):
        if log.gimbal_source is None:
            # Missing data never changes the physical model: a gimbal flight read as a
            # fixed mount would give a wrong map.
            read = "; ".join(log.damage) or "read whole, no damage found"
            raise TelemetryError(f"{log.path}: the mount is a gimbal but the log has no gimbal "
                                 "attitude (GIMBAL_DEVICE_ATTITUDE_STATUS / MNT / "
                                 "gimbal_device_attitude_status), so the camera's attitude is "
                                 f"unknown; reading the log: {read}. Use a log that recorded "
                                 "the gimbal's attitude")
        where = {"tlog": "the tlog's PARAM_VALUE messages (a tlog records parameters only "
                         "when the ground station read them)",
                 "dataflash": "the DataFlash PARM records",
                 "ulog": "the ULog parameters"}[log.format]
        interp = resolve_interpretation(mount, log.params, where)
    lens = None if zoom is None else LensReports(zoom)
    max_gap_s, frame_rate_hz = framing.max_gap_s, framing.frame_rate_hz
    tracker = PoseTracker.from_flight_log(log, origin, mount, interp, max_gap_s,
                                          use_estimator=framing.estimator_status, lens=lens)
    choice = frame_source_for(framing.frame_source,
                              sum(c.source == RECORDED_SOURCE for c in log.captures))
    frame_source = choice.source
    t, how = frame_times(tracker, log, frame_rate_hz, frame_source)

    chunks = range(0, len(t), _CHUNK)
    if progress:
        from tqdm import tqdm
        chunks = tqdm(chunks, desc="poses", unit="chunk", total=len(chunks))
    counts = FrameCounts.new()
    decided = [decide_frames(tracker, t[i:i + _CHUNK], framing, counts) for i in chunks]
    b = FrameBatch(**{name: np.concatenate([getattr(d.batch, name) for d in decided])
                      for name in FrameBatch.__slots__})
    sel = SelectedFrames.concatenate([d.selected for d in decided])
    use, poses = sel.use, sel.poses

    valid = b.valid
    policy = untrusted_policy(mount)
    rpy = np.degrees(euler_zyx_from_R_many(b.R_ned_body[use])) if use.any() else np.zeros((0, 3))

    step = 1.0 / frame_rate_hz if frame_source == "rate" else max_gap_s
    lines = [f"log: {log.path} ({log.format})", *log.notes, describe_faults(log.faults),
             f"origin: {origin.lat_deg:.7f}, {origin.lon_deg:.7f}, ground {ground_alt:.2f} m "
             f"MSL ({ground_how})",
             *(x for x in (choice.line,) if x),
             *(f"WARNING: {x}" for x in (choice.warning,) if x),
             f"frames: {how}; {int(use.sum())} used of {len(t)}"]
    skipped = b.t_s[~valid]
    if len(skipped):
        why = Counter(b.skip_reason[~valid])
        runs = _intervals(skipped, step)
        shown = ", ".join(f"{a:.2f}-{e:.2f} s ({k})" for a, e, k in runs[:8])
        more = f" and {len(runs) - 8} more" if len(runs) > 8 else ""
        lines.append(f"skipped {len(skipped)} frames in {len(runs)} gaps longer than "
                     f"{max_gap_s:g} s or outside the data: {shown}{more}; reasons: "
                     + ", ".join(f"{r} {c}" for r, c in why.most_common()))
    # Of the frames no other rule skipped: how many a report was in force for.
    checkable = valid | np.isin(b.skip_reason, ESTIMATOR_REASONS)
    lines.append(describe_estimator(log.estimator, log.estimator_source,
                                    int((b.estimator_judged & checkable).sum()),
                                    int(checkable.sum()), framing.estimator_status))
    lines.append(describe_skipped(counts))
    if lens is not None:
        lines.append(describe_lens(lens, b.lens_value[use]))
    lines.append(describe_accuracy(log.gnss_accuracy, sel.accuracies))
    if interp is not None:  # set exactly when the mount is a GimbalMount
        lines.append(interp.describe())
        lines.append(f"gimbal source (system, component, device id) {log.gimbal_source}")
        if tracker.dropped_gimbal_reports:
            lines.append(f"{tracker.dropped_gimbal_reports} gimbal reports without a "
                         "quaternion ignored")
        bad = valid & ~b.trusted
        why = Counter(b.untrusted_reason[bad])
        action = "skipped" if policy == "skip" else "used anyway"
        lines.append(f"untrusted frames: {int(bad.sum())} ({action}, mount.untrusted="
                     f"{policy!r})" + (": " + ", ".join(f"{r} {c}" for r, c in
                                                        why.most_common()) if why else ""))
        if interp.frame == "body":
            n_limit = int((valid & b.at_limit).sum())
            lines.append(f"frames with a servo demand at its limit: {n_limit} (trusted: the "
                         "autopilot clipped the demand, the servo is at its stop)")
    else:
        lines.append("fixed mount: camera attitude from the vehicle attitude and the mount "
                     "angles")
    utc = utc_clock_of(log)
    lines.append(describe_utc(log, utc, float(poses[0].t_s) if poses else math.nan))
    return LogPoses(poses, origin, tracker.positions_enu, tuple(lines), sel.q_enu_cam_wxyz, rpy,
                    b.gimbal_q_wxyz[use], b.gimbal_flags[use],
                    tuple(str(s) for s in b.interpretation[use]), b.trusted[use].copy(),
                    tuple(str(s) for s in b.untrusted_reason[use]), b.at_limit[use].copy(),
                    skipped, tuple(x for x in (choice.warning,) if x),
                    _frame_boxes(log) if frame_source == "capture" else {},
                    sel.cameras if zoom is not None else (), sel.accuracies,
                    {**log.faults, **{str(k): n for k, n in counts.faults.items() if n}},
                    sel.low, dict(counts.skipped), utc,
                    utc.unix_s_many(tracker.positions_t_s))


def describe_faults(faults: Mapping[str, int]) -> str:
    """The summary line of the bad telemetry counted (the daemon's status counts the same
    under faults)."""
    if not faults:
        return "bad telemetry: none counted"
    return ("bad telemetry counted (as pdcov serve counts it in its status): "
            + ", ".join(f"{k} {n}" for k, n in faults.items()))


def describe_skipped(counts: FrameCounts) -> str:
    """The summary line of the frames not used, by the reasons and fault keys the daemon's
    status counts them under (frames.skipped, faults)."""
    faults = {str(k): n for k, n in counts.faults.items() if n}
    if not counts.skipped and not faults:
        return "frames skipped (as pdcov serve counts them in its status): none"
    return ("frames skipped (as pdcov serve counts them in its status): "
            + (", ".join(f"{r} {n}" for r, n in counts.skipped.most_common()) or "none")
            + ("; faults: " + ", ".join(f"{k} {n}" for k, n in faults.items())
               if faults else ""))


def _frame_boxes(log: FlightLog) -> dict[float, tuple[float, tuple[Box, ...]]]:
    """The recorded boxes by their frame's time, in the order recorded."""
    out: dict[float, tuple[float, tuple[Box, ...]]] = {}
    for b in log.boxes:
        t_boot_s, boxes = out.get(b.t_s, (b.t_boot_s, ()))
        out[b.t_s] = (t_boot_s, (*boxes, b.box))
    return out
