"""Gap finder and follow-up flight: which free cells are still below the target P_D after a
flight, and a short plan that lifts them to it.

Several follow-ups are built and predicted, and the shortest flight that reaches the target
(else the one leaving the fewest gap cells) is kept; every option is reported. Per heading:

* a greedy pick of tracks (a set-cover heuristic, not an optimum): candidate tracks are
  straight lines over the gaps, half a spacing apart; each is flown on its own through a
  fresh grid, giving its log-miss contribution per cell. Repeatedly, the track with the most
  still-needed log-miss per second of flight (its own time plus the transit to it) is taken,
  until every gap cell reaches the target or no track helps. The chosen tracks are flown
  part by part of the gap area, as a boustrophedon (by offset across the heading,
  alternating direction), not in the order picked;
* a lawnmower over the gap regions;
* a lawnmower over the whole free space, at the spacing and at half of it (re-flying
  everything can be shorter than chasing scattered gaps).

Every plan is predicted whole (its transits and turns see cells too), and P_D after both
flights is the flown grid and the prediction combined by the grid's rule
(``grid.combined_pd``: under correlated or viewpoint looks their looks states add, as
``CoverageGrid.merge`` adds them; the greedy's per-track gains are independent-looks sums,
which choose, never judge, an option).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import shapely
from shapely.geometry import LineString, MultiPolygon, Polygon, box

from pdcov.core.combine_cameras import combined_pd
from pdcov.core.grid import CoverageGrid
from pdcov.core.grid_layer import Layer
from pdcov.core.looks import LooksConfig
from pdcov.errors import ConfigError
from pdcov.planning.decomposition import SweepFrame, polygons_of
from pdcov.planning.optimise import Prediction, Scenario, predict
from pdcov.planning.patterns import lawnmower, track_spacing_m
from pdcov.planning.plan import Plan
from pdcov.planning.progress import progress as show_progress
from pdcov.planning.routing import FreeSpaceRouter, PathBuilder, clip_polyline
from pdcov.planning.scenario import check_plan_size


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
class Option:
    """One follow-up that was built and predicted: what it is, its predicted flight time (s)
    and path length (m), and the gap cells it would leave."""

    description: str
    flight_time_s: float
    path_length_m: float
    gaps_after: int


@dataclass(frozen=True, slots=True)
class Refly:
    """A follow-up: the plan, its prediction alone, P_D after both flights, the gaps before
    and after, and every option compared (the chosen one included), in the order built."""

    plan: Plan
    prediction: Prediction
    pd_after: np.ndarray
    gaps_before: Gaps
    gaps_after: Gaps
    compared: tuple[Option, ...] = ()


@dataclass(frozen=True, slots=True)
class Track:
    """A candidate straight track: (2, 2) ENU ends, its heading (rad), the part of the
    survey area it lies in, and its offset across the heading (m)."""

    seg_enu_m: np.ndarray
    heading_rad: float
    part: int
    across_m: float


def candidate_tracks(gaps: Gaps, scenario: Scenario, spacing_m: float,
                     headings_rad: tuple[float, ...]) -> list[Track]:
    """Tracks over the gaps (widened by half a spacing) in the free space, half a spacing
    apart in each heading. A chord shorter than half a spacing that passes over no gap cell
    is left out: it is a sliver of the widened area's rounded edge (a metre or so long),
    which the greedy pick took for its low cost and flew as a short reversing leg."""
    gap_union = shapely.union_all(gaps.regions)
    area = gap_union.buffer(spacing_m / 2).intersection(scenario.free_space)
    shapely.prepare(gap_union)
    out = []
    for part_index, part in enumerate(polygons_of(area)):
        for heading in headings_rad:
            frame = SweepFrame(-heading)  # x' across the tracks, y' along them
            x0, y0, x1, y1 = frame.to_sweep(part).bounds
            n = max(1, math.ceil((x1 - x0) / (spacing_m / 2)))
            for x in x0 + (x1 - x0) * (np.arange(n) + 0.5) / n:
                line = frame.points_to_enu(np.array([[x, y0 - 1.0], [x, y1 + 1.0]]))
                for piece in clip_polyline(line, part):
                    seg = piece[[0, -1]]
                    line = LineString(seg)
                    if line.length >= spacing_m / 2 or shapely.intersects(gap_union, line):
                        out.append(Track(seg, heading, part_index, float(x)))
    return out


def sweep_order(tracks: list[Track], start_enu_m: np.ndarray) -> list[np.ndarray]:
    """Chosen tracks as (2, 2) segments in flying order: part by part (nearest next), each
    part heading by heading, and within a heading by offset across it, alternating
    direction (a boustrophedon), so that no transit cuts across other tracks."""
    groups: dict[tuple[int, float], list[Track]] = {}
    for t in tracks:
        groups.setdefault((t.part, t.heading_rad), []).append(t)
    here = np.asarray(start_enu_m, dtype=float)
    out: list[np.ndarray] = []
    while groups:
        options = []
        for key, group in groups.items():
            frame = SweepFrame(-key[1])
            lines = sorted({round(t.across_m, 6) for t in group})
            for across_rev in (False, True):
                for along_rev in (False, True):
                    ordered = _boustrophedon(group, frame, lines, across_rev, along_rev)
                    options.append((float(np.linalg.norm(ordered[0][0] - here)), key, ordered))
        _, key, ordered = min(options, key=lambda o: o[0])
        out.extend(ordered)
        here = ordered[-1][1]
        del groups[key]
    return out


def _boustrophedon(group: list[Track], frame: SweepFrame, lines: list[float],
                   across_rev: bool, along_rev: bool) -> list[np.ndarray]:
    out = []
    for k, x in enumerate(lines[::-1] if across_rev else lines):
        on_line = [t.seg_enu_m for t in group if round(t.across_m, 6) == x]
        # y' of each end in the sweep frame: tracks run along y'.
        segs = [s if _along(frame, s[1]) >= _along(frame, s[0]) else s[::-1] for s in on_line]
        segs.sort(key=lambda s: _along(frame, s[0]))
        if (k % 2 == 1) != along_rev:
            segs = [s[::-1] for s in segs[::-1]]
        out.extend(segs)
    return out


def _along(frame: SweepFrame, p_enu: np.ndarray) -> float:
    a, b = math.cos(frame.h_angle_rad), math.sin(frame.h_angle_rad)
    return float(-b * p_enu[0] + a * p_enu[1])


def greedy_tracks(tracks: list[Track], gain: list[np.ndarray], cost_s: list[float],
                  deficit: np.ndarray, start_enu_m: np.ndarray, speed_mps: float
                  ) -> list[Track]:
    """Set-cover heuristic: repeatedly the track with the most still-needed log-miss
    (``deficit``, > 0 where needed) per second of flight, its own and the transit to it,
    until nothing is needed or no track helps."""
    chosen: list[Track] = []
    here = np.asarray(start_enu_m, dtype=float)
    available = list(range(len(tracks)))
    while available and np.any(deficit > 1e-9):
        best, best_rate = -1, 0.0
        for i in available:
            seg = tracks[i].seg_enu_m
            transit_m = float(min(np.linalg.norm(seg[0] - here), np.linalg.norm(seg[1] - here)))
            benefit = float(np.minimum(deficit, gain[i]).sum())
            rate = benefit / (cost_s[i] + transit_m / speed_mps)
            if rate > best_rate:
                best, best_rate = i, rate
        if best < 0:
            break
        chosen.append(tracks[best])
        deficit = np.maximum(deficit - gain[best], 0.0)
        available.remove(best)
        seg = tracks[best].seg_enu_m
        here = seg[1] if np.linalg.norm(seg[0] - here) <= np.linalg.norm(seg[1] - here) \
            else seg[0]
    return chosen


def plan_refly(scenario: Scenario, flown: CoverageGrid, target_pd: float,
               alt_agl_m: float, speed_mps: float, spacing_m: float,
               headings_rad: tuple[float, ...] = (0.0, math.pi / 2),
               start_enu_m: tuple[float, float] = (0.0, 0.0), progress: bool = False
               ) -> Refly:
    """A follow-up plan lifting the gap cells of the ``flown`` grid (the scenario's cells)
    to ``target_pd``; starts from ``start_enu_m`` (home).

    Options built and predicted, per heading: the greedy tracks over the gaps, a lawnmower
    over the gaps, and a lawnmower over the whole free space at the spacing and at half
    of it. The shortest flight that lifts every gap cell to the target is kept, else the
    one leaving the fewest gap cells (then the shortest); ``compared`` lists them all."""
    L_now = flown.log_miss_d.astype(np.float64)
    gaps = find_gaps(flown.pd, scenario, target_pd)
    if gaps.n_cells == 0:
        raise ConfigError(f"no gaps: every free cell already has P_D >= {target_pd}")
    start = np.asarray(start_enu_m, dtype=float)
    tracks = candidate_tracks(gaps, scenario, spacing_m, headings_rad)
    L_target = math.log1p(-target_pd)
    deficit = (L_now - L_target)[gaps.mask]  # > 0 where needed
    gain, cost = [], []
    for t in show_progress(tracks, desc="candidate tracks", unit="track", enabled=progress):
        p = predict(scenario, Plan.from_xy(t.seg_enu_m, alt_agl_m, speed_mps))
        gain.append(-p.grid.log_miss_d.astype(np.float64)[gaps.mask])
        cost.append(p.flight.duration_s)
    router = FreeSpaceRouter(scenario.free_space)
    what = f"refly to P_D {target_pd:g}"
    options = []
    for heading in headings_rad:
        # One heading at a time: tracks of another heading picked to mop up the ends of
        # these would be joined by transits across them.
        idx = [i for i, t in enumerate(tracks) if t.heading_rad == heading]
        chosen = greedy_tracks([tracks[i] for i in idx], [gain[i] for i in idx],
                               [cost[i] for i in idx], deficit, start, speed_mps)
        if chosen:
            builder = PathBuilder(router)
            for seg in sweep_order(chosen, start):
                builder.add(seg)
            options.append(Plan.from_xy(
                builder.points(), alt_agl_m, speed_mps,
                f"{what}: {len(chosen)} greedy tracks heading {math.degrees(heading):g} deg "
                f"over {gaps.n_cells} gap cells"))
    area = _survey_area(gaps, scenario)
    for heading in headings_rad:
        plan = lawnmower(area, spacing_m, heading, alt_agl_m, speed_mps,
                         route_in_enu=scenario.free_space)
        options.append(replace(plan, description=f"{what}: lawnmower over {gaps.n_cells} "
                                                 f"gap cells ({plan.description})"))
    for s in (spacing_m, spacing_m / 2):
        for heading in headings_rad:
            plan = lawnmower(scenario.free_space, s, heading, alt_agl_m, speed_mps)
            options.append(replace(plan, description=f"{what}: whole-area pass "
                                                     f"({plan.description})"))
    results = []
    for plan in options:
        pred = predict(scenario, plan, progress=progress)
        pd_after = combined_pd([flown, pred.grid])
        results.append(Refly(plan, pred, pd_after, gaps,
                             find_gaps(pd_after, scenario, target_pd)))
    compared = tuple(Option(r.plan.description, r.prediction.flight.duration_s,
                            r.prediction.flight.path_length_m, r.gaps_after.n_cells)
                     for r in results)
    best = min(results, key=lambda r: (r.gaps_after.n_cells > 0, r.gaps_after.n_cells,
                                       r.prediction.flight.duration_s))
    return replace(best, compared=compared)


@dataclass(frozen=True, slots=True)
class ReflySettings:
    """What a re-fly is asked for: the P_D every free cell should reach, the altitude above
    ground (m) and speed (m/s) to fly it at, the track spacing (m; None: from the camera's
    swath at that altitude and ``overlap``, the side overlap) and the track headings (deg
    clockwise from north). The defaults are ``pdcov refly``'s."""

    target_pd: float
    alt_agl_m: float = 10.0
    speed_mps: float = 3.0
    spacing_m: float | None = None
    overlap: float = 0.2
    headings_deg: tuple[float, ...] = (0.0, 90.0)

    def __post_init__(self) -> None:
        if not 0.0 < self.target_pd < 1.0:
            raise ConfigError(f"target P_D: expected a probability in (0, 1), got "
                              f"{self.target_pd}")
        for name in ("alt_agl_m", "speed_mps"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"re-fly {name}: expected a number > 0, got {v}")

    def spacing_for(self, scenario: Scenario) -> float:
        """The track spacing (m): as given, else from the swath and the overlap."""
        if self.spacing_m is not None:
            return self.spacing_m
        return track_spacing_m(scenario.swath_width_m(self.alt_agl_m), self.overlap)


def independent_grid(scenario: Scenario, log_miss_d: np.ndarray) -> CoverageGrid:
    """An independent-looks grid of the scenario's cells holding the log-miss sums
    ``log_miss_d`` (float (n_rows, n_cols), <= 0): what the ground station's fleet merge
    gives (it adds the vehicles' derived log-misses)."""
    grid = replace(scenario, looks=LooksConfig()).new_grid()
    grid.layer(Layer.LOG_MISS_D).write((0, grid.geometry.n_rows, 0, grid.geometry.n_cols),
                                       log_miss_d)
    return grid


def refly_of_grid(scenario: Scenario, flown: CoverageGrid, settings: ReflySettings,
                  start_enu_m: tuple[float, float] = (0.0, 0.0), progress: bool = False
                  ) -> Refly:
    """The re-fly of a grid's gaps as ``pdcov refly`` and the ground station (``pdcov watch
    --refly``, the web map) make it: the spacing resolved, the plan's size checked
    (``check_plan_size``), then ``plan_refly`` from ``start_enu_m`` (ENU m: home, or
    where the vehicle is now)."""
    spacing = settings.spacing_for(scenario)
    check_plan_size(scenario, spacing, settings.speed_mps)
    return plan_refly(scenario, flown, settings.target_pd, settings.alt_agl_m,
                      settings.speed_mps, spacing,
                      tuple(math.radians(h) for h in settings.headings_deg), start_enu_m,
                      progress=progress)


def _survey_area(gaps: Gaps, scenario: Scenario) -> Polygon | MultiPolygon:
    """The gap regions as a few-vertex area to sweep: grown by a cell and simplified, so
    that the staircase of cell edges does not split the decomposition into slivers."""
    c = scenario.geometry.cell_size_m
    area = shapely.union_all(gaps.regions).buffer(c, join_style="mitre").simplify(c)
    return area.intersection(scenario.free_space)
