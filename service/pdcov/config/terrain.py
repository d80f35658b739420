"""The mission config's ``terrain`` section: the DEM (heights m MSL) under the domain, read
over the grid, and the ground altitude it gives at the origin; with ``surface`` (a DSM) and
``landcover``, what stands on the ground (``cover_terrain``) and the cells under roofs that
are not searched (``searched_domain``)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from pdcov.config.origin import OriginSection
from pdcov.config.values import number, resolve
from pdcov.core import dem as dem_rules
from pdcov.core.dem import MAX_WINDOW_PIXELS, Dem, VerticalDatum
from pdcov.core.domain import Domain, GridGeometry
from pdcov.core.dsm import CoverRules, cover_surface
from pdcov.core.geodesy import Origin, enu_to_geodetic
from pdcov.core.ground_cover import (
    DEFAULT_EXTINCTION_PER_M,
    DEFAULT_MIN_OBJECT_HEIGHT_M,
    CoverKind,
    GroundCover,
)
from pdcov.core.landcover import WORLDCOVER_CLASSES, LandCover
from pdcov.core.terrain import TerrainSurface
from pdcov.errors import ConfigError, PdcovError, where

DEFAULT_TERRAIN_MARGIN_M = 10.0
"""terrain.check_margin_m when the config does not set it (m): how far the DEM may disagree
with the home altitude and what the aircraft measures before it is said."""

COVER_CLASS_NAMES = {"foliage": CoverKind.FOLIAGE, "solid": CoverKind.SOLID,
                     "open": CoverKind.OPEN}
"""What terrain.landcover_classes may call a class."""

_COVER_KEYS = ("landcover", "landcover_classes", "canopy_extinction_per_m",
               "min_object_height_m", "search_under_roofs")
"""The keys that describe the DSM's surfaces: meaningless without terrain.surface."""

_COVER_MARGIN_M = 10.0
"""Metres around the grid the DSM and land-cover windows also read (the cells' centres lie
inside it; the margin only guards the box where the rasters' CRS bends it)."""


@dataclass(frozen=True, slots=True)
class TerrainSection:
    """``terrain``: the DEM file (GeoTIFF, COG or SRTM .hgt, any CRS; relative to the config's
    folder), the datum of its heights ('msl', or 'ellipsoid' with geoid_height_m, the geoid's
    height N above the ellipsoid at the site in m: H_msl = h_ellipsoid - N), the margin
    (m) beyond which an altitude measured or configured that disagrees with it is warned of,
    and the most (m) a configured home altitude may differ from it (else refused).

    What stands on the ground: surface, a DSM file (heights of roofs and tree tops, m; the
    DEM's datum: vertical_datum and geoid_height_m apply to it too); landcover, a raster of
    class codes; landcover_classes, code -> CoverKind (None: ``WORLDCOVER_CLASSES``; a code
    not listed is solid where raised); canopy_extinction_per_m, foliage's Beer-Lambert k
    (1/m); min_object_height_m (m): lower surfaces are open ground; search_under_roofs:
    whether cells under solid cover stay free (searched)."""

    dem: str
    vertical_datum: str = "msl"
    geoid_height_m: float | None = None
    check_margin_m: float = DEFAULT_TERRAIN_MARGIN_M
    max_home_offset_m: float = dem_rules.DEFAULT_MAX_HOME_OFFSET_M
    surface: str | None = None
    landcover: str | None = None
    landcover_classes: Mapping[int, CoverKind] | None = None
    canopy_extinction_per_m: float = DEFAULT_EXTINCTION_PER_M
    min_object_height_m: float = DEFAULT_MIN_OBJECT_HEIGHT_M
    search_under_roofs: bool = False

    @classmethod
    def from_mapping(cls, doc: Mapping[str, Any], src: str | None) -> TerrainSection:
        dem = doc.get("dem")
        if not isinstance(dem, str) or not dem:
            raise ConfigError(f"{where(src, 'terrain.dem')}: expected the path of a DEM file "
                              f"(GeoTIFF, Cloud-Optimized GeoTIFF, SRTM .hgt), got {dem!r}")
        datum = doc.get("vertical_datum", "msl")
        if datum not in tuple(VerticalDatum):
            raise ConfigError(f"{where(src, 'terrain.vertical_datum')}: expected 'msl' or "
                              f"'ellipsoid', got {datum!r}")
        geoid = (None if doc.get("geoid_height_m") is None
                 else number(doc, "geoid_height_m", src, "terrain"))
        if datum == VerticalDatum.ELLIPSOID and geoid is None:
            raise ConfigError(f"{where(src, 'terrain.geoid_height_m')}: missing: with "
                              "vertical_datum: ellipsoid, give the geoid's height N above the "
                              "WGS84 ellipsoid at the site in metres (H_msl = h_ellipsoid - "
                              "N; EGM2008 gives it)")
        if datum == VerticalDatum.MSL and geoid is not None:
            raise ConfigError(f"{where(src, 'terrain.geoid_height_m')}: only used with "
                              "vertical_datum: ellipsoid (the DEM's heights are MSL)")
        return cls(dem, datum, geoid,
                   number(doc, "check_margin_m", src, "terrain",
                          default=DEFAULT_TERRAIN_MARGIN_M, positive=True),
                   number(doc, "max_home_offset_m", src, "terrain",
                          default=dem_rules.DEFAULT_MAX_HOME_OFFSET_M, positive=True),
                   **_cover_options(doc, src))

    @property
    def cover_rules(self) -> CoverRules:
        """How the surface and its classes make the ground cover."""
        classes = (WORLDCOVER_CLASSES if self.landcover_classes is None
                   else self.landcover_classes)
        return CoverRules(classes, self.canopy_extinction_per_m, self.min_object_height_m)


