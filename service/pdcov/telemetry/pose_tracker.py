"""Camera poses at frame times, interpolated from attitude, position and gimbal telemetry.

One ``PoseTracker`` serves both drivers (DESIGN.md "one pipeline, two drivers"): the live
daemon feeds samples as they arrive (``add_attitude`` / ``add_position`` / ``add_gimbal``)
and asks ``pose_at(t_s)`` per camera frame; offline, ``flight/log_frames.poses_from_log``
loads a whole ``FlightLog`` into one and asks ``frames_at`` for every frame time, in chunks
(vectorised).

Interpolation: attitude and gimbal quaternions by slerp, positions linearly in ENU, between
the two samples that bracket the frame time; a frame whose bracketing samples of any stream
are more than ``max_gap_s`` apart (or that lies outside a stream) is skipped, with the
reason. Frames whose position the autopilot's estimator calls bad are skipped too
(telemetry/estimator.py), unless ``use_estimator`` is False. Times are seconds in the
autopilot clock (telemetry/logs/).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from pdcov.core.geodesy import Origin, geodetic_to_enu
from pdcov.core.pose import (
    R_ENU_NED,
    R_GIMBAL_CAM,
    CameraPose,
    FixedMount,
    camera_motion,
    known_motion,
)
from pdcov.core.rotations import R_from_quat_wxyz, quat_norm, slerp_quat_wxyz
from pdcov.errors import ConfigError
from pdcov.telemetry.estimator import estimator_reasons, merge_estimator
from pdcov.telemetry.frame_policy import SkipReason, untrusted_policy
from pdcov.telemetry.gimbal import (
    GimbalInterpretation,
    GimbalMount,
    earth_frame_mask,
    interpret_gimbal,
    preferred_gimbal_source,
    resolve_interpretation,
)
from pdcov.telemetry.gnss_accuracy import accuracy_at, merge_accuracy
from pdcov.telemetry.lens_reports import LensReports
from pdcov.telemetry.samples import (
    AttitudeSample,
    EstimatorSample,
    GimbalSample,
    GnssAccuracySample,
    LensSample,
    PositionSample,
)
from pdcov.telemetry.series import (
    AttitudeSeries,
    EstimatorSeries,
    GimbalSeries,
    GnssAccuracySeries,
    PositionSeries,
    merge_sorted_columns,
)

if TYPE_CHECKING:
    from pdcov.telemetry.logs import FlightLog

MAX_SPEED_MPS = 60.0
"""Faster than this between two position samples (plus POSITION_JUMP_SLACK_M) is not flight
but a jump of the reported position (a GPS glitch, an EKF reset): a frame between the two
is skipped as 'position jump', never interpolated across it."""
POSITION_JUMP_SLACK_M = 2.0


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


RATE_STEP_S = 1e-3
"""Time step (s) of the difference that gives the camera's velocity and angular rate
(PoseTracker._rates)."""


def _rate_bracket(ts: np.ndarray, t: np.ndarray, max_gap_s: float
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """For query times ``t`` in sorted sample times ``ts``: (lo, hi, w, rate, ok) with hi
    the first sample at or after t and lo the one before it, w the fraction of t from lo to
    hi, rate = 1 / (ts[hi] - ts[lo]) the fraction per second; ok False (rate 0) where there
    is no such pair within max_gap_s (no sample before t or none after)."""
    n = len(ts)
    if n < 2:
        z = np.zeros(len(t), int)
        return z, z, np.zeros(len(t)), np.zeros(len(t)), np.zeros(len(t), bool)
    i = ts.searchsorted(t, side="left")
    hi = np.clip(i, 1, n - 1)
    lo = hi - 1
    gap = ts[hi] - ts[lo]
    ok = (i >= 1) & (i <= n - 1) & (gap > 0) & (gap <= max_gap_s)
    gap = np.where(ok, gap, 1.0)
    return lo, hi, (t - ts[lo]) / gap, np.where(ok, 1.0 / gap, 0.0), ok


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
    position-estimate rule could judge the frame). v_cam_enu_m_s (N, 3): the camera centre's
    velocity, ENU m/s; omega_enu_rad_s (N, 3): the camera's angular rate, ENU rad/s (both
    the derivative of the interpolated pose, PoseTracker._rates; NaN when unknown).
    lens_value (N,): the zoom report in force (lens_reports.py; NaN without a zoom lens or
    where none is). gnss_h_acc_m, gnss_v_acc_m (N,): the GNSS accuracy the autopilot
    reported, in force (gnss_accuracy.py), m, NaN where unknown."""

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
    v_cam_enu_m_s: np.ndarray
    omega_enu_rad_s: np.ndarray
    lens_value: np.ndarray
    gnss_h_acc_m: np.ndarray
    gnss_v_acc_m: np.ndarray

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
    lens: the zoom reports (lens_reports.py; None: the camera does not zoom).
    """

    def __init__(self, origin: Origin, mount: FixedMount | GimbalMount, *,
                 interpretation: GimbalInterpretation | None = None, max_gap_s: float = 1.0,
                 history_s: float | None = None, use_estimator: bool = True,
                 lens: LensReports | None = None) -> None:
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
        self._gnss = GnssAccuracySeries.from_samples([])
        self._pending_gnss: list[GnssAccuracySample] = []
        self._gimbal_flags_seen: dict[tuple[int, int, int], int] = {}
        self.gimbal_source: tuple[int, int, int] | None = None
        self.dropped_gimbal_reports = 0
        self.lens = lens

    @classmethod
    def from_flight_log(cls, log: FlightLog, origin: Origin, mount: FixedMount | GimbalMount,
                        interpretation: GimbalInterpretation | None,
                        max_gap_s: float = 1.0, use_estimator: bool = True,
                        lens: LensReports | None = None) -> PoseTracker:
        """A tracker holding a whole log's series (offline evaluation)."""
        tracker = cls(origin, mount, interpretation=interpretation, max_gap_s=max_gap_s,
                      use_estimator=use_estimator, lens=lens)
        for sample in log.lens:
            tracker.add_lens(sample)
        tracker._est = log.estimator
        tracker._gnss = log.gnss_accuracy
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

    def add_gnss_accuracy(self, sample: GnssAccuracySample) -> None:
        self._pending_gnss.append(sample)

    def add_lens(self, sample: LensSample) -> None:
        """Add a zoom report (ignored when the camera does not zoom)."""
        if self.lens is not None:
            self.lens.add(sample)

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
        cut_s = (self._att.t_s[-1] - self.history_s
                 if self.history_s is not None and len(self._att.t_s) else None)
        if self._pending_est:  # older reports than can be in force go with them
            self._est = merge_estimator(self._est,
                                        EstimatorSeries.from_samples(self._pending_est), cut_s)
            self._pending_est = []
        if self._pending_gnss:  # likewise
            self._gnss = merge_accuracy(self._gnss,
                                        GnssAccuracySeries.from_samples(self._pending_gnss),
                                        cut_s)
            self._pending_gnss = []
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

    @property
    def positions_t_s(self) -> np.ndarray:
        """The buffered positions' times (M,), s (autopilot clock), as ``positions_enu``."""
        self._merge()
        return self._pos_t.copy()

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
        return FrameResult(CameraPose(b.R_enu_cam[0], b.r_cam_enu[0], float(t_s),
                                      *known_motion(b.v_cam_enu_m_s[0], b.omega_enu_rad_s[0])),
                           trusted, reason)

    def frames_at(self, t_s: np.ndarray) -> FrameBatch:
        """Poses at the frame times ``t_s`` (N,), vectorised."""
        self._merge()
        t = np.asarray(t_s, float).reshape(-1)
        n = len(t)
        reason = np.full(n, "", dtype=object)

        def check(name: str, ts: np.ndarray, inside: np.ndarray, gap_ok: np.ndarray) -> None:
            # After a stream's last sample is a gap in it: the daemon decides such a frame
            # once the gap is longer than max_gap_s, before it knows whether the stream
            # resumes (as a log then shows), so both call it a gap.
            before = t < ts[0] if len(ts) else np.ones(n, bool)
            reason[~inside & before & (reason == "")] = f"outside the {name} samples"
            reason[~(inside & gap_ok) & (reason == "")] = f"{name} gap"

        lo, hi, w, inside, gap_ok = _bracket(self._att.t_s, t, self.max_gap_s)
        check("attitude", self._att.t_s, inside, gap_ok)
        att = (lo, hi, w)
        lo, hi, w, inside, gap_ok = _bracket(self._pos_t, t, self.max_gap_s)
        check("position", self._pos_t, inside, gap_ok)
        pos = (lo, hi, w)
        if len(self._pos_t):
            step = self._pos_enu[hi] - self._pos_enu[lo]
            jump = np.linalg.norm(step, axis=1) > (
                MAX_SPEED_MPS * (self._pos_t[hi] - self._pos_t[lo]) + POSITION_JUMP_SLACK_M)
            reason[inside & jump & (reason == "")] = SkipReason.POSITION_JUMP.value
        gim = (lo, hi, w)  # unused for a fixed mount
        if isinstance(self.mount, GimbalMount):
            lo, hi, w, inside, gap_ok = _bracket(self._gim.t_s, t, self.max_gap_s)
            check("gimbal", self._gim.t_s, inside, gap_ok)
            gim = (lo, hi, w)
        c = self._interpolate(n, att, pos, gim, gim[2])
        v_cam, omega = self._rates(t, c)
        c.update(t_s=t, skip_reason=reason, v_cam_enu_m_s=v_cam, omega_enu_rad_s=omega)
        # The estimator's verdict, where no rule above skipped the frame (a jump stays a jump).
        est_reason, judged = estimator_reasons(self._est, t)
        if not self.use_estimator:
            judged[:] = False
        else:
            reason[(est_reason != "") & (reason == "")] = est_reason[(est_reason != "")
                                                                     & (reason == "")]
        lens_value = np.full(n, np.nan)
        if self.lens is not None:
            lens_value, lens_reason = self.lens.at(t)
            late = (lens_reason != "") & (reason == "")
            reason[late] = lens_reason[late]
        h_acc, v_acc = accuracy_at(self._gnss, t)
        return FrameBatch(**c, estimator_judged=judged, lens_value=lens_value,
                          gnss_h_acc_m=h_acc, gnss_v_acc_m=v_acc)

    def _rates(self, t: np.ndarray, at_t: dict[str, np.ndarray]
               ) -> tuple[np.ndarray, np.ndarray]:
        """The camera's ENU velocity (N, 3) m/s and angular rate (N, 3) rad/s at ``t``: the
        derivative of the interpolated camera pose (``at_t``: the pose at t), a difference
        over RATE_STEP_S of each stream's interpolation between the last sample before t
        and the first at or after it (``_rate_bracket``, continued past the later sample
        for a frame on it), so that the daemon, which has those two once the frame is due,
        and evaluate, which has the whole log, give the same rates. NaN (unknown) where a
        stream the mount needs has no such pair within max_gap_s (a frame at a stream's
        first sample)."""
        n = len(t)
        h = RATE_STEP_S
        streams = [self._att.t_s, self._pos_t, self._gim.t_s]
        brackets = [_rate_bracket(ts, t, self.max_gap_s) for ts in streams]
        known = brackets[0][4] & brackets[1][4]
        if isinstance(self.mount, GimbalMount):
            known &= brackets[2][4]
        att, pos, gim = ((lo, hi, w + h * rate) for lo, hi, w, rate, _ok in brackets)
        later = self._interpolate(n, att, pos, gim, brackets[2][2])
        v_cam, omega = camera_motion(at_t["R_enu_cam"], at_t["r_cam_enu"],
                                     later["R_enu_cam"], later["r_cam_enu"], np.full(n, h))
        v_cam[~known] = np.nan
        omega[~known] = np.nan
        return v_cam, omega

    def _interpolate(self, n: int, att: tuple[np.ndarray, np.ndarray, np.ndarray],
                     pos: tuple[np.ndarray, np.ndarray, np.ndarray],
                     gim: tuple[np.ndarray, np.ndarray, np.ndarray], gim_near_w: np.ndarray
                     ) -> dict[str, np.ndarray]:
        """The camera of N frames from each stream's bracket (lo, hi, w): attitude and
        gimbal by slerp, position linearly; ``gim_near_w`` picks the nearer gimbal report
        (its flags, and its attitude across a change of frame). Returns FrameBatch's arrays
        of the pose, by field name."""
        lo, hi, w = att
        q = self._att.q_ned_body_wxyz
        if len(q):
            q_body = slerp_quat_wxyz(q[lo], q[hi], w)
        else:
            q_body = np.tile([1.0, 0, 0, 0], (n, 1))
        R_ned_body = R_from_quat_wxyz(q_body).reshape(n, 3, 3)

        lo, hi, w = pos
        if len(self._pos_t):
            r_body = self._pos_enu[lo] + w[:, None] * (self._pos_enu[hi] - self._pos_enu[lo])
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
            lo, hi, w = gim
            R_ned_gimbal = np.repeat(np.eye(3)[None], n, axis=0)  # no samples: skipped
            interp = np.full(n, interpretation.frame, dtype=object)
            if len(g.t_s):
                near = np.where(gim_near_w < 0.5, lo, hi)
                q_near = g.q_wxyz[near]
                norm = quat_norm(q_near)
                flags_lo, flags_hi = g.flags[lo], g.flags[hi]
                # Never slerp across a change of frame.
                same = earth_frame_mask(flags_lo) == earth_frame_mask(flags_hi)
                q_i = slerp_quat_wxyz(g.q_wxyz[lo], g.q_wxyz[hi], np.where(same, w, 0.0))
                q_i = np.where(same[:, None], q_i, q_near / norm[:, None])
                # Carry the nearer report's norm so that a non-unit report is judged as sent.
                gimbal_q = q_i * norm[:, None]
                gimbal_flags = np.where(gim_near_w < 0.5, flags_lo, flags_hi)
                failure = g.failure_flags[lo] | g.failure_flags[hi]
                att_g = interpret_gimbal(gimbal_q, gimbal_flags, failure, R_ned_body,
                                         interpretation)
                R_ned_gimbal, trusted, untrusted = att_g.R_ned_gimbal, att_g.trusted, \
                    att_g.reasons
                at_limit = att_g.at_limit
                if interpretation.frame == "flags":
                    interp = np.where(earth_frame_mask(gimbal_flags), "flags:earth",
                                      "flags:vehicle").astype(object)
        R_enu_cam = R_ENU_NED @ R_ned_gimbal @ R_GIMBAL_CAM
        r_cam = r_body + np.einsum("ij,njk,k->ni", R_ENU_NED, R_ned_body, lever)
        return {"R_ned_body": R_ned_body, "r_body_enu": r_body, "R_enu_cam": R_enu_cam,
                "r_cam_enu": r_cam, "gimbal_q_wxyz": gimbal_q, "gimbal_flags": gimbal_flags,
                "interpretation": interp, "trusted": trusted, "untrusted_reason": untrusted,
                "at_limit": at_limit}
