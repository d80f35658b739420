"""Two cameras through the daemon's decisions for whole flights: it follows both as evaluate
does, and a two-camera checkpoint resumes every camera."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from pdcov.bus.status import decode_status, encode_status
from pdcov.config.load import mission_from_dict
from pdcov.core.combine_cameras import combine_cameras
from pdcov.core.grid import CoverageGrid
from pdcov.service.checkpoint import CHECKPOINT_NAME, resume, write_checkpoint
from pdcov.service.settings import load_serve_config, mission_hash
from tests.support import two_camera_flight as tcf
from tests.support import zoom_flight as zf
from tests.support.evaluate_inputs import load_grid, run
from tests.support.link_feed import LinkFeed


def _fly(tmp_path, looks: str = "independent"):
    """The flight's bytes to the daemon's decisions and as a tlog to pdcov evaluate: the
    feed, the evaluate run's folder and the mission config."""
    config = tcf.write_mission(tmp_path / f"{looks}.yaml", tcf.mission(looks))
    data = tcf.frames()
    tlog = zf.write_tlog(tmp_path / "flight.tlog", data)
    out = tmp_path / f"run-{looks}"
    assert run("evaluate", "--config", str(config), "--log", str(tlog), "--out", str(out),
               "--no-progress") == 0
    feed = LinkFeed(load_serve_config(config))
    for i, d in enumerate(data):
        feed.feed(d, 0.001 * i)
    feed.tick(1e4)
    return feed, out, config


def _same(live: CoverageGrid, offline: dict, what: str) -> None:
    assert live.frames == int(offline["frames"]), what
    for key in ("log_miss_d", "log_miss_fa", "n_obs", "limiting"):
        np.testing.assert_array_equal(getattr(live, key), offline[key], err_msg=f"{what} {key}")


@pytest.mark.parametrize("looks", ["independent", "correlated"])
def test_the_daemon_follows_both_cameras_as_evaluate_does(tmp_path, looks):
    """Visible (gimbal device 1, CAMERA_FOV_STATUS of component 100, 2 Hz) and thermal
    (fixed, CAMERA_SETTINGS of component 101, 1.5 Hz, another detector model): the daemon's
    grid is evaluate's cell for cell, each camera's too; it is neither camera's alone, and
    the third camera's reports are counted, not used."""
    feed, out, _config = _fly(tmp_path, looks)
    live = feed.live
    offline = load_grid(out)
    per_camera = {c.cam.name: c.grid for c in live.cameras}
    assert list(per_camera) == ["visible", "thermal"]
    _same(live.grid, offline, "combined")
    for name, grid in per_camera.items():
        _same(grid, load_grid(out / "cameras" / name), name)
    vis, th = per_camera["visible"], per_camera["thermal"]
    assert vis.frames > 30 and th.frames > 22  # 2 Hz and 1.5 Hz over about 19 s
    # Both zooms were followed: the frames' focal lengths changed mid-flight.
    assert len({id(k) for k in vis._cameras}) > 1 and len(th._cameras) > 1
    seen = (vis.n_obs > 0) & (th.n_obs > 0)
    assert seen.sum() > 200
    pd = live.grid.pd
    open_ = seen & (vis.pd < 0.99) & (th.pd < 0.99)  # not saturated by either alone
    assert open_.sum() > 50
    assert (pd[open_] > vis.pd[open_] + 1e-3).all() and (pd[open_] > th.pd[open_] + 1e-3).all()
    np.testing.assert_allclose(pd, 1 - (1 - vis.pd) * (1 - th.pd), atol=2e-6)
    status = decode_status(encode_status(feed.status()))  # what a watcher reads
    assert status["frames"]["by_camera"] == {"visible": vis.frames, "thermal": th.frames}
    assert status["frames"]["used"] == vis.frames + th.frames == status["frames"]["grid"]
    assert status["faults"]["zoom_reports_other_camera"] == int(tcf.SECONDS * 10) + 1
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["cameras"]["thermal"]["frames"] == th.frames


def test_a_two_camera_checkpoint_resumes_every_camera(tmp_path):
    """The checkpoint holds the combined grid (a Zarr store any reader opens) and each
    camera's own grid, lattice and count; a daemon stopped half-way and resumed from it
    continues every camera where it was."""
    from pdcov.service.core import ServiceCore

    config = tcf.write_mission(tmp_path / "m.yaml", tcf.mission())
    cfg = load_serve_config(config)
    m = cfg.mission
    fresh = m.new_mission_grid()
    mhash = mission_hash(m, fresh)
    data = tcf.frames()
    half = len(data) // 2  # 0.02 s apart: the mount parameters' wait ends before it
    whole, first = LinkFeed(cfg), LinkFeed(cfg)
    for i, d in enumerate(data):
        whole.feed(d, 0.02 * i)
        if i < half:
            first.feed(d, 0.02 * i)
    whole.tick(1e4)
    state = tmp_path / "ck"
    state.mkdir()
    meta = dataclasses.replace(first.core.checkpoint_meta(0.0), mission_hash=mhash)
    assert meta.cameras is not None and meta.cameras["visible"].frames_used > 10
    write_checkpoint(state / CHECKPOINT_NAME, first.live.grid, meta,
                     first.live.checkpoint_cameras)
    r = resume(state, mhash, fresh, {c.name: m.new_grid(c) for c in m.cameras})
    assert r.grid is not None and r.cameras is not None and r.meta is not None, r.message
    second = LinkFeed(cfg)
    second.core = ServiceCore(cfg, r.grid, 0.0, mission_hash=mhash, resumed=r.meta,
                              camera_grids=r.cameras)
    for i, d in enumerate(data[half:], start=half):
        second.feed(d, 0.02 * i)
    second.tick(1e4)
    # Each camera continues its own lattice (its last frame is the uninterrupted one's);
    # the frame whose samples straddle the restart is lost, as with one camera.
    for done, cam in zip(second.live.cameras, whole.live.cameras, strict=True):
        before = meta.cameras[cam.cam.name].frames_used
        assert done.schedule.last_frame_t_s == cam.schedule.last_frame_t_s, cam.cam.name
        assert before < done.grid.frames <= cam.grid.frames <= done.grid.frames + 1
        assert done.used == done.grid.frames
    check = m.new_mission_grid()
    combine_cameras(check, second.live.camera_grids)
    for key in ("log_miss_d", "log_miss_fa", "n_obs", "limiting"):
        np.testing.assert_array_equal(getattr(second.live.grid, key), getattr(check, key))
    assert second.status()["frames"]["by_camera"] == {
        c.cam.name: c.grid.frames for c in second.live.cameras}
    # Another camera list is another mission: its checkpoint is set aside.
    other = mission_from_dict(dict(tcf.mission(), cameras=tcf.cameras()[:1]))
    assert mission_hash(other, other.new_mission_grid()) != mhash
