"""`pdcov evaluate` end to end: pose CSV and tlog inputs give the core's grid, the outputs
are complete and readable, and bad input fails with a clear message and exit status 2."""

from __future__ import annotations

import contextlib
import io
import json

import numpy as np
import pytest

from pdcov.config.load import load_mission
from pdcov.core.pose import (
    GIMBAL_FLAG_YAW_IN_EARTH_FRAME,
    GIMBAL_FLAG_YAW_IN_VEHICLE_FRAME,
    GimbalFrame,
)
from tests.support.evaluate_inputs import (
    ORIGIN,
    assert_clean_failure,
    cli,
    expected_poses,
    known_flight,
    load_grid,
    mission_doc,
    run,
    write_config,
    write_pose_csv,
)
from tests.support.mavlink_fixtures import samples_from_flight, write_tlog


def test_pose_csv_gives_the_core_grid(tmp_path):
    config = write_config(tmp_path, mission_doc())
    poses = expected_poses(known_flight(), None)
    csv = write_pose_csv(tmp_path / "poses.csv", poses)
    assert run("evaluate", "--config", str(config), "--poses", str(csv), "--out",
               str(tmp_path / "run"), "--no-progress") == 0
    grid = load_mission(config).new_mission_grid()
    for p in poses:
        grid.update(p)
    out = load_grid(tmp_path / "run")
    np.testing.assert_allclose(out["pd"], grid.pd, atol=1e-6)
    np.testing.assert_array_equal(out["n_obs"], grid.n_obs)
    assert grid.n_obs.sum() > 1000 and out["pd"].max() > 0.5
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert set(metrics) == {"version", "frames", "cells_free", "cells_observed",
                            "proportion_at_or_above", "mean_pd", "expected_false_alarms",
                            "limiting_cells", "motion_blur", "extent", "time_on_scene_s",
                            "sweep_width"}
    # A small grid's outputs cover it whole (docs/outputs.md "Extent").
    assert metrics["extent"]["cropped"] is False and metrics["extent"]["rows"] == [0, 40]
    assert metrics["extent"]["x_enu_m"] == [0, 40] and metrics["extent"]["cols"] == [0, 40]
    assert metrics["motion_blur"] == {"effect": "no_exposure", "exposure_s": None,
                                      "frames_blurred": 0}
    assert metrics["limiting_cells"] == grid.limiting_counts()
    assert metrics["limiting_cells"]["hidden"] == 0  # flat ground hides nothing
    assert metrics["frames"] == len(poses) and metrics["cells_free"] == 1600 - 16
    assert list(metrics["proportion_at_or_above"]) == ["0.5", "0.7", "0.8"]
    free_pd = grid.pd[grid.mask]
    assert metrics["proportion_at_or_above"]["0.7"] == pytest.approx((free_pd >= 0.7).mean())
    assert float(out["x0_m"]) == 0 and float(out["y0_m"]) == 0 and out["mask"].shape == (40, 40)


@pytest.mark.parametrize("flags, frame, mount", [
    (None, None, None),
    (GIMBAL_FLAG_YAW_IN_VEHICLE_FRAME, GimbalFrame.VEHICLE,
     {"type": "gimbal", "attitude_frame": "flags"}),
    (GIMBAL_FLAG_YAW_IN_EARTH_FRAME, GimbalFrame.EARTH,
     {"type": "gimbal", "attitude_frame": "flags"}),
], ids=["fixed", "gimbal-yaw-in-vehicle-frame", "gimbal-yaw-in-earth-frame"])
def test_tlog_evaluates_to_the_pose_csv_grid(tmp_path, flags, frame, mount):
    flight = known_flight(flags)
    tlog = write_tlog(tmp_path / "flight.tlog", samples_from_flight(flight))
    config = write_config(tmp_path, mission_doc(mount))
    csv = write_pose_csv(tmp_path / "poses.csv", expected_poses(flight, frame))
    assert run("evaluate", "--config", str(config), "--log", str(tlog), "--out",
               str(tmp_path / "from_log"), "--export-poses", str(tmp_path / "used.csv"),
               "--no-progress") == 0
    assert run("evaluate", "--config", str(config), "--poses", str(csv), "--out",
               str(tmp_path / "from_csv"), "--no-progress") == 0
    a, b = load_grid(tmp_path / "from_log"), load_grid(tmp_path / "from_csv")
    # The tlog carries float32 angles and degE7 / mm positions: a cell on the edge of a
    # footprint may flip; nearly all agree exactly.
    assert (a["n_obs"] != b["n_obs"]).sum() <= 0.01 * b["n_obs"].size
    assert np.abs(a["pd"] - b["pd"]).mean() < 2e-3
    # The exported poses evaluate to exactly the log's grid.
    assert run("evaluate", "--config", str(config), "--poses", str(tmp_path / "used.csv"),
               "--out", str(tmp_path / "from_export"), "--no-progress") == 0
    c = load_grid(tmp_path / "from_export")
    np.testing.assert_array_equal(c["n_obs"], a["n_obs"])
    np.testing.assert_allclose(c["pd"], a["pd"], atol=1e-7)


