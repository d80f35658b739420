"""The position accuracy of each frame, live and offline alike (PoseTracker.frames_at gives
it next to the estimator rule): what the autopilot's GNSS receiver reported, which the
geolocation of the frame's boxes takes for the camera position's 1-sigma error in place of
the configured ``detections.horizontal_sigma_m`` / ``vertical_sigma_m``
(core/geolocate.py ``Geolocation.with_accuracy``).

The accuracy in force at a frame time is that of the latest report strictly before it,
held for at most GNSS_ACCURACY_HOLD_S -- the estimator's rule (telemetry/estimator.py):
GPS_RAW_INT carries no boot time, so it is stamped with the autopilot time of the last
timed message before it, and a report stamped exactly at a frame's time may reach the
daemon after the frame was decided. None (unknown: the configured sigmas) where no report
is in force, or where the one in force says none (samples.gnss_accuracy_m: 0, out of
bounds; either value unknown) -- never an accuracy made up from HDOP.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from pdcov.core.geolocate import PositionAccuracy
from pdcov.telemetry.series import GnssAccuracySeries, merge_sorted_columns

GNSS_ACCURACY_HOLD_S = 5.0
"""A report applies to frames up to this long after it (s). ArduPilot sends GPS_RAW_INT in
its EXTENDED_STATUS stream (2 Hz as a ground station usually asks), PX4 at 1 Hz or more; the
daemon asks service/link_setup.py GNSS_ACCURACY_HZ."""


def accuracy_at(series: GnssAccuracySeries, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For frame times ``t_s`` (N,) s: the reported (horizontal, vertical) accuracy in force
    (N,) each, m, NaN where unknown (module docstring)."""
    t = np.asarray(t_s, float).reshape(-1)
    h, v = np.full(len(t), np.nan), np.full(len(t), np.nan)
    if len(series.t_s) == 0:
        return h, v
    i = np.searchsorted(series.t_s, t, side="left") - 1
    k = np.clip(i, 0, None)
    held = (i >= 0) & (t - series.t_s[k] <= GNSS_ACCURACY_HOLD_S)
    known = held & np.isfinite(series.horizontal_m[k]) & np.isfinite(series.vertical_m[k])
    h[known], v[known] = series.horizontal_m[k[known]], series.vertical_m[k[known]]
    return h, v


def position_accuracies(horizontal_m: np.ndarray, vertical_m: np.ndarray
                        ) -> tuple[PositionAccuracy | None, ...]:
    """Per frame, the PositionAccuracy of ``accuracy_at``'s arrays (None where unknown)."""
    return tuple(None if not (np.isfinite(h) and np.isfinite(v))
                 else PositionAccuracy(float(h), float(v))
                 for h, v in zip(horizontal_m, vertical_m, strict=True))


def describe_accuracy(series: GnssAccuracySeries,
                      accuracies: Sequence[PositionAccuracy | None]) -> str:
    """The summary line of the rule for the frames used (their accuracies in force)."""
    known = [a.horizontal_m for a in accuracies if a is not None]
    if len(series.t_s) == 0:
        return ("GNSS accuracy: the log carries none (GPS_RAW_INT h_acc/v_acc, GPA, "
                "vehicle_gps_position); boxes geolocated with the configured "
                "detections.horizontal_sigma_m / vertical_sigma_m")
    line = (f"GNSS accuracy: {len(series.t_s)} reports, each in force for "
            f"{GNSS_ACCURACY_HOLD_S:g} s; {len(known)} of {len(accuracies)} frames used had "
            "one")
    if known:
        line += (f" (horizontal {min(known):.3g}-{max(known):.3g} m, in place of the "
                 "configured detections sigmas)")
    return line


def merge_accuracy(old: GnssAccuracySeries, new: GnssAccuracySeries,
                   keep_from_s: float | None = None) -> GnssAccuracySeries:
    """The reports of both in time order (of equal times ``new``'s kept); with
    ``keep_from_s``, without those that can no longer be in force at or after it."""
    t, h, v = merge_sorted_columns(_columns(old), _columns(new))
    if keep_from_s is not None:
        keep = t >= keep_from_s - GNSS_ACCURACY_HOLD_S
        t, h, v = t[keep], h[keep], v[keep]
    return GnssAccuracySeries(t, h, v)


def _columns(s: GnssAccuracySeries) -> tuple[np.ndarray, ...]:
    return (s.t_s, s.horizontal_m, s.vertical_m)
