"""The simulated object detector: the stand-in for an onboard detector, drawing from the
mission's detector model (docs/simulator.md, "Targets and the simulated detector").

At each camera frame, given the true camera pose:

* **People.** A person is in the picture when their ground point is in front of the camera,
  inside the calibrated field of view, inside the picture and within the grid's maximum
  slant range, and the terrain (the mission's, if any) does not hide it
  (``core.occlusion.hidden_by_terrain``). Their apparent size is computed here, not by the
  coverage grid's kernel: the four corners of a cell-sized square centred on the person (on
  the terrain, or the flat ground) are projected with ``CameraModel.project`` and the size
  is the square root of the area of that quadrilateral inside the picture, scaled to
  detector-input pixels (``DetectorModel.image_to_input_scale``), as the detector model
  bins sizes. Under what stands on the ground (the mission's ``terrain.surface``) the
  line of sight from the person's ground point to the camera has a transmittance
  (``core.ground_cover.transmittance``, the grid's rule for each of a cell's rays): 0
  behind or under something solid (not in view), else exp(-k L) through tree cover, and
  P_D is multiplied by it. The person is detected with P_D(size); with a model whose
  ``looks`` section
  gives the per-bin correlation, each person draws one latent quantile q ~ U(0, 1) and is
  detected with their own detectability ``core.looks.detectability_quantile`` (the Beta
  quantile of the bin's mean and correlation at q, the rule ``coverage.looks: correlated``
  integrates over): a person hard to see stays hard to see.
* **False alarms.** Each free cell the grid observes gives a false alarm with the grid's
  P_FA per look, 1 - exp(-rate(size) A) (``DetectorModel.p_false_alarm_per_look``; A the
  cell's image area, size^2, in detector-input px^2; the grid's ``observe`` gives the cells
  and their sizes), placed uniformly inside the cell.
* **Looks.** With ``look_interval_s`` (default: the mission's ``coverage.min_revisit_s``)
  the detector's outcomes are drawn afresh for a person or a cell only once per interval,
  by the grid's revisit rule (the first frame that sees it at least that long after the
  last draw); on the frames in between it reports what that draw found, as long as it
  stays in view. This is the world the model's revisit setting describes: frames closer
  than the interval are not independent looks. Without it every frame draws afresh.
* **Boxes.** A detection's box has its bottom-centre at the pixel of the ground point (the
  person's feet, or the false alarm's point) plus Gaussian noise of ``box_noise_px`` per
  axis; its width is ``person_width_m`` projected at the point's depth, its height the
  projected length of the person standing there (``person_height_m``), at least the width
  (from straight above a person is as tall as wide in the picture); clipped to the picture.
  Confidence: with a model whose ``confidence`` section gives the histograms, a person's box
  draws a confidence bin from the true boxes' histogram of the box's size bin (its own size
  sqrt(w h) in detector-input pixels, as the fit bins boxes; outside the bins the nearest
  one), a false alarm's from the false boxes' histogram, and the confidence uniformly
  within that bin. Without the section: threshold + (1 - threshold) * Beta(4, 2) for people,
  Beta(2, 4) for false alarms (threshold: the model's confidence_threshold, else 0.25).

Pure: no I/O, no clock; a seed fixes every draw.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pdcov.core.camera import CameraModel
from pdcov.core.cell_area import clipped_quad_area
from pdcov.core.detections import Box
from pdcov.core.grid import CoverageGrid
from pdcov.core.ground_cover import transmittance
from pdcov.core.looks import detectability_quantile
from pdcov.core.occlusion import hidden_by_terrain
from pdcov.core.pose import CameraPose

from .targets import Targets

PERSON_CLASS = "person"
FALSE_ALARM_ID = -1
_DEFAULT_THRESHOLD = 0.25
_REVISIT_TOL_S = 1e-6  # as the grid's: times within 1 us count as equal
# The corners of a square centred on a point, in order around it, in units of its side.
_SQUARE = np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]])


@dataclass(frozen=True, slots=True)
class DetectorOptions:
    """person_height_m, person_width_m: the standing person a box frames (m);
    box_noise_px: 1-sigma pixel noise of a box's ground point, per axis; look_interval_s:
    seconds between independent draws for one person or cell (None: every frame)."""

    person_height_m: float = 1.7
    person_width_m: float = 0.5
    box_noise_px: float = 1.0
    look_interval_s: float | None = None

    def __post_init__(self) -> None:
        for name in ("person_height_m", "person_width_m"):
            if not 0 < getattr(self, name) < 100:
                raise ValueError(f"{name} {getattr(self, name)!r}: expected 0 < m < 100")
        if not 0 <= self.box_noise_px < 1000:
            raise ValueError(f"box_noise_px {self.box_noise_px!r}: expected 0 <= px < 1000")
        if self.look_interval_s is not None and not 0 <= self.look_interval_s < 3600:
            raise ValueError(f"look_interval_s {self.look_interval_s!r}: expected "
                             "0 <= s < 3600")


@dataclass(frozen=True, slots=True)
class SimulatedDetection:
    """One box of a frame: ``person_id`` (index into the targets) or FALSE_ALARM_ID."""

    person_id: int
    box: Box


class SimulatedDetector:
    """Boxes per frame for ``targets`` seen through ``camera``; ``grid`` is an empty
    coverage grid of the mission (its geometry, free mask, detector model, maximum range
    and terrain; the detector keeps its own copy of the looks in it)."""

    def __init__(self, grid: CoverageGrid, targets: Targets, options: DetectorOptions,
                 seed: int) -> None:
        interval = options.look_interval_s or None
        self.grid = CoverageGrid(grid.geometry, grid.mask, grid.camera, grid.detector,
                                 max_range_m=grid.max_range_m, min_revisit_s=interval,
                                 terrain=grid.terrain)
        self.camera: CameraModel = grid.camera
        self.detector = grid.detector
        self.terrain = None if grid.terrain is None or grid.terrain.is_level_zero \
            else grid.terrain
        self.covered = None if grid.terrain is None or grid.terrain.cover is None \
            else grid.terrain
        self.targets = targets
        self.options = options
        self.interval_s = interval
        self.scale = self.detector.image_to_input_scale(self.camera.width_px,
                                                        self.camera.height_px)
        threshold = self.detector.confidence_threshold
        self.threshold = _DEFAULT_THRESHOLD if threshold is None else threshold
        self.rng = np.random.default_rng([seed, 0xDE7EC7])
        n = len(targets)
        self._person_last_s = np.full(n, -np.inf)
        self._person_found = np.zeros(n, dtype=bool)
        looks = self.detector.looks
        # Each person's latent quantile, from its own stream (the other draws stay as they
        # were without a looks section); and the correlation per padded bin index.
        self.person_q = (None if looks is None
                         else np.random.default_rng([seed, 0x1A7E]).random(n))
        self._rho = (None if looks is None
                     else np.concatenate(([0.0], looks.correlation, [0.0])))
        shape = grid.geometry.shape
        self._fa_on = np.zeros(shape, dtype=bool)
        self._fa_enu_m = np.zeros((*shape, 3))

    # -- people -------------------------------------------------------------------------

    def person_sizes_px(self, pose: CameraPose) -> tuple[np.ndarray, np.ndarray]:
        """Per person: whether it is in view (in the picture, in range, not hidden) and its
        apparent size in detector-input pixels (NaN where not in view)."""
        r = self.targets.r_enu_m
        cam = self.camera
        p_cam = (r - pose.r_cam_enu) @ pose.R_enu_cam
        _, in_view = cam.visible(p_cam)
        in_view &= np.linalg.norm(r - pose.r_cam_enu, axis=1) <= self.grid.max_range_m
        if self.terrain is not None and in_view.any():
            k = np.flatnonzero(in_view)
            in_view[k[hidden_by_terrain(self.terrain, pose.r_cam_enu, r[k, 0], r[k, 1],
                                        r[k, 2])]] = False
        size = np.full(len(r), np.nan)
        k = np.flatnonzero(in_view)
        if len(k):
            cs = self.grid.geometry.cell_size_m
            xy = r[k, None, :2] + cs * _SQUARE                      # (k, 4, 2)
            z = (np.repeat(r[k, None, 2], 4, axis=1) if self.terrain is None
                 else self.terrain.height_m(xy[..., 0], xy[..., 1]))
            corners = np.concatenate([xy, z[..., None]], axis=-1).reshape(-1, 3)
            c_cam = (corners - pose.r_cam_enu) @ pose.R_enu_cam
            ok = cam.projectable(c_cam).reshape(-1, 4).all(axis=1)
            px = np.zeros((len(c_cam), 2))
            good = np.repeat(ok, 4)
            px[good] = cam.project(c_cam[good])
            area = clipped_quad_area(px.reshape(-1, 4, 2), cam.width_px, cam.height_px)
            size[k] = np.where(ok, np.sqrt(area) * self.scale, np.nan)
        return in_view, size

    def person_p_detect(self, size_px: np.ndarray) -> np.ndarray:
        """Per person, their P_D at this apparent size (detector-input px; NaN: 0): the
        model's, or with its looks section their own detectability at their latent q."""
        p_d, _ = self.detector.lookup(size_px)
        if self.person_q is None or self._rho is None:
            return p_d
        rho = self._rho[self.detector.bin_index(size_px)]
        return detectability_quantile(p_d, rho, self.person_q)

    def person_transmittance(self, pose: CameraPose, in_view: np.ndarray) -> np.ndarray:
        """Per person, the transmittance of their line of sight to the camera through what
        stands on the ground (module docstring): 1 without it, 0 where not ``in_view``."""
        out = in_view.astype(np.float64)
        terrain = self.covered
        k = np.flatnonzero(in_view)
        if terrain is None or not len(k):
            return out
        assert terrain.cover is not None and terrain.cover_tops is not None
        r = self.targets.r_enu_m[k]
        out[k] = transmittance(terrain.cover, terrain.cover_tops, terrain.max_slope,
                               pose.r_cam_enu, r[:, 0], r[:, 1], r[:, 2])
        return out

    def _people(self, pose: CameraPose, t_s: float) -> list[SimulatedDetection]:
        in_view, size = self.person_sizes_px(pose)
        through = self.person_transmittance(pose, in_view)
        in_view &= through > 0
        p_d = self.person_p_detect(size) * through
        if self.interval_s is None:
            found = in_view & (self.rng.random(len(size)) < p_d)
        else:
            look = in_view & (t_s - self._person_last_s >= self.interval_s - _REVISIT_TOL_S)
            self._person_last_s[look] = t_s
            self._person_found[look] = self.rng.random(int(look.sum())) < p_d[look]
            found = in_view & self._person_found
        k = np.flatnonzero(found)
        boxes = self._boxes(pose, self.targets.r_enu_m[k], true_positive=True)
        return [SimulatedDetection(int(i), b) for i, b in zip(k, boxes, strict=True)
                if b is not None]

    # -- false alarms ---------------------------------------------------------------------

    def _false_alarms(self, pose: CameraPose, t_s: float) -> list[SimulatedDetection]:
        grid = self.grid
        grid.update(pose, t_s)
        window = grid.touched
        if window is None:
            return []
        r0, r1, c0, c1 = window
        observed, size_px = grid.observe(pose, window)
        s_px = size_px * self.scale
        p_fa = self.detector.p_false_alarm_per_look(s_px, s_px**2)
        p = np.zeros(observed.shape)
        p[observed] = p_fa
        look = observed if grid.last_obs_s is None \
            else observed & (grid.last_obs_s[r0:r1, c0:c1] == t_s)
        on = self._fa_on[r0:r1, c0:c1]
        drawn = look & (self.rng.random(look.shape) < p)
        on[look] = drawn[look]
        rows, cols = np.nonzero(drawn)
        if len(rows):
            g = grid.geometry
            x = g.x0_m + g.cell_size_m * (cols + c0 + self.rng.random(len(rows)))
            y = g.y0_m + g.cell_size_m * (rows + r0 + self.rng.random(len(rows)))
            z = np.zeros_like(x) if self.terrain is None else self.terrain.height_m(x, y)
            self._fa_enu_m[rows + r0, cols + c0] = np.stack([x, y, z], axis=-1)
        rows, cols = np.nonzero(observed & on)
        boxes = self._boxes(pose, self._fa_enu_m[rows + r0, cols + c0], true_positive=False)
        return [SimulatedDetection(FALSE_ALARM_ID, b) for b in boxes if b is not None]

    # -- frames and boxes -----------------------------------------------------------------

    def frame(self, pose: CameraPose, t_s: float) -> list[SimulatedDetection]:
        """The boxes the detector reports for the frame at ``t_s`` (s, any clock that only
        moves forward) seen from the true ``pose``: people first, then false alarms."""
        return self._people(pose, t_s) + self._false_alarms(pose, t_s)

    def _boxes(self, pose: CameraPose, r_enu_m: np.ndarray, true_positive: bool
               ) -> list[Box | None]:
        """Boxes standing on the ground points (k, 3) (module docstring), of people
        (``true_positive``) or false alarms; None for a point whose pixel falls outside the
        picture once its noise is added."""
        if len(r_enu_m) == 0:
            return []
        cam, o = self.camera, self.options
        R, c = pose.R_enu_cam, pose.r_cam_enu
        foot_cam = (r_enu_m - c) @ R
        head_cam = (r_enu_m + [0.0, 0.0, o.person_height_m] - c) @ R
        foot_px = cam.project(foot_cam)
        width = o.person_width_m * cam.focal_px / foot_cam[:, 2]
        height = np.linalg.norm(cam.project(head_cam) - foot_px, axis=1)
        height = np.where(cam.projectable(head_cam) & (height > width), height, width)
        foot_px = foot_px + self.rng.normal(0.0, o.box_noise_px, foot_px.shape) \
            if o.box_noise_px > 0 else foot_px
        lo_x, hi_x, lo_y, hi_y = -0.5, cam.width_px - 0.5, -0.5, cam.height_px - 0.5
        left = np.clip(foot_px[:, 0] - 0.5 * width, lo_x, hi_x)
        right = np.clip(foot_px[:, 0] + 0.5 * width, lo_x, hi_x)
        top = np.clip(foot_px[:, 1] - height, lo_y, hi_y)
        bottom = np.clip(foot_px[:, 1], lo_y, hi_y)
        conf = self._confidences(np.sqrt((right - left) * (bottom - top)) * self.scale,
                                 true_positive)
        inside = cam.in_picture(foot_px)
        out: list[Box | None] = []
        for i in range(len(foot_px)):
            w, h = right[i] - left[i], bottom[i] - top[i]
            out.append(Box(PERSON_CLASS, float(conf[i]), float(left[i]), float(top[i]),
                           float(w), float(h)) if inside[i] and w > 0 and h > 0 else None)
        return out

    def _confidences(self, size_px: np.ndarray, true_positive: bool) -> np.ndarray:
        """The confidences of boxes of these sizes (detector-input px) by the module
        docstring's rule: the model's histograms, else the Beta rule."""
        n = len(size_px)
        hist = self.detector.confidence
        if hist is None:
            a, b = (4.0, 2.0) if true_positive else (2.0, 4.0)
            return self.threshold + (1 - self.threshold) * self.rng.beta(a, b, n)
        cdf = np.cumsum(hist.probabilities(true_positive), axis=1)
        k = (self.rng.random(n)[:, None] >= cdf[self.detector.nearest_bin(size_px)]).sum(1)
        k = np.minimum(k, hist.n_bins - 1)  # rounding of the cumulative sum's last value
        edges = np.asarray(hist.edges)
        return edges[k] + (edges[k + 1] - edges[k]) * self.rng.random(n)
