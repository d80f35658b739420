"""Terrain scenarios (issue 21): pdcov over a valley DEM against R3, the per-pixel DEM ray
caster (its site: tests.support.terrain_site), and the cost of terrain against flat S1."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from tests.support.grid_agreement import (
    R3_MIN_SHARE,
    R3_TOLERANCE_PD,
    TerrainAgreement,
    terrain_agreement,
)
from tests.support.references import pixel_rays
from tests.support.scenarios import Scenario, spaced, strided
from tests.support.terrain_reference import r3_update
from tests.support.terrain_site import VALLEY_STEP_PX, TerrainSite

from .measure import time_frames, time_updates
from .report import Row

TERRAIN_COST_MAX = 2.0   # per-frame cost with the DEM over flat S1's
R3_SPEEDUP_MIN = 20.0


def agreement_text(a: TerrainAgreement) -> str:
    return (f"{a.share_within:.2%} of {a.cells_free:,} cells within {a.tolerance:g} "
            f"({a.share_within_observed:.2%} of the {a.cells_observed:,} either observed); "
            f"of {a.never_seen:,} cells no ray saw, {a.never_seen_counted:,} counted as seen; "
            f"of {a.hidden:,} hidden by terrain, {a.hidden_counted:,} counted as seen")


def agreement_ok(a: TerrainAgreement, observed_only: bool) -> bool:
    """The target: no hidden cell seen, and P_D within the tolerance on the share of all
    free cells (a whole flight) or of the cells observed (a few frames of a large grid)."""
    share = a.share_within_observed if observed_only else a.share_within
    return share >= R3_MIN_SHARE and a.hidden_counted == 0


def valley_rows(site: TerrainSite, max_frames: int) -> list[Row]:
    """The flight over the valley (at most ``max_frames`` of it, strided): flat pdcov, then
    pdcov with the DEM, against R3."""
    sc = site.scenario
    poses = strided(sc.poses(), max_frames)
    flat = sc.new_grid()
    time_updates(flat, poses)
    ref = site.run_reference(flat, poses, VALLEY_STEP_PX)
    terrain = site.terrain_grid()
    time_updates(terrain, poses)
    target = f">= {R3_MIN_SHARE:.0%} within {R3_TOLERANCE_PD:g}, no hidden cell seen"
    rows = [Row(sc.name, "setup", sc.describe()),
            Row(sc.name, f"R3 vs flat pdcov grid ({len(poses)} frames)",
                agreement_text(terrain_agreement(flat, ref, R3_TOLERANCE_PD)))]
    a = terrain_agreement(terrain, ref, R3_TOLERANCE_PD)
    rows.append(Row(sc.name, f"R3 vs pdcov grid with the DEM ({len(poses)} frames)",
                    agreement_text(a), target, agreement_ok(a, observed_only=False)))
    return rows


def cost_rows(s1: Scenario, s5: Scenario, folder: Path, max_timed_frames: int
              ) -> list[Row]:
    """The cost of terrain, in one run: CPU per frame of the update with the DEM over S5's
    flight against flat S1's over its own, at S5's camera tilt and at nadir (S1's camera
    tilted alike), side by side; and S5's frames flat. ``folder``: for the nadir mission."""
    tilts = (s5.off_nadir_deg, 0.0)
    timed = {}
    for tilt in tilts:
        flat_s1 = replace(s1, off_nadir_deg=tilt)
        sc = replace(s5, off_nadir_deg=tilt)
        (folder / f"tilt-{tilt:g}").mkdir()
        site = TerrainSite.prepare(folder / f"tilt-{tilt:g}", sc)
        frames = strided(sc.poses(), max_timed_frames)
        timed[tilt] = (time_updates(flat_s1.new_grid(), strided(flat_s1.poses(),
                                                                max_timed_frames)),
                       time_updates(site.terrain_grid(), frames),
                       time_updates(sc.new_grid(), frames))
    rows = []
    for tilt in tilts:
        flat_s1, dem, flat_s5 = timed[tilt]
        ratio = dem.mean_cpu_s / flat_s1.mean_cpu_s
        rows.append(Row(
            s5.name, f"update with the DEM / flat S1, CPU per frame, {tilt:g} deg off nadir",
            f"{ratio:.2f}x ({dem.mean_cpu_s * 1e3:.3f} vs {flat_s1.mean_cpu_s * 1e3:.3f} ms; "
            f"S5's frames flat: {flat_s5.mean_cpu_s * 1e3:.3f} ms; {dem.cells.mean():,.0f} vs "
            f"{flat_s1.cells.mean():,.0f} cells/frame, {len(dem.frame_s)} frames)",
            f"<= {TERRAIN_COST_MAX:g}x", ratio <= TERRAIN_COST_MAX))
    return rows


def s5_rows(site: TerrainSite, max_timed_frames: int, r3_frames: int) -> list[Row]:
    """S5: per-frame time with the DEM, and R3 against pdcov on frames from the middle of
    the flight (its cost against flat S1's: ``cost_rows``)."""
    sc = site.scenario
    name = sc.name
    poses = sc.poses()
    timed = strided(poses, max_timed_frames)
    t = time_updates(site.terrain_grid(), timed)
    frames = spaced(poses, r3_frames, max(1, round(sc.rate_hz * 0.5)))
    grid = site.terrain_grid()
    mine = time_updates(grid, frames)
    ref = site.reference(grid)
    rays = pixel_rays(grid.camera)
    ref_s = time_frames(lambda p: r3_update(ref, rays, p), frames)
    speedup = float(ref_s.mean()) / mine.mean_s
    a = terrain_agreement(grid, ref, R3_TOLERANCE_PD)
    return [
        Row(name, "setup", sc.describe()),
        Row(name, "update with the DEM: per frame p50 / p99",
            f"{t.percentile_s(50) * 1e3:.3f} / {t.percentile_s(99) * 1e3:.3f} ms "
            f"({t.cells.mean():,.0f} cells/frame, {len(timed)} frames)"),
        Row(name, "R3 / pdcov with the DEM, time per frame",
            f"{speedup:,.1f}x ({float(ref_s.mean()) * 1e3:,.1f} vs {mine.mean_s * 1e3:.2f} ms, "
            f"{len(frames)} frames, every pixel)",
            f">= {R3_SPEEDUP_MIN:g}x", speedup >= R3_SPEEDUP_MIN),
        Row(name, f"R3 vs pdcov grid with the DEM ({len(frames)} frames)", agreement_text(a),
            f">= {R3_MIN_SHARE:.0%} of observed cells within {R3_TOLERANCE_PD:g}, no hidden "
            f"cell seen", agreement_ok(a, observed_only=True)),
    ]
