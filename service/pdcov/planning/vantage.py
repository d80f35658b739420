"""Vantage points (the paper's future work): hover poses whose frames together bring the
free cells to a target P_D, chosen by a covering integer program (planning/cover.py).

Candidates: points of a square lattice in the free space kept ``clearance_m`` from its
boundary (planning/tours.py routes through the same space), at each given altitude above
ground, hovering each given time, on a gimbal at each given pitch, with an oblique pitch
at each given earth-frame yaw (``candidate_pointings``), and with the camera zoomed to each
given field of view (``zooms_hfov_deg``; none given: the configured camera, no zoom
command). A candidate is scored with the prediction every plan uses: the scenario's
CoverageGrid (camera, detector model, terrain, range limit) fed the camera pose of a level
vehicle at rest there (``camera_poses``: the mount, or the gimbal at the candidate's
pointing), with the camera at the candidate's zoom (``Scenario.camera_at``: core/zoom.py's
focal-length scaling; its own default range limit, which grows with the focal length).
A hover of ``hover_s`` gives ``looks`` frames at the camera's rate (at least
floor(hover_s * rate) of them fall in it; with the mission's ``min_revisit_s``, one in every
ceil(min_revisit_s * rate)); under independent looks they add ``looks`` times the frame's
log(1 - P_D) per cell.

The heading at a hover is the direction the route arrives from, unknown while choosing the
points. A gimbal holding an earth-frame yaw (GIMBAL_MANAGER_FLAGS_YAW_LOCK) sees the same
footprint whatever the heading: such a candidate is credited with exactly its frame. Any
other (a fixed mount, a gimbal whose yaw follows the vehicle, nadir) is credited, per cell,
only with the least it sees over ``HOVER_HEADINGS`` headings (a footprint turns with the
heading): the cover then holds whatever the route, up to what changes between those
headings (a cell at a footprint's corner); the whole flight's prediction is what is
reported. Frames taken in transit only add to it.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, replace
from enum import Enum

import numpy as np
import shapely
from scipy import sparse
from shapely.geometry import MultiPolygon, Polygon

from pdcov.core.camera import CameraModel
from pdcov.core.grid_layer import Layer
from pdcov.core.limiting import LimitingFactor
from pdcov.core.mount import GimbalMount
from pdcov.errors import ConfigError
from pdcov.planning.cover import Cover, CoverProblem, exact_cover, greedy_cover
from pdcov.planning.decomposition import polygons_of
from pdcov.planning.optimise import Scenario
from pdcov.planning.plan import GimbalPointing, Plan, Waypoint
from pdcov.planning.progress import progress as show_progress
from pdcov.planning.trajectory import Flight, camera_poses

HOVER_HEADINGS = 16
"""Headings, 22.5 deg apart, over which a candidate's view is taken as the least."""
EXACT_MAX_CANDIDATES = 5000
"""Above this many candidates the integer program is not tried (greedy only)."""
NADIR_TOLERANCE_DEG = 1e-6
"""A pitch this close to -90 deg is nadir: its yaw only turns the footprint."""


def is_nadir(pitch_deg: float) -> bool:
    """Whether a gimbal pitch (deg) looks straight down (within NADIR_TOLERANCE_DEG)."""
    return abs(pitch_deg + 90.0) <= NADIR_TOLERANCE_DEG


class CoverObjective(str, Enum):
    """What the cover minimises: the number of points (fewer hovers first, then shorter
    ones), or the time they take (hover plus the stop: v / a, decelerating and accelerating
    again). Prints as its text."""

    POINTS = "points"
    TIME = "time"

    def __str__(self) -> str:
        return str(self.value)


