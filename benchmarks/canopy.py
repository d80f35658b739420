"""What stands on the ground (issue 38): the cost per frame of the canopy and buildings over
the terrain alone, on the canopy scene (tests.support.canopy_scene: hills, a town block, a
forest), and pdcov against R4, the per-pixel forward ray caster, on its nadir and oblique
frames."""

from __future__ import annotations

import math

import numpy as np

from pdcov.core.grid import CoverageGrid
from pdcov.core.ground_cover import CoverKind
from pdcov.core.pose import CameraPose, FixedMount, fixed_mount_pose
from pdcov.core.rotations import R_from_euler_zyx
from pdcov.core.terrain import TerrainSurface
from tests.support import canopy_scene as scene
from tests.support.canopy_reference import CanopyReference

from .measure import UpdateTiming, time_frames, time_updates
from .report import Row

CANOPY_COST_MAX = 2.0  # per-frame cost with the cover over the terrain's alone
SURVEY_AGL_M = 60.0
SURVEY_SPACING_M = 40.0
FRAME_SPACING_M = 2.0
R4_TOLERANCE_PD, R4_MIN_SHARE = 0.05, 0.97
NAME = "canopy"


def survey_poses(off_nadir_deg: float) -> list[CameraPose]:
    """A lawnmower over the scene SURVEY_AGL_M above its ground, legs SURVEY_SPACING_M
    apart running north and south, a frame every FRAME_SPACING_M, the camera
    ``off_nadir_deg`` forward of nadir."""
    mount = FixedMount(pitch_rad=math.radians(off_nadir_deg - 90.0))
    poses = []
    for k, x in enumerate(np.arange(SURVEY_SPACING_M / 2, scene.SIDE_M, SURVEY_SPACING_M)):
        ys = np.arange(0.0, scene.SIDE_M + 1e-9, FRAME_SPACING_M)
        heading = 0.0 if k % 2 == 0 else math.pi
        for y in ys if k % 2 == 0 else ys[::-1]:
            z = float(scene.ground_z_m(x, y)) + SURVEY_AGL_M
            poses.append(fixed_mount_pose(R_from_euler_zyx(0.0, 0.0, heading),
                                          (float(x), float(y), z), mount))
    return poses


def grid_over(terrain: TerrainSurface) -> CoverageGrid:
    g = scene.GEOMETRY
    return CoverageGrid(g, np.ones(g.shape, bool), scene.camera(), scene.smooth_detector(),
                        terrain=terrain)


def _cost_row(tilt_deg: float, bare: UpdateTiming, covered: UpdateTiming,
              forest_share: float) -> Row:
    ratio = covered.mean_cpu_s / bare.mean_cpu_s
    return Row(NAME, f"update with the cover / the terrain alone, CPU per frame, "
                     f"{tilt_deg:g} deg off nadir",
               f"{ratio:.2f}x ({covered.mean_cpu_s * 1e3:.3f} vs {bare.mean_cpu_s * 1e3:.3f} "
               f"ms; {covered.cells.mean():,.0f} cells/frame, {forest_share:.0%} of them "
               f"under trees or roofs, {len(covered.frame_s)} frames)",
               f"<= {CANOPY_COST_MAX:g}x", ratio <= CANOPY_COST_MAX)


def cost_rows(max_frames: int) -> list[Row]:
    """The survey at 20 deg off nadir and at nadir: the same frames through a grid over the
    bare terrain and one over the terrain and its cover, side by side."""
    bare, covered = scene.terrain(with_cover=False), scene.terrain()
    assert covered.cover is not None
    raised = covered.cover.kind != CoverKind.OPEN
    rows = [Row(NAME, "setup", f"{scene.SIDE_M:g} m square at {scene.CELL_M:g} m, hills, a "
                f"town block and a forest ({raised.mean():.0%} of the cells under trees or "
                f"roofs); lawnmower {SURVEY_AGL_M:g} m above the ground, legs "
                f"{SURVEY_SPACING_M:g} m apart, a frame every {FRAME_SPACING_M:g} m; "
                f"640x480 camera, 70 deg")]
    for tilt in (20.0, 0.0):
        poses = survey_poses(tilt)
        frames = poses[::max(1, len(poses) // max_frames)][:max_frames]
        time_updates(grid_over(covered), frames[:3])  # warm: the cover's derived arrays
        t_bare = time_updates(grid_over(bare), frames)
        g = grid_over(covered)
        t_covered = time_updates(g, frames)
        share = float(raised[g.n_obs > 0].mean()) if (g.n_obs > 0).any() else 0.0
        rows.append(_cost_row(tilt, t_bare, t_covered, share))
    return rows


def r4_rows() -> list[Row]:
    """R4 against pdcov on the scene's nadir and oblique frames, each in a fresh grid."""
    terrain = scene.terrain()
    assert terrain.cover is not None
    forest = terrain.cover.kind == CoverKind.FOLIAGE
    roof = terrain.cover.kind == CoverKind.SOLID
    rows = []
    reference = None
    for name, pose in (("nadir", scene.nadir_pose()), ("oblique", scene.oblique_pose())):
        grid = grid_over(terrain)
        mine = time_updates(grid, [pose])
        reference = reference or CanopyReference(terrain, grid.camera, grid.detector,
                                                 grid.max_range_m)
        looks: list = []
        ref_s = time_frames(lambda p, ref=reference, out=looks: out.append(ref.look(p)),
                            [pose])
        look = looks[0]
        either = (grid.pd > 0) | (look.pd > 0)
        share = float((np.abs(grid.pd - look.pd)[either] <= R4_TOLERANCE_PD).mean())
        cells = either & forest
        gap = abs(float(grid.pd[cells].mean()) - float(look.pd[cells].mean()))
        roofs_seen = int((grid.pd[roof] > 0).sum())
        ok = share >= R4_MIN_SHARE and gap <= 0.03 and roofs_seen == 0
        rows.append(Row(NAME, f"R4 vs pdcov, {name} frame",
                        f"{share:.2%} of {int(either.sum()):,} cells within "
                        f"{R4_TOLERANCE_PD:g}; forest mean P_D within {gap:.4f}; "
                        f"{roofs_seen} roof cells seen; R4 {float(ref_s[0]):.1f} s vs pdcov "
                        f"{mine.mean_s * 1e3:.1f} ms",
                        f">= {R4_MIN_SHARE:.0%} within {R4_TOLERANCE_PD:g}, forest mean "
                        "within 0.03, no roof cell seen", ok))
    return rows
