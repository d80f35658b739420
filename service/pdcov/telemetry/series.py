"""Time-sorted telemetry series: one array a field, sorted by time with one row a time.

Built from samples (``samples``) for the offline readers and the PoseTracker. Times ``t_s``
(N,) in s of the autopilot clock; quaternions (N, 4) (w, x, y, z) as their samples hold
them; latitude/longitude deg, altitudes m.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pdcov.telemetry.samples import (
    MIN_QUAT_NORM,
    AttitudeSample,
    EstimatorSample,
    GimbalSample,
    GnssAccuracySample,
    MountTargetSample,
    PositionSample,
    gnss_accuracy_m,
)


def _sort_unique(t_s: np.ndarray) -> np.ndarray:
    """Indices that sort ``t_s`` (stable) and keep the last of equal times."""
    order = np.argsort(t_s, kind="stable")
    ts = t_s[order]
    keep = np.append(ts[1:] != ts[:-1], True) if len(ts) else np.zeros(0, bool)
    return order[keep]


def merge_sorted_columns(old: tuple[np.ndarray, ...], new: tuple[np.ndarray, ...]
                         ) -> list[np.ndarray]:
    """Columns (time first) of two sets, each by strictly increasing time as the series
    keep them, merged in time order; of equal times the one from ``new`` is kept. Either set
    may be empty."""
    cols = [np.concatenate([a, b]) for a, b in zip(old, new, strict=True)]
    if not len(old[0]) or not len(new[0]) or new[0][0] > old[0][-1]:
        return cols  # live telemetry comes in order: ``new`` follows ``old``
    order = np.argsort(cols[0], kind="stable")
    keep = np.diff(cols[0][order], append=np.inf) > 0
    return [c[order][keep] for c in cols]


def _sorted_columns(rows: list[tuple[float, ...]], n_columns: int,
                    n_required: int) -> list[np.ndarray]:
    """Columns of ``rows`` (first = time) without rows whose first ``n_required`` values are
    not finite, sorted by time with unique times."""
    a = np.array(rows, float).reshape(-1, n_columns)
    a = a[np.all(np.isfinite(a[:, :n_required]), axis=1)]
    a = a[_sort_unique(a[:, 0])]
    return [a[:, i].copy() for i in range(n_columns)]


@dataclass(frozen=True, slots=True)
class AttitudeSeries:
    """Attitude samples as arrays sorted by strictly increasing t_s (s): q_ned_body_wxyz
    (N, 4) unit quaternions of R_ned_body."""

    t_s: np.ndarray
    q_ned_body_wxyz: np.ndarray

    @classmethod
    def from_samples(cls, samples: Sequence[AttitudeSample]) -> AttitudeSeries:
        t = np.array([s.t_s for s in samples], float)
        q = np.array([s.q_ned_body_wxyz for s in samples], float).reshape(-1, 4)
        with np.errstate(invalid="ignore", over="ignore"):
            norm = np.linalg.norm(q, axis=1)
        ok = np.isfinite(t) & np.all(np.isfinite(q), axis=1) & (norm > MIN_QUAT_NORM)
        t, q = t[ok], q[ok] / norm[ok, None]
        idx = _sort_unique(t)
        return cls(t[idx], q[idx])


@dataclass(frozen=True, slots=True)
class PositionSeries:
    """Position samples sorted by strictly increasing t_s (s): degrees, metres MSL, metres
    above home (NaN where unknown)."""

    t_s: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    alt_msl_m: np.ndarray
    relative_alt_m: np.ndarray

    @classmethod
    def from_samples(cls, samples: Sequence[PositionSample]) -> PositionSeries:
        return cls(*_sorted_columns([(s.t_s, s.lat_deg, s.lon_deg, s.alt_msl_m,
                                      s.relative_alt_m) for s in samples], 5, 4))


@dataclass(frozen=True, slots=True)
class GimbalSeries:
    """Gimbal status samples of one source sorted by strictly increasing t_s (s): q_wxyz
    (N, 4) as sent (NaN rows kept, so that they are counted), flags, failure_flags (N,)."""

    t_s: np.ndarray
    q_wxyz: np.ndarray
    flags: np.ndarray
    failure_flags: np.ndarray

    @classmethod
    def from_samples(cls, samples: Sequence[GimbalSample]) -> GimbalSeries:
        t = np.array([s.t_s for s in samples], float)
        q = np.array([s.q_wxyz for s in samples], float).reshape(-1, 4)
        flags = np.array([s.flags for s in samples], np.int64)
        fail = np.array([s.failure_flags for s in samples], np.int64)
        ok = np.isfinite(t)
        idx = _sort_unique(t[ok])
        return cls(t[ok][idx], q[ok][idx], flags[ok][idx], fail[ok][idx])


@dataclass(frozen=True, slots=True)
class EstimatorSeries:
    """Estimator verdicts (EstimatorSample) sorted by strictly increasing t_s (s): boolean
    arrays pos_horiz_abs, const_pos_mode, gps_glitch (N,)."""

    t_s: np.ndarray
    pos_horiz_abs: np.ndarray
    const_pos_mode: np.ndarray
    gps_glitch: np.ndarray

    @classmethod
    def from_samples(cls, samples: Sequence[EstimatorSample]) -> EstimatorSeries:
        t, *flags = _sorted_columns([(s.t_s, s.pos_horiz_abs, s.const_pos_mode, s.gps_glitch)
                                     for s in samples], 4, 1)
        return cls(t, *(f.astype(bool) for f in flags))


@dataclass(frozen=True, slots=True)
class MountTargetSeries:
    """Mount targets (DataFlash MNT desired angles, radians) sorted by t_s (s)."""

    t_s: np.ndarray
    roll_rad: np.ndarray
    pitch_rad: np.ndarray
    yaw_body_rad: np.ndarray
    yaw_earth_rad: np.ndarray

    @classmethod
    def from_samples(cls, samples: Sequence[MountTargetSample]) -> MountTargetSeries:
        return cls(*_sorted_columns([(s.t_s, s.roll_rad, s.pitch_rad, s.yaw_body_rad,
                                      s.yaw_earth_rad) for s in samples], 5, 1))


@dataclass(frozen=True, slots=True)
class GnssAccuracySeries:
    """Reported GNSS accuracies (GnssAccuracySample) sorted by strictly increasing t_s (s):
    horizontal_m, vertical_m (N,) in m, NaN where unknown (samples.gnss_accuracy_m)."""

    t_s: np.ndarray
    horizontal_m: np.ndarray
    vertical_m: np.ndarray

    @classmethod
    def from_samples(cls, samples: Sequence[GnssAccuracySample]) -> GnssAccuracySeries:
        return cls(*_sorted_columns([(s.t_s, gnss_accuracy_m(s.horizontal_m),
                                      gnss_accuracy_m(s.vertical_m)) for s in samples], 3, 1))