@dataclass(frozen=True, slots=True)
class VantageSettings:
    """target_pd in (0, 1); target_share: proportion of free cells that must reach it;
    alts_agl_m: candidate altitudes above ground (m); hover_s: candidate hover times (s);
    lattice_m: candidate spacing (m; None: half the swath at the lowest altitude);
    clearance_m: distance kept from obstacles and the domain's edge (m; None: the
    kinematics' corner cut, so that rounded corners stay clear); speed_mps: transit speed;
    objective; exact_time_limit_s: the integer program's time (0: greedy only);
    gimbal_pitches_deg: candidate gimbal pitches (deg, -90: nadir; None: the scenario's
    planning.gimbal_pitch_deg, or the fixed mount's own); gimbal_yaws: earth-frame yaws
    per non-nadir pitch, 360 / gimbal_yaws deg apart from north (0: the yaw follows the
    vehicle, credited as the least over headings); zooms_hfov_deg: candidate camera zooms
    as horizontal fields of view (deg; None: the configured camera, no zoom command)."""

    target_pd: float
    alts_agl_m: tuple[float, ...]
    hover_s: tuple[float, ...] = (2.0,)
    target_share: float = 1.0
    lattice_m: float | None = None
    clearance_m: float | None = None
    speed_mps: float = 5.0
    objective: CoverObjective = CoverObjective.POINTS
    exact_time_limit_s: float = 20.0
    gimbal_pitches_deg: tuple[float, ...] | None = None
    gimbal_yaws: int = 0
    zooms_hfov_deg: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        if self.zooms_hfov_deg is not None and not (self.zooms_hfov_deg and all(
                math.isfinite(z) and 0 < z < 180 for z in self.zooms_hfov_deg)):
            raise ConfigError(f"--zooms-hfov-deg: expected fields of view in (0, 180) deg, "
                              f"got {list(self.zooms_hfov_deg)}")
        if self.gimbal_pitches_deg is not None and not (self.gimbal_pitches_deg and all(
                math.isfinite(p) and -90.0 <= p <= 90.0 for p in self.gimbal_pitches_deg)):
            raise ConfigError(f"--gimbal-pitches-deg: expected pitches in [-90, 90] deg, got "
                              f"{list(self.gimbal_pitches_deg)}")
        if self.gimbal_yaws < 0:
            raise ConfigError(f"--gimbal-yaws: expected a count >= 0, got {self.gimbal_yaws}")
        if not 0.0 < self.target_pd < 1.0:
            raise ConfigError(f"--target-pd: expected a probability in (0, 1), got "
                              f"{self.target_pd}")
        if not 0.0 < self.target_share <= 1.0:
            raise ConfigError(f"--target-share: expected a proportion in (0, 1], got "
                              f"{self.target_share}")
        for name, values in (("--altitudes-m", self.alts_agl_m), ("--hover-s", self.hover_s)):
            if not values or not all(v > 0 and math.isfinite(v) for v in values):
                raise ConfigError(f"{name}: expected positive numbers, got {values}")


@dataclass(frozen=True, slots=True)
class VantagePoint:
    """A hover: ENU position (m), altitude above ground (m), hover time (s), frames it
    counts (``looks``), the gimbal's pointing there (None: a fixed mount) and the camera's
    zoom, a horizontal field of view (deg; None: the configured camera)."""

    x_enu_m: float
    y_enu_m: float
    alt_agl_m: float
    hover_s: float
    looks: int
    pointing: GimbalPointing | None = None
    zoom_hfov_deg: float | None = None


@dataclass(frozen=True, slots=True)
class VantageCover:
    """The chosen points, the candidates there were, and the greedy and exact covers (their
    cost in the objective's units; exact None when not tried or not found in time)."""

    points: tuple[VantagePoint, ...]
    n_candidates: int
    greedy: Cover
    exact: Cover | None
    objective: CoverObjective

    @property
    def greedy_gap(self) -> float | None:
        """(greedy - exact) / exact cost; None without an exact cover."""
        if self.exact is None:
            return None
        return (self.greedy.cost - self.exact.cost) / self.exact.cost


def clearance_of(sc: Scenario, settings: VantageSettings) -> float:
    return sc.kinematics.corner_cut_m if settings.clearance_m is None else settings.clearance_m