def _cover_options(doc: Mapping[str, Any], src: str | None) -> dict[str, Any]:
    """The keys of what stands on the ground, checked; each refused without ``surface``."""
    surface = doc.get("surface")
    if surface is None:
        for key in _COVER_KEYS:
            if doc.get(key) is not None:
                raise ConfigError(f"{where(src, 'terrain.' + key)}: only used with "
                                  "terrain.surface (a DSM: the heights of roofs and tree "
                                  "tops), which is not set")
        return {}
    if not isinstance(surface, str) or not surface:
        raise ConfigError(f"{where(src, 'terrain.surface')}: expected the path of a DSM file "
                          "(GeoTIFF or Cloud-Optimized GeoTIFF of the heights of roofs and "
                          f"tree tops, m, the DEM's datum), got {surface!r}")
    landcover = doc.get("landcover")
    if landcover is not None and (not isinstance(landcover, str) or not landcover):
        raise ConfigError(f"{where(src, 'terrain.landcover')}: expected the path of a "
                          "land-cover raster (class codes, e.g. ESA WorldCover), got "
                          f"{landcover!r}")
    classes = doc.get("landcover_classes")
    if classes is not None and landcover is None:
        raise ConfigError(f"{where(src, 'terrain.landcover_classes')}: only used with "
                          "terrain.landcover (the raster of the codes), which is not set")
    k = number(doc, "canopy_extinction_per_m", src, "terrain",
               default=DEFAULT_EXTINCTION_PER_M)
    if k < 0:
        raise ConfigError(f"{where(src, 'terrain.canopy_extinction_per_m')}: expected a "
                          f"number >= 0 (1/m; 0: foliage hides nothing), got {k:g}")
    roofs = doc.get("search_under_roofs", False)
    if not isinstance(roofs, bool):
        raise ConfigError(f"{where(src, 'terrain.search_under_roofs')}: expected true or "
                          f"false, got {roofs!r}")
    return {"surface": surface, "landcover": landcover,
            "landcover_classes": None if classes is None else _classes(classes, src),
            "canopy_extinction_per_m": k,
            "min_object_height_m": number(doc, "min_object_height_m", src, "terrain",
                                          default=DEFAULT_MIN_OBJECT_HEIGHT_M, positive=True),
            "search_under_roofs": roofs}


def _classes(v: Any, src: str | None) -> Mapping[int, CoverKind]:
    """terrain.landcover_classes: {integer code: foliage | solid | open}."""
    key = "terrain.landcover_classes"
    if not isinstance(v, dict):
        raise ConfigError(f"{where(src, key)}: expected a mapping of the raster's class codes "
                          f"to foliage, solid or open, e.g. {{10: foliage, 50: solid}}, got "
                          f"{v!r}")
    out: dict[int, CoverKind] = {}
    for code, name in v.items():
        c = (code if isinstance(code, int) and not isinstance(code, bool)
             else int(code) if isinstance(code, str) and code.strip().lstrip("+-").isdigit()
             else None)
        if c is None or c in out:
            why = "not an integer class code" if c is None else "the same code twice"
            raise ConfigError(f"{where(src, key)}: {code!r}: {why}")
        if name not in COVER_CLASS_NAMES:
            raise ConfigError(f"{where(src, f'{key}.{code}')}: expected foliage, solid or "
                              f"open, got {name!r}")
        out[c] = COVER_CLASS_NAMES[name]
    return MappingProxyType(out)


def _area_lonlat(g: GridGeometry, origin: Origin, with_origin: bool
                 ) -> tuple[float, float, float, float]:
    """(west, south, east, north) degrees of the grid's corners (and of the origin)."""
    x1, y1 = g.x0_m + g.cell_size_m * g.n_cols, g.y0_m + g.cell_size_m * g.n_rows
    corners = np.array([[g.x0_m, g.y0_m, 0.0], [x1, g.y0_m, 0.0], [x1, y1, 0.0],
                        [g.x0_m, y1, 0.0]])
    geo = enu_to_geodetic(corners, origin)
    lat, lon = geo[:, 0], geo[:, 1]
    if with_origin:
        lat, lon = np.append(lat, origin.lat_deg), np.append(lon, origin.lon_deg)
    return float(lon.min()), float(lat.min()), float(lon.max()), float(lat.max())


