"""Vantage plans with a zoom lens: a high vantage point zooms in and its mission says so,
and `pdcov plan --pattern vantage` writes each point's zoom."""

from __future__ import annotations

import numpy as np

from pdcov.config.load import mission_from_dict
from pdcov.core.mission import MAV_CMD_SET_CAMERA_ZOOM
from pdcov.planning.optimise import predict
from pdcov.planning.plan_files import read_plan as read_plan_file
from pdcov.planning.plan_items import mission_items
from pdcov.planning.scenario import scenario_of
from tests.support import zoom_flight as zf

MISSION = mission_from_dict(zf.mission())
ORIGIN = MISSION.origin()
HIGH_M = 200.0
"""From this high, people at the widest zoom are small enough in the picture that the range
limit (core/grid.default_max_range_m) keeps each frame's ground small: zooming in reaches
farther."""


def _vantage(zooms: tuple[float, ...] | None):
    from pdcov.planning.vantage import VantageSettings
    from pdcov.planning.vantage_missions import plan_vantage_missions

    settings = VantageSettings(0.4, (HIGH_M,), (2.0,), lattice_m=10.0, exact_time_limit_s=5.0,
                               zooms_hfov_deg=zooms)
    return plan_vantage_missions(scenario_of(MISSION), settings, routing_time_s=1.0)


def test_a_high_vantage_point_zooms_in_and_its_mission_says_so():
    """Zoom as a candidate dimension: candidates at the widest field of view only choose the
    unzoomed cover exactly (and write it zoomed to the widest once); with 28 deg too, fewer
    points reach the target, the mission zooms before a hover where the zoom changes and the
    whole flight's prediction (each frame at its waypoint's zoom) holds the target."""
    plain, widest, both = _vantage(None), _vantage((zf.WIDE_DEG,)), _vantage((zf.WIDE_DEG, 28.0))
    assert [(p.x_enu_m, p.y_enu_m) for p in widest.cover.points] == [
        (p.x_enu_m, p.y_enu_m) for p in plain.cover.points]
    np.testing.assert_allclose(widest.grid.log_miss_d, plain.grid.log_miss_d, rtol=1e-6)
    plan = plain.missions[0].prediction.plan
    assert not any(it.command == MAV_CMD_SET_CAMERA_ZOOM for it in mission_items(plan, ORIGIN))
    items = mission_items(widest.missions[0].prediction.plan, ORIGIN)
    assert [it.command for it in items].count(MAV_CMD_SET_CAMERA_ZOOM) == 1
    zooms = {p.zoom_hfov_deg for p in both.cover.points}
    print(f"{HIGH_M:g} m, P_D 0.4: {len(plain.cover.points)} points unzoomed "
          f"({plain.longest_s:.0f} s), {len(both.cover.points)} with 28 deg too "
          f"({both.longest_s:.0f} s); zooms chosen {sorted(zooms)}")
    assert len(both.cover.points) < len(plain.cover.points) and 28.0 in zooms
    pd = both.grid.pd[both.grid.mask]
    assert (pd >= 0.4).all()
    (m,) = both.missions
    items = mission_items(m.prediction.plan, ORIGIN)
    per_hover = []
    zoom = None
    for it in items:
        if it.command == MAV_CMD_SET_CAMERA_ZOOM:
            zoom = it.param2
        elif it.command == 16 and it.param1 > 0:
            per_hover.append(zoom)
    stops = [both.cover.points[s] for s in m.route.stops]
    assert per_hover == [p.zoom_hfov_deg for p in stops]
    changes = sum(a != b for a, b in zip(per_hover[:-1], per_hover[1:], strict=True))
    assert [it.command for it in items].count(MAV_CMD_SET_CAMERA_ZOOM) == 1 + changes


def test_cli_vantage_zooms_write_each_points_zoom(tmp_path):
    import json

    from pdcov.cli import main as pdcov_main

    cfg = zf.write_mission(tmp_path / "m.yaml", zf.mission())
    out = tmp_path / "o"
    assert pdcov_main(["plan", "--config", str(cfg), "--pattern", "vantage", "--target-pd",
                       "0.2", "--altitudes-m", str(HIGH_M), "--lattice-m", "10",
                       "--zooms-hfov-deg", str(zf.WIDE_DEG), "28", "--ilp-time-limit-s", "5",
                       "--routing-time-s", "1", "--no-figures", "--out", str(out)]) == 0
    doc = json.loads((out / "vantage.json").read_text())
    zooms = [p["zoom_hfov_deg"] for p in doc["points"]]
    assert 28.0 in zooms and set(zooms) <= {zf.WIDE_DEG, 28.0}
    back = read_plan_file(out / "plan.plan", ORIGIN)
    hovers = [z for w, z in zip(back.waypoints, back.zooms_hfov_deg(), strict=True)
              if w.hover_s > 0]
    assert sorted(hovers) == sorted(zooms)
    grid = predict(scenario_of(MISSION), back).grid  # the files predict as planned
    with np.load(out / "grid.npz") as z:
        np.testing.assert_allclose(grid.log_miss_d, z["log_miss_d"], atol=1e-4)
