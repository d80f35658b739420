"""A flight far from the mission origin is refused with its distance over the ground
(core/geodesy.py ``distance_from_origin_m``), not the ENU plane's horizontal distance, which
falls short far away (issue 39: '3,748 km' for a flight 16,012 km off)."""

import math

import numpy as np
import pytest

from pdcov.commands.input_run import _check_near_origin
from pdcov.core.geodesy import Origin, distance_from_origin_m, geodetic_to_enu
from pdcov.core.pose import CameraPose
from pdcov.errors import InputFileError

ZURICH = Origin(47.37, 8.54, 400.0)
SYDNEY = (-33.87, 151.21)


def geodesic_km(lat1, lon1, lat2, lon2):
    """The WGS84 ellipsoid's geodesic (Vincenty, pymap3d): an independent reference."""
    from pymap3d.vincenty import vdist

    return float(vdist(lat1, lon1, lat2, lon2)[0]) / 1000


def test_the_distance_is_over_the_ground_at_any_range():
    far = geodetic_to_enu(*SYDNEY, 100.0, ZURICH)
    near = np.array([1000.0, 0.0, 50.0])
    antipode = geodetic_to_enu(-ZURICH.lat_deg, ZURICH.lon_deg - 180.0, 0.0, ZURICH)
    d = distance_from_origin_m(np.array([far, near, antipode]), ZURICH)
    assert d[0] / 1000 == pytest.approx(geodesic_km(*ZURICH_LL, *SYDNEY), rel=0.005)
    assert math.hypot(*far[:2]) / 1000 < 7000  # what the plane said: far short
    assert d[1] == pytest.approx(1000.0, rel=0.005)  # the sphere: 0.3 % short here
    assert d[2] / 1000 == pytest.approx(20004.0, rel=0.005)  # half a meridian, 20,004 km


ZURICH_LL = (ZURICH.lat_deg, ZURICH.lon_deg)


def test_a_flight_across_the_globe_is_refused_with_its_true_distance(tmp_path):
    r = geodetic_to_enu(*SYDNEY, 100.0, ZURICH)
    poses = [CameraPose(np.eye(3), r, float(t)) for t in range(3)]
    with pytest.raises(InputFileError) as err:
        _check_near_origin(poses, tmp_path / "f.tlog", "m.yaml", ZURICH)
    km = geodesic_km(*ZURICH_LL, *SYDNEY)
    shown = float(str(err.value).split("the camera is ")[1].split(" km")[0].replace(",", ""))
    assert shown == pytest.approx(km, rel=0.005) and "origin.lat_deg" in str(err.value)
    _check_near_origin([CameraPose(np.eye(3), np.array([900.0, 0.0, 60.0]), 0.0)],
                       tmp_path / "f.tlog", "m.yaml", ZURICH)  # a survey: nothing said