def open_dem(ter: TerrainSection, src: str | None, base: Path, g: GridGeometry,
             origin: Origin) -> Dem:
    """The DEM, read over the grid and the origin (``Dem.open``'s margin around them)."""
    path = resolve(ter.dem, base, src, "terrain.dem")
    try:
        return Dem.open(path, vertical_datum=ter.vertical_datum,
                        geoid_height_m=ter.geoid_height_m,
                        area_lonlat_deg=_area_lonlat(g, origin, with_origin=True))
    except PdcovError as exc:
        raise ConfigError(f"{where(src, 'terrain.dem')}: {exc}") from None


def cover_terrain(ter: TerrainSection, src: str | None, base: Path, terrain: TerrainSurface,
                  dem: Dem, origin: Origin, free: np.ndarray
                  ) -> tuple[TerrainSurface, list[str]]:
    """``terrain`` (from ``dem``) carrying what stands on it: terrain.surface, read over the
    grid with the DEM's datum, and terrain.landcover's classes (``dsm.cover_surface``), and
    the warnings to show (lines naming the file and key). free: the domain's free cells
    (bool, the grid's shape), each of which needs a DSM height."""
    assert ter.surface is not None
    area = _area_lonlat(terrain.geometry, origin, with_origin=False)
    path = resolve(ter.surface, base, src, "terrain.surface")
    try:
        dsm = Dem.open(path, vertical_datum=ter.vertical_datum, geoid_height_m=ter.geoid_height_m,
                       area_lonlat_deg=area, margin_m=_COVER_MARGIN_M,
                       max_pixels=MAX_WINDOW_PIXELS)
    except PdcovError as exc:
        raise ConfigError(f"{where(src, 'terrain.surface')}: {exc}") from None
    landcover = None
    if ter.landcover is not None:
        path = resolve(ter.landcover, base, src, "terrain.landcover")
        try:
            landcover = LandCover.open(path, area_lonlat_deg=area, margin_m=_COVER_MARGIN_M)
        except PdcovError as exc:
            raise ConfigError(f"{where(src, 'terrain.landcover')}: {exc}") from None
    try:
        covered = cover_surface(terrain, dem, dsm, origin, free, landcover, ter.cover_rules)
    except PdcovError as exc:
        raise ConfigError(f"{where(src, 'terrain.surface')}: {exc}") from None
    return covered.terrain, [f"{where(src, key)}: {line}" for key, line in covered.warnings]


def searched_domain(ter: TerrainSection, src: str | None, domain: Domain, cover: GroundCover,
                    free: np.ndarray) -> Domain:
    """The domain whose free cells are searched: without the free cells under solid cover
    (roofs: no one there is ever seen) unless terrain.search_under_roofs. They become
    obstacles (``Domain.without_cells``), so every grid, checkpoint, snapshot, mission
    payload and map has them as not free; the planners still fly over them (``domain``,
    kept as ``Mission.flight_domain``). ConfigError when no free cell is left."""
    free = np.asarray(free, dtype=bool)
    roofs = cover.roof & free
    if ter.search_under_roofs or not roofs.any():
        return domain
    if not (free & ~roofs).any():
        raise ConfigError(
            f"{where(src, 'terrain.surface')}: every free cell of the domain is under solid "
            f"cover (the DSM {ter.min_object_height_m:g} m or more above the DEM, of no "
            "class that lets a line of sight through): none is left to search; check the "
            "DSM's vertical datum, give terrain.landcover, or set terrain.search_under_roofs: "
            "true")
    return domain.without_cells(cover.geometry, roofs)


def dem_ground_alt(dem: Dem, origin: OriginSection, src: str | None, g: GridGeometry,
                   origin_value: Origin) -> float:
    """The DEM's height (m MSL) at the origin, for an origin.ground_alt_msl_m not given.
    When it has none there, a DEM that misses the grid ``g`` (about ``origin_value``)
    altogether is said first: a wrong DEM, not a missing altitude."""
    h = float(dem.height_msl_m(origin.lat_deg, origin.lon_deg))
    if not math.isfinite(h):
        if elsewhere := dem_rules.elsewhere_message(dem, g, origin_value):
            raise ConfigError(f"{where(src, 'terrain.dem')}: {elsewhere}")
        raise ConfigError(f"{where(src, 'terrain.dem')}: {dem.path}: no height at the origin "
                          f"({origin.lat_deg:.6f}, {origin.lon_deg:.6f}): it is outside the "
                          "DEM or on nodata; set origin.ground_alt_msl_m")
    return h
