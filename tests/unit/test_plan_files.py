"""Plan files: QGC .plan and WPL 110 round trips, a schema check of the QGC format, errors."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from pdcov.core.geodesy import Origin
from pdcov.core.mission import (
    MAV_CMD_DO_CHANGE_SPEED,
    MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW,
    MAV_CMD_NAV_RETURN_TO_LAUNCH,
    MAV_CMD_NAV_TAKEOFF,
    MAV_CMD_NAV_WAYPOINT,
    AltitudeFrame,
    Firmware,
    GimbalCommand,
)
from pdcov.errors import ConfigError, InputFileError
from pdcov.planning.plan import Plan, Waypoint
from pdcov.planning.plan_files import read_mission, read_plan, wpl_text, write_plan
from pdcov.planning.plan_items import mission_items

ORIGIN = Origin(39.35, -76.33, 12.5)
PLAN = Plan((Waypoint(-60.0, -60.0, 10.0, 5.0), Waypoint(-60.0, -20.0, 10.0, 5.0, 3.0),
             Waypoint(-52.5, -20.0, 12.0, 3.5), Waypoint(-52.5, -60.0, 12.0, 3.5, 0.5)))

# QGroundControl plan file (docs.qgroundcontrol.com, "Plan File Format"): the keys QGC's
# loader requires, with their JSON types. Values: a type, a nested schema, or a list schema.
NUM = (int, float)
ITEM_SCHEMA = {"type": str, "command": int, "frame": int, "params": [NUM + (type(None),)],
               "autoContinue": bool, "doJumpId": int}
QGC_SCHEMA = {
    "fileType": str, "version": int, "groundStation": str,
    "geoFence": {"version": int, "circles": list, "polygons": list},
    "rallyPoints": {"version": int, "points": list},
    "mission": {"version": int, "firmwareType": int, "vehicleType": int,
                "globalPlanAltitudeMode": int, "cruiseSpeed": NUM, "hoverSpeed": NUM,
                "plannedHomePosition": [NUM], "items": [ITEM_SCHEMA]},
}


def check_schema(doc, schema, path="$"):
    if isinstance(schema, dict):
        assert isinstance(doc, dict), path
        for key, sub in schema.items():
            assert key in doc, f"{path}.{key} missing"
            check_schema(doc[key], sub, f"{path}.{key}")
    elif isinstance(schema, list):
        assert isinstance(doc, list), path
        for k, v in enumerate(doc):
            check_schema(v, schema[0], f"{path}[{k}]")
    else:
        assert isinstance(doc, schema) and not (schema is int and isinstance(doc, bool)), \
            f"{path}: {doc!r} is not {schema}"


def assert_same_plan(a: Plan, b: Plan, tol_m=1e-3):
    assert len(a.waypoints) == len(b.waypoints)
    for p, q in zip(a.waypoints, b.waypoints, strict=True):
        assert math.hypot(p.x_enu_m - q.x_enu_m, p.y_enu_m - q.y_enu_m) < tol_m
        assert (p.alt_agl_m, p.speed_mps, p.hover_s) == pytest.approx(
            (q.alt_agl_m, q.speed_mps, q.hover_s), abs=1e-6)


@pytest.mark.parametrize("name", ["mission.plan", "mission.waypoints"])
def test_round_trip(tmp_path, name):
    path = write_plan(tmp_path / name, PLAN, ORIGIN)
    assert_same_plan(read_plan(path, ORIGIN), PLAN)


def test_qgc_plan_passes_schema_and_holds_the_mission(tmp_path):
    doc = json.loads(write_plan(tmp_path / "m.plan", PLAN, ORIGIN).read_text())
    check_schema(doc, QGC_SCHEMA)
    assert doc["fileType"] == "Plan" and doc["version"] == 1 and doc["mission"]["version"] == 2
    assert doc["mission"]["plannedHomePosition"] == [39.35, -76.33, 12.5]
    items = doc["mission"]["items"]
    assert all(len(i["params"]) == 7 and i["type"] == "SimpleItem" for i in items)
    assert [i["doJumpId"] for i in items] == list(range(1, len(items) + 1))
    cmds = [i["command"] for i in items]
    assert cmds == [MAV_CMD_NAV_TAKEOFF, MAV_CMD_DO_CHANGE_SPEED, MAV_CMD_NAV_WAYPOINT,
                    MAV_CMD_NAV_WAYPOINT, MAV_CMD_DO_CHANGE_SPEED, MAV_CMD_NAV_WAYPOINT,
                    MAV_CMD_NAV_WAYPOINT, MAV_CMD_NAV_RETURN_TO_LAUNCH]
    wp = items[3]
    assert wp["frame"] == 3 and wp["params"][0] == 3.0 and wp["Altitude"] == 10.0
    # The first waypoint is 60 m west and 60 m south of the origin.
    lat, lon = items[2]["params"][4:6]
    assert lat < ORIGIN.lat_deg and lon < ORIGIN.lon_deg
    assert (ORIGIN.lat_deg - lat) * 111_000 == pytest.approx(60.0, rel=0.01)


@pytest.mark.parametrize(("firmware", "firmware_type"), [(Firmware.ARDUPILOT, 3),
                                                         (Firmware.PX4, 12)])
def test_qgc_firmware_type_is_the_firmwares_mav_autopilot(tmp_path, firmware, firmware_type):
    """QGC's .plan firmwareType is MAV_AUTOPILOT, as the vehicle's HEARTBEAT says it."""
    doc = json.loads(write_plan(tmp_path / "m.plan", PLAN, ORIGIN, firmware).read_text())
    assert doc["mission"]["firmwareType"] == firmware_type
    assert Firmware.of_mav_autopilot(firmware_type) is firmware
    assert json.loads(write_plan(tmp_path / "d.plan", PLAN, ORIGIN).read_text())[
        "mission"]["firmwareType"] == 3  # ArduPilot unless told


def test_px4_plan_refuses_terrain_frame_waypoints(tmp_path):
    terrain = Plan(PLAN.waypoints, altitude_frame=AltitudeFrame.TERRAIN_ALT)
    for name in ("m.plan", "m.waypoints"):
        with pytest.raises(ConfigError, match="px4 plan cannot hold item 2: "
                                              "MAV_FRAME_GLOBAL_TERRAIN_ALT"):
            write_plan(tmp_path / name, terrain, ORIGIN, Firmware.PX4)
        assert not (tmp_path / name).exists()
    write_plan(tmp_path / "a.plan", terrain, ORIGIN, Firmware.ARDUPILOT)
    assert Firmware.of_mav_autopilot(0) is None  # MAV_AUTOPILOT_GENERIC


def test_wpl_layout(tmp_path):
    text = write_plan(tmp_path / "m.waypoints", PLAN, ORIGIN).read_text()
    lines = text.splitlines()
    assert lines[0] == "QGC WPL 110"
    home = lines[1].split("\t")
    assert home[:4] == ["0", "1", "0", "16"] and float(home[10]) == 12.5
    rows = [ln.split("\t") for ln in lines[1:]]
    assert all(len(r) == 12 for r in rows)
    assert [int(r[0]) for r in rows] == list(range(len(rows)))
    assert int(rows[-1][3]) == MAV_CMD_NAV_RETURN_TO_LAUNCH


def test_wpl_from_other_tools_with_msl_frame_and_default_speed(tmp_path):
    # As MAVProxy writes it: home, then global-MSL waypoints without a speed change.
    path = tmp_path / "mavproxy.txt"
    path.write_text("QGC WPL 110\n"
                    "0\t1\t0\t16\t0\t0\t0\t0\t39.350000\t-76.330000\t12.5\t1\n"
                    "1\t0\t0\t16\t0\t0\t0\t0\t39.350100\t-76.330000\t32.5\t1\n")
    with pytest.raises(InputFileError, match="item 0: no speed"):
        read_plan(path, ORIGIN)
    plan = read_plan(path, ORIGIN, default_speed_mps=4.0)
    (w,) = plan.waypoints
    assert w.alt_agl_m == pytest.approx(20.0) and w.speed_mps == 4.0
    assert w.y_enu_m == pytest.approx(11.1, abs=0.05) and abs(w.x_enu_m) < 1e-6
    assert read_mission(path).home.z_m == 12.5


@pytest.mark.parametrize("text, match", [
    ("not a plan", "line 1: expected the header"),
    ("QGC WPL 110\n0\t1\t0\t16\t0\t0\t0\t0\t1\t2\n", "line 2: expected 12 fields"),
    ("QGC WPL 110\n0\t1\t0\t16\t0\t0\t0\t0\t1\t2\t3\t1\n"
     "1\t0\t3\t18\t0\t0\t0\t0\t1\t2\t3\t1\n", "item 0: command 18 is not supported"),
    ('{"fileType": "Plan", "mission": {"items": [{"type": "ComplexItem"}]}}',
     r"mission.items\[0\]: only SimpleItem"),
    ('{"fileType": "Plan"}', "not a QGroundControl plan"),
])
def test_bad_files_name_the_file_and_place(tmp_path, text, match):
    path = tmp_path / "bad.plan"
    path.write_text(text)
    with pytest.raises(InputFileError, match=match) as err:
        read_plan(path, ORIGIN, default_speed_mps=5.0)
    assert str(path) in str(err.value)


def test_unknown_suffix_is_refused(tmp_path):
    with pytest.raises(InputFileError, match="unknown plan format"):
        write_plan(tmp_path / "m.kml", PLAN, ORIGIN)


def test_speed_changes_only_where_the_speed_changes():
    items = mission_items(PLAN, ORIGIN)
    speeds = [i.param2 for i in items if i.command == MAV_CMD_DO_CHANGE_SPEED]
    assert speeds == [5.0, 3.5]
    takeoff = items[0]
    assert takeoff.z_m == 10.0 and np.isnan(takeoff.param4)


def test_wpl_keeps_unset_parameters_unset(tmp_path, monkeypatch):
    """The take-off's yaw and the gimbal's rates are unset (NaN): written "NaN", as Mission
    Planner writes and reads it, not 0.0 (yaw north, rates zero), and read back as NaN by
    pymavlink's loader (MAVProxy's) and by pdcov's, every other value as written."""
    from pymavlink import mavutil, mavwp

    # mavwp builds MAVLink 2 items when MAVLINK20 is set, whichever dialect mavutil loaded
    # first (other test modules set it at import): ask the loaded dialect instead.
    monkeypatch.setattr(mavutil, "mavlink20", lambda: "mission_type" in
                        mavutil.mavlink.MAVLink_mission_item_message.fieldnames)
    takeoff, *rest = mission_items(PLAN, ORIGIN)
    items = (takeoff, GimbalCommand.MANAGER.item(-90.0), *rest)
    path = tmp_path / "m.waypoints"
    path.write_text(wpl_text(items, ORIGIN))
    rows = [ln.split("\t") for ln in path.read_text().splitlines()[1:]]
    assert rows[1][3] == str(MAV_CMD_NAV_TAKEOFF) and rows[1][7] == "NaN"
    assert rows[2][3] == str(MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW)
    assert rows[2][4:8] == ["-90.0", "0.0", "NaN", "NaN"]
    loader = mavwp.MAVWPLoader()
    assert loader.load(str(path)) == len(items) + 1  # and home
    ours = read_mission(path).items
    assert len(ours) == len(items)
    for k, it in enumerate(items):
        want = [it.param1, it.param2, it.param3, it.param4]
        w = loader.wp(k + 1)
        np.testing.assert_array_equal([w.param1, w.param2, w.param3, w.param4], want)
        got = ours[k]
        np.testing.assert_array_equal([got.param1, got.param2, got.param3, got.param4], want)
        assert (w.command, got.command) == (it.command, it.command)
