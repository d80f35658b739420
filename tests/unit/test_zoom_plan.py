"""Plans that zoom per waypoint (planning/plan.py Waypoint.zoom_hfov_deg, optimise.predict):
the mission items where the zoom changes, the files read back, the simulator's legs, the
prediction frame by frame against cameras chosen from where the flight hovers, and bad
input. The mission is tests/support/zoom_flight.py's: a 66 deg camera whose lens zooms to 20 deg
(camera.zoom fov_status) over an 80 m square of 2 m cells."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from pdcov.config.load import mission_from_dict
from pdcov.core.mission import MAV_CMD_SET_CAMERA_ZOOM, MissionItem
from pdcov.errors import ConfigError, InputFileError
from pdcov.planning.optimise import PlanParams, build_plan, flight_poses, predict
from pdcov.planning.plan import Plan, Waypoint
from pdcov.planning.plan_files import read_plan as read_plan_file
from pdcov.planning.plan_files import write_plan as write_plan_file
from pdcov.planning.plan_items import (
    ZOOM_TYPE_HORIZONTAL_FOV,
    mission_items,
    plan_from_mission_items,
    zoom_item,
)
from pdcov.planning.scenario import scenario_of
from pdcov.planning.trajectory import fly
from tests.support import zoom_flight as zf

MISSION = mission_from_dict(zf.mission())
ORIGIN = MISSION.origin()
ZOOM_TYPE_RANGE = 2


def zoomed_plan() -> Plan:
    """A square at 30 m with hovers of 2 s: wide to the first corner, zoomed to 40 deg for
    two legs (commanded once), back to the widest for the last."""
    return Plan((Waypoint(10.0, 10.0, 30.0, 4.0, hover_s=2.0),
                 Waypoint(70.0, 10.0, 30.0, 4.0, hover_s=2.0, zoom_hfov_deg=40.0),
                 Waypoint(70.0, 70.0, 30.0, 4.0, hover_s=2.0),
                 Waypoint(10.0, 70.0, 30.0, 4.0, hover_s=2.0, zoom_hfov_deg=zf.WIDE_DEG)))


def test_zoom_items_where_it_changes_and_the_files_round_trip(tmp_path):
    from pdcov_sitl.mission import flight_plan_from_items

    plan = zoomed_plan()
    items = mission_items(plan, ORIGIN)
    assert [it.command for it in items] == [22, 178, 16, 531, 16, 16, 531, 16, 20]
    zooms = [(it.param1, it.param2) for it in items if it.command == MAV_CMD_SET_CAMERA_ZOOM]
    assert zooms == [(4.0, 40.0), (4.0, zf.WIDE_DEG)]
    assert plan.zooms_hfov_deg() == [None, 40.0, 40.0, zf.WIDE_DEG]
    for name in ("p.plan", "p.waypoints"):
        write_plan_file(tmp_path / name, plan, ORIGIN)
        back = read_plan_file(tmp_path / name, ORIGIN)
        assert [w.zoom_hfov_deg for w in back.waypoints] == [None, 40.0, None, zf.WIDE_DEG]
        again = mission_items(back, ORIGIN)  # written again as it was
        assert [it.command for it in again] == [it.command for it in items]
        for x, y in zip(again, items, strict=True):
            np.testing.assert_allclose([x.param1, x.param2, x.lat_deg, x.lon_deg, x.z_m],
                                       [y.param1, y.param2, y.lat_deg, y.lon_deg, y.z_m],
                                       atol=1e-6)
    # The simulator zooms the camera from each leg's start as the prediction does.
    legs = flight_plan_from_items(items, ORIGIN, "test").survey_legs
    assert [leg.camera_zoom for leg in legs] == [None, (4, 40.0), (4, 40.0), (4, zf.WIDE_DEG)]


def test_each_frame_is_predicted_with_its_waypoints_zoom():
    """The prediction against one built by hand: every frame with the camera of the zoom
    commanded when the flight last left a hover (found from where the vehicle stands
    still, not from the flight's waypoint index), in time order."""
    sc = scenario_of(MISSION)
    plan = zoomed_plan()
    pred = predict(sc, plan)
    flight = fly(plan, sc.frame_rate_hz, sc.kinematics)
    hover_xy = plan.xy_enu_m
    at = np.linalg.norm(flight.r_body_enu[:, None, :2] - hover_xy[None], axis=2) < 1e-6
    zoom_after = {0: None, 1: 40.0, 2: 40.0, 3: zf.WIDE_DEG}  # zoom on the way to wp k
    cams = {z: sc.camera_at(z) for z in zoom_after.values()}
    grid = sc.new_grid()
    last_left = -1
    for i, pose in enumerate(flight_poses(sc, plan, flight)):
        here = np.flatnonzero(at[i])
        heading_to = int(here[0]) if here.size else last_left + 1
        last_left = heading_to if here.size else last_left
        grid.update_with(pose, cams[zoom_after[heading_to]])
    np.testing.assert_array_equal(pred.grid.n_obs, grid.n_obs)
    np.testing.assert_allclose(pred.grid.log_miss_d, grid.log_miss_d, rtol=1e-6)
    # Zoomed at 40 deg over the east and north legs, the P_D per look is higher there.
    wide = predict(sc, Plan(tuple(Waypoint(w.x_enu_m, w.y_enu_m, w.alt_agl_m, w.speed_mps,
                                           w.hover_s) for w in plan.waypoints)))
    assert pred.grid.frames == wide.grid.frames
    assert not np.array_equal(pred.grid.log_miss_d, wide.grid.log_miss_d)


def test_a_zoom_outside_the_lens_in_a_plan_read_back_names_the_waypoint(tmp_path):
    sc = scenario_of(MISSION)
    plan = zoomed_plan()
    bad = Plan((*plan.waypoints[:2], Waypoint(70.0, 70.0, 30.0, 4.0, zoom_hfov_deg=12.0)))
    write_plan_file(tmp_path / "bad.plan", bad, ORIGIN)
    back = read_plan_file(tmp_path / "bad.plan", ORIGIN)
    with pytest.raises(ConfigError, match=r"bad.plan: waypoint 2: zoom 12 deg: .*outside "
                                          r"the calibrated 20.00-66.00 deg"):
        predict(sc, back)
    items = list(mission_items(plan, ORIGIN))
    assert items[3] == zoom_item(40.0)
    items[3] = MissionItem(MAV_CMD_SET_CAMERA_ZOOM, items[3].frame, 4.0, 190.0)
    with pytest.raises(InputFileError, match="item 3: MAV_CMD_SET_CAMERA_ZOOM to a horizontal "
                                             "field of view of 190.0 deg"):
        plan_from_mission_items(tuple(items), ORIGIN, "m")
    fixed = scenario_of(mission_from_dict(zf.mission("none")))
    with pytest.raises(ConfigError, match="waypoint 1: a zoom of 40 deg needs camera.zoom "
                                          "fov_status"):
        predict(fixed, plan)


@pytest.mark.parametrize("zoom_type", [ZOOM_TYPE_RANGE, 1, 0])  # range, continuous, step
def test_a_zoom_of_another_type_reads_but_is_not_predicted(zoom_type):
    """A range, continuous or step zoom says nothing of the field of view: the plan reads
    (the simulator carries a range zoom out), its prediction is refused naming the item."""
    items = list(mission_items(zoomed_plan(), ORIGIN))
    items[3] = MissionItem(MAV_CMD_SET_CAMERA_ZOOM, items[3].frame, float(zoom_type), 50.0)
    back = plan_from_mission_items(tuple(items), ORIGIN, "m.plan")
    assert back.zooms_hfov_deg() == [None, None, None, zf.WIDE_DEG]
    assert back.zoom_not_predicted.startswith("m.plan: item 3: MAV_CMD_SET_CAMERA_ZOOM of "
                                              f"zoom type {zoom_type}")
    with pytest.raises(ConfigError, match=f"item 3: .*zoom type {zoom_type} .*"
                                          f"{ZOOM_TYPE_HORIZONTAL_FOV}.*not predicted"):
        predict(scenario_of(MISSION), back)


def test_plan_zoom_hfov_deg_is_the_first_waypoints(tmp_path: Path):
    """`pdcov plan --zoom-hfov-deg`: one zoom item after the take-off, read back as the
    first waypoint's zoom; the prediction is the plan's with every frame at that zoom."""
    from tests.support.evaluate_inputs import load_grid, run

    cfg = zf.write_mission(tmp_path / "m.yaml", zf.mission())
    assert run("plan", "--config", str(cfg), "--altitude-m", "40", "--zoom-hfov-deg", "30",
               "--no-figures", "--out", str(tmp_path / "p")) == 0
    back = read_plan_file(tmp_path / "p" / "plan.plan", ORIGIN)
    assert back.zooms_hfov_deg() == [30.0] * len(back.waypoints)
    assert [w.zoom_hfov_deg for w in back.waypoints][:2] == [30.0, None]
    sc = scenario_of(MISSION)
    plan, _ = build_plan(sc, PlanParams("lawnmower", 40.0, 5.0, zoom_hfov_deg=30.0))
    np.testing.assert_allclose(back.xy_enu_m, plan.xy_enu_m, atol=1e-3)
    flight = fly(plan, sc.frame_rate_hz, sc.kinematics)
    grid = sc.new_grid()
    for pose in flight_poses(sc, plan, flight):
        grid.update_with(pose, sc.camera_at(30.0))
    np.testing.assert_allclose(load_grid(tmp_path / "p")["log_miss_d"], grid.log_miss_d,
                               atol=1e-5)
    assert math.isfinite(float(grid.log_miss_d.sum()))


# -- flown by the simulator -----------------------------------------------------------------


# -- vantage points --------------------------------------------------------------------------


@pytest.mark.parametrize("zoom, extra, message", [
    ("none", ["--zooms-hfov-deg", "40"],
     "--zooms-hfov-deg: a zoom of 40 deg needs camera.zoom fov_status"),
    ("fov_status", ["--zooms-hfov-deg", "66", "10"],
     "--zooms-hfov-deg: zoom 10 deg: reported field of view 10.00 deg outside the calibrated"),
    ("fov_status", ["--zoom-hfov-deg", "40"],
     "--zoom-hfov-deg does not apply to the vantage pattern: give its candidate zooms with "
     "--zooms-hfov-deg"),
    ("fov_status", ["--zooms-hfov-deg", "190"], "--zooms-hfov-deg: expected fields of view in "
                                                "(0, 180) deg, got [190.0]"),
])
def test_cli_bad_vantage_zooms_are_one_line_exit_2(tmp_path, capsys, zoom, extra, message):
    from pdcov.cli import main as pdcov_main

    cfg = zf.write_mission(tmp_path / "m.yaml", zf.mission(zoom))
    rc = pdcov_main(["plan", "--config", str(cfg), "--pattern", "vantage", "--target-pd", "0.3",
                     "--altitudes-m", "60", "--lattice-m", "20", "--ilp-time-limit-s", "0",
                     "--routing-time-s", "0.5", "--no-figures", "--out", str(tmp_path / "o"),
                     *extra])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert len(err) == 1 and message in err[0], err