def flight_space(free_enu: Polygon | MultiPolygon, clearance_m: float
                 ) -> Polygon | MultiPolygon:
    """The free space kept ``clearance_m`` from its boundary (obstacles and the domain's
    edge): where vantage points lie and transits run."""
    inner = free_enu.buffer(-clearance_m, join_style="mitre") if clearance_m > 0 else free_enu
    if inner.is_empty:
        raise ConfigError(f"vantage: no free space is {clearance_m:g} m from the obstacles "
                          "and the domain's edge; lower --clearance-m")
    return inner


def lattice_enu_m(space: Polygon | MultiPolygon, spacing_m: float) -> np.ndarray:
    """(N, 2) ENU candidate positions in ``space``: a square lattice of ``spacing_m``
    centred on its bounding box, and its boundary's vertices and points every ``spacing_m``
    along it (where the lattice falls short of corners and edges)."""
    x0, y0, x1, y1 = space.bounds
    nx, ny = (max(1, math.ceil((b - a) / spacing_m)) for a, b in ((x0, x1), (y0, y1)))
    xs = 0.5 * (x0 + x1) + spacing_m * (np.arange(nx + 1) - nx / 2)
    ys = 0.5 * (y0 + y1) + spacing_m * (np.arange(ny + 1) - ny / 2)
    X, Y = np.meshgrid(xs, ys)
    inside = shapely.contains_xy(space, X, Y)
    pts = [np.column_stack([X[inside], Y[inside]])]
    for poly in polygons_of(space):
        for ring in (poly.exterior, *poly.interiors):
            along = shapely.line_interpolate_point(
                ring, np.arange(0.0, ring.length, spacing_m))
            pts += [shapely.get_coordinates(along), np.asarray(ring.coords)[:-1]]
    xy = np.vstack(pts)
    # One of each point closer than a centimetre to another (a vertex on the sampled ring).
    _, first = np.unique(np.round(xy / 0.01), axis=0, return_index=True)
    return xy[np.sort(first)]


def hover_looks(sc: Scenario, hover_s: float) -> int:
    """Frames a hover of ``hover_s`` is sure to count (module doc)."""
    frames = math.floor(hover_s * sc.frame_rate_hz + 1e-9)
    step = 1 if not sc.min_revisit_s else max(1, math.ceil(sc.min_revisit_s
                                                          * sc.frame_rate_hz - 1e-9))
    return frames // step


def hover_z_enu_m(sc: Scenario, x_m: float, y_m: float, alt_agl_m: float) -> float:
    """ENU height of a hover point: the scenario's rule for a waypoint over its terrain."""
    plan = sc.over_terrain(Plan((Waypoint(x_m, y_m, alt_agl_m, 1.0),)))
    return plan.waypoints[0].z_enu_m


