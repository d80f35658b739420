"""What stands on the ground under a grid (``GroundCover``), from a digital surface model
(DSM: heights of roofs and tree tops, m MSL, read as a ``Dem``) over the DEM, and a
land-cover raster saying what each raised surface is.

Per cell, at its centre's latitude and longitude (``enu_to_geodetic`` of (x, y, 0), as
``terrain_surface`` does for corners): the height above the ground h = DSM - DEM (m: the
DSM's pixel the centre falls in, ``Dem.nearest_msl_m``, so that an edge of a roof or of a
stand of trees stays an edge rather than a ramp of walls; the DEM bilinear,
``Dem.height_msl_m``); h below ``min_object_height_m`` (or negative) is open
ground, h = 0. A raised cell's kind is its land-cover class's (``landcover.cover_kinds``:
the pixel its centre falls in), SOLID for a class not listed, no class (nodata, outside the
raster) or no land-cover raster. Every free cell needs a DSM height (else InputFileError,
``missing_heights_message``); other cells without one are open.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from pdcov.core.dem import Dem, missing_heights_message
from pdcov.core.geodesy import Origin, enu_to_geodetic
from pdcov.core.ground_cover import (
    DEFAULT_EXTINCTION_PER_M,
    DEFAULT_MIN_OBJECT_HEIGHT_M,
    CoverKind,
    GroundCover,
)
from pdcov.core.landcover import WORLDCOVER_CLASSES, LandCover, cover_kinds
from pdcov.core.terrain import TerrainSurface
from pdcov.errors import InputFileError

__all__ = ["CoverRules", "CoveredTerrain", "cover_surface"]

_DATUM_SHARE = 0.5
"""Warned of when the DSM lies below the DEM under more than this share of the free
cells: a vertical datum the two do not share, more likely than a sunken domain."""


@dataclass(frozen=True, slots=True)
class CoverRules:
    """How a DSM and its classes make a GroundCover: classes (land-cover code ->
    CoverKind; a code not listed is SOLID where raised), extinction_per_m (Beer-Lambert k
    of foliage, 1/m) and min_object_height_m (m: lower surfaces are open ground)."""

    classes: Mapping[int, CoverKind] = field(default_factory=lambda: WORLDCOVER_CLASSES)
    extinction_per_m: float = DEFAULT_EXTINCTION_PER_M
    min_object_height_m: float = DEFAULT_MIN_OBJECT_HEIGHT_M


@dataclass(frozen=True, slots=True)
class CoveredTerrain:
    """``cover_surface``'s result: the terrain carrying its cover, and what to warn of,
    (config key, one line) each."""

    terrain: TerrainSurface
    warnings: tuple[tuple[str, str], ...] = ()

    @property
    def cover(self) -> GroundCover:
        assert self.terrain.cover is not None
        return self.terrain.cover


def cover_surface(terrain: TerrainSurface, dem: Dem, dsm: Dem, origin: Origin,
                  free: np.ndarray, landcover: LandCover | None = None,
                  rules: CoverRules | None = None) -> CoveredTerrain:
    """``terrain`` (from ``dem``: ``terrain_surface``) with the cover the DSM ``dsm`` and
    ``landcover`` give (module docstring). free: the free cells (bool, the grid's shape),
    each of which needs a DSM height. Raises InputFileError naming the DSM (how much of the
    domain it misses, where)."""
    rules = rules or CoverRules()
    g = terrain.geometry
    free = np.asarray(free, dtype=bool)
    xx, yy = np.meshgrid(*g.centres_enu())
    geo = enu_to_geodetic(np.stack([xx, yy, np.zeros_like(xx)], axis=-1), origin)
    lat, lon = geo[..., 0], geo[..., 1]
    top = dsm.nearest_msl_m(lat, lon)
    has = np.isfinite(top)
    if (free & ~has).any():
        raise InputFileError(missing_heights_message(
            dsm, g, origin, free, has, dsm.covers(lat, lon), what="DSM",
            key="terrain.surface", hole="have no height at their centre"))
    ground = dem.height_msl_m(lat, lon)
    gap = has & ~np.isfinite(ground)
    if gap.any():  # a DEM hole between the corners: the terrain's own centre height
        zc = terrain.centre_z_m(0, g.n_rows, 0, g.n_cols)
        ground[gap] = enu_to_geodetic(np.stack([xx[gap], yy[gap], zc[gap]], axis=-1),
                                      origin)[:, 2]
    rise = np.where(has, top - ground, 0.0)
    height = np.where(rise >= rules.min_object_height_m, rise, 0.0)
    raised = height > 0
    warnings: list[tuple[str, str]] = []
    n_free = int(free.sum())
    below = free & (rise < -rules.min_object_height_m)
    if below.sum() > _DATUM_SHARE * n_free:
        warnings.append(("terrain.surface", (
            f"{dsm.path}: the DSM lies more than {rules.min_object_height_m:g} m below the "
            f"DEM ({dem.path.name}) under {100 * below.sum() / n_free:.0f} % of the free "
            f"cells (median {float(np.median(rise[free])):+.1f} m), taken as open ground: "
            "check that it has the DEM's vertical datum (terrain.vertical_datum and "
            "geoid_height_m apply to both)")))
    if landcover is None:
        kind = np.full(g.shape, CoverKind.SOLID, dtype=np.uint8)
    else:
        codes, has_code = landcover.codes_at(lat, lon)
        kind = cover_kinds(codes, has_code, rules.classes)
        unknown = raised & free & ~has_code
        if unknown.any():
            k, n = int(unknown.sum()), int((raised & free).sum())
            warnings.append(("terrain.landcover", (
                f"{landcover.path}: {k} of the {n} free cells raised "
                f"{rules.min_object_height_m:g} m or more above the ground have no class "
                "there (nodata, or outside the raster): taken as solid")))
    kind = np.where(raised, kind, CoverKind.OPEN).astype(np.uint8)
    source = str(dsm.path) + ("" if landcover is None else f" with {landcover.path}")
    cover = GroundCover(g, height.astype(np.float32), kind, rules.extinction_per_m, source)
    return CoveredTerrain(TerrainSurface(g, terrain.z_corner_m, terrain.source, cover=cover),
                          tuple(warnings))
