"""Zoom: each frame evaluated with the camera of the zoom report in force (core/zoom.py,
telemetry/lens_reports.py), live and offline alike; more than one camera's looks in the
same cells. The reference is the per-pixel ray cast of tests/support/references.py (R1) with
each frame's own camera built from its field of view (CameraModel.from_fov), independently
of the focal-length scaling under test."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from pdcov.config.load import load_mission, mission_from_dict
from pdcov.core.camera import CameraModel
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import GridGeometry
from pdcov.core.grid import CoverageGrid
from pdcov.core.grid_camera import default_max_range_m
from pdcov.core.pose import CameraPose
from pdcov.core.zoom import (
    FovLens,
    LensQuantity,
    TableLens,
    Zoom,
    hfov_rad,
    jumps,
)
from pdcov.errors import CalibrationError, ConfigError
from pdcov.flight.frame_decision import Framing
from pdcov.flight.log_frames import poses_from_log
from pdcov.service.settings import load_serve_config
from pdcov.telemetry.frame_policy import SkipReason
from pdcov.telemetry.lens_reports import LensReports
from pdcov.telemetry.samples import LensSample
from tests.support import zoom_flight as zf
from tests.support.evaluate_inputs import load_grid, run
from tests.support.link_feed import LinkFeed
from tests.support.references import ReferenceGrid, pixel_rays, r1_update


def _evaluate(tmp_path: Path, doc: dict, tlog: Path, name: str) -> dict:
    config = zf.write_mission(tmp_path / f"{name}.yaml", doc)
    assert run("evaluate", "--config", str(config), "--log", str(tlog), "--out",
               str(tmp_path / name), "--no-progress") == 0
    return load_grid(tmp_path / name)


def _poses(doc: dict, tlog: Path):
    m = mission_from_dict(doc)
    (cam,) = m.cameras
    return m, poses_from_log(tlog, Framing(cam.mount, cam.frame_rate_hz, cam.zoom,
                                           max_gap_s=m.max_gap_s),
                             origin_lat_deg=m.origin_lat_deg,
                             origin_lon_deg=m.origin_lon_deg,
                             ground_alt_msl_m=m.ground_alt_msl_m)


def _reference_pd(tlog: Path) -> np.ndarray:
    """R1 frame by frame, each frame with the camera of the field of view the scenario
    reported last before it (reports every 0.1 s from 1.0 s: the frame at 1.0 s has none
    before it and is not evaluated)."""
    m, lp = _poses(zf.mission("none"), tlog)
    g = m.domain.grid_geometry(m.cell_size_m)
    ref = None
    for pose in (p for p in lp.poses if p.t_s > zf.FIRST_REPORT_S):
        cam = CameraModel.from_fov(zf.WIDTH_PX, zf.HEIGHT_PX, zf.hfov_deg(pose.t_s - 0.1))
        rng = default_max_range_m(cam, m.first_camera.detector, m.cell_size_m)
        if ref is None:
            ref = ReferenceGrid(g, m.domain.free_mask(g), cam, m.first_camera.detector, rng)
        ref.max_range_m = rng
        r1_update(ref, pixel_rays(cam), pose)
    assert ref is not None
    return ref.pd


@pytest.fixture(scope="module")
def hover(tmp_path_factory) -> Path:
    return zf.write_tlog(tmp_path_factory.mktemp("zoom") / "hover.tlog", zf.frames())


def test_fov_status_agrees_with_the_per_pixel_reference(tmp_path, hover):
    """The acceptance case: a hover at 60 m zooming from 66 to 28 deg half-way."""
    ref = _reference_pd(hover)
    zoomed = _evaluate(tmp_path, zf.mission(), hover, "zoomed")
    wide = _evaluate(tmp_path, zf.mission("none"), hover, "wide")
    mask = zoomed["mask"]
    agree = float((np.abs(zoomed["pd"] - ref)[mask] <= 0.05).mean())
    agree_wide = float((np.abs(wide["pd"] - ref)[mask] <= 0.05).mean())
    assert agree >= 0.95, agree
    # The wide lens for every frame misses: the test can fail.
    assert agree_wide < 0.6, agree_wide
    assert ref[mask].max() > 0.8  # the zoomed looks are large enough to matter


def test_zoom_none_gives_todays_grid_exactly(tmp_path, hover):
    """camera.zoom none (or no key) evaluates every frame with the configured K through
    ``update``, as before zoom existed."""
    doc = zf.mission("none")
    out = _evaluate(tmp_path, doc, hover, "none")
    bare = dict(doc, camera={k: v for k, v in doc["camera"].items() if k != "zoom"})
    m, lp = _poses(bare, hover)
    assert lp.cameras == ()
    grid = m.new_mission_grid()
    for p in lp.poses:
        grid.update(p)
    for key in ("log_miss_d", "log_miss_fa", "n_obs", "limiting"):
        np.testing.assert_array_equal(out[key], getattr(grid, key), err_msg=key)
    # And update_with the grid's own camera is update.
    again = m.new_mission_grid()
    for p in lp.poses:
        again.update_with(p, m.first_camera.camera, m.first_camera.detector)
    np.testing.assert_array_equal(again.log_miss_d, grid.log_miss_d)


def test_the_daemon_gives_the_offline_grid_while_zooming(tmp_path, hover):
    """The same bytes fed to the daemon's decisions (LinkFeed) give evaluate's grid, cell
    for cell."""
    cfg = load_serve_config(zf.write_mission(tmp_path / "serve.yaml", zf.mission(),
                                             service=True))
    out = _evaluate(tmp_path, zf.mission(), hover, "offline")
    feed = LinkFeed(cfg)
    for i, frame in enumerate(zf.frames()):
        feed.feed(frame, 0.01 * i)
    feed.tick(100.0)
    live = feed.live
    assert live.grid.frames == 10
    assert live.counters.skipped[SkipReason.ZOOM_MISSING] == 1  # the first frame: no report yet
    for key in ("log_miss_d", "log_miss_fa", "n_obs", "limiting"):
        np.testing.assert_array_equal(getattr(live.grid, key), out[key], err_msg=key)


def test_fov_lens_scales_the_focal_length_by_hand():
    wide = CameraModel.from_fov(320, 240, 66.0)
    lens = FovLens(wide, math.radians(20.0))
    assert lens.camera(hfov_rad(wide)) is wide
    narrow = lens.camera(math.radians(28.0))
    f = 160 / math.tan(math.radians(14.0))
    np.testing.assert_allclose(narrow.K, [[f, 0, 159.5], [0, f, 119.5], [0, 0, 1]],
                               rtol=1e-4)  # the field of view quantised: FOV_FOCAL_STEP
    assert lens.camera(math.radians(28.0)) is narrow  # built once per value
    assert lens.refusal(math.radians(28.0)) == ""
    assert "outside the calibrated 20.00-66.00 deg" in lens.refusal(math.radians(70.0))
    assert "outside" in lens.refusal(math.radians(18.0))
    assert lens.refusal(math.radians(66.5)) == ""  # within the 1 deg tolerance: the widest
    assert lens.camera(math.radians(66.5)).K[0, 0] == wide.K[0, 0]


def test_table_lens_interpolates_in_focal_length():
    def cam(f: float, cx: float, k1: float) -> CameraModel:
        return CameraModel(320, 240, np.array([[f, 0, cx], [0, f, 120], [0, 0, 1]]),
                           "plumb_bob", np.array([k1, 0, 0, 0, 0]))

    lens = TableLens(LensQuantity.ZOOM_LEVEL, (0.0, 100.0),
                     (cam(300, 160, -0.1), cam(600, 150, 0.0)))
    mid = lens.camera(50.0)
    assert mid.K[0, 0] == pytest.approx(450) and mid.K[0, 2] == pytest.approx(155)
    assert mid.dist_coeffs[0] == pytest.approx(-0.05)
    assert "outside the calibrated 0-100" in lens.refusal(120.0)
    with pytest.raises(CalibrationError, match="must increase with zoom_level"):
        TableLens(LensQuantity.ZOOM_LEVEL, (0.0, 100.0), (cam(600, 160, 0), cam(300, 160, 0)))
    with pytest.raises(CalibrationError, match="increase strictly"):
        TableLens(LensQuantity.ZOOM_LEVEL, (50.0, 10.0), (cam(300, 160, 0), cam(600, 160, 0)))


def test_reports_held_stale_out_of_range_jumping_and_from_another_camera():
    lens = FovLens(CameraModel.from_fov(320, 240, 66.0), math.radians(20.0),
                   max_rate_per_s=2.0)
    reports = LensReports(Zoom(lens, max_report_age_s=1.0, camera_id=(100, 0)))
    deg = math.radians
    for t, h in ((1.0, 66.0), (2.0, 60.0), (2.1, 30.0), (2.2, 60.0), (2.3, 60.0),
                 (5.0, 80.0)):
        reports.add(LensSample(t, hfov_rad=deg(h)))
    reports.add(LensSample(1.5, hfov_rad=deg(40.0), component_id=101))  # another camera
    value, reason = reports.at(np.array([0.5, 1.0, 1.5, 2.05, 2.15, 2.25, 2.35, 4.0, 5.5]))
    assert list(reason) == [SkipReason.ZOOM_MISSING, SkipReason.ZOOM_MISSING, "", "",
                            SkipReason.ZOOM_JUMP, SkipReason.ZOOM_JUMP, "",
                            SkipReason.ZOOM_STALE, SkipReason.ZOOM_OUT_OF_RANGE]
    assert np.degrees(value[2]) == pytest.approx(66.0)  # held from 1.0 s, not camera 101's
    assert reports.other_camera == 1
    # The rule by hand: ln(f(30 deg) / f(60 deg)) in 0.1 s is far faster than 2 / s.
    f = lens.focal_px(np.radians([60.0, 30.0]))
    assert jumps(np.array([0.0, 0.1]), f, 2.0).tolist() == [False, True]
    assert jumps(np.array([0.0, 1.0]), f, 2.0).tolist() == [False, False]


def test_a_report_outside_the_calibration_skips_frames_with_a_reason(tmp_path):
    tlog = zf.write_tlog(tmp_path / "wide.tlog", zf.frames(lambda t: 90.0))
    m, lp = _poses(zf.mission(), tlog)
    assert lp.poses == ()
    assert "camera zoom outside calibration 10" in "\n".join(lp.summary_lines)


def test_two_cameras_combine_as_independent_looks_by_hand():
    """A visible and a thermal camera, each with a detector of constant P_D (0.3, 0.5), both
    see the cells under the hover: there P_D = 1 - (1 - 0.3)(1 - 0.5) = 0.65."""
    base = DetectorModel.illustrative().to_dict()

    def constant(p: float) -> DetectorModel:
        n = len(base["p_detect"])
        return DetectorModel.from_dict(dict(base, p_detect=[p] * n,
                                            p_false_alarm=[0.01] * n,
                                            fa_rate_per_mpx=[0.05] * n))

    visible, thermal = constant(0.3), constant(0.5)
    g = GridGeometry(0.0, 0.0, 1.0, 40, 40)
    cam_v = CameraModel.from_fov(640, 480, 60.0)
    cam_t = CameraModel.from_fov(320, 256, 40.0)
    grid = CoverageGrid(g, np.ones(g.shape, bool), cam_v, visible)
    R_down = np.array([[1.0, 0, 0], [0, -1, 0], [0, 0, -1]])  # optical axis down
    pose = CameraPose(R_down, np.array([20.0, 20.0, 20.0]), 0.0)
    grid.update_with(pose)  # the grid's own camera: the visible one
    grid.update_with(pose, cam_t, thermal)
    one_v = CoverageGrid(g, np.ones(g.shape, bool), cam_v, visible)
    one_v.update(pose)
    one_t = CoverageGrid(g, np.ones(g.shape, bool), cam_t, thermal)
    one_t.update(pose)
    both = (one_v.n_obs > 0) & (one_t.n_obs > 0)
    assert both.sum() > 100 and ((one_v.n_obs > 0) & ~both).sum() > 100
    np.testing.assert_allclose(grid.pd[both], 0.65, atol=1e-6)
    np.testing.assert_allclose(grid.pd[(one_v.n_obs > 0) & ~both], 0.3, atol=1e-6)
    np.testing.assert_allclose(grid.pd, 1 - (1 - one_v.pd) * (1 - one_t.pd), atol=1e-6)
    assert grid.camera is cam_v and grid.detector is visible  # its own again


@pytest.mark.parametrize(("camera", "message"), [
    ({"zoom": "optical"}, "camera.zoom: expected one of none, fov_status, table"),
    ({"zoom": "fov_status"}, "camera.zoom_lens.min_hfov_deg: missing"),
    ({"zoom": "fov_status", "zoom_lens": {"min_hfov_deg": 80}},
     "min_hfov_deg: expected a field of view in (0, 66.000] deg"),
    ({"zoom": "none", "zoom_lens": {"min_hfov_deg": 20}}, "given with camera.zoom none"),
    ({"zoom": "table", "zoom_lens": {"table": [{"zoom_level": 0}]}},
     "at least two entries"),
    ({"zoom": "table", "zoom_lens": {"table_by": "zoom", "table": []}},
     "table_by: expected one of zoom_level, focal_length_mm"),
    ({"zoom": "table", "zoom_lens": {"table": [
        {"zoom_level": 0, "K": [[500, 0, 160], [0, 500, 120], [0, 0, 1]]},
        {"zoom_level": 50, "K": [[400, 0, 160], [0, 400, 120], [0, 0, 1]]}]}},
     "must increase with zoom_level"),
    ({"zoom": "fov_status", "zoom_lens": {"min_hfov_deg": 20, "fov": 1}},
     "camera.zoom_lens.fov: unknown key"),
])
def test_bad_zoom_config_says_what_is_wrong(tmp_path, camera, message):
    doc = zf.mission("none")
    doc["camera"] = {**{k: v for k, v in doc["camera"].items() if k != "zoom"}, **camera}
    path = zf.write_mission(tmp_path / "bad.yaml", doc)
    with pytest.raises(ConfigError) as err:
        load_mission(path)
    assert message in str(err.value) and str(path) in str(err.value)


def test_a_zoom_table_follows_camera_settings(tmp_path):
    """camera.zoom table keyed by zoom level: a CAMERA_SETTINGS report selects the
    interpolated calibration (here the table's second entry exactly)."""
    f0 = (zf.WIDTH_PX / 2) / math.tan(math.radians(zf.WIDE_DEG) / 2)
    doc = zf.mission("none")
    doc["camera"] = dict(doc["camera"], zoom="table", zoom_lens={"table": [
        {"zoom_level": 0, "K": [[f0, 0, 159.5], [0, f0, 119.5], [0, 0, 1]]},
        {"zoom_level": 100, "K": [[3 * f0, 0, 159.5], [0, 3 * f0, 119.5], [0, 0, 1]]}]})
    (cam,) = mission_from_dict(doc).cameras
    assert cam.zoom is not None and cam.zoom.lens.quantity == LensQuantity.ZOOM_LEVEL
    reports = LensReports(cam.zoom)
    reports.add(LensSample(1.0, zoom_level=100.0))
    reports.add(LensSample(1.0, hfov_rad=0.5))  # another message of the camera: not this one
    value, reason = reports.at(np.array([1.5]))
    assert reason[0] == "" and value[0] == 100.0
    assert cam.zoom.lens.camera(50.0).K[0, 0] == pytest.approx(2 * f0)


def test_a_two_camera_flight_combines_both_cameras_looks(tmp_path, hover):
    """A visible camera (fixed lens, P_D 0.3 per look) and a zooming thermal camera (P_D 0.5)
    on one hover: each cell's P_D is 1 - 0.7^n_visible 0.5^n_thermal over the looks each
    camera's own grid counts; metrics and maps per camera beside the combined ones."""
    base = DetectorModel.illustrative().to_dict()
    n = len(base["p_detect"])
    primary = zf.mission("none")
    thermal_cam = dict(zf.mission(component_id=100)["camera"], width_px=160, height_px=120,
                       K=[[123.2, 0, 79.5], [0, 123.2, 59.5], [0, 0, 1]], frame_rate_hz=1.0)
    doc = {k: v for k, v in primary.items() if k not in ("camera", "mount", "detector")}
    doc["cameras"] = [
        {"name": "visible", "camera": primary["camera"], "mount": primary["mount"],
         "detector": dict(base, p_detect=[0.3] * n)},
        {"name": "thermal", "camera": thermal_cam, "mount": primary["mount"],
         "detector": dict(base, p_detect=[0.5] * n)}]
    out = _evaluate(tmp_path, doc, hover, "two")
    vis = load_grid(tmp_path / "two" / "cameras" / "visible")
    th = load_grid(tmp_path / "two" / "cameras" / "thermal")
    m = out["mask"]
    both = m & (vis["n_obs"] > 0) & (th["n_obs"] > 0)
    assert both.sum() > 100 and th["n_obs"].max() > vis["n_obs"].max()  # 1 Hz against 0.5
    expected = 1 - 0.7 ** vis["n_obs"] * 0.5 ** th["n_obs"]
    np.testing.assert_allclose(out["pd"][m], expected[m], atol=1e-5)
    np.testing.assert_array_equal(out["n_obs"], vis["n_obs"] + th["n_obs"])
    import json
    metrics = json.loads((tmp_path / "two" / "metrics.json").read_text())
    assert set(metrics["cameras"]) == {"visible", "thermal"}
    assert metrics["cameras"]["thermal"]["frames"] == int(th["frames"]) > 15


def test_a_cameras_list_refuses_the_top_level_camera(tmp_path):
    doc = zf.mission("none")
    doc = {**{k: v for k, v in doc.items() if k not in ("camera", "mount", "detector")},
           "cameras": [{"name": "a", "camera": doc["camera"], "detector": "illustrative"},
                       {"name": "b", "camera": doc["camera"], "detector": "illustrative"}]}
    doc["camera"] = doc["cameras"][0]["camera"]
    with pytest.raises(ConfigError, match="camera: not allowed with a cameras list"):
        load_mission(zf.write_mission(tmp_path / "both.yaml", doc))


def test_a_plan_zooms_its_camera_and_predicts_with_the_zoomed_k(tmp_path):
    """`pdcov plan --zoom-hfov-deg`: the swath narrows by tan(hfov/2) (both focal lengths
    scale alike), the mission carries MAV_CMD_SET_CAMERA_ZOOM (ZOOM_TYPE_HORIZONTAL_FOV) and
    reads back with it, and a zoom outside the lens is refused."""
    from pdcov.core.mission import MAV_CMD_SET_CAMERA_ZOOM
    from pdcov.planning.optimise import PlanParams, build_plan, candidates, predict
    from pdcov.planning.plan_items import mission_items, plan_from_mission_items
    from pdcov.planning.scenario import scenario_of

    m = mission_from_dict(zf.mission())
    sc = scenario_of(m)
    wide, narrow = sc.swath_width_m(60.0), sc.swath_width_m(60.0, zoom_hfov_deg=28.0)
    ratio = math.tan(math.radians(14.0)) / math.tan(math.radians(zf.WIDE_DEG / 2))
    assert narrow / wide == pytest.approx(ratio, rel=0.02)
    params = PlanParams("lawnmower", 60.0, 5.0, zoom_hfov_deg=28.0)
    plan, spacing = build_plan(sc, params)
    assert plan.zooms_hfov_deg() == [28.0] * len(plan.waypoints)
    assert [w.zoom_hfov_deg for w in plan.waypoints[1:]] == [None] * (len(plan.waypoints) - 1)
    assert spacing < 0.5 * build_plan(
        sc, PlanParams("lawnmower", 60.0, 5.0))[1]
    items = mission_items(plan, m.origin())
    zoom = [it for it in items if it.command == MAV_CMD_SET_CAMERA_ZOOM]
    assert [(z.param1, z.param2) for z in zoom] == [(4.0, 28.0)]
    assert items[1] == zoom[0]  # after the take-off
    assert plan_from_mission_items(items, m.origin()).zooms_hfov_deg() == plan.zooms_hfov_deg()
    # The prediction evaluates every frame with the zoomed camera: fewer looks per cell
    # (a narrower footprint over the same tracks), each more likely to detect (a 2 m cell at
    # 60 m: 8 px wide, 21 px zoomed; the illustrative detector's P_D ~0.28 and ~0.43).
    zoomed = predict(sc, plan, params).grid
    flat = predict(sc, build_plan(sc, PlanParams("lawnmower", 60.0, 5.0, spacing_m=spacing))[0]
                   ).grid
    assert zoomed.frames == flat.frames
    seen_z, seen_f = zoomed.n_obs > 0, flat.n_obs > 0
    assert zoomed.n_obs[seen_z].mean() < 0.5 * flat.n_obs[seen_f].mean()
    per_look = [float((g.log_miss_d[s] / g.n_obs[s]).mean())
                for g, s in ((zoomed, seen_z), (flat, seen_f))]
    assert per_look[0] < 1.5 * per_look[1] < 0  # log(1 - P) per look
    with pytest.raises(ConfigError, match="outside the calibrated"):
        build_plan(sc, PlanParams("lawnmower", 60.0, 5.0, zoom_hfov_deg=10.0))
    assert {p.zoom_hfov_deg for p in candidates(["lawnmower"], [30.0, 60.0], [5.0], [0.0],
                                                None, [0.2], [66.0, 28.0])} == {66.0, 28.0}
    fixed = scenario_of(mission_from_dict(zf.mission("none")))
    with pytest.raises(ConfigError, match="needs camera.zoom fov_status"):
        fixed.swath_width_m(60.0, zoom_hfov_deg=28.0)


def test_the_daemon_counts_zoom_reports_of_another_camera(tmp_path):
    """A second camera (component 101) reporting its own field of view changes nothing in
    the grid; its reports are counted in the status's faults."""
    cfg = load_serve_config(zf.write_mission(
        tmp_path / "serve.yaml", zf.mission(component_id=100), service=True))
    grids = []
    other = zf.frames(lambda t: 40.0, camera_component=101)
    for extra in (False, True):
        data = []
        for ours, theirs in zip(zf.frames(), other, strict=True):
            data.append(ours)
            if extra and theirs[6] == 101:  # MAVLink 2: byte 6 is the sender's component
                data.append(theirs)
        feed = LinkFeed(cfg)
        for i, frame in enumerate(data):
            feed.feed(frame, 0.01 * i)
        feed.tick(100.0)
        grids.append(feed.live)
    assert grids[1].counters.faults["zoom_reports_other_camera"] == 201
    np.testing.assert_array_equal(grids[0].grid.log_miss_d, grids[1].grid.log_miss_d)


def test_the_daemon_asks_for_the_zoom_report_it_follows(tmp_path):
    from pdcov.service.link_setup import link_requests

    for doc, expected in ((zf.mission(), {271}), (zf.mission("none"), set())):
        cfg = load_serve_config(zf.write_mission(tmp_path / "s.yaml", doc, service=True))
        asked = set(link_requests(cfg)[0])
        assert asked & {259, 260, 271} == expected


def test_boxes_of_a_zoomed_frame_are_located_with_its_camera():
    """A box centred 140 px right of the principal point, seen straight down from 60 m:
    60 * 140 / f on the ground, f the frame's focal length (the wide one would put it 2.6x
    farther out)."""
    from pdcov.core.detections import Box
    from pdcov.detection.candidates import DetectionTracker

    m = mission_from_dict(zf.mission())
    assert m.first_camera.zoom is not None
    narrow = m.first_camera.zoom.lens.camera(math.radians(28.0))
    R_down = np.array([[1.0, 0, 0], [0, -1, 0], [0, 0, -1]])
    pose = CameraPose(R_down, np.array([40.0, 40.0, 60.0]), 1.0)
    box = Box("person", 0.9, 159.5 + 140 - 2.0, 119.5 - 2.0, 4.0, 4.0)
    xs = []
    for camera in (narrow, None):
        (det,) = DetectionTracker.for_mission(m).frame(pose, 1.0, [box], camera=camera)
        xs.append(det.r_enu_m[0] - 40.0)
    f_narrow = 160 / math.tan(math.radians(14.0))
    assert xs[0] == pytest.approx(60 * 140 / f_narrow, abs=0.1)
    assert xs[1] == pytest.approx(60 * 140 / m.first_camera.camera.K[0, 0], abs=0.3)
