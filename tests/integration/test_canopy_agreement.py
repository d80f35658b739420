"""The canopy/building kernel's done-when: on the canopy scene (tests/support/canopy_scene.py:
hills, a town block, a forest), one nadir and one oblique frame, each through a fresh
CoverageGrid over the terrain and its cover, agree with R4, the per-pixel forward ray
caster (tests/support/canopy_reference.py):

* on at least 97 % of the cells either observes (P_D > 0 in either), P_D within 0.05;
* no cell under a roof has P_D > 0 (the free mask includes the roofs, as if the mission
  said people may be there), and those in view are limited by BUILDING;
* over the forest's cells either observes, the mean P_D differs by at most 0.03.

The figures are printed (``pytest -s``); a failure says where the cells that disagree lie.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from scipy.ndimage import binary_dilation, distance_transform_edt

from pdcov.core.grid import CoverageGrid
from pdcov.core.ground_cover import CoverKind
from pdcov.core.limiting import LimitingFactor
from tests.support import canopy_scene
from tests.support.canopy_reference import CanopyLook, CanopyReference

TOLERANCE_PD, MIN_SHARE = 0.05, 0.97
FOREST_MEAN_TOLERANCE = 0.03
EDGE_PX = 1.0  # cells whose centre is this close to the picture's border may be judged apart
POSES = {"nadir": canopy_scene.nadir_pose, "oblique": canopy_scene.oblique_pose}


@dataclass(frozen=True)
class Frame:
    """One frame through pdcov's grid and through R4, and the scene's cells."""

    name: str
    grid: CoverageGrid
    look: CanopyLook
    kind: np.ndarray
    kernel_t: np.ndarray | None  # the grid's transmittance per cell (NaN where unknown)

    @property
    def either(self) -> np.ndarray:
        return (self.grid.pd > 0) | (self.look.pd > 0)

    @property
    def diff(self) -> np.ndarray:
        return np.abs(self.grid.pd - self.look.pd)

    @property
    def share_within(self) -> float:
        return float((self.diff[self.either] <= TOLERANCE_PD).mean())

    @property
    def near_edge(self) -> np.ndarray:
        """Cells whose centre is within EDGE_PX of the picture's border."""
        cam = self.grid.camera
        u, v = self.look.centre_px[..., 0], self.look.centre_px[..., 1]
        with np.errstate(invalid="ignore"):
            return ((np.minimum(u + 0.5, cam.width_px - 0.5 - u) < EDGE_PX)
                    | (np.minimum(v + 0.5, cam.height_px - 0.5 - v) < EDGE_PX))

    def forest_means(self) -> tuple[float, float, int]:
        """Mean P_D of the grid and of R4 over the forest cells either observes, and their
        number."""
        cells = self.either & (self.kind == CoverKind.FOLIAGE)
        return float(self.grid.pd[cells].mean()), float(self.look.pd[cells].mean()), \
            int(cells.sum())

    def report(self) -> str:
        g_mean, r_mean, n_forest = self.forest_means()
        return (f"{self.name}: {int(self.either.sum())} cells observed by either, "
                f"{self.share_within:.4f} within {TOLERANCE_PD} (need {MIN_SHARE}); forest "
                f"mean P_D grid {g_mean:.4f} vs R4 {r_mean:.4f} over {n_forest} cells "
                f"(|diff| {abs(g_mean - r_mean):.4f}, need <= {FOREST_MEAN_TOLERANCE})")

    def where_they_disagree(self, limit: int = 12) -> str:
        """The cells beyond the tolerance by place (a cell counts in its first place), and
        the worst of them."""
        look, kind = self.look, self.kind
        bad = self.either & (self.diff > TOLERANCE_PD)
        foliage, solid = kind == CoverKind.FOLIAGE, kind == CoverKind.SOLID
        forest_edge = binary_dilation(foliage, np.ones((3, 3))) & binary_dilation(
            ~foliage, np.ones((3, 3)))
        to_solid = distance_transform_edt(~solid)
        to_foliage = distance_transform_edt(~foliage)
        shaded = ~foliage & ~solid & (np.nan_to_num(look.transmittance, nan=1.0) < 1.0)
        places = [
            ("picture edge", self.near_edge),
            ("terrain: R4 or the grid (HIDDEN where R4 sees it clear) hides it",
             look.hidden | (look.in_view & ~look.observed)
             | ((self.grid.limiting == LimitingFactor.HIDDEN) & (look.transmittance == 1.0))),
            ("roof", solid),
            ("forest edge (1 cell)", forest_edge),
            ("forest inside", foliage),
            ("building shadow (open ground, T < 1, nearer a building)",
             shaded & (to_solid <= to_foliage)),
            ("tree shadow (open ground, T < 1, nearer the forest)", shaded),
            ("other", np.ones_like(bad)),
        ]
        lines, left = [], bad.copy()
        for name, mask in places:
            n = int((left & mask).sum())
            if n:
                lines.append(f"  {name}: {n}")
            left &= ~mask
        rows, cols = np.nonzero(bad)
        worst = np.argsort(-self.diff[rows, cols])[:limit]
        for i in worst:
            r, c = rows[i], cols[i]
            kt = np.nan if self.kernel_t is None else self.kernel_t[r, c]
            lines.append(
                f"  cell [{r}, {c}] {CoverKind(kind[r, c]).name}: P_D grid "
                f"{self.grid.pd[r, c]:.3f} R4 {look.pd[r, c]:.3f}; T grid {kt:.3f} R4 "
                f"{look.transmittance[r, c]:.3f}; R4 area {look.area_px2[r, c]:.2f} px^2, "
                f"limiting {LimitingFactor(self.grid.limiting[r, c]).name}")
        return f"{self.name}: {int(bad.sum())} cells beyond {TOLERANCE_PD}:\n" + "\n".join(lines)


