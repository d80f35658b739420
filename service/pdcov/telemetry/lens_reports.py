"""Which zoom report applies to a frame: the camera model of each frame, live and offline alike
(PoseTracker.frames_at applies it next to the estimator rule, so both drivers share it).

The report in force at a frame time is the latest one of the followed camera strictly before
it, held for at most ``Zoom.max_report_age_s`` -- the estimator's rule (telemetry/
estimator.py): a report stamped exactly at a frame's time may reach the daemon after the
frame was decided. Reports are not a stream a frame waits for. A frame is skipped
(frame_policy.SkipReason), never evaluated with a guessed K, when

* no report came before it (``ZOOM_MISSING``) or the latest is older than the bound
  (``ZOOM_STALE``);
* the report in force lies outside the calibrated range (``ZOOM_OUT_OF_RANGE``,
  core/zoom.py ``refusal``);
* the report in force changed the focal length faster than the lens can zoom from the report
  before it (``ZOOM_JUMP``, core/zoom.py ``jumps``): a report flickering between two values
  skips its frames until two successive reports agree within the lens's speed.

Reports of another camera than the followed one (``Zoom.camera_id``, else the first heard)
and reports without the followed quantity are not used, and counted.
"""

from __future__ import annotations

import numpy as np

from pdcov.core.zoom import Zoom, jumps
from pdcov.telemetry.frame_policy import SkipReason
from pdcov.telemetry.samples import LensSample


class LensReports:
    """The followed camera's zoom reports (any order; kept whole: a few per second) and the
    value in force at frame times (autopilot clock, s)."""

    def __init__(self, zoom: Zoom) -> None:
        self.zoom = zoom
        self.camera_id = zoom.camera_id
        self.other_camera = 0  # reports of other cameras, not used
        self._t: list[float] = []
        self._v: list[float] = []
        self._arrays: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def add(self, sample: LensSample) -> None:
        if self.camera_id is None:
            self.camera_id = sample.camera_id
        if sample.camera_id != self.camera_id:
            self.other_camera += 1
            return
        value = float(getattr(sample, self.zoom.lens.quantity.value))
        if value != value:  # NaN: another message of the camera (or an unknown value)
            return
        self._t.append(float(sample.t_s))
        self._v.append(value)
        self._arrays = None

    @property
    def n_reports(self) -> int:
        """Reports of the followed camera with the followed quantity (distinct times)."""
        return len(self._series()[0])

    def _series(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(t_s, value, jump) by increasing time; of equal times the last added."""
        if self._arrays is None:
            t, v = np.asarray(self._t, float), np.asarray(self._v, float)
            order = np.argsort(t, kind="stable")
            t, v = t[order], v[order]
            keep = np.diff(t, append=np.inf) > 0
            t, v = t[keep], v[keep]
            lens = self.zoom.lens
            self._arrays = (t, v, jumps(t, lens.focal_px(v), lens.max_rate_per_s))
        return self._arrays

    def at(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For frame times (N,): the value in force (N,) (NaN where none) and the skip reason
        (N,) object ('' where the frame can use it)."""
        t = np.asarray(t_s, float).reshape(-1)
        ts, v, jump = self._series()
        reason = np.full(len(t), "", dtype=object)
        value = np.full(len(t), np.nan)
        if len(ts) == 0:
            reason[:] = SkipReason.ZOOM_MISSING.value
            return value, reason
        i = np.searchsorted(ts, t, side="left") - 1
        k = np.clip(i, 0, None)
        reason[i < 0] = SkipReason.ZOOM_MISSING.value
        held = i >= 0
        stale = held & (t - ts[k] > self.zoom.max_report_age_s)
        reason[stale] = SkipReason.ZOOM_STALE.value
        ok = held & ~stale
        reason[ok & jump[k]] = SkipReason.ZOOM_JUMP.value
        refusals = {x: self.zoom.lens.refusal(x) for x in np.unique(v[k[ok]])}
        out = ok & np.array([bool(refusals.get(x, "")) for x in v[k]], bool)
        reason[out & (reason == "")] = SkipReason.ZOOM_OUT_OF_RANGE.value
        value[ok] = v[k[ok]]
        return value, reason


def describe_lens(reports: LensReports, used_values: np.ndarray) -> str:
    """The summary line of the zoom for the frames used (their values in force)."""
    z = reports.zoom
    q = z.lens.quantity
    n = reports.n_reports
    line = (f"zoom: following {q} of camera (component, device) {reports.camera_id} "
            f"({n} reports, each in force for {z.max_report_age_s:g} s)")
    if len(used_values):
        lo, hi = float(np.min(used_values)), float(np.max(used_values))
        if q == "hfov_rad":
            line += f"; frames used at hfov {np.degrees(lo):.2f}-{np.degrees(hi):.2f} deg"
        else:
            line += f"; frames used at {q} {lo:g}-{hi:g}"
    if reports.other_camera:
        line += f"; {reports.other_camera} reports of other cameras not used"
    return line
