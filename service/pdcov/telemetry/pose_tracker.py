"""Camera poses at frame times, interpolated from attitude, position and gimbal telemetry.

One ``PoseTracker`` serves both drivers (DESIGN.md "one pipeline, two drivers"): the live
daemon feeds samples as they arrive (``add_attitude`` / ``add_position`` / ``add_gimbal``)
and asks ``pose_at(t_s)`` per camera frame; offline, ``poses_from_log`` loads a whole
``FlightLog`` into one and asks ``frames_at`` for every frame time at once (vectorised).

Interpolation: attitude and gimbal quaternions by slerp, positions linearly in ENU, between
the two samples that bracket the frame time; a frame whose bracketing samples of any stream
are more than ``max_gap_s`` apart (or that lies outside a stream) is skipped, with the
reason. Frames whose position the autopilot's estimator calls bad are skipped too
(telemetry/estimator.py), unless ``use_estimator`` is False. Times are seconds in the
autopilot clock (telemetry/logs/).
"""

from __future__ import annotations

import csv
import io
import math
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pdcov.atomic import atomic_write
from pdcov.core.geodesy import Origin, geodetic_to_enu
from pdcov.core.pose import (
    R_ENU_NED,
    R_GIMBAL_CAM,
    CameraPose,
    FixedMount,
)
from pdcov.core.rotations import (
    R_from_quat_wxyz,
    euler_zyx_from_R_many,
    quat_norm,
    slerp_quat_wxyz,
)
from pdcov.errors import ConfigError, InputFileError, TelemetryError
from pdcov.telemetry.estimator import REASONS as ESTIMATOR_REASONS
from pdcov.telemetry.estimator import describe as describe_estimator
from pdcov.telemetry.estimator import estimator_reasons, merge_estimator
from pdcov.telemetry.frame_policy import (
    FrameLattice,
    FrameSource,
    SkipReason,
    frames_used,
    home_ground_alt,
    position_ground_alt,
    rebuilt_R_enu_cam,
    untrusted_policy,
)
from pdcov.telemetry.gimbal import (
    GimbalInterpretation,
    GimbalMount,
    earth_frame_mask,
    interpret_gimbal,
    preferred_gimbal_source,
    resolve_interpretation,
)
from pdcov.telemetry.logs import FlightLog, read_flight_log
from pdcov.telemetry.recorded_frames import SOURCE as RECORDED_SOURCE
from pdcov.telemetry.recorded_frames import frame_source_for
from pdcov.telemetry.samples import (
    AttitudeSample,
    AttitudeSeries,
    EstimatorSample,
    EstimatorSeries,
    GimbalSample,
    GimbalSeries,
    PositionSample,
    PositionSeries,
    merge_sorted_columns,
)
from pdcov.yaml_file import read_text

POSE_CSV_COLUMNS = ("t_s", "x_m", "y_m", "z_m", "qw", "qx", "qy", "qz")
EXPORT_EXTRA_COLUMNS = ("roll_deg", "pitch_deg", "yaw_deg", "gimbal_qw", "gimbal_qx",
                        "gimbal_qy", "gimbal_qz", "gimbal_flags", "interpretation", "trusted",
                        "untrusted_reason")
QUAT_NORM_TOL = 1e-3
MAX_SPEED_MPS = 60.0
"""Faster than this between two position samples (plus POSITION_JUMP_SLACK_M) is not flight
but a jump of the reported position (a GPS glitch, an EKF reset): a frame between the two
is skipped as 'position jump', never interpolated across it."""
POSITION_JUMP_SLACK_M = 2.0


def position_jump(a: PositionSample, b: PositionSample) -> bool:
    """True when the reported position moved faster than MAX_SPEED_MPS (+ slack) from sample
    ``a`` to the later sample ``b``: the rule ``frames_at`` skips frames by, for counting."""
    dt = b.t_s - a.t_s
    if not dt > 0:
        return False
    step = geodetic_to_enu(b.lat_deg, b.lon_deg, b.alt_msl_m,
                           Origin(a.lat_deg, a.lon_deg, a.alt_msl_m))
    return float(np.linalg.norm(step)) > MAX_SPEED_MPS * dt + POSITION_JUMP_SLACK_M


