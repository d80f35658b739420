"""Gap finder and follow-up flight: which free cells are still below the target P_D after a
flight, and a short plan that lifts them to it.

Two kinds of follow-up are built and the shorter one that reaches the target (else the one
leaving the fewest gap cells) is kept: a lawnmower over the gaps in each given direction, and
a greedy pick of tracks (a set-cover heuristic, not an optimum): candidate tracks
are straight lines over the gaps in a few directions, half a spacing apart; each is flown
on its own through a fresh grid, giving its log-miss contribution per cell. Repeatedly, the
track with the most still-needed log-miss per second of flight (its own time plus the transit
to it from where the last one ended) is taken, until every gap cell reaches the target or no
track helps. The chosen tracks are joined through the free space in that order, and the
whole plan is predicted again (its transits see cells too).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import shapely
from shapely.geometry import LineString, MultiPolygon, Polygon, box
from tqdm import tqdm

from pdcov.errors import ConfigError
from pdcov.planning.decomposition import SweepFrame, polygons_of
from pdcov.planning.optimise import Prediction, Scenario, predict
from pdcov.planning.patterns import FreeSpaceRouter, PathBuilder, clip_polyline, lawnmower
from pdcov.planning.plan import Plan


@dataclass(frozen=True, slots=True)
class Gaps:
    """Free cells below the target: mask (n_rows, n_cols), their count, their share of the
    free cells, and the gap regions as ENU polygons (largest first)."""

    mask: np.ndarray
    n_cells: int
    proportion: float
    regions: tuple[Polygon, ...]


def find_gaps(pd: np.ndarray, scenario: Scenario, target_pd: float) -> Gaps:
    """The free cells whose P_D is below ``target_pd``."""
    if not 0.0 < target_pd < 1.0:
        raise ConfigError(f"target P_D: expected a probability in (0, 1), got {target_pd}")
    if pd.shape != scenario.mask.shape:
        raise ConfigError(f"grid shape {pd.shape} does not match the mission's grid "
                          f"{scenario.mask.shape} (same domain and cell size?)")
    gap = scenario.mask & (pd < target_pd)
    g = scenario.geometry
    rows, cols = np.nonzero(gap)
    cells = [box(g.x0_m + c * g.cell_size_m, g.y0_m + r * g.cell_size_m,
                 g.x0_m + (c + 1) * g.cell_size_m, g.y0_m + (r + 1) * g.cell_size_m)
             for r, c in zip(rows, cols, strict=True)]
    regions = sorted(polygons_of(shapely.union_all(cells)), key=lambda p: -p.area) \
        if cells else []
    n_free = int(scenario.mask.sum())
    return Gaps(gap, int(gap.sum()), int(gap.sum()) / n_free if n_free else 0.0,
                tuple(regions))


@dataclass(frozen=True, slots=True)
class Refly:
    """A follow-up: the plan, its prediction alone, P_D after both flights, the gaps before
    and after."""

    plan: Plan
    prediction: Prediction
    pd_after: np.ndarray
    gaps_before: Gaps
    gaps_after: Gaps


def candidate_tracks(gaps: Gaps, scenario: Scenario, spacing_m: float,
                     headings_rad: tuple[float, ...]) -> list[np.ndarray]:
    """(2, 2) ENU segments over the gaps (widened by half a spacing) in the free space."""
    area = shapely.union_all(gaps.regions).buffer(spacing_m / 2).intersection(
        scenario.free_space)
    out = []
    for heading in headings_rad:
        frame = SweepFrame(-heading)  # x' across the tracks, y' along them
        x0, y0, x1, y1 = frame.to_sweep(area).bounds
        n = max(1, math.ceil((x1 - x0) / (spacing_m / 2)))
        for x in x0 + (x1 - x0) * (np.arange(n) + 0.5) / n:
            line = frame.points_to_enu(np.array([[x, y0 - 1.0], [x, y1 + 1.0]]))
            for piece in clip_polyline(line, area):
                if LineString(piece).length > 0.5:
                    out.append(piece[[0, -1]])
    return out


def plan_refly(scenario: Scenario, log_miss_now: np.ndarray, target_pd: float,
               alt_agl_m: float, speed_mps: float, spacing_m: float,
               headings_rad: tuple[float, ...] = (0.0, math.pi / 2),
               start_enu_m: tuple[float, float] = (0.0, 0.0), progress: bool = False
               ) -> Refly:
    """A follow-up plan lifting the gap cells of a grid (log-miss sums ``log_miss_now``,
    float (n_rows, n_cols)) to ``target_pd``; starts from ``start_enu_m`` (home)."""
    L_now = np.asarray(log_miss_now, dtype=np.float64)
    gaps = find_gaps(-np.expm1(L_now), scenario, target_pd)
    if gaps.n_cells == 0:
        raise ConfigError(f"no gaps: every free cell already has P_D >= {target_pd}")
    tracks = candidate_tracks(gaps, scenario, spacing_m, headings_rad)
    L_target = math.log1p(-target_pd)
    deficit = np.where(gaps.mask, L_now - L_target, 0.0)[gaps.mask]  # > 0 where needed
    gain, cost = [], []
    for seg in tqdm(tracks, desc="candidate tracks", unit="track", disable=not progress):
        p = predict(scenario, Plan.from_xy(seg, alt_agl_m, speed_mps))
        gain.append(-p.grid.log_miss_d.astype(np.float64)[gaps.mask])
        cost.append(p.flight.duration_s)
    chosen: list[np.ndarray] = []
    here = np.asarray(start_enu_m, dtype=float)
    available = list(range(len(tracks)))
    while available and np.any(deficit > 1e-9):
        best, best_rate, best_seg = -1, 0.0, None
        for i in available:
            benefit = float(np.minimum(deficit, gain[i]).sum())
            seg = tracks[i] if (np.linalg.norm(tracks[i][0] - here)
                                <= np.linalg.norm(tracks[i][1] - here)) else tracks[i][::-1]
            rate = float(benefit / (cost[i] + np.linalg.norm(seg[0] - here) / speed_mps))
            if rate > best_rate:
                best, best_rate, best_seg = i, rate, seg
        if best_seg is None:
            break
        chosen.append(best_seg)
        deficit = np.maximum(deficit - gain[best], 0.0)
        available.remove(best)
        here = best_seg[1]
    options = []
    if chosen:
        builder = PathBuilder(FreeSpaceRouter(scenario.free_space))
        for seg in chosen:
            builder.add(seg)
        options.append(Plan.from_xy(builder.points(), alt_agl_m, speed_mps,
                                    f"refly to P_D {target_pd:g}: {len(chosen)} greedy tracks "
                                    f"over {gaps.n_cells} gap cells"))
    area = _survey_area(gaps, scenario)
    for heading in headings_rad:
        plan = lawnmower(area, spacing_m, heading, alt_agl_m, speed_mps,
                         route_in_enu=scenario.free_space)
        options.append(replace(plan, description=f"refly to P_D {target_pd:g}: lawnmower "
                               f"over {gaps.n_cells} gap cells ({plan.description})"))
    results = []
    for plan in options:
        pred = predict(scenario, plan, progress=progress)
        pd_after = -np.expm1(L_now + pred.grid.log_miss_d.astype(np.float64))
        results.append(Refly(plan, pred, pd_after, gaps,
                             find_gaps(pd_after, scenario, target_pd)))
    return min(results, key=lambda r: (r.gaps_after.n_cells > 0, r.gaps_after.n_cells,
                                       r.prediction.flight.duration_s))


def _survey_area(gaps: Gaps, scenario: Scenario) -> Polygon | MultiPolygon:
    """The gap regions as a few-vertex area to sweep: grown by a cell and simplified, so
    that the staircase of cell edges does not split the decomposition into slivers."""
    c = scenario.geometry.cell_size_m
    area = shapely.union_all(gaps.regions).buffer(c, join_style="mitre").simplify(c)
    return area.intersection(scenario.free_space)