def candidate_pointings(sc: Scenario, settings: VantageSettings
                        ) -> list[GimbalPointing | None]:
    """The gimbal pointings candidates take (module doc): each pitch, a non-nadir one at
    each earth-frame yaw; [None] for a fixed mount. ConfigError (one line) for a pitch
    outside the mount's pitch_limits_deg, a fixed mount given another pitch than its own or
    earth-frame yaws, and earth-frame yaws on a gimbal whose yaw_limits_deg do not turn
    all round (it could hold them only at some of the route's headings)."""
    given = settings.gimbal_pitches_deg
    mount = sc.mount
    if not isinstance(mount, GimbalMount):
        own = math.degrees(mount.pitch_rad)
        if given is not None and any(abs(p - own) > NADIR_TOLERANCE_DEG for p in given):
            raise ConfigError(f"--gimbal-pitches-deg {' '.join(f'{p:g}' for p in given)}: a "
                              f"fixed mount points at its own pitch ({own:g} deg); plan "
                              "other pitches with a gimbal (mount: {type: gimbal})")
        if settings.gimbal_yaws and not is_nadir(own):
            raise ConfigError(f"--gimbal-yaws {settings.gimbal_yaws}: a fixed mount turns "
                              "with the vehicle and holds no earth-frame yaw; give "
                              "--gimbal-yaws 0")
        return [None]
    what = "--gimbal-pitches-deg" if given is not None else "planning.gimbal_pitch_deg"
    pitches = given if given is not None else (math.degrees(sc.gimbal_pitch_rad),)
    limits = mount.pitch_limits_deg
    for pitch in pitches:
        if limits is not None and not limits[0] - 1e-6 <= pitch <= limits[1] + 1e-6:
            raise ConfigError(f"{what} {pitch:g}: outside the mount's pitch_limits_deg "
                              f"{list(limits)}")
    n = settings.gimbal_yaws
    oblique = [p for p in pitches if not is_nadir(p)]
    yaw_limits = mount.yaw_limits_deg
    if n and oblique and yaw_limits is not None and yaw_limits[1] - yaw_limits[0] < 360 - 1e-6:
        raise ConfigError(f"--gimbal-yaws {n}: the mount's yaw_limits_deg {list(yaw_limits)} "
                          "cannot hold an earth-frame yaw at every heading of the route; "
                          "give --gimbal-yaws 0 (the yaw follows the vehicle)")
    out: list[GimbalPointing | None] = []
    for pitch in dict.fromkeys(pitches):
        if pitch in oblique and n:
            out += [GimbalPointing(math.radians(pitch), 2 * math.pi * k / n, earth_yaw=True)
                    for k in range(n)]
        else:
            out.append(GimbalPointing(math.radians(pitch)))
    return out


def candidate_cameras(sc: Scenario, settings: VantageSettings
                      ) -> dict[float | None, CameraModel]:
    """The camera at each candidate zoom (``Scenario.camera_at``); {None: the configured
    camera} without zooms. ConfigError (one line) for a zoom outside the lens's calibrated
    range or without camera.zoom fov_status."""
    zooms = settings.zooms_hfov_deg
    if zooms is None:
        return {None: sc.camera}
    try:
        return {z: sc.camera_at(z) for z in zooms}
    except ConfigError as exc:
        raise ConfigError(f"--zooms-hfov-deg: {exc}") from None


def _frame_log_miss(sc: Scenario, scratch_grid, x: float, y: float, z: float,
                    aim: GimbalPointing | None, camera: CameraModel
                    ) -> tuple[tuple[int, int, int, int], np.ndarray] | None:
    """The least log-miss (closest to 0) per cell over HOVER_HEADINGS of one frame at rest
    at (x, y, z) with the gimbal at ``aim`` (an earth-frame yaw: its one frame), taken with
    ``camera``: its window (r0, r1, c0, c1) and values; None when it sees nothing."""
    n = 1 if aim is not None and aim.earth_yaw else HOVER_HEADINGS
    headings = 2 * math.pi * np.arange(n) / n
    R = np.array([[[math.cos(h), -math.sin(h), 0.0], [math.sin(h), math.cos(h), 0.0],
                   [0.0, 0.0, 1.0]] for h in headings])  # Rz(heading): level, at rest
    at_rest = Flight(np.zeros(len(headings)), np.tile([x, y, z], (len(headings), 1)), R,
                     np.zeros(len(headings)), 0.0, 0.0)
    views = []
    for pose in camera_poses(at_rest, sc.mount, sc.gimbal_pitch_rad, [aim] * n):
        scratch_grid.update_with(pose, camera)
        w = scratch_grid.touched
        if w is None:
            return None
        views.append((w, scratch_grid.read(Layer.LOG_MISS_D, w).astype(np.float64)))
        scratch_grid.layer(Layer.LOG_MISS_D).write(w, 0.0)  # the scratch grid keeps one frame
    r0 = min(v[0][0] for v in views)
    r1 = max(v[0][1] for v in views)
    c0 = min(v[0][2] for v in views)
    c1 = max(v[0][3] for v in views)
    least = np.full((r1 - r0, c1 - c0), -np.inf)
    for (a0, a1, b0, b1), L in views:
        full = np.zeros_like(least)
        full[a0 - r0:a1 - r0, b0 - c0:b1 - c0] = L
        least = np.maximum(least, full)
    return (r0, r1, c0, c1), least


