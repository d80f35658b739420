"""The mission config's ``terrain`` section: the DEM (heights m MSL) under the domain, read
over the grid, and the ground altitude it gives at the origin."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pdcov.config.origin import OriginSection
from pdcov.config.values import number, resolve
from pdcov.core import dem as dem_rules
from pdcov.core.dem import Dem, VerticalDatum
from pdcov.core.domain import GridGeometry
from pdcov.core.geodesy import Origin, enu_to_geodetic
from pdcov.errors import ConfigError, PdcovError, where

DEFAULT_TERRAIN_MARGIN_M = 10.0
"""terrain.check_margin_m when the config does not set it (m): how far the DEM may disagree
with the home altitude and what the aircraft measures before it is said."""


@dataclass(frozen=True, slots=True)
class TerrainSection:
    """``terrain``: the DEM file (GeoTIFF, COG or SRTM .hgt, any CRS; relative to the config's
    folder), the datum of its heights ('msl', or 'ellipsoid' with geoid_height_m, the geoid's
    height N above the ellipsoid at the site in m: H_msl = h_ellipsoid - N), the margin
    (m) beyond which an altitude measured or configured that disagrees with it is warned of,
    and the most (m) a configured home altitude may differ from it (else refused)."""

    dem: str
    vertical_datum: str = "msl"
    geoid_height_m: float | None = None
    check_margin_m: float = DEFAULT_TERRAIN_MARGIN_M
    max_home_offset_m: float = dem_rules.DEFAULT_MAX_HOME_OFFSET_M

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
        return cls(dem, datum, geoid, *(number(doc, k, src, "terrain", default=d, positive=True)
                   for k, d in (("check_margin_m", DEFAULT_TERRAIN_MARGIN_M),
                                ("max_home_offset_m", dem_rules.DEFAULT_MAX_HOME_OFFSET_M))))


def open_dem(ter: TerrainSection, src: str | None, base: Path, g: GridGeometry,
             origin: Origin) -> Dem:
    """The DEM, read over the grid and the origin (``Dem.open``'s margin around them)."""
    path = resolve(ter.dem, base, src, "terrain.dem")
    x1, y1 = g.x0_m + g.cell_size_m * g.n_cols, g.y0_m + g.cell_size_m * g.n_rows
    corners = np.array([[g.x0_m, g.y0_m, 0.0], [x1, g.y0_m, 0.0], [x1, y1, 0.0],
                        [g.x0_m, y1, 0.0]])
    geo = enu_to_geodetic(corners, origin)
    lat = np.append(geo[:, 0], origin.lat_deg)
    lon = np.append(geo[:, 1], origin.lon_deg)
    try:
        return Dem.open(path, vertical_datum=ter.vertical_datum,
                        geoid_height_m=ter.geoid_height_m,
                        area_lonlat_deg=(lon.min(), lat.min(), lon.max(), lat.max()))
    except PdcovError as exc:
        raise ConfigError(f"{where(src, 'terrain.dem')}: {exc}") from None


def dem_ground_alt(dem: Dem, origin: OriginSection, src: str | None) -> float:
    """The DEM's height (m MSL) at the origin, for an origin.ground_alt_msl_m not given."""
    h = float(dem.height_msl_m(origin.lat_deg, origin.lon_deg))
    if not math.isfinite(h):
        raise ConfigError(f"{where(src, 'terrain.dem')}: {dem.path}: no height at the origin "
                          f"({origin.lat_deg:.6f}, {origin.lon_deg:.6f}): it is outside the "
                          "DEM or on nodata; set origin.ground_alt_msl_m")
    return h
