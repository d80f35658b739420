"""The simulated world's ground: heights above MSL at any latitude/longitude, in the
simulator's local frame about home, and the downward rangefinder's ray against it.

``GroundModel`` is what the world needs of a DEM: ``height_msl_m(lat_deg, lon_deg)``,
vectorised, NaN where it has no height (pdcov's ``core.dem.Dem`` has this shape; so does
``FlatGround``, the paper's level ground). ``LocalGround`` puts it in the simulator's frame:
heights above home (m, up) at north/east metres about home on the flat-earth scales that
``dynamics.py`` uses. Pure: no I/O, no clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from .dynamics import local_scales

RAY_STEP_M = 0.25
"""Ray-marching step of the rangefinder (the crossing is then refined by bisection)."""


class GroundModel(Protocol):
    """Ground heights (m above MSL) at geodetic points; NaN where unknown."""

    def height_msl_m(self, lat_deg: np.ndarray | float, lon_deg: np.ndarray | float
                     ) -> np.ndarray: ...


@dataclass(frozen=True, slots=True)
class FlatGround:
    """Level ground at ``alt_msl_m`` everywhere."""

    alt_msl_m: float

    def height_msl_m(self, lat_deg: np.ndarray | float, lon_deg: np.ndarray | float
                     ) -> np.ndarray:
        return np.full(np.broadcast(np.asarray(lat_deg), np.asarray(lon_deg)).shape,
                       float(self.alt_msl_m))


class LocalGround:
    """A GroundModel about home (lat_deg, lon_deg; the ground there is home's altitude).

    ``height_m(n, e)``: ground height above home (m, up) at NED metres about home, NaN where
    the model has none. ``geodetic(n, e)``: the (lat_deg, lon_deg) of such points.
    """

    def __init__(self, model: GroundModel, home_lat_deg: float, home_lon_deg: float) -> None:
        self.model = model
        self.home_lat_deg = home_lat_deg
        self.home_lon_deg = home_lon_deg
        self._m_per_rad = local_scales(home_lat_deg)
        home = float(np.asarray(model.height_msl_m(home_lat_deg, home_lon_deg)))
        if not math.isfinite(home):
            raise ValueError(f"no ground height at home ({home_lat_deg:.7f}, "
                             f"{home_lon_deg:.7f}): it lies outside the DEM or in a hole")
        self.home_alt_msl_m = home

    def geodetic(self, n_m: np.ndarray | float, e_m: np.ndarray | float
                 ) -> tuple[np.ndarray, np.ndarray]:
        lat = self.home_lat_deg + np.degrees(np.asarray(n_m, float) / self._m_per_rad[0])
        lon = self.home_lon_deg + np.degrees(np.asarray(e_m, float) / self._m_per_rad[1])
        return lat, lon

    def height_m(self, n_m: np.ndarray | float, e_m: np.ndarray | float) -> np.ndarray:
        lat, lon = self.geodetic(n_m, e_m)
        return np.asarray(self.model.height_msl_m(lat, lon), float) - self.home_alt_msl_m


def slant_range_m(model: GroundModel, lat_deg: float, lon_deg: float, alt_msl_m: float,
                  down_ned: tuple[float, float, float], max_m: float) -> float:
    """Distance (m) from a point along the unit NED direction ``down_ned`` to where the ray
    first meets the ground, NaN when it does not within ``max_m`` (pointing up, or the
    ground unknown along it). Marched every RAY_STEP_M, refined by bisection to ~1 mm."""
    dn, de, dd = down_ned
    if dd <= 0 or not max_m > 0:
        return math.nan
    m_n, m_e = local_scales(lat_deg)

    def above_m(t: np.ndarray) -> np.ndarray:
        """Height of the ray's points above the ground (m; NaN: ground unknown)."""
        lat = lat_deg + np.degrees(t * dn / m_n)
        lon = lon_deg + np.degrees(t * de / m_e)
        return alt_msl_m - t * dd - np.asarray(model.height_msl_m(lat, lon), float)

    t = np.append(np.arange(0.0, max_m, RAY_STEP_M), max_m)
    h = above_m(t)
    below = np.flatnonzero(~(h > 0))  # the first point at or below the ground, or unknown
    if len(below) == 0 or np.isnan(h[below[0]]):
        return math.nan
    k = int(below[0])
    if k == 0:
        return 0.0
    lo, hi = float(t[k - 1]), float(t[k])
    while hi - lo > 1e-3:
        mid = 0.5 * (lo + hi)
        if float(above_m(np.array([mid]))[0]) > 0:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)