def candidate_evidence(sc: Scenario, settings: VantageSettings, *, progress: bool = False
                       ) -> tuple[list[VantagePoint], sparse.csc_matrix, np.ndarray]:
    """The candidates, their evidence (n_free_cells, n_candidates: -log-miss of their hover,
    rows the free cells in row-major order) and the best LimitingFactor any candidate frame
    gave each free cell; ``progress``: a bar over the candidate views on stderr."""
    aims = candidate_pointings(sc, settings)
    cameras = candidate_cameras(sc, settings)
    space = flight_space(sc.free_space, clearance_of(sc, settings))
    spacing = settings.lattice_m or 0.5 * sc.swath_width_m(min(settings.alts_agl_m))
    if not (spacing > 0 and math.isfinite(spacing)):
        raise ConfigError(f"vantage lattice: expected a positive spacing, got {spacing}; "
                          "give --lattice-m")
    xy = lattice_enu_m(space, spacing)
    if len(xy) == 0:
        raise ConfigError(f"vantage: no lattice point of {spacing:g} m falls in the free "
                          "space; lower --lattice-m")
    scratch = replace(sc, min_revisit_s=None).new_grid()
    row_of = np.full(sc.mask.shape, -1, dtype=np.int64)
    row_of[sc.mask] = np.arange(int(sc.mask.sum()))
    looks = [hover_looks(sc, h) for h in settings.hover_s]
    if max(looks) == 0:
        raise ConfigError(f"--hover-s {list(settings.hover_s)}: shorter than one frame at "
                          f"{sc.frame_rate_hz:g} Hz (min_revisit_s {sc.min_revisit_s}); "
                          "hover longer")
    points: list[VantagePoint] = []
    rows: list[np.ndarray] = []
    vals: list[np.ndarray] = []
    views = itertools.product(settings.alts_agl_m, xy, aims, cameras.items())
    total = len(settings.alts_agl_m) * len(xy) * len(aims) * len(cameras)
    for alt, (x, y), aim, (zoom, camera) in show_progress(
            views, desc="vantage candidates", unit="view", total=total, enabled=progress):
        seen = _frame_log_miss(sc, scratch, float(x), float(y),
                               hover_z_enu_m(sc, float(x), float(y), alt), aim, camera)
        if seen is None:
            continue
        (r0, r1, c0, c1), least = seen
        idx = row_of[r0:r1, c0:c1]
        keep = (idx >= 0) & (least < 0)
        if not keep.any():
            continue
        for hover, n in zip(settings.hover_s, looks, strict=True):
            if n == 0:
                continue
            points.append(VantagePoint(float(x), float(y), alt, hover, n, aim, zoom))
            rows.append(idx[keep])
            vals.append(-n * least[keep])
    n_cells = int(sc.mask.sum())
    if not points:
        evidence = sparse.csc_matrix((n_cells, 0))
    else:
        cols = np.repeat(np.arange(len(points)), [len(r) for r in rows])
        evidence = sparse.csc_matrix((np.concatenate(vals), (np.concatenate(rows), cols)),
                                     shape=(n_cells, len(points)))
    return points, evidence, scratch.limiting[sc.mask]


_WHY = {LimitingFactor.NEVER_IN_VIEW: "in no candidate's view",
        LimitingFactor.TOO_FAR: "too far (beyond the range limit) from every candidate",
        LimitingFactor.HIDDEN: "hidden by the terrain or a building from every candidate",
        LimitingFactor.BUILDING: "under a roof",
        LimitingFactor.TOO_SMALL: "too small in the picture at every height",
        LimitingFactor.TOO_LARGE: "too large in the picture at every height"}
