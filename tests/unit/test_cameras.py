"""A mission of several cameras (``cameras``): the one rule that combines their grids
(``core.combine_cameras``: one latent per detector model), the config's checks of the
cameras' ids, gimbal devices and models, and ``pdcov serve`` following every camera: the
daemon fed a two-camera flight's bytes gives ``pdcov evaluate``'s grids of its tlog."""

from __future__ import annotations

import io

import numpy as np
import pytest

from pdcov.bus.status import decode_status, encode_status
from pdcov.config.load import load_mission, mission_from_dict
from pdcov.core.camera import CameraModel
from pdcov.core.combine_cameras import combine_cameras
from pdcov.core.detector import DetectorModel
from pdcov.core.domain import GridGeometry
from pdcov.core.grid import CoverageGrid
from pdcov.core.looks import LooksConfig, LooksRule
from pdcov.core.pose import CameraPose
from pdcov.errors import ConfigError
from pdcov.service.settings import load_serve_config
from tests.support import two_camera_flight as tcf
from tests.support.evaluate_inputs import run
from tests.support.link_feed import LinkFeed

R_DOWN = np.array([[1.0, 0, 0], [0, -1, 0], [0, 0, -1]])  # optical axis down


def _model(scale: float, rho: float | None) -> DetectorModel:
    doc = DetectorModel.illustrative().to_dict()
    doc["p_detect"] = [scale * p for p in doc["p_detect"]]
    if rho is not None:
        doc.update(looks={"correlation": [rho] * len(doc["p_detect"])})
    return DetectorModel.from_dict(doc)


def _grid(det: DetectorModel, rule: LooksRule, cam: CameraModel | None = None
          ) -> CoverageGrid:
    g = GridGeometry(0.0, 0.0, 1.0, 40, 40)
    return CoverageGrid(g, np.ones(g.shape, bool), cam or CameraModel.from_fov(320, 240, 60.0),
                        det, looks=LooksConfig(rule))


def _poses(n: int, x0: float) -> list[CameraPose]:
    return [CameraPose(R_DOWN, np.array([x0 + 1.5 * k, 20.0, 12.0 + k]), float(k))
            for k in range(n)]


def _independent_holder() -> CoverageGrid:
    return _grid(DetectorModel.illustrative(), LooksRule.INDEPENDENT)


@pytest.mark.parametrize("rule", [LooksRule.CORRELATED, LooksRule.VIEWPOINT])
def test_cameras_of_one_model_share_its_latent(rule):
    """Two cameras with the same detector model (equal but separate objects, as two
    entries naming one file) give the grid of one camera that took all their frames."""
    a, b = _model(1.0, 0.3), _model(1.0, 0.3)
    cam_b = CameraModel.from_fov(640, 480, 45.0)
    one, two = _grid(a, rule), _grid(b, rule, cam_b)
    alone = _grid(a, rule)
    for p in _poses(6, 10.0):
        one.update(p)
        alone.update(p)
    for p in _poses(5, 14.0):
        two.update(p)
        alone.update_with(p, cam_b)
    both = _independent_holder()
    combine_cameras(both, [one, two])
    assert (one.n_obs > 0).sum() > 200 and ((one.n_obs > 0) & (two.n_obs > 0)).sum() > 100
    np.testing.assert_array_equal(both.log_miss_d, alone.log_miss_d)
    np.testing.assert_array_equal(both.n_obs, alone.n_obs)
    # P_FA: the same float32 sums in another order.
    np.testing.assert_allclose(both.log_miss_fa, alone.log_miss_fa, rtol=1e-6)
    # Not the independent product of the two grids: a shared latent gives less.
    product = 1 - (1 - one.pd) * (1 - two.pd)
    seen = (one.n_obs > 0) & (two.n_obs > 0)
    assert (both.pd[seen] < product[seen] - 1e-4).mean() > 0.9


@pytest.mark.parametrize("rule", list(LooksRule))
def test_cameras_of_different_models_are_independent(rule):
    """A visible and a thermal model: P_D = 1 - (1 - P_visible)(1 - P_thermal) of each
    camera's own grid, under every looks rule."""
    rho = None if rule is LooksRule.INDEPENDENT else 0.3
    vis, th = _grid(_model(1.0, rho), rule), _grid(_model(0.6, rho), rule)
    for p in _poses(6, 10.0):
        vis.update(p)
    for p in _poses(4, 13.0):
        th.update(p)
    both = _independent_holder()
    combine_cameras(both, [vis, th])
    seen = (vis.n_obs > 0) & (th.n_obs > 0)
    assert seen.sum() > 100
    np.testing.assert_allclose(both.pd, 1 - (1 - vis.pd) * (1 - th.pd), atol=2e-6)
    assert (both.pd[seen] > vis.pd[seen] + 1e-3).all()
    assert both.frames == 10