def _bracket(ts: np.ndarray, t: np.ndarray, max_gap_s: float
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """For query times ``t`` in sorted sample times ``ts``: (lo, hi, w, inside, gap_ok) with
    ts[lo] <= t <= ts[hi], w the fraction from lo to hi, inside = within the samples, gap_ok
    = inside and ts[hi] - ts[lo] <= max_gap_s."""
    n = len(ts)
    if n == 0:
        z = np.zeros(len(t), int)
        f = np.zeros(len(t), bool)
        return z, z, np.zeros(len(t)), f, f
    i = ts.searchsorted(t, side="right")
    lo = np.maximum(i - 1, 0)  # i <= n
    exact = ts[lo] == t
    hi = np.where(exact, lo, np.minimum(i, n - 1))
    inside = (i >= 1) & ((i < n) | exact)
    gap = ts[hi] - ts[lo]
    w = np.where(gap > 0, (t - ts[lo]) / np.where(gap > 0, gap, 1.0), 0.0)
    return lo, hi, w, inside, inside & (gap <= max_gap_s)


def _gimbal_columns(g: GimbalSeries) -> tuple[np.ndarray, ...]:
    return (g.t_s, g.q_wxyz, g.flags, g.failure_flags)


@dataclass(frozen=True, slots=True)
class FrameBatch:
    """Poses for N frame times. ``skip_reason`` is '' where all streams bracket the frame
    (then the pose is valid); ``trusted``/``untrusted_reason`` judge the camera direction.
    Arrays: t_s (N,), R_ned_body (N, 3, 3), r_body_enu (N, 3) m, R_enu_cam (N, 3, 3),
    r_cam_enu (N, 3) m, gimbal_q_wxyz (N, 4) as interpolated (NaN for a fixed mount),
    gimbal_flags (N,) (-1 for a fixed mount), interpretation (N,) str, at_limit (N,) a
    servo demand at its limit. estimator_judged (N,): an estimator status was in force (the
    position-estimate rule could judge the frame)."""

    t_s: np.ndarray
    skip_reason: np.ndarray
    R_ned_body: np.ndarray
    r_body_enu: np.ndarray
    R_enu_cam: np.ndarray
    r_cam_enu: np.ndarray
    gimbal_q_wxyz: np.ndarray
    gimbal_flags: np.ndarray
    interpretation: np.ndarray
    trusted: np.ndarray
    untrusted_reason: np.ndarray
    at_limit: np.ndarray
    estimator_judged: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        return self.skip_reason == ""


@dataclass(frozen=True, slots=True)
class FrameResult:
    """One frame for the live daemon: the pose (None when skipped), whether its camera
    direction is trusted, and why it was skipped or not trusted ('' when neither)."""

    pose: CameraPose | None
    trusted: bool
    reason: str


class PoseTracker:
    """Buffers telemetry and gives camera poses at frame times (autopilot clock, s).

    origin: the ENU origin (ground altitude resolved). mount: FixedMount or GimbalMount.
    interpretation: the gimbal interpretation in force (gimbal.resolve_interpretation);
    None resolves a GimbalMount without autopilot parameters (its auto_fallback).
    history_s: live use keeps only this much history behind the newest sample.
    use_estimator: skip frames by the estimator status (telemetry/estimator.py).
    """

    def __init__(self, origin: Origin, mount: FixedMount | GimbalMount, *,
                 interpretation: GimbalInterpretation | None = None, max_gap_s: float = 1.0,
                 history_s: float | None = None, use_estimator: bool = True) -> None:
        if not (math.isfinite(max_gap_s) and max_gap_s > 0):
            raise ConfigError(f"max_gap_s: expected a positive number of seconds, "
                              f"got {max_gap_s!r}")
        self.origin = origin
        self.mount = mount
        if isinstance(mount, GimbalMount) and interpretation is None:
            interpretation = resolve_interpretation(mount, {}, "the link")
        self.interpretation = interpretation
        self.max_gap_s = float(max_gap_s)
        self.history_s = history_s
        self._att = AttitudeSeries.from_samples([])
        self._pos_t = np.zeros(0)
        self._pos_enu = np.zeros((0, 3))
        self._gim = GimbalSeries.from_samples([])
        self._pending_att: list[AttitudeSample] = []
        self._pending_pos: list[PositionSample] = []
        self._pending_gim: list[GimbalSample] = []
        self.use_estimator = use_estimator
        self._est = EstimatorSeries.from_samples([])
        self._pending_est: list[EstimatorSample] = []
        self._gimbal_flags_seen: dict[tuple[int, int, int], int] = {}
        self.gimbal_source: tuple[int, int, int] | None = None
        self.dropped_gimbal_reports = 0

    @classmethod
    def from_flight_log(cls, log: FlightLog, origin: Origin, mount: FixedMount | GimbalMount,
                        interpretation: GimbalInterpretation | None,
                        max_gap_s: float = 1.0, use_estimator: bool = True) -> PoseTracker:
        """A tracker holding a whole log's series (offline evaluation)."""
        tracker = cls(origin, mount, interpretation=interpretation, max_gap_s=max_gap_s,
                      use_estimator=use_estimator)
        tracker._est = log.estimator
        tracker._att = log.attitude
        tracker._set_positions(log.position)
        tracker._gim = tracker._usable_gimbal(log.gimbal)
        tracker.gimbal_source = log.gimbal_source
        return tracker

    # --- feeding (live) --------------------------------------------------------------------

    def add_attitude(self, sample: AttitudeSample) -> None:
        self._pending_att.append(sample)

    def add_position(self, sample: PositionSample) -> None:
        self._pending_pos.append(sample)

    def add_estimator(self, sample: EstimatorSample) -> None:
        self._pending_est.append(sample)

    def add_gimbal(self, sample: GimbalSample) -> None:
        """Add a gimbal status; reports of other sources than the preferred one (gimbal.
        preferred_gimbal_source) are ignored."""
        seen = self._gimbal_flags_seen
        seen[sample.source] = seen.get(sample.source, 0) | sample.flags
        source = preferred_gimbal_source(seen, 1, getattr(self.mount, "instance", 1))
        if source != self.gimbal_source:
            self.gimbal_source = source
            self._gim = GimbalSeries.from_samples([])
            self._pending_gim = [s for s in self._pending_gim if s.source == source]
        if sample.source == source:
            self._pending_gim.append(sample)

    def _set_positions(self, pos: PositionSeries) -> None:
        self._pos_t = pos.t_s
        self._pos_enu = geodetic_to_enu(pos.lat_deg, pos.lon_deg, pos.alt_msl_m,
                                        self.origin).reshape(-1, 3)

    def _usable_gimbal(self, g: GimbalSeries) -> GimbalSeries:
        norm = np.linalg.norm(g.q_wxyz, axis=1)
        ok = np.isfinite(norm) & (norm > 0.5)
        self.dropped_gimbal_reports += int((~ok).sum())
        return GimbalSeries(*(c[ok] for c in _gimbal_columns(g)))

    def _merge(self) -> None:
        """Fold pending samples into the sorted series; drop history older than history_s."""
        if self._pending_att:
            new_att = AttitudeSeries.from_samples(self._pending_att)
            self._att = AttitudeSeries(*merge_sorted_columns(
                (self._att.t_s, self._att.q_ned_body_wxyz),
                (new_att.t_s, new_att.q_ned_body_wxyz)))
            self._pending_att = []
        if self._pending_pos:
            new_pos = PositionSeries.from_samples(self._pending_pos)
            enu = geodetic_to_enu(new_pos.lat_deg, new_pos.lon_deg, new_pos.alt_msl_m,
                                  self.origin).reshape(-1, 3)
            self._pos_t, self._pos_enu = merge_sorted_columns((self._pos_t, self._pos_enu),
                                                       (new_pos.t_s, enu))
            self._pending_pos = []
        if self._pending_gim:
            new_gim = self._usable_gimbal(GimbalSeries.from_samples(self._pending_gim))
            self._gim = GimbalSeries(*merge_sorted_columns(_gimbal_columns(self._gim),
                                                    _gimbal_columns(new_gim)))
            self._pending_gim = []
        if self._pending_est:  # older reports than can be in force go with them
            cut_s = (self._att.t_s[-1] - self.history_s
                     if self.history_s is not None and len(self._att.t_s) else None)
            self._est = merge_estimator(self._est,
                                        EstimatorSeries.from_samples(self._pending_est), cut_s)
            self._pending_est = []
        if self.history_s is not None and len(self._att.t_s):
            cut = self._att.t_s[-1] - self.history_s
            # Sorted times: the history kept is a slice from the first time >= cut.
            a = int(self._att.t_s.searchsorted(cut))
            if a:
                self._att = AttitudeSeries(self._att.t_s[a:], self._att.q_ned_body_wxyz[a:])
            p = int(self._pos_t.searchsorted(cut))
            self._pos_t, self._pos_enu = self._pos_t[p:], self._pos_enu[p:]
            g = int(self._gim.t_s.searchsorted(cut))
            if g:
                self._gim = GimbalSeries(*(c[g:] for c in _gimbal_columns(self._gim)))

    # --- querying --------------------------------------------------------------------------

    @property
    def positions_enu(self) -> np.ndarray:
        """The buffered vehicle positions (M, 3), ENU m, in time order."""
        self._merge()
        return self._pos_enu.copy()

    def coverage_s(self) -> tuple[float, float]:
        """(first, last) time at which every stream the mount needs has samples (NaN, NaN
        when one is empty)."""
        self._merge()
        streams = [self._att.t_s, self._pos_t]
        if isinstance(self.mount, GimbalMount):
            streams.append(self._gim.t_s)
        if any(len(s) == 0 for s in streams):
            return math.nan, math.nan
        return max(s[0] for s in streams), min(s[-1] for s in streams)

    def pose_at(self, t_s: float) -> FrameResult:
        """The camera pose at ``t_s`` (live use); skipped frames have pose None."""
        b = self.frames_at(np.array([t_s], float))
        reason = str(b.skip_reason[0] or b.untrusted_reason[0])
        if not b.valid[0]:
            return FrameResult(None, False, reason)
        trusted = bool(b.trusted[0])
        if not trusted and untrusted_policy(self.mount) == "skip":
            return FrameResult(None, False, reason)
        return FrameResult(CameraPose(b.R_enu_cam[0], b.r_cam_enu[0], float(t_s)), trusted,
                           reason)

    def frames_at(self, t_s: np.ndarray) -> FrameBatch:
        """Poses at the frame times ``t_s`` (N,), vectorised."""
        self._merge()
        t = np.asarray(t_s, float).reshape(-1)
        n = len(t)
        reason = np.full(n, "", dtype=object)

        def check(name: str, inside: np.ndarray, gap_ok: np.ndarray) -> None:
            reason[~inside & (reason == "")] = f"outside the {name} samples"
            reason[inside & ~gap_ok & (reason == "")] = f"{name} gap"

        lo, hi, w, inside, gap_ok = _bracket(self._att.t_s, t, self.max_gap_s)
        check("attitude", inside, gap_ok)
        q = self._att.q_ned_body_wxyz
        if len(q):
            q_body = slerp_quat_wxyz(q[lo], q[hi], w)
        else:
            q_body = np.tile([1.0, 0, 0, 0], (n, 1))
        R_ned_body = R_from_quat_wxyz(q_body).reshape(n, 3, 3)

        lo, hi, w, inside, gap_ok = _bracket(self._pos_t, t, self.max_gap_s)
        check("position", inside, gap_ok)
        if len(self._pos_t):
            step = self._pos_enu[hi] - self._pos_enu[lo]
            r_body = self._pos_enu[lo] + w[:, None] * step
            jump = np.linalg.norm(step, axis=1) > (
                MAX_SPEED_MPS * (self._pos_t[hi] - self._pos_t[lo]) + POSITION_JUMP_SLACK_M)
            reason[inside & jump & (reason == "")] = SkipReason.POSITION_JUMP.value
        else:
            r_body = np.zeros((n, 3))

        gimbal_q = np.full((n, 4), np.nan)
        gimbal_flags = np.full(n, -1, np.int64)
        trusted = np.ones(n, bool)
        at_limit = np.zeros(n, bool)
        untrusted = np.full(n, "", dtype=object)
        lever = np.asarray(self.mount.lever_arm_frd_m, float)
        if isinstance(self.mount, FixedMount):
            R_ned_gimbal = R_ned_body @ self.mount.R_body_gimbal
            interp = np.full(n, "fixed", dtype=object)
        else:
            interpretation = self.interpretation
            if interpretation is None:  # __init__ resolves one for every GimbalMount
                raise AttributeError("PoseTracker.interpretation is None for a gimbal mount")
            g = self._gim
            lo, hi, w, inside, gap_ok = _bracket(g.t_s, t, self.max_gap_s)
            check("gimbal", inside, gap_ok)
            R_ned_gimbal = np.repeat(np.eye(3)[None], n, axis=0)  # no samples: skipped
            interp = np.full(n, interpretation.frame, dtype=object)
            if len(g.t_s):
                near = np.where(w < 0.5, lo, hi)
                q_near = g.q_wxyz[near]
                norm = quat_norm(q_near)
                flags_lo, flags_hi = g.flags[lo], g.flags[hi]
                # Never slerp across a change of frame.
                same = earth_frame_mask(flags_lo) == earth_frame_mask(flags_hi)
                q_i = slerp_quat_wxyz(g.q_wxyz[lo], g.q_wxyz[hi], np.where(same, w, 0.0))
                q_i = np.where(same[:, None], q_i, q_near / norm[:, None])
                # Carry the nearer report's norm so that a non-unit report is judged as sent.
                gimbal_q = q_i * norm[:, None]
                gimbal_flags = np.where(w < 0.5, flags_lo, flags_hi)
                failure = g.failure_flags[lo] | g.failure_flags[hi]
                att = interpret_gimbal(gimbal_q, gimbal_flags, failure, R_ned_body,
                                       interpretation)
                R_ned_gimbal, trusted, untrusted = att.R_ned_gimbal, att.trusted, att.reasons
                at_limit = att.at_limit
                if interpretation.frame == "flags":
                    interp = np.where(earth_frame_mask(gimbal_flags), "flags:earth",
                                      "flags:vehicle").astype(object)
        # The estimator's verdict, where no rule above skipped the frame (a jump stays a jump).
        est_reason, judged = estimator_reasons(self._est, t)
        if not self.use_estimator:
            judged[:] = False
        else:
            reason[(est_reason != "") & (reason == "")] = est_reason[(est_reason != "")
                                                                     & (reason == "")]
        R_enu_cam = R_ENU_NED @ R_ned_gimbal @ R_GIMBAL_CAM
        r_cam = r_body + np.einsum("ij,njk,k->ni", R_ENU_NED, R_ned_body, lever)
        return FrameBatch(t, reason, R_ned_body, r_body, R_enu_cam, r_cam, gimbal_q,
                          gimbal_flags, interp, trusted, untrusted, at_limit, judged)


# --- offline: a whole log ----------------------------------------------------------------

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
    summary lines).
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