def test_outputs_are_readable_and_follow_the_input(tmp_path):
    import rasterio
    from PIL import Image

    config = write_config(tmp_path, mission_doc())
    poses = expected_poses(known_flight(), None)
    csv_a = write_pose_csv(tmp_path / "a.csv", poses)
    csv_b = write_pose_csv(tmp_path / "b.csv", poses[: len(poses) // 2])
    for name, csv in (("a", csv_a), ("b", csv_b)):
        assert run("evaluate", "--config", str(config), "--poses", str(csv), "--out",
                   str(tmp_path / name), "--no-progress") == 0
    for png in ("heatmap.png", "thresholds.png"):
        images = [np.asarray(Image.open(tmp_path / n / png)) for n in "ab"]
        assert images[0].shape[0] > 300 and images[0].shape[1] > 400
        assert images[0].shape != images[1].shape or np.any(images[0] != images[1])
    grid = load_grid(tmp_path / "a")
    # In UTM zone 18N by nearest neighbour (test_grid_geotiffs.py: cell by cell): every
    # value a free cell's, and nearly every free cell's value there.
    with rasterio.open(tmp_path / "a" / "pd.tif") as tif:
        assert tif.count == 2 and tif.crs.to_epsg() == 32618
        assert tif.descriptions == ("pd", "pfa")
        band = tif.read(1)
    free_pd = set(grid["pd"][grid["mask"]].astype(np.float32))
    assert set(band[np.isfinite(band)]) <= free_pd
    assert len(set(band[np.isfinite(band)])) > 0.95 * len(free_pd)
    with rasterio.open(tmp_path / "a" / "limiting.tif") as tif:  # uint8 (looks.tif: int32)
        codes = tif.read(1)
    assert set(np.unique(codes)) == set(np.unique(grid["limiting"][grid["mask"]])) | {255}
    outline = json.loads((tmp_path / "a" / "outline.geojson").read_text())
    geom = outline["features"][0]["geometry"]
    assert geom["type"] == "MultiPolygon" and geom["coordinates"]
    lon, lat = geom["coordinates"][0][0][0]
    assert abs(lat - ORIGIN.lat_deg) < 0.001 and abs(lon - ORIGIN.lon_deg) < 0.001


def test_prior_gives_probability_of_success_and_posterior(tmp_path):
    config = write_config(tmp_path, mission_doc())
    csv = write_pose_csv(tmp_path / "poses.csv", expected_poses(known_flight(), None))
    poa = np.zeros((40, 40))
    poa[:, :20] = 1.0 / (40 * 20)  # the person is somewhere in the western half
    np.save(tmp_path / "prior.npy", poa)
    assert run("evaluate", "--config", str(config), "--poses", str(csv), "--out",
               str(tmp_path / "run"), "--prior", str(tmp_path / "prior.npy"),
               "--no-progress") == 0
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    pd = load_grid(tmp_path / "run")["pd"]
    mask = load_grid(tmp_path / "run")["mask"]
    assert metrics["probability_of_success"] == pytest.approx((poa * pd * mask).sum())
    posterior = np.load(tmp_path / "run" / "posterior.npy")
    assert posterior.sum() == pytest.approx(1.0)
    expected = poa * (1 - pd * mask)
    np.testing.assert_allclose(posterior, expected / expected.sum())


def test_compare_and_footprint(tmp_path, capsys):
    config = write_config(tmp_path, mission_doc())
    poses = expected_poses(known_flight(), None)
    for name, subset in (("full", poses), ("half", poses[::2])):
        csv = write_pose_csv(tmp_path / f"{name}.csv", subset)
        assert run("evaluate", "--config", str(config), "--poses", str(csv), "--out",
                   str(tmp_path / name), "--no-progress") == 0
    capsys.readouterr()
    assert run("compare", str(tmp_path / "full"), str(tmp_path / "half"), "--out",
               str(tmp_path / "cmp.png")) == 0
    table = capsys.readouterr().out
    assert "full" in table and "half" in table and (tmp_path / "cmp.png").stat().st_size > 0
    assert run("footprint", "--config", str(config), "--altitude-m", "10", "--out",
               str(tmp_path / "fp.png")) == 0
    out = capsys.readouterr().out
    # Nadir 640x480, f = 480 px, 10 m: 13.33 m x 10 m (barrel distortion widens it a bit).
    area = float(out.split("footprint area ")[1].split(" ")[0])
    assert 133.0 < area < 150.0


def test_bad_inputs_fail_clearly(tmp_path):
    config = write_config(tmp_path, mission_doc())
    out = str(tmp_path / "run")
    assert_clean_failure(cli("evaluate", "--config", str(config), "--poses",
                             str(tmp_path / "missing.csv"), "--out", out), "missing.csv")
    nan_csv = tmp_path / "nan.csv"
    nan_csv.write_text("t_s,x_m,y_m,z_m,qw,qx,qy,qz\n0,1,2,nan,1,0,0,0\n")
    assert_clean_failure(cli("evaluate", "--config", str(config), "--poses", str(nan_csv),
                             "--out", out), "nan.csv:2")
    bad_q = tmp_path / "q.csv"
    bad_q.write_text("t_s,x_m,y_m,z_m,qw,qx,qy,qz\n0,1,2,10,0.9,0,0,0\n")
    assert_clean_failure(cli("evaluate", "--config", str(config), "--poses", str(bad_q),
                             "--out", out), "q.csv:2")
    flight = known_flight()
    good = write_tlog(tmp_path / "good.tlog", samples_from_flight(flight))
    truncated = tmp_path / "truncated.tlog"
    truncated.write_bytes(good.read_bytes()[:37])
    assert_clean_failure(cli("evaluate", "--config", str(config), "--log", str(truncated),
                             "--out", out), "truncated.tlog")
    garbage = tmp_path / "garbage.bin"
    garbage.write_bytes(np.random.default_rng(3).bytes(5000))
    assert_clean_failure(cli("evaluate", "--config", str(config), "--log", str(garbage),
                             "--out", out), "garbage.bin")
    from pdcov.telemetry.samples import PositionSample
    no_pos = write_tlog(tmp_path / "nopos.tlog", [s for s in samples_from_flight(flight)
                                                 if not isinstance(s, PositionSample)])
    assert_clean_failure(cli("evaluate", "--config", str(config), "--log", str(no_pos),
                             "--out", out), "nopos.tlog")
    assert not (tmp_path / "run").exists(), "nothing may be written on bad input"


@pytest.mark.parametrize("change, words", [
    ({"origin": {"lat_deg": 95, "lon_deg": 0}}, ["mission.yaml", "origin.lat_deg"]),
    ({"camera": {"width_px": 640, "height_px": 480, "K": [[0, 0, 320], [0, 480, 240],
                                                           [0, 0, 1]], "frame_rate_hz": 5}},
     ["mission.yaml", "camera", "focal"]),
    ({"camera": {"width_px": 640, "height_px": 480, "K": [[480, 0, 320], [0, 480, 240],
                                                           [0, 0, 1]]}},
     ["mission.yaml", "camera.frame_rate_hz"]),
    ({"domain": {"polygon_enu_m": [[0, 0], [1, 1]]}}, ["mission.yaml", "domain.polygon_enu_m"]),
    ({"detector": "nowhere.yaml"}, ["mission.yaml", "detector", "nowhere.yaml"]),
    ({"thresholds": [0.5, 1.5]}, ["mission.yaml", "thresholds"]),
    ({"mount": {"type": "fixed", "pitch": -90}}, ["mission.yaml", "mount.pitch"]),
    ({"mount": {"type": "gimbal", "attitude_frame": "sideways"}},
     ["mission.yaml", "mount.attitude_frame"]),
    ({"treshold": [0.5]}, ["mission.yaml", "treshold"]),
])
def test_config_errors_name_file_and_key(tmp_path, change, words):
    config = write_config(tmp_path, mission_doc() | change)
    csv = write_pose_csv(tmp_path / "poses.csv", expected_poses(known_flight(), None)[:3])
    proc = cli("evaluate", "--config", str(config), "--poses", str(csv), "--out",
               str(tmp_path / "run"))
    assert_clean_failure(proc, *words)
    assert not (tmp_path / "run").exists()


def test_prior_segments_with_holes_multipolygons_and_parts_outside_the_grid(tmp_path):
    # A segment's POA used to be spread over its holes too, and a segment reaching past the
    # domain poured all of its POA into the grid.
    from pdcov.core.geodesy import enu_to_geodetic
    from pdcov.core.search_theory import search_outcome
    from pdcov.report.outputs import read_prior

    mission = load_mission(write_config(tmp_path, mission_doc()))
    g = mission.domain.grid_geometry(1.0)
    mask = mission.domain.free_mask(g)
    assert (g.x0_m, g.y0_m) == (0.0, 0.0)

    def ring(x0, y0, x1, y1):
        enu = np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0], [x0, y0, 0]])
        return [[lon, lat] for lat, lon, _ in enu_to_geodetic(enu, ORIGIN)]

    doc = {"type": "FeatureCollection", "features": [
        # 20 x 20 m with a 10 x 10 m hole: 300 m^2.
        {"type": "Feature", "properties": {"poa": 0.3},
         "geometry": {"type": "Polygon", "coordinates": [ring(0, 0, 20, 20),
                                                         ring(5, 5, 15, 15)]}},
        # Two 10 x 10 m squares.
        {"type": "Feature", "properties": {"poa": 0.4},
         "geometry": {"type": "MultiPolygon", "coordinates": [[ring(25, 0, 35, 10)],
                                                              [ring(25, 30, 35, 40)]]}},
        # Half of it west of the grid.
        {"type": "Feature", "properties": {"poa": 0.2},
         "geometry": {"type": "Polygon", "coordinates": [ring(-10, 30, 10, 40)]}}]}
    (tmp_path / "segments.geojson").write_text(json.dumps(doc))
    prior = read_prior(tmp_path / "segments.geojson", g, mask, ORIGIN)
    poa = prior.poa
    assert poa[2, 2] == pytest.approx(0.3 / 300) and poa[10, 10] == pytest.approx(0, abs=1e-9)
    assert poa[5, 30] == pytest.approx(0.4 / 200) and poa[35, 30] == pytest.approx(0.4 / 200)
    assert poa[35, 5] == pytest.approx(0.2 / 200)
    assert poa.sum() == pytest.approx(0.3 + 0.4 + 0.1)
    first, third = prior.notes  # the obstacle (18..22 m) takes 4 m^2 of the first
    assert first.startswith("segments.geojson: segment 0 (poa 0.3): 0.0% of it (POA 0) lies "
                            "outside the grid and 1.3% (POA 0.004) on cells that are not free")
    assert third.startswith("segments.geojson: segment 2 (poa 0.2): 50.0% of it (POA 0.1) "
                            "lies outside the grid")
    # POS against an independent count: P_D 1 over the hole only finds nothing there.
    pd = np.zeros(g.shape)
    pd[5:15, 5:15] = 1.0
    pd[0:5, 0:20] = 0.5
    expected = 0.5 * 0.3 * (5 * 20) / 300
    assert search_outcome(poa, pd, mask).probability_of_success == pytest.approx(expected)
    # pdcov evaluate prints each segment's note in its summary.
    config = write_config(tmp_path, mission_doc())
    csv = write_pose_csv(tmp_path / "poses.csv", expected_poses(known_flight(), None))
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert run("evaluate", "--config", str(config), "--poses", str(csv), "--out",
                   str(tmp_path / "run"), "--prior", str(tmp_path / "segments.geojson"),
                   "--no-progress") == 0
    assert first in out.getvalue() and third in out.getvalue()