@pytest.fixture(scope="module")
def frames() -> dict[str, Frame]:
    geometry = canopy_scene.GEOMETRY
    terrain = canopy_scene.terrain()
    camera, detector = canopy_scene.camera(), canopy_scene.smooth_detector()
    free = np.ones(geometry.shape, dtype=bool)
    assert terrain.cover is not None
    kind = np.asarray(terrain.cover.kind)
    out: dict[str, Frame] = {}
    reference: CanopyReference | None = None
    for name, pose_of in POSES.items():
        pose = pose_of()
        grid = CoverageGrid(geometry, free, camera, detector, terrain=terrain)
        grid.update(pose)
        if reference is None:
            reference = CanopyReference(terrain, camera, detector, grid.max_range_m)
        out[name] = Frame(name, grid, reference.look(pose), kind, _kernel_t(grid))
    return out


def _kernel_t(grid: CoverageGrid) -> np.ndarray | None:
    """The grid's transmittance per cell in its latest frame, when it says (diagnostics)."""
    last = grid.last_look
    t = getattr(last, "transmittance", None)
    if last is None or t is None:
        return None
    out = np.full(grid.geometry.shape, np.nan)
    r0, r1, c0, c1 = last.window
    out[r0:r1, c0:c1] = t
    return out


@pytest.mark.parametrize("name", POSES)
def test_the_grid_agrees_with_the_ray_caster(frames, name):
    f = frames[name]
    print("\n" + f.report())
    assert f.either.sum() > 5000  # the frame sees the scene
    assert f.share_within >= MIN_SHARE, f.report() + "\n" + f.where_they_disagree()


@pytest.mark.parametrize("name", POSES)
def test_no_one_under_a_roof_is_seen(frames, name):
    f = frames[name]
    roof = f.kind == CoverKind.SOLID
    look = f.look
    seen_roof = roof & (f.grid.pd > 0)
    assert not seen_roof.any(), f"{name}: {int(seen_roof.sum())} roof cells with P_D > 0"
    assert not (roof & (look.pd > 0)).any()  # R4 agrees: the roof blocks every ray
    # In view within range (and not behind the terrain): limited by the building.
    in_view = roof & look.in_view & look.in_range & ~look.hidden & ~f.near_edge
    limiting = f.grid.limiting[in_view]
    building = limiting == LimitingFactor.BUILDING
    print(f"\n{name}: {int(in_view.sum())} roof cells in view, "
          f"{int(building.sum())} limited by BUILDING")
    assert in_view.sum() > 500
    assert building.all(), (
        f"{name}: roof cells in view not BUILDING: "
        f"{dict(zip(*np.unique(limiting[~building], return_counts=True), strict=True))}")


@pytest.mark.parametrize("name", POSES)
def test_the_forest_mean_pd_agrees(frames, name):
    f = frames[name]
    g_mean, r_mean, n_forest = f.forest_means()
    print(f"\n{name}: forest mean P_D grid {g_mean:.4f}, R4 {r_mean:.4f} ({n_forest} cells)")
    assert n_forest > 2000
    assert abs(g_mean - r_mean) <= FOREST_MEAN_TOLERANCE, f.report()
