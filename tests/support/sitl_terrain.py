"""Analytic terrain for the simulator's tests: a tilted plane with a ridge, heights MSL at
any latitude/longitude, on the simulator's flat-earth scales about a point, so that the
expected heights can be computed by hand."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pdcov_sitl.dynamics import local_scales


@dataclass(frozen=True, slots=True)
class TiltedPlane:
    """h = h0_m + slope_e * east + slope_n * north + ridge_m * sin(north / ridge_len_m),
    metres about (lat0_deg, lon0_deg); NaN farther than extent_m from it (outside the
    DEM)."""

    lat0_deg: float
    lon0_deg: float
    h0_m: float
    slope_e: float = 0.0
    slope_n: float = 0.0
    ridge_m: float = 0.0
    ridge_len_m: float = 15.0
    extent_m: float = 1000.0

    def ne_m(self, lat_deg, lon_deg) -> tuple[np.ndarray, np.ndarray]:
        m_n, m_e = local_scales(self.lat0_deg)
        return (np.radians(np.asarray(lat_deg, float) - self.lat0_deg) * m_n,
                np.radians(np.asarray(lon_deg, float) - self.lon0_deg) * m_e)

    def height_msl_m(self, lat_deg, lon_deg) -> np.ndarray:
        n, e = self.ne_m(lat_deg, lon_deg)
        h = (self.h0_m + self.slope_e * e + self.slope_n * n
             + self.ridge_m * np.sin(n / self.ridge_len_m))
        return np.where(np.maximum(abs(n), abs(e)) <= self.extent_m, h, math.nan)
