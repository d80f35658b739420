"""The position-estimate rule: frames whose position the autopilot's own estimator calls bad
are skipped, live and offline alike (PoseTracker.frames_at applies it next to the
position-jump rule).

The estimator status in force at a frame time is the latest report strictly before it, held
for at most ESTIMATOR_HOLD_S. Strictly before, because EKF_STATUS_REPORT and ESTIMATOR_STATUS
are stamped with the autopilot time of the last timed message before them (they carry no
boot time of their own, clocks.BootClock): a report stamped exactly at a frame's time may
reach the daemon after the frame was decided. A frame with no report in force (the log or
link carries none, the stream stopped, or before its first report) is not judged by this
rule: it is counted, never skipped for it.

Verdicts, first that applies (samples.EstimatorSample):
* "position estimate: GPS glitching": the estimator takes its GPS for faulty (ArduPilot
  EKF_GPS_GLITCHING / nav_filter_status.gps_glitching, PX4 ESTIMATOR_GPS_GLITCH);
* "position estimate: constant position mode": no absolute horizontal position and the
  estimator holds a constant position (no aiding at all);
* "position estimate: no absolute position": no absolute horizontal position (no GPS fix
  used yet, relative aiding only, or EKF_UNINITIALIZED).
PX4 also sets its constant-position bit while the vehicle is at rest with a good position;
that alone skips nothing. The reports' "variances" are not read: ArduPilot fills
pos_horiz_variance with sqrt(position innovation test ratio) (NavEKF3_core::getVariances),
PX4 pos_horiz_ratio likewise, and both EKFs raise their glitch flag from those innovations.
"""

from __future__ import annotations

import numpy as np

from pdcov.telemetry.series import EstimatorSeries, merge_sorted_columns

ESTIMATOR_HOLD_S = 3.0
"""A report applies to frames up to this long after it (s). ArduPilot sends EXTRA3 at 1-4 Hz,
PX4 ESTIMATOR_STATUS at 0.5 Hz by default, the daemon asks link.estimator_hz (5 Hz)."""

GPS_GLITCHING = "position estimate: GPS glitching"
CONSTANT_POSITION = "position estimate: constant position mode"
NO_ABSOLUTE_POSITION = "position estimate: no absolute position"
REASONS = (GPS_GLITCHING, CONSTANT_POSITION, NO_ABSOLUTE_POSITION)


def estimator_reasons(est: EstimatorSeries, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For frame times ``t_s`` (N,) s: (reason (N,) object, '' where the position is good or
    the frame is not judged; judged (N,) bool, a report is in force)."""
    t = np.asarray(t_s, float).reshape(-1)
    reason = np.full(len(t), "", dtype=object)
    if len(est.t_s) == 0:
        return reason, np.zeros(len(t), bool)
    i = np.searchsorted(est.t_s, t, side="left") - 1
    k = np.clip(i, 0, None)
    judged = (i >= 0) & (t - est.t_s[k] <= ESTIMATOR_HOLD_S)
    no_abs = judged & ~est.pos_horiz_abs[k]
    reason[no_abs] = NO_ABSOLUTE_POSITION
    reason[no_abs & est.const_pos_mode[k]] = CONSTANT_POSITION
    reason[judged & est.gps_glitch[k]] = GPS_GLITCHING
    return reason, judged


def merge_estimator(old: EstimatorSeries, new: EstimatorSeries,
                    keep_from_s: float | None = None) -> EstimatorSeries:
    """The reports of both in time order (of equal times ``new``'s kept); with
    ``keep_from_s``, without those that can no longer be in force at or after it."""
    t, *flags = merge_sorted_columns(_columns(old), _columns(new))
    if keep_from_s is not None:
        keep = t >= keep_from_s - ESTIMATOR_HOLD_S
        t, flags = t[keep], [f[keep] for f in flags]
    return EstimatorSeries(t, *flags)


def _columns(e: EstimatorSeries) -> tuple[np.ndarray, ...]:
    return (e.t_s, e.pos_horiz_abs, e.const_pos_mode, e.gps_glitch)


def describe(est: EstimatorSeries, source: str, judged: int, n_frames: int,
             enabled: bool) -> str:
    """The summary line of the rule for ``n_frames`` frames (those no other rule skipped) of
    which ``judged`` had a report in force."""
    if not enabled:
        return "position estimate: not checked (log.estimator_status is false)"
    if len(est.t_s) == 0:
        return ("position estimate: the log carries no estimator status (EKF_STATUS_REPORT, "
                "ESTIMATOR_STATUS, XKF4/NKF4, estimator_status), so frames could not be "
                "checked against it")
    unchecked = (f"; {n_frames - judged} not checked (no report within "
                 f"{ESTIMATOR_HOLD_S:g} s before them)" if judged < n_frames else "")
    return (f"position estimate: {len(est.t_s)} reports ({source}); {judged} of {n_frames} "
            f"frames (not skipped otherwise) checked against the latest before them"
            f"{unchecked}")
