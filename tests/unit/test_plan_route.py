"""A plan's route as GPX (commands/plan_output.write_route, report/gpx.route_document), read
back by gpxpy: a route point per mission waypoint, where the .plan puts it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from pdcov import cli

DEMO = Path(__file__).resolve().parents[2] / "service" / "pdcov" / "data" / "demo_mission.yaml"
NAV_WAYPOINT = 16


def test_plan_gpx_is_the_plans_waypoints_as_a_route(tmp_path, capsys):
    gpxpy = pytest.importorskip("gpxpy")
    out = tmp_path / "p"
    assert cli.main(["plan", "--config", str(DEMO), "--altitude-m", "12", "--out", str(out),
                     "--no-figures"]) == 0
    assert "plan.gpx (its route)" in capsys.readouterr().out
    items = json.loads((out / "plan.plan").read_text())["mission"]["items"]
    waypoints = [i["params"][4:7] for i in items if i["command"] == NAV_WAYPOINT]
    with open(out / "plan.gpx") as f:
        doc = gpxpy.parse(f)
    [route] = doc.routes
    assert route.name == "plan" and len(route.points) == len(waypoints) > 3
    for k, (p, (lat, lon, _)) in enumerate(zip(route.points, waypoints, strict=True), 1):
        assert p.name == f"WP {k}"
        assert (p.latitude, p.longitude) == pytest.approx((lat, lon), abs=0.5e-7)
        assert p.elevation == pytest.approx(5.0 + 12.0)  # the demo's ground 5 m MSL, +12 m
