"""A small hilly scene for the end-to-end tests over terrain: a DEM GeoTIFF in UTM 32N (the
projected CRS of tests.support.harness.SMALL_MISSION's origin, Zurich) with a gentle hill and
a steep north-south ridge, the mission over it, and hand-written survey plans.

Heights are analytic in the mission's ENU frame (metres about the origin, z = 0 at its
ground altitude, 488 m MSL), so a test can say by hand where the ground is:

* the hill: HILL_M high at HILL_ENU_M, a Gaussian of HILL_SIGMA_M (slopes up to 0.3: a
  terrain-following plan at 3 m/s stays within ArduCopter's climb and descent rates);
* the ridge: RIDGE_M high along x = RIDGE_X_M, a Gaussian across of RIDGE_SIGMA_M (slopes up
  to 2.4): seen from the west at a camera height of about twice its own, it hides the
  ground 2 to 13 m east of its crest.

The raster is 1 m pixels over x, y in [-EXTENT_M, EXTENT_M + DOMAIN_M]: the domain, home
and the simulator's climb and return, and Dem.open's margin around the grid.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import yaml

from pdcov.core.geodesy import Origin, enu_to_geodetic
from pdcov.core.mission import MAV_CMD_DO_CHANGE_SPEED, MAV_CMD_NAV_WAYPOINT, MissionItem
from pdcov.planning.plan_files import wpl_text
from tests.support.harness import small_mission
from tests.support.valley import write_enu_geotiff

DOMAIN_M = 60.0
"""The domain: the square [0, DOMAIN_M] east by [0, 40] north (1 m cells)."""
DOMAIN_ENU_M = [[0.0, 0.0], [DOMAIN_M, 0.0], [DOMAIN_M, 40.0], [0.0, 40.0]]
EXTENT_M = 50.0
HILL_M, HILL_ENU_M, HILL_SIGMA_M = 6.0, (15.0, 20.0), 12.0
RIDGE_M, RIDGE_X_M, RIDGE_SIGMA_M = 12.0, 45.0, 3.0
MAV_FRAME_GLOBAL_RELATIVE_ALT = 3


def height_enu_m(x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
    """The scene's ground height (m above the origin's ground) at ENU x, y (m)."""
    x, y = np.asarray(x_m, float), np.asarray(y_m, float)
    r2 = (x - HILL_ENU_M[0]) ** 2 + (y - HILL_ENU_M[1]) ** 2
    return (HILL_M * np.exp(-r2 / (2 * HILL_SIGMA_M**2))
            + RIDGE_M * np.exp(-((x - RIDGE_X_M) ** 2) / (2 * RIDGE_SIGMA_M**2)))


def origin() -> Origin:
    o = small_mission()["origin"]
    return Origin(o["lat_deg"], o["lon_deg"], o["ground_alt_msl_m"])


def write_dem(path: Path, shift_m: float = 0.0) -> Path:
    """The scene's DEM (m MSL, ``shift_m`` added: a wrong DEM) as a float32 GeoTIFF in UTM
    32N, 1 m pixels aligned to whole metres of easting and northing."""
    o = origin()
    return write_enu_geotiff(path, lambda x, y: height_enu_m(x, y) + shift_m, o.lat_deg,
                             o.lon_deg, o.ground_alt_msl_m,
                             (-EXTENT_M, -EXTENT_M, DOMAIN_M + EXTENT_M, DOMAIN_M + EXTENT_M),
                             1.0)


def terrain_mission(dem: Path, **sections: Any) -> dict[str, Any]:
    """tests.support.harness.small_mission over the scene: its camera, origin and detector, the
    domain DOMAIN_ENU_M, ``terrain.dem`` the file given, ``sections`` set."""
    return small_mission(**{"domain": {"polygon_enu_m": DOMAIN_ENU_M, "cell_size_m": 1.0},
                            "terrain": {"dem": str(dem)}, **sections})


def write_mission(path: Path, doc: dict[str, Any]) -> Path:
    path.write_text(yaml.safe_dump(doc))
    return path


def write_survey(path: Path, xy_enu_m: list[tuple[float, float]], z_m: float,
                 speed_mps: float = 5.0) -> Path:
    """A WPL 110 survey through the ENU points at ``z_m`` above home
    (MAV_FRAME_GLOBAL_RELATIVE_ALT) and ``speed_mps``."""
    o = origin()
    geo = enu_to_geodetic(np.array([[x, y, 0.0] for x, y in xy_enu_m]), o)
    items = [MissionItem(MAV_CMD_DO_CHANGE_SPEED, 2, 1.0, speed_mps, -1.0)]
    items += [MissionItem(MAV_CMD_NAV_WAYPOINT, MAV_FRAME_GLOBAL_RELATIVE_ALT,
                          lat_deg=float(lat), lon_deg=float(lon), z_m=z_m)
              for lat, lon, _h in geo]
    path.write_text(wpl_text(tuple(items), o))
    return path