@pytest.mark.parametrize("rule", list(LooksRule))
def test_one_camera_combined_is_its_grid_but_for_the_looks_state(rule):
    """Why one camera's grid is the mission's grid, not combined (``Mission.several_cameras``):
    combining one grid gives its P_D, P_FA, counts, limiting, clocks and frame counts bit for
    bit (and, with independent looks, the same grid.npz bytes), but as an independent-looks
    grid: the correlated or viewpoint looks state its grid.npz and checkpoint keep is lost."""
    rho = None if rule is LooksRule.INDEPENDENT else 0.3
    g = GridGeometry(0.0, 0.0, 1.0, 40, 40)
    kw = {"min_revisit_s": 1.0, "exposure_s": 0.01}
    one = CoverageGrid(g, np.ones(g.shape, bool), CameraModel.from_fov(320, 240, 60.0),
                       _model(1.0, rho), looks=LooksConfig(rule), **kw)
    for p in _poses(8, 10.0):
        one.update(p)
    one.refresh()
    both = CoverageGrid(g, one.mask, one.camera, one.detector, **kw)
    combine_cameras(both, [one])
    for key in ("log_miss_d", "log_miss_fa", "n_obs", "limiting", "last_obs_s"):
        assert getattr(both, key).tobytes() == getattr(one, key).tobytes(), key
    assert (both.frames, both.frames_blurred, both.latest_frame_t_s) == \
        (one.frames, one.frames_blurred, one.latest_frame_t_s)
    assert one.frames == 8 and one.n_obs.sum() > 200
    a, b = io.BytesIO(), io.BytesIO()
    one.write_npz(a)
    both.write_npz(b)
    assert (a.getvalue() == b.getvalue()) is (rule is LooksRule.INDEPENDENT)


def test_a_window_combined_frame_by_frame_equals_the_whole_grid_combined():
    """The daemon combines the window each frame touched; evaluate the whole grid once."""
    rule = LooksRule.CORRELATED
    grids = [_grid(_model(1.0, 0.3), rule), _grid(_model(1.0, 0.3), rule),
             _grid(_model(0.5, 0.1), rule)]
    live, offline = _independent_holder(), _independent_holder()
    for k, p in enumerate(_poses(12, 8.0)):
        g = grids[k % 3]
        g.update(p)
        assert g.touched is not None
        combine_cameras(live, grids, g.touched)
    combine_cameras(offline, grids)
    for key in ("log_miss_d", "log_miss_fa", "n_obs", "limiting"):
        np.testing.assert_array_equal(getattr(live, key), getattr(offline, key), err_msg=key)


def test_a_frame_detector_without_blur_bins_in_a_blurring_grid_is_refused():
    from tests.support.blur_detector import blur_detector

    g = GridGeometry(0.0, 0.0, 1.0, 20, 20)
    grid = CoverageGrid(g, np.ones(g.shape, bool), CameraModel.from_fov(320, 240, 60.0),
                        blur_detector(), exposure_s=0.01)
    pose = CameraPose(R_DOWN, np.array([10.0, 10.0, 12.0]), 0.0)
    with pytest.raises(ValueError, match="has no blur bins"):
        grid.update_with(pose, detector=DetectorModel.illustrative())
    assert grid.frames == 0


def _doc(**changes) -> dict:
    doc = tcf.mission()
    for i, entry in changes.items():
        doc["cameras"][int(i[1:])] = entry(doc["cameras"][int(i[1:])])
    return doc


@pytest.mark.parametrize(("change", "message"), [
    ({"c1": lambda e: {**e, "camera": {**e["camera"], "zoom_lens": {
        **e["camera"]["zoom_lens"], "component_id": 100}}}},
     "cameras[1].camera.zoom_lens.component_id: component 100, camera_device_id 0 is also "
     "cameras[0]'s"),
    ({"c1": lambda e: {**e, "camera": {**e["camera"], "zoom_lens": {
        **e["camera"]["zoom_lens"], "component_id": 154}}}},
     "cameras[1].camera.zoom_lens.component_id: expected a MAVLink camera component "
     "100..105 (camera_device_id 0), got 154"),
    ({"c1": lambda e: {**e, "camera": {**e["camera"], "zoom_lens": {
        k: v for k, v in e["camera"]["zoom_lens"].items() if k != "component_id"}}}},
     "cameras[1].camera.zoom_lens.component_id: missing"),
    ({"c1": lambda e: {**e, "mount": {"type": "gimbal", "attitude_frame": "body",
                                      "instance": 1}}},
     "cameras[1].mount: gimbal device 1 (mount.instance) is also cameras[0]'s, with other "
     "settings"),
])
def test_bad_camera_ids_say_which_camera(tmp_path, change, message):
    path = tcf.write_mission(tmp_path / "bad.yaml", _doc(**change))
    with pytest.raises(ConfigError) as err:
        load_mission(path)
    assert f"{path}: {message}" in str(err.value)