def _ground_alt(log: FlightLog, ground_alt_msl_m: float | None) -> tuple[float, str]:
    """The ground altitude of a whole log: configured, else the last home
    (frame_policy.home_ground_alt, as the daemon falls back to), else the first position's
    (frame_policy.position_ground_alt)."""
    if ground_alt_msl_m is not None:
        return float(ground_alt_msl_m), "configured"
    home = home_ground_alt(log.homes)
    if home is not None:
        return home
    p = log.position
    ok = np.isfinite(p.relative_alt_m)
    if ok.any():
        i = int(np.argmax(ok))
        return position_ground_alt(p.alt_msl_m[i], p.relative_alt_m[i])
    raise TelemetryError(f"{log.path}: the log gives no home altitude (no HOME_POSITION, ORGN "
                         "or relative altitude); set origin.ground_alt_msl_m in the config")


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


def poses_from_log(path: str | Path, *, origin_lat_deg: float, origin_lon_deg: float,
                   ground_alt_msl_m: float | None, mount: FixedMount | GimbalMount,
                   frame_rate_hz: float, frame_source: str | None = "rate",
                   max_gap_s: float = 1.0,
                   system_id: int | None = None, progress: bool = False,
                   estimator_status: bool = True) -> LogPoses:
    """Camera poses of a flight log (.tlog, DataFlash .bin, PX4 .ulg) at the camera's frames.

    origin_*_deg: the ENU origin; ground_alt_msl_m: ground altitude there (m MSL), None =
    the autopilot's home altitude from the log. frame_source 'rate' places frames every
    1/frame_rate_hz s; 'capture' at the log's capture events; None (the user chose none):
    at the detector frames ``pdcov serve`` recorded in the log if it holds any, else 'rate'
    (recorded_frames.frame_source_for; a chosen 'rate' over such a log warns). Frames whose
    telemetry has a
    gap longer than max_gap_s are skipped; untrusted gimbal frames follow mount.untrusted.
    estimator_status: skip frames the autopilot's estimator calls bad (estimator.py).
    Raises TelemetryError / ConfigError with a message naming the file.
    """
    log = read_flight_log(path, system_id=system_id,
                          gimbal_instance=mount.instance if isinstance(mount, GimbalMount)
                          else 1)
    ground_alt, ground_how = _ground_alt(log, ground_alt_msl_m)
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
    tracker = PoseTracker.from_flight_log(log, origin, mount, interp, max_gap_s,
                                          use_estimator=estimator_status)
    choice = frame_source_for(frame_source,
                              sum(c.source == RECORDED_SOURCE for c in log.captures))
    frame_source = choice.source
    t, how = frame_times(tracker, log, frame_rate_hz, frame_source)

    chunks = range(0, len(t), _CHUNK)
    if progress:
        from tqdm import tqdm
        chunks = tqdm(chunks, desc="poses", unit="chunk", total=len(chunks))
    batches = [tracker.frames_at(t[i:i + _CHUNK]) for i in chunks]
    cat = {name: np.concatenate([getattr(b, name) for b in batches]) if batches else
           np.zeros(0) for name in FrameBatch.__slots__}
    b = FrameBatch(**cat)

    valid = b.valid
    policy = untrusted_policy(mount)
    use = frames_used(valid, b.trusted, policy)
    q_cam, R_cam = rebuilt_R_enu_cam(b.R_enu_cam[use])
    poses = tuple(CameraPose(R, r, float(ts)) for R, r, ts in
                  zip(R_cam, b.r_cam_enu[use], b.t_s[use], strict=True))
    rpy = np.degrees(euler_zyx_from_R_many(b.R_ned_body[use])) if use.any() else np.zeros((0, 3))

    step = 1.0 / frame_rate_hz if frame_source == "rate" else max_gap_s
    lines = [f"log: {log.path} ({log.format})", *log.notes,
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
                                    int(checkable.sum()), estimator_status))
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
    return LogPoses(poses, origin, tracker.positions_enu, tuple(lines), q_cam, rpy,
                    b.gimbal_q_wxyz[use], b.gimbal_flags[use],
                    tuple(str(s) for s in b.interpretation[use]), b.trusted[use].copy(),
                    tuple(str(s) for s in b.untrusted_reason[use]), b.at_limit[use].copy(),
                    skipped, tuple(x for x in (choice.warning,) if x))


