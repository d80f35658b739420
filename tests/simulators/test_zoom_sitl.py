"""The simulator's zoom camera (pdcov_sitl/camera.py): its MAVLink answers in memory, and a
hover flown by the simulator whose mission zooms half-way (MAV_CMD_SET_CAMERA_ZOOM): the
daemon's decisions fed the flight's bytes give ``pdcov evaluate``'s grid of its tlog, cell
for cell, with the frames before and after the zoom at their own fields of view."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pdcov.config.load import load_mission
from pdcov.flight.frame_decision import Framing
from pdcov.flight.log_frames import poses_from_log
from pdcov.report.outputs import evaluate_poses
from pdcov.service.settings import load_serve_config
from pdcov.telemetry.frame_policy import below_min_height
from tests.support import zoom_flight as zf
from tests.support.link_feed import feed_tlog


def test_a_simulated_hover_zooming_gives_the_same_grid_live_and_offline(tmp_path):
    from pdcov_sitl.fly import FlyOptions, fly

    doc = zf.mission()
    doc["domain"]["polygon_enu_m"] = [[-40, -40], [40, -40], [40, 40], [-40, 40]]
    doc["camera"]["frame_rate_hz"] = 1.0
    config = zf.write_mission(tmp_path / "mission.yaml", doc, service=True)
    lat, lon = doc["origin"]["lat_deg"], doc["origin"]["lon_deg"]
    # Hover 8 s at 20 m, then zoom to the narrowest (ZOOM_TYPE_RANGE 100 %) and hover 8 s
    # 3 m north (the simulator carries out a zoom item from the next waypoint's leg on).
    rows = [(0, 1, 0, 16, 0, 0, lat, lon, 0), (1, 0, 3, 178, 0, 3, 0, 0, 0),
            (2, 0, 3, 16, 8, 0, lat, lon, 20), (3, 0, 3, 531, 2, 100, 0, 0, 0),
            (4, 0, 3, 16, 8, 0, lat + 3 / 111_320, lon, 20)]
    plan = tmp_path / "hover.waypoints"
    plan.write_text("QGC WPL 110\n" + "".join(
        f"{s}\t{c}\t{fr}\t{cmd}\t{p1}\t{p2}\t0\t0\t{la}\t{lo}\t{alt}\t1\n"
        for s, c, fr, cmd, p1, p2, la, lo, alt in rows))
    mission = load_mission(config)
    fly(FlyOptions(mission=mission, plan_path=plan, out_dir=tmp_path / "run", speed=0,
                   gimbal_mode="fixed", connect="udpout:127.0.0.1:9"))
    tlog = tmp_path / "run" / "flight.tlog"

    (cam,) = mission.cameras
    lp = poses_from_log(tlog, Framing(cam.mount, cam.frame_rate_hz, cam.zoom,
                                      max_gap_s=mission.max_gap_s),
                        origin_lat_deg=mission.origin_lat_deg,
                        origin_lon_deg=mission.origin_lon_deg,
                        ground_alt_msl_m=mission.ground_alt_msl_m)
    high = [not below_min_height(p.r_cam_enu[2], mission.min_height_m) for p in lp.poses]
    offline = mission.new_mission_grid()
    evaluate_poses(offline, [p for p, h in zip(lp.poses, high, strict=True) if h],
                   cameras=[c for c, h in zip(lp.cameras, high, strict=True) if h])
    fx = sorted({c.K[0, 0] for c in lp.cameras})
    assert fx[0] == pytest.approx(cam.camera.K[0, 0])
    assert fx[-1] == pytest.approx(160 / math.tan(math.radians(10.0)), rel=1e-4)  # 20 deg

    feed = feed_tlog(load_serve_config(config), tlog)
    live = feed.live.grid
    assert live.frames == offline.frames > 50
    for key in ("log_miss_d", "log_miss_fa", "n_obs", "limiting"):
        np.testing.assert_array_equal(getattr(live, key), getattr(offline, key), err_msg=key)