def test_a_mission_is_a_list_of_cameras_in_config_order():
    """The single camera/mount/detector form is one camera named 'camera'; a list, its
    entries in order. A rule that cannot tell cameras apart refuses several, naming the
    key it was asked by (``only_camera``); a list of one entry is one camera."""
    doc = tcf.mission()
    m = mission_from_dict(doc, source="m.yaml")
    assert [c.name for c in m.cameras] == ["visible", "thermal"] and m.several_cameras
    assert m.first_camera is m.cameras[0]
    with pytest.raises(ConfigError, match=r"^m.yaml: log.frame_source: capture with a "):
        m.cameras_frame_source("capture", "log.frame_source")
    assert m.cameras_frame_source(None, "log.frame_source") == "rate"
    one = mission_from_dict(dict(doc, cameras=doc["cameras"][1:]))
    assert [c.name for c in one.cameras] == ["thermal"] and not one.several_cameras
    assert one.only_camera("--poses", "why") is one.cameras[0]
    assert one.cameras_frame_source("capture", "--frame-source") == "capture"
    flat = {k: v for k, v in doc.items() if k != "cameras"}
    entry = doc["cameras"][0]
    single = mission_from_dict({**flat, **{k: entry[k] for k in ("camera", "mount",
                                                                 "detector")}})
    (cam,), visible = single.cameras, m.cameras[0]
    assert (cam.name, cam.mount, cam.frame_rate_hz) == ("camera", visible.mount, 2.0)
    np.testing.assert_array_equal(cam.camera.K, visible.camera.K)


def test_cameras_may_share_a_gimbal_and_an_autopilot_camera_id(tmp_path):
    """Two cameras on one gimbal device with their own lever arms, and autopilot-attached
    cameras (component 1, camera_device_id 1 and 2), are a valid mission."""
    def same_gimbal(e):
        return {**e, "mount": {"type": "gimbal", "attitude_frame": "flags", "instance": 1,
                               "lever_arm_frd_m": [0.05, 0, 0]}}

    def attached(device):
        def f(e):
            return {**e, "camera": {**e["camera"], "zoom_lens": {
                **e["camera"]["zoom_lens"], "component_id": 1, "camera_device_id": device}}}
        return f

    m = mission_from_dict(_doc(c1=same_gimbal))
    assert [c.mount.instance for c in m.cameras] == [1, 1]
    m = mission_from_dict(_doc(c0=attached(1), c1=attached(2)))
    assert [c.zoom.camera_id for c in m.cameras] == [(1, 1), (1, 2)]


def test_an_extra_camera_without_looks_is_named_under_correlated_looks():
    doc = tcf.mission("correlated")
    doc["cameras"][1]["detector"] = tcf.thermal_detector(looks=False)
    with pytest.raises(ConfigError, match=r"m.yaml: cameras\[1\].detector: coverage.looks "
                                          "correlated needs the detector model's looks"):
        mission_from_dict(doc, source="m.yaml")
    assert mission_from_dict(tcf.mission("correlated")).looks.rule is LooksRule.CORRELATED


def test_serve_refuses_capture_frames_with_a_cameras_list(tmp_path):
    doc = dict(tcf.mission(), log={"frame_source": "capture"})
    with pytest.raises(ConfigError, match="log.frame_source: capture with a cameras list"):
        load_serve_config(tcf.write_mission(tmp_path / "capture.yaml", doc))


@pytest.mark.parametrize("log_doc, option, named", [
    ({"frame_source": "capture"}, [], "m.yaml: log.frame_source: capture"),
    ({}, ["--frame-source", "capture"], "--frame-source: capture")])
def test_evaluate_refuses_capture_frames_with_a_cameras_list(tmp_path, capsys, log_doc, option,
                                                              named):
    """The daemon's rule: one line naming where the capture source was asked for, exit 2,
    before the log is read (the log given does not exist)."""
    config = tcf.write_mission(tmp_path / "m.yaml", dict(tcf.mission(), log=log_doc))
    assert run("evaluate", "--config", str(config), "--log", str(tmp_path / "none.tlog"),
               "--out", str(tmp_path / "out"), "--no-progress", *option) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and named in err and "cameras list" in err, err
    assert not (tmp_path / "out").exists()


# -- the daemon and pdcov evaluate ------------------------------------------------------------


def test_a_watcher_refuses_a_bad_frames_by_camera(tmp_path):
    """frames.by_camera is checked like the other counts: a negative one is refused."""
    from pdcov.bus.errors import BusPayloadError

    feed = LinkFeed(load_serve_config(tcf.write_mission(tmp_path / "m.yaml", tcf.mission())))
    fields = feed.status()
    assert fields["frames"]["by_camera"] == {"visible": 0, "thermal": 0}
    decode_status(encode_status(fields))
    fields["frames"]["by_camera"] = {"visible": -1}
    with pytest.raises(BusPayloadError, match="by_camera"):
        decode_status(encode_status(fields))
