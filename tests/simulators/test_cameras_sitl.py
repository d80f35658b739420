"""Two cameras flown by the simulator: a visible camera on the simulated gimbal (its device
status, mount instance 1) whose lens the mission zooms (the simulator's MAVLink camera,
component 100, CAMERA_FOV_STATUS), and a thermal camera on a fixed mount with its own
detector model and frame rate. The daemon's decisions fed the flight's bytes give
``pdcov evaluate``'s grids of its tlog, the combined one and each camera's, cell for cell,
and the combined grid is neither camera's alone."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pdcov.config.load import load_mission
from pdcov.core.grid import CoverageGrid
from pdcov.service.checkpoint import CHECKPOINT_NAME
from pdcov.service.settings import load_serve_config
from tests.support import two_camera_flight as tcf
from tests.support.checkpoint_files import read_checkpoint
from tests.support.evaluate_inputs import load_grid, run
from tests.support.link_feed import LAT_DEG, LON_DEG, feed_tlog
from tests.support.serve_harness import fly_udp, offline, same


def _survey(tmp_path: Path, vehicle_id: str = "twocam") -> tuple[dict, Path]:
    """The two cameras' mission (visible on gimbal instance 1 zooming by the simulator's
    camera 100, thermal fixed at 1 Hz) and its plan: take off to 40 m, fly 30 m north,
    zoom in (ZOOM_TYPE_RANGE 100 %), fly 30 m back."""
    doc = dict(tcf.mission(), vehicle_id=vehicle_id)
    visible, thermal = doc["cameras"]
    visible["camera"] = dict(visible["camera"], zoom_lens={"min_hfov_deg": 20.0,
                                                           "component_id": 100})
    visible["mount"] = {"type": "gimbal", "attitude_frame": "flags", "instance": 1}
    thermal["camera"] = {k: v for k, v in thermal["camera"].items()
                         if k not in ("zoom", "zoom_lens")}
    thermal["camera"]["frame_rate_hz"] = 1.0
    doc["domain"]["polygon_enu_m"] = [[-60, -60], [60, -60], [60, 60], [-60, 60]]
    north = 30 / 111_320
    rows = [(0, 1, 0, 16, 0, 0, LAT_DEG, LON_DEG, 0), (1, 0, 3, 178, 0, 4, 0, 0, 0),
            (2, 0, 3, 16, 2, 0, LAT_DEG, LON_DEG, 40), (3, 0, 3, 16, 0, 0, LAT_DEG + north,
                                                        LON_DEG, 40),
            (4, 0, 3, 531, 2, 100, 0, 0, 0), (5, 0, 3, 16, 2, 0, LAT_DEG, LON_DEG, 40)]
    plan = tmp_path / "leg.waypoints"
    plan.write_text("QGC WPL 110\n" + "".join(
        f"{s}\t{c}\t{fr}\t{cmd}\t{p1}\t{p2}\t0\t0\t{la}\t{lo}\t{alt}\t1\n"
        for s, c, fr, cmd, p1, p2, la, lo, alt in rows))
    return doc, plan


def _neither_alone(combined: np.ndarray, vis: CoverageGrid, th: CoverageGrid) -> None:
    """The combined P_D is above each camera's alone where both saw a cell unsaturated."""
    seen = (vis.n_obs > 0) & (th.n_obs > 0) & (vis.pd < 0.99) & (th.pd < 0.99)
    assert seen.sum() > 50
    assert (combined[seen] > vis.pd[seen] + 1e-3).all()
    assert (combined[seen] > th.pd[seen] + 1e-3).all()


def test_a_simulated_two_camera_survey_gives_the_same_grids_live_and_offline(tmp_path):
    from pdcov_sitl.fly import FlyOptions, fly

    doc, plan = _survey(tmp_path)
    config = tcf.write_mission(tmp_path / "mission.yaml", doc)
    fly(FlyOptions(mission=load_mission(config), plan_path=plan, out_dir=tmp_path / "run",
                   speed=0, gimbal_mode="ardupilot-device", connect="udpout:127.0.0.1:9"))
    tlog = tmp_path / "run" / "flight.tlog"
    out = tmp_path / "evaluate"
    assert run("evaluate", "--config", str(config), "--log", str(tlog), "--out", str(out),
               "--no-progress") == 0

    feed = feed_tlog(load_serve_config(config), tlog)
    live = feed.live
    grids = {"combined": (live.grid, load_grid(out))} | {
        c.cam.name: (c.grid, load_grid(out / "cameras" / c.cam.name)) for c in live.cameras}
    for name, (grid, off) in grids.items():
        assert grid.frames == int(off["frames"]), name
        for key in ("log_miss_d", "log_miss_fa", "n_obs", "limiting"):
            np.testing.assert_array_equal(getattr(grid, key), off[key],
                                          err_msg=f"{name} {key}")
    vis, th = grids["visible"][0], grids["thermal"][0]
    print(f"frames: visible {vis.frames}, thermal {th.frames}; mean P_D visible "
          f"{vis.pd[vis.mask].mean():.3f}, thermal {th.pd[th.mask].mean():.3f}, combined "
          f"{live.grid.pd[vis.mask].mean():.3f}")
    assert vis.frames > 20 and th.frames > 10
    assert len(vis._cameras) > 1  # the zoom was followed: frames at another K
    _neither_alone(live.grid.pd, vis, th)
    status = feed.status()
    assert status["frames"]["by_camera"] == {"visible": vis.frames, "thermal": th.frames}


def test_a_two_camera_flight_into_the_daemon_equals_evaluate(tmp_path):
    """The same survey flown by the simulator over UDP into a running ``pdcov serve``: the
    grid a Zenoh subscriber rebuilds from its tiles (and its snapshot) is ``pdcov
    evaluate``'s of the simulator's tlog, and the final checkpoint's per-camera grids are
    evaluate's per-camera grids."""
    doc, plan = _survey(tmp_path, "sim1")
    out = fly_udp(tmp_path, doc, plan, "--gimbal", "ardupilot-device")
    ref = offline(out["cfg"], tmp_path / "fly" / "flight.tlog", tmp_path / "off")
    same(out["grid"], ref, "tiles")
    same(out["snap"], ref, "snapshot")
    ck = tmp_path / "st" / CHECKPOINT_NAME
    cams = {}
    for name in ("visible", "thermal"):
        with np.load(tmp_path / "off" / "cameras" / name / "grid.npz") as z:
            off = {k: z[k] for k in z.files}
        mine = read_checkpoint(ck, name)
        for key in ("log_miss_d", "log_miss_fa", "n_obs", "limiting", "frames"):
            np.testing.assert_array_equal(mine[key], off[key], err_msg=f"{name} {key}")
        cams[name] = int(off["frames"])
    assert out["st"]["frames"]["by_camera"] == cams and min(cams.values()) > 10
    print(f"frames by camera {cams}; combined frames {int(ref['frames'])}")