_SOME_HEADINGS = ("in view of candidates only at some headings (a hover's heading is its "
                  "route's: a finer --lattice-m, a lower --clearance-m or, for oblique "
                  "pitches, earth-frame --gimbal-yaws help)")
_TOO_FEW_LOOKS = ("seen, but all candidates' looks together stay below the target (hover "
                  "longer: --hover-s)")


def unreachable_message(sc: Scenario, reachable: np.ndarray, limiting: np.ndarray,
                        seen_all_headings: np.ndarray, settings: VantageSettings) -> str:
    """One line: how many free cells no candidate set brings to the target, and why (the
    best LimitingFactor of any candidate frame; ``seen_all_headings``: cells some candidate
    sees whatever its heading), with the first such cell's position."""
    bad = ~reachable
    why = [(n, _WHY[f]) for f in _WHY if (n := int((bad & (limiting == f)).sum()))]
    seen = bad & np.isin(limiting, (LimitingFactor.SEEN, LimitingFactor.CANOPY))
    why += [(n, text) for n, text in ((int((seen & ~seen_all_headings).sum()), _SOME_HEADINGS),
                                      (int((seen & seen_all_headings).sum()), _TOO_FEW_LOOKS))
            if n]
    rr, cc = np.nonzero(sc.mask)
    first = int(np.flatnonzero(bad)[0])
    xs, ys = sc.geometry.centres_enu()
    need = math.ceil(settings.target_share * len(reachable) - 1e-9)
    return (f"vantage: {int(bad.sum())} of {len(reachable)} free cells cannot reach P_D "
            f"{settings.target_pd:g} from any set of candidates (at most "
            f"{int(reachable.sum())} can, {need} are required): "
            f"{'; '.join(f'{n} {text}' for n, text in why)}; e.g. the cell at "
            f"({xs[cc[first]]:.1f}, {ys[rr[first]]:.1f}) m")


def choose_vantage_points(sc: Scenario, settings: VantageSettings, *, progress: bool = False
                          ) -> VantageCover:
    """The cover of the free cells (module doc): greedy, and the integer program when there
    are at most EXACT_MAX_CANDIDATES candidates; the cheaper one is kept. ConfigError (one
    line) when the target cannot be reached. ``progress``: candidate_evidence's."""
    points, evidence, limiting = candidate_evidence(sc, settings, progress=progress)
    n_cells = evidence.shape[0]
    need = math.ceil(settings.target_share * n_cells - 1e-9)
    accel = sc.kinematics.max_accel_mps2
    hover = np.array([p.hover_s for p in points])
    if settings.objective is CoverObjective.TIME:
        cost = hover + settings.speed_mps / accel
    else:
        cost = 1.0 + 1e-3 * hover / max(settings.hover_s)
    problem = CoverProblem.of(evidence, cost, settings.target_pd, need)
    reachable = problem.reachable() if points else np.zeros(n_cells, dtype=bool)
    seen = np.diff(evidence.tocsr().indptr) > 0
    if int(reachable.sum()) < need:
        raise ConfigError(unreachable_message(sc, reachable, limiting, seen, settings))
    greedy = greedy_cover(problem)
    if greedy is None:  # cannot happen when the reachable cells suffice
        raise ConfigError(unreachable_message(sc, reachable, limiting, seen, settings))
    exact = None
    if 0 < settings.exact_time_limit_s and len(points) <= EXACT_MAX_CANDIDATES:
        exact = exact_cover(problem, settings.exact_time_limit_s)
        if exact is not None and int(problem.reached(exact.chosen).sum()) < need:
            exact = None  # within the solver's tolerance only
    best = exact if exact is not None and exact.cost < greedy.cost else greedy
    return VantageCover(tuple(points[j] for j in best.chosen), len(points), greedy, exact,
                        settings.objective)
