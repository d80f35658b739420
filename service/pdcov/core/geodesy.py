"""Geodetic <-> local ENU about the mission origin (pymap3d, WGS84); how exports write a
latitude or longitude, and a point's MGRS and UTM grid references.

Altitudes are metres above mean sea level at both ends; the ENU z of a point is then its
height above the origin's ground altitude (flat earth, as in the paper).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np
import pymap3d

from pdcov.errors import ConfigError

DEG_DECIMALS = 7
"""Decimal places of a latitude or longitude in what pdcov exports (GeoJSON, CalTopo, KML,
CoT): 1e-7 deg is 1.1 cm of latitude (less of longitude), MAVLink's own resolution (degE7)
and far below a GNSS fix's error."""


def deg_rounded(v: float) -> float:
    """A latitude or longitude (deg) rounded to DEG_DECIMALS places (JSON)."""
    return round(float(v), DEG_DECIMALS)


def deg_text(v: float) -> str:
    """A latitude or longitude (deg) as text with DEG_DECIMALS places (KML, CoT)."""
    return f"{float(v):.{DEG_DECIMALS}f}"


_MGRS = re.compile(r"(\d{0,2}[A-Z])([A-Z]{2})(\d{5})(\d{5})")
"""An MGRS reference to 1 m as mgrs writes it: grid zone (UTM zone and latitude band, or a
UPS letter alone), 100 km square, easting, northing."""


def grid_references(lat_deg: float, lon_deg: float) -> tuple[str, str | None]:
    """The MGRS and UTM references of a WGS84 point, to the metre: ("32T LR 66145 51998",
    "32T 366145 5151998"), the UTM zone and latitude band then easting and northing in m.
    Both name the 1 m square holding the point (truncated, as grid references are read),
    in the zone MGRS gives it (Norway's and Svalbard's exceptions included). The UTM is None
    beyond UTM's latitudes (84 N, 80 S), where MGRS is polar stereographic (UPS). Computed
    by the mgrs package (NGA's GEOTRANS; the gis and ground extras): ImportError without
    it. ValueError for a point that is not a latitude and longitude."""
    import mgrs

    converter = mgrs.MGRS()
    try:
        code = converter.toMGRS(float(lat_deg), float(lon_deg), MGRSPrecision=5)
    except mgrs.core.MGRSError as exc:
        raise ValueError(f"no MGRS reference for ({lat_deg}, {lon_deg}): {exc}") from None
    parts = _MGRS.fullmatch(code)
    if parts is None:
        raise ValueError(f"mgrs wrote {code!r} for ({lat_deg}, {lon_deg})")
    zone = parts.group(1)
    if not zone[0].isdigit():  # a polar zone letter: UPS, no UTM
        return " ".join(parts.groups()), None
    # The 1 m square's centre (mgrs >= 1.6) or its corner: its floor is the corner.
    _, _, east_m, north_m = converter.MGRSToUTM(code)
    return " ".join(parts.groups()), f"{zone} {math.floor(east_m)} {math.floor(north_m)}"


@dataclass(frozen=True, slots=True)
class Origin:
    """The local ENU origin: a geodetic point and the ground altitude there (m MSL)."""

    lat_deg: float
    lon_deg: float
    ground_alt_msl_m: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.lat_deg) and -90.0 <= self.lat_deg <= 90.0):
            raise ConfigError(f"origin.lat_deg: expected a latitude in [-90, 90], "
                              f"got {self.lat_deg}")
        if not (math.isfinite(self.lon_deg) and -180.0 <= self.lon_deg <= 360.0):
            raise ConfigError(f"origin.lon_deg: expected a longitude in [-180, 360], "
                              f"got {self.lon_deg}")
        if not math.isfinite(self.ground_alt_msl_m):
            raise ConfigError(f"origin.ground_alt_msl_m: expected a finite altitude in metres, "
                              f"got {self.ground_alt_msl_m}")


def geodetic_to_enu(lat_deg: np.ndarray | float, lon_deg: np.ndarray | float,
                    alt_msl_m: np.ndarray | float, origin: Origin) -> np.ndarray:
    """ENU metres (..., 3) of geodetic points about ``origin``; a scalar ``alt_msl_m``
    broadcasts over the points."""
    e, n, u = pymap3d.geodetic2enu(lat_deg, lon_deg, alt_msl_m, origin.lat_deg,
                                   origin.lon_deg, origin.ground_alt_msl_m)
    return np.stack([np.asarray(e), np.asarray(n), np.asarray(u)], axis=-1)


MEAN_EARTH_RADIUS_M = 6_371_008.8  # IUGG mean radius R1


def distance_from_origin_m(r_enu: np.ndarray, origin: Origin) -> np.ndarray:
    """The distance over the ground (m; great circle on the mean-radius sphere, within
    0.5 % of the ellipsoid's geodesic) from ``origin`` to the points below ENU points
    (..., 3): right at any distance, where the ENU plane's horizontal distance is not (a
    point across the globe lies far below the plane)."""
    geo = np.radians(enu_to_geodetic(r_enu, origin)[..., :2])
    lat0, lon0 = math.radians(origin.lat_deg), math.radians(origin.lon_deg)
    a = (np.sin((geo[..., 0] - lat0) / 2) ** 2
         + math.cos(lat0) * np.cos(geo[..., 0]) * np.sin((geo[..., 1] - lon0) / 2) ** 2)
    return 2 * MEAN_EARTH_RADIUS_M * np.arcsin(np.sqrt(np.clip(a, 0.0, 1.0)))


def enu_to_geodetic(r_enu: np.ndarray, origin: Origin) -> np.ndarray:
    """(lat_deg, lon_deg, alt_msl_m) (..., 3) of ENU points about ``origin``."""
    r = np.asarray(r_enu, dtype=float)
    lat, lon, alt = pymap3d.enu2geodetic(r[..., 0], r[..., 1], r[..., 2], origin.lat_deg,
                                         origin.lon_deg, origin.ground_alt_msl_m)
    return np.stack([np.asarray(lat), np.asarray(lon), np.asarray(alt)], axis=-1)
