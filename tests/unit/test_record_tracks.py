"""The recording's fleet report draws every vehicle's track, each its own line: on the heat
map (ENU, broken by NaN rows between vehicles) and on map.png; and the demo's daemons send
their status, the ground station's only positions, every 0.5 s of simulated flight."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pdcov.bus.grid_state import decode_snapshot, encode_snapshot
from pdcov.config.load import load_mission
from pdcov.core.geodesy import enu_to_geodetic
from pdcov.ground.demo import DemoVehicle, vehicle_config
from pdcov.ground.record import Recording
from pdcov.ground.watcher import Watcher
from pdcov.report.exports import VehicleTrack, tracks_enu

DEMO = Path(__file__).resolve().parents[2] / "service/pdcov/data/demo_mission.yaml"


@pytest.fixture(scope="module")
def mission():
    return load_mission(DEMO)


def square_enu(x0_m: float) -> np.ndarray:
    return np.array([[x0_m, -55.0, 10.0], [x0_m + 10.0, -55.0, 10.0],
                     [x0_m + 10.0, -25.0, 10.0], [x0_m, -25.0, 10.0]])


def test_tracks_enu_breaks_between_vehicles_and_round_trips(mission):
    origin = mission.origin()
    tracks = [VehicleTrack.from_enu(v, [square_enu(x0)], origin)
              for v, x0 in (("uav1", -58.0), ("uav2", -38.0))]
    xy = tracks_enu(tracks, origin)
    assert xy is not None and xy.shape == (9, 2)
    assert np.isnan(xy[4]).all() and np.isfinite(np.delete(xy, 4, axis=0)).all()
    np.testing.assert_allclose(xy[:4], square_enu(-58.0)[:, :2], atol=1e-6)
    np.testing.assert_allclose(xy[5:], square_enu(-38.0)[:, :2], atol=1e-6)
    assert tracks_enu([], origin) is None


def test_the_two_vehicle_fleet_report_draws_both_tracks(tmp_path, mission, monkeypatch):
    import pdcov.report.map_figure as map_figure_module
    import pdcov.report.plots as plots

    drawn: dict[str, object] = {}
    heatmap, map_figure = plots.heatmap_figure, map_figure_module.map_figure

    def spy_heatmap(*args, **kw):
        drawn["heatmap"] = kw["track_enu"]
        return heatmap(*args, **kw)

    def spy_map(*args, **kw):
        drawn["map"] = kw["tracks"]
        return map_figure(*args, **kw)

    monkeypatch.setattr(plots, "heatmap_figure", spy_heatmap)
    monkeypatch.setattr(map_figure_module, "map_figure", spy_map)
    origin = mission.origin()
    w = Watcher()
    for vid, x0 in (("uav1", -58.0), ("uav2", -38.0)):
        grid = mission.new_mission_grid()
        w.on_snapshot(vid, decode_snapshot(encode_snapshot(grid)), 0.0)
        w.feeds[vid].track_lat_lon_alt = [tuple(p) for p in enu_to_geodetic(square_enu(x0),
                                                                             origin)]
    rec = Recording(tmp_path / "rec")
    rec.close()
    rec.finish(w, mission)
    assert [t.vehicle for t in drawn["map"]] == ["uav1", "uav2"]
    xy = drawn["heatmap"]
    assert xy.shape == (9, 2) and np.isnan(xy[4]).all()
    np.testing.assert_allclose(xy[5:], square_enu(-38.0)[:, :2], atol=1e-6)
    assert (tmp_path / "rec" / "fleet" / "heatmap.png").stat().st_size > 0


@pytest.mark.parametrize(("speed", "period_s"), [(1.0, 0.5), (4.0, 0.125), (8.0, 0.1)])
def test_the_demo_status_is_every_half_second_of_flight_at_most_10_hz(mission, speed,
                                                                       period_s):
    cfg = vehicle_config({"vehicle_id": "x"}, DemoVehicle("uav1", 1, Path("p.plan")),
                         "tcp/127.0.0.1:1", Path("state"), speed)
    assert cfg["bus"]["status_period_s"] == pytest.approx(period_s)