# --- pose CSV ------------------------------------------------------------------------------

def write_pose_csv(path: str | Path, log_poses: LogPoses) -> None:
    """Write the poses as CSV (POSE_CSV_COLUMNS + EXPORT_EXTRA_COLUMNS), atomically."""
    with atomic_write(path, "w", newline="") as f:
        writer = csv.writer(f, lineterminator="\n")
        writer.writerow(POSE_CSV_COLUMNS + EXPORT_EXTRA_COLUMNS)
        writer.writerows(log_poses.export_rows())


def read_pose_csv(path: str | Path) -> tuple[CameraPose, ...]:
    """Camera poses from a pose CSV: header starting ``t_s,x_m,y_m,z_m,qw,qx,qy,qz`` (more
    columns allowed and ignored), camera centre ENU m and the unit quaternion (w, x, y, z)
    of R_enu_cam. The poses come sorted by time, whatever the order of the rows. Raises
    InputFileError naming the file and line."""
    path = Path(path)
    text = read_text(path, "pose CSV", InputFileError)
    rows: list[list[float]] = []
    lines: list[int] = []
    reader = csv.reader(io.StringIO(text, newline=""))
    try:
        header = [h.strip() for h in next(reader, [])]
        if tuple(header[:8]) != POSE_CSV_COLUMNS:
            raise InputFileError(f"{path}:1: expected the header "
                                 f"{','.join(POSE_CSV_COLUMNS)}, got {','.join(header)!r}")
        for row in reader:
            line = reader.line_num
            if not row or all(not c.strip() for c in row):
                continue
            if len(row) < 8:
                raise InputFileError(f"{path}:{line}: expected 8 columns, got {len(row)}")
            try:
                rows.append([float(c) for c in row[:8]])
            except ValueError:
                raise InputFileError(f"{path}:{line}: expected 8 numbers, got {row[:8]!r}"
                                     ) from None
            lines.append(line)
    except csv.Error as exc:
        raise InputFileError(f"{path}:{reader.line_num}: {exc}") from None
    values = np.array(rows, dtype=float).reshape(-1, 8)
    finite = np.isfinite(values)
    if not finite.all():
        k = int(np.flatnonzero(~finite.all(axis=1))[0])
        bad = [POSE_CSV_COLUMNS[i] for i in np.flatnonzero(~finite[k])]
        raise InputFileError(f"{path}:{lines[k]}: {', '.join(bad)} not a finite number")
    norm = np.linalg.norm(values[:, 4:], axis=1)
    off = np.abs(norm - 1.0) > QUAT_NORM_TOL
    if off.any():
        k = int(np.flatnonzero(off)[0])
        raise InputFileError(f"{path}:{lines[k]}: quaternion (qw, qx, qy, qz) has norm "
                             f"{norm[k]:.6f}; expected a unit quaternion "
                             f"(within {QUAT_NORM_TOL})")
    # Rows in time order (ties by their values): which look counts with
    # coverage.min_revisit_s depends on the order of the frames, and the grid's float sums on
    # the order of the additions, so any order of the same rows gives the same grid.
    values = values[np.lexsort(values.T[::-1])]
    # from_quat normalises, exactly as when the poses were written.
    R_enu_cam = R_from_quat_wxyz(values[:, 4:]).reshape(-1, 3, 3)
    poses = [CameraPose(R, v[1:4], float(v[0])) for R, v in zip(R_enu_cam, values, strict=True)]
    if not poses:
        raise InputFileError(f"{path}: no pose rows after the header")
    return tuple(poses)
