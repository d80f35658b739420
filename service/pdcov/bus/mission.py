"""The mission payload (queryable ``pdcov/<id>/mission``): the geometry a ground station
needs to draw a vehicle's grid without the aircraft's mission file.

UTF-8 JSON, one object (docs/protocol.md "mission"): schema "pdcov.mission", version 1,
vehicle_id, grid_hash (the grid it describes, as in the status and tiles), origin
{lat_deg, lon_deg, ground_alt_msl_m (null until known)}, grid {x0_m, y0_m, cell_size_m,
n_rows, n_cols}, domain {boundary_enu_m, obstacles_enu_m, boundary_lon_lat_deg,
obstacles_lon_lat_deg} (closed rings; ENU metres about the origin, and WGS84 [lon, lat]
degrees as GeoJSON orders them), thresholds and target_pd.

A separate queryable rather than more arrays in the snapshot: the snapshot stays exactly a
grid.npz (``np.load`` and ``pdcov evaluate`` read it as any other), and the geometry, which
changes only with the grid hash, is not sent again with every snapshot a gap asks for.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from shapely.geometry import Polygon
from shapely.validation import explain_validity

from pdcov.bus.errors import Refusal, Refuser
from pdcov.bus.grid_state import GRID_HASH, MAX_ENU_M
from pdcov.bus.json_doc import Fields, check_schema, is_number, json_object
from pdcov.config.mission import MAX_THRESHOLDS
from pdcov.core.domain import MAX_GRID_CELLS, Domain, GridGeometry
from pdcov.core.geodesy import Origin, enu_to_geodetic
from pdcov.errors import PdcovError

MISSION_SCHEMA = "pdcov.mission"
MISSION_VERSION = 1
MAX_MISSION_BYTES = 8 << 20
MAX_OBSTACLES = 10_000
MAX_VERTICES = 100_000
"""Positions in all rings together (each ring is sent twice: ENU and WGS84)."""
WGS84_TOLERANCE_M = 0.05
"""How far a WGS84 position may lie from its ENU twin (the encoder rounds to 1e-9 deg)."""

Ring = tuple[tuple[float, float], ...]


@dataclass(frozen=True, slots=True)
class MissionGeometry:
    """A decoded mission payload. Rings are closed (first position repeated last);
    ``*_enu_m`` (x east, y north) metres about the origin, ``*_lon_lat_deg`` WGS84.
    ground_alt_msl_m: None until the daemon knows it (the autopilot's home)."""

    vehicle_id: str
    grid_hash: str
    origin_lat_deg: float
    origin_lon_deg: float
    ground_alt_msl_m: float | None
    geometry: GridGeometry
    boundary_enu_m: Ring
    obstacles_enu_m: tuple[Ring, ...]
    boundary_lon_lat_deg: Ring
    obstacles_lon_lat_deg: tuple[Ring, ...]
    thresholds: tuple[float, ...]
    target_pd: float

    def domain(self) -> Domain:
        """The search domain as the daemon holds it (ENU)."""
        return Domain.from_enu(self.boundary_enu_m, self.obstacles_enu_m)


def encode_mission(vehicle_id: str, origin: Origin, domain: Domain, geometry: GridGeometry,
                   grid_hash: str, *, ground_alt_known: bool, thresholds: Sequence[float],
                   target_pd: float) -> bytes:
    """The mission payload. ENU coordinates go out at full float precision (a receiver
    rebuilding the grid from them gets the same free mask, hence the same grid hash); WGS84
    positions are projected from them about ``origin`` and rounded to 1e-9 deg (0.1 mm).
    ground_alt_known: whether ``origin.ground_alt_msl_m`` is known (else sent as null)."""
    def enu(ring: Any) -> list[list[float]]:
        return [[float(x), float(y)] for x, y in list(ring)]

    def lon_lat(ring: list[list[float]]) -> list[list[float]]:
        r = np.asarray(ring, dtype=float)
        llh = enu_to_geodetic(np.column_stack([r, np.zeros(len(r))]), origin)
        return [[round(float(lon), 9), round(float(lat), 9)] for lat, lon, _ in llh]

    boundary = enu(domain.boundary.exterior.coords)
    obstacles = [enu(o.exterior.coords) for o in domain.obstacles]
    g = geometry
    doc = {"schema": MISSION_SCHEMA, "version": MISSION_VERSION, "vehicle_id": vehicle_id,
           "grid_hash": grid_hash,
           "origin": {"lat_deg": origin.lat_deg, "lon_deg": origin.lon_deg,
                      "ground_alt_msl_m": origin.ground_alt_msl_m if ground_alt_known
                      else None},
           "grid": {"x0_m": g.x0_m, "y0_m": g.y0_m, "cell_size_m": g.cell_size_m,
                    "n_rows": g.n_rows, "n_cols": g.n_cols},
           "domain": {"boundary_enu_m": boundary, "obstacles_enu_m": obstacles,
                      "boundary_lon_lat_deg": lon_lat(boundary),
                      "obstacles_lon_lat_deg": [lon_lat(o) for o in obstacles]},
           "thresholds": [float(t) for t in thresholds], "target_pd": float(target_pd)}
    return json.dumps(doc, separators=(",", ":"), allow_nan=False).encode()


def decode_mission(payload: bytes, key: str = "mission",
                   vehicle_id: str | None = None) -> MissionGeometry:
    """Validate a mission payload: size, UTF-8 JSON, schema and version, the vehicle id
    (``vehicle_id`` when given: the one in the key), a 16-digit grid hash, an origin in
    range, a grid of at most MAX_GRID_CELLS, closed rings of finite positions forming valid
    polygons of non-zero area, the boundary inside the grid, WGS84 rings agreeing with the
    ENU ones within WGS84_TOLERANCE_M, thresholds and target in (0, 1]. Raises
    BusPayloadError naming ``key`` and the field; nothing is returned from bad data."""
    bad = Refuser(f"{key}: not a usable mission")
    doc = json_object(payload, MAX_MISSION_BYTES, bad)
    check_schema(doc, MISSION_SCHEMA, MISSION_VERSION, bad)
    vid = Fields(doc, bad).vehicle_id("vehicle_id", vehicle_id)
    ghash = doc.get("grid_hash")
    if not isinstance(ghash, str) or not GRID_HASH.fullmatch(ghash):
        raise bad("grid_hash: expected 16 lowercase hex digits")
    origin, ground_alt = _origin(_object(doc, "origin", bad), bad)
    geometry = _grid(_object(doc, "grid", bad), bad)
    dom = _object(doc, "domain", bad)
    obstacles_enu = _list(dom, "obstacles_enu_m", MAX_OBSTACLES, bad)
    obstacles_ll = _list(dom, "obstacles_lon_lat_deg", MAX_OBSTACLES, bad)
    if len(obstacles_ll) != len(obstacles_enu):
        raise bad(f"domain.obstacles_lon_lat_deg: {len(obstacles_ll)} rings, "
                  f"obstacles_enu_m has {len(obstacles_enu)}")
    budget = [MAX_VERTICES]
    boundary = _ring(dom.get("boundary_enu_m"), "domain.boundary_enu_m", False, budget, bad)
    obstacles = tuple(_ring(r, f"domain.obstacles_enu_m[{i}]", False, budget, bad)
                      for i, r in enumerate(obstacles_enu))
    boundary_ll = _ring(dom.get("boundary_lon_lat_deg"), "domain.boundary_lon_lat_deg",
                        True, budget, bad)
    obstacles_ll_rings = tuple(
        _ring(r, f"domain.obstacles_lon_lat_deg[{i}]", True, budget, bad)
        for i, r in enumerate(obstacles_ll))
    domain = Domain(_polygon(boundary, "domain.boundary_enu_m", bad),
                    tuple(_polygon(r, f"domain.obstacles_enu_m[{i}]", bad)
                          for i, r in enumerate(obstacles)))
    x_min, x_max, y_min, y_max = geometry.extent_enu
    bx0, by0, bx1, by1 = domain.boundary.bounds
    slack = 1e-6 * max(1.0, abs(x_min), abs(x_max), abs(y_min), abs(y_max))
    if bx0 < x_min - slack or bx1 > x_max + slack or by0 < y_min - slack \
            or by1 > y_max + slack:
        raise bad(f"domain.boundary_enu_m: extends beyond the grid "
                  f"({x_min:g}..{x_max:g} x {y_min:g}..{y_max:g} m)")
    for name, enu_ring, ll_ring in [("boundary", boundary, boundary_ll)] + [
            (f"obstacles[{i}]", a, b)
            for i, (a, b) in enumerate(zip(obstacles, obstacles_ll_rings, strict=True))]:
        _check_twins(name, enu_ring, ll_ring, origin, bad)
    thresholds = doc.get("thresholds")
    if not isinstance(thresholds, list) or not 1 <= len(thresholds) <= MAX_THRESHOLDS \
            or not all(_probability(t) for t in thresholds):
        raise bad(f"thresholds: expected 1..{MAX_THRESHOLDS} probabilities in (0, 1]")
    target: Any = doc.get("target_pd")
    if not _probability(target):
        raise bad("target_pd: expected a probability in (0, 1]")
    return MissionGeometry(vid, ghash, origin.lat_deg, origin.lon_deg, ground_alt, geometry,
                           boundary, obstacles, boundary_ll, obstacles_ll_rings,
                           tuple(float(t) for t in thresholds), float(target))


def _probability(v: Any) -> bool:
    return is_number(v) and 0 < v <= 1


def _object(doc: dict[str, Any], name: str, bad: Refuser) -> dict[str, Any]:
    v = doc.get(name)
    if not isinstance(v, dict):
        raise bad(f"{name}: expected an object")
    return v


def _list(doc: dict[str, Any], name: str, most: int, bad: Refuser) -> list[Any]:
    v = doc.get(name)
    if not isinstance(v, list):
        raise bad(f"domain.{name}: expected a list of rings")
    if len(v) > most:
        raise bad(f"domain.{name}: {len(v)} rings, more than {most}", Refusal.OVER_BOUND)
    return v


def _origin(o: dict[str, Any], bad: Refuser) -> tuple[Origin, float | None]:
    lat: Any = o.get("lat_deg")
    lon: Any = o.get("lon_deg")
    alt: Any = o.get("ground_alt_msl_m")
    if not (is_number(lat) and -90 <= lat <= 90 and is_number(lon) and -180 <= lon <= 360):
        raise bad("origin: expected lat_deg in [-90, 90] and lon_deg in [-180, 360]")
    if alt is not None and not (is_number(alt) and -1e4 <= alt <= 1e5):
        raise bad("origin.ground_alt_msl_m: expected metres in [-10000, 100000] or null")
    return (Origin(float(lat), float(lon), 0.0 if alt is None else float(alt)),
            None if alt is None else float(alt))


def _grid(g: dict[str, Any], bad: Refuser) -> GridGeometry:
    x0: Any = g.get("x0_m")
    y0: Any = g.get("y0_m")
    c: Any = g.get("cell_size_m")
    n_rows: Any = g.get("n_rows")
    n_cols: Any = g.get("n_cols")
    if not (is_number(x0) and is_number(y0) and abs(x0) <= MAX_ENU_M and abs(y0) <= MAX_ENU_M):
        raise bad(f"grid: x0_m and y0_m: expected finite metres within {MAX_ENU_M:g}")
    if not (is_number(c) and c > 0):
        raise bad("grid.cell_size_m: expected a positive number of metres")
    if not all(isinstance(n, int) and not isinstance(n, bool) and n >= 1
               for n in (n_rows, n_cols)):
        raise bad("grid: n_rows and n_cols: expected positive integers")
    if n_rows * n_cols > MAX_GRID_CELLS:
        raise bad(f"grid: {n_rows} x {n_cols} cells: at most MAX_GRID_CELLS {MAX_GRID_CELLS}",
                  Refusal.OVER_BOUND)
    try:
        return GridGeometry(float(x0), float(y0), float(c), n_rows, n_cols)
    except PdcovError as exc:
        raise bad(f"grid: {exc}") from None


def _ring(v: Any, name: str, lon_lat: bool, budget: list[int], bad: Refuser) -> Ring:
    """A closed ring of 4 or more finite positions (within the vertex budget)."""
    if not isinstance(v, list) or len(v) < 4:
        raise bad(f"{name}: expected a closed ring of 4 or more positions")
    if len(v) > budget[0]:
        raise bad(f"{name}: more positions than MAX_VERTICES: at most {MAX_VERTICES} in all rings",
                  Refusal.OVER_BOUND)
    budget[0] -= len(v)
    out = []
    for p in v:
        if not (isinstance(p, list) and len(p) == 2 and all(is_number(c) for c in p)):
            raise bad(f"{name}: position {p!r} is not a pair of finite numbers"[:200])
        x, y = float(p[0]), float(p[1])
        if lon_lat and not (-180 <= x <= 360 and -90 <= y <= 90):
            raise bad(f"{name}: position {p!r} is not [lon, lat] in degrees")
        if not lon_lat and not (abs(x) <= MAX_ENU_M and abs(y) <= MAX_ENU_M):
            raise bad(f"{name}: position {p!r} lies beyond {MAX_ENU_M:g} m")
        out.append((x, y))
    if out[0] != out[-1]:
        raise bad(f"{name}: the ring is not closed (the last position must repeat the first)")
    return tuple(out)


def _polygon(ring: Ring, name: str, bad: Refuser) -> Polygon:
    """A valid polygon of non-zero area (what Domain requires), or ``bad`` naming ``name``."""
    poly = Polygon(ring)
    if not poly.is_valid:
        raise bad(f"{name}: invalid polygon ({explain_validity(poly)})")
    if not poly.area > 0:
        raise bad(f"{name}: the polygon has no area")
    return poly


def _check_twins(name: str, enu: Ring, lon_lat: Ring, origin: Origin, bad: Refuser) -> None:
    """The WGS84 ring must be the ENU ring's projection, as the encoder makes it (ENU at
    z = 0 to WGS84 about the origin): same length, within WGS84_TOLERANCE_M."""
    if len(enu) != len(lon_lat):
        raise bad(f"domain.{name}: {len(lon_lat)} WGS84 positions for {len(enu)} ENU ones")
    r = np.asarray(enu)
    llh = enu_to_geodetic(np.column_stack([r, np.zeros(len(r))]), origin)
    ll = np.asarray(lon_lat)
    m_per_deg = math.pi / 180 * 6_378_137.0
    d_north = (ll[:, 1] - llh[:, 0]) * m_per_deg
    d_lon = (ll[:, 0] - llh[:, 1] + 180.0) % 360.0 - 180.0  # -170 and 190 are one meridian
    d_east = d_lon * m_per_deg * np.cos(np.radians(llh[:, 0]))
    err = float(np.max(np.hypot(d_north, d_east)))
    if not err <= WGS84_TOLERANCE_M:
        raise bad(f"domain.{name}: the WGS84 ring lies {err:.3g} m from the ENU ring "
                  f"(more than {WGS84_TOLERANCE_M} m)")
