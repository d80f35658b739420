"""`pdcov evaluate` of several logs (--log A --log B, or a folder): the map equals each log
evaluated alone and the grids merged with CoverageGrid.merge in log order, whether the logs
ran in this process or in worker processes; folders, repeated logs, logs in different ENU
frames and an unreadable log among several are handled with a clear message."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from pdcov.core.geodesy import Origin
from tests.support.evaluate_inputs import ORIGIN, mission_doc, run, write_config
from tests.support.sortie_logs import assert_same_map, one_by_one, write_sorties

CORRELATED = {"version": 4, "input_size_px": None, "bin_edges_px": [4, 16, 40, 100, 400],
              "p_detect": [0.2, 0.4, 0.5, 0.3], "p_false_alarm": [0.02, 0.03, 0.04, 0.05],
              "fa_rate_per_mpx": [0.05, 0.06, 0.08, 0.1],
              "looks": {"correlation": [0.4, 0.3, 0.3, 0.5]}}


def gpx_tracks(run_dir: Path) -> list:
    import gpxpy

    return gpxpy.parse((run_dir / "pdcov.gpx").read_text()).tracks


def points(segment) -> list[tuple[float, float, float]]:
    return [(p.latitude, p.longitude, p.elevation) for p in segment.points]


def evaluate(config: Path, out: Path, *logs: Path, more: tuple[str, ...] = ()) -> int:
    return run("evaluate", "--config", str(config), *(a for p in logs for a in ("--log", str(p))),
               "--out", str(out), "--no-progress", *more)


@pytest.mark.parametrize("n, jobs", [(2, "1"), (3, "2")])
def test_logs_merge_as_one_by_one(tmp_path, capsys, n, jobs):
    config = write_config(tmp_path, mission_doc())
    logs = write_sorties(tmp_path / "logs", n)
    assert evaluate(config, tmp_path / "merged", *logs, more=("--jobs", jobs)) == 0
    out = capsys.readouterr().out
    how = "in this process" if jobs == "1" else f"in {jobs} worker processes"
    assert f"logs: {n} merged in log order ({how})" in out
    assert f"log {n} of {n}: {logs[-1]}" in out
    alone = one_by_one(config, logs, tmp_path)
    assert_same_map(tmp_path / "merged", alone)
    metrics = json.loads((tmp_path / "merged" / "metrics.json").read_text())
    each = [json.loads((tmp_path / f"alone_{k}" / "metrics.json").read_text())
            for k in range(n)]
    assert metrics["frames"] == alone.frames == sum(m["frames"] for m in each)
    assert [x["log"] for x in metrics["logs"]] == [str(p) for p in logs]
    assert [x["frames"] for x in metrics["logs"]] == [m["frames"] for m in each]
    # Per log as a run of that log alone says; the totals added up.
    assert [x["telemetry_faults"] for x in metrics["logs"]] == \
        [m["telemetry_faults"] for m in each]
    assert metrics["telemetry_faults"]["frames_without_estimator_status"] == alone.frames
    assert metrics["frames_skipped"] == {}
    # Each sortie saw cells the others did not: the merged map covers more than any one.
    assert metrics["cells_observed"] > max(m["cells_observed"] for m in each)
    # pdcov.gpx: the vehicle's track, a segment per log, each as that log's alone.
    (track,) = gpx_tracks(tmp_path / "merged")
    assert [points(s) for s in track.segments] == [
        points(gpx_tracks(tmp_path / f"alone_{k}")[0].segments[0]) for k in range(n)]


def test_one_log_keeps_its_metrics_and_lists_itself(tmp_path):
    config = write_config(tmp_path, mission_doc())
    (log,) = write_sorties(tmp_path / "logs", 1)
    assert evaluate(config, tmp_path / "run", log) == 0
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["logs"] == [{"log": str(log), "frames": metrics["frames"],
                                "telemetry_faults": metrics["telemetry_faults"],
                                "frames_skipped": metrics["frames_skipped"],
                                "warnings": []}]


def test_worker_processes_give_the_map_of_one_process(tmp_path):
    """The grids cross the process boundary as snapshot bytes, looks state and all."""
    config = write_config(tmp_path, mission_doc(detector=CORRELATED,
                                                coverage={"looks": "correlated"}))
    logs = write_sorties(tmp_path / "logs", 3)
    assert evaluate(config, tmp_path / "one", *logs, more=("--jobs", "1")) == 0
    assert evaluate(config, tmp_path / "two", *logs, more=("--jobs", "2")) == 0
    with np.load(tmp_path / "one" / "grid.npz") as a, np.load(tmp_path / "two" / "grid.npz") as b:
        assert a.files == b.files and "looks_counts" in a.files
        for name in a.files:
            np.testing.assert_array_equal(a[name], b[name], err_msg=name)
    assert (tmp_path / "one" / "metrics.json").read_text() == \
        (tmp_path / "two" / "metrics.json").read_text()


def test_a_folder_is_its_logs_by_name(tmp_path, capsys):
    config = write_config(tmp_path, mission_doc())
    logs = write_sorties(tmp_path / "logs", 3)
    (tmp_path / "logs" / "notes.txt").write_text("sorties of Saturday\n")
    (tmp_path / "logs" / "older").mkdir()
    assert evaluate(config, tmp_path / "folder", tmp_path / "logs") == 0
    assert evaluate(config, tmp_path / "listed", *logs) == 0
    metrics = json.loads((tmp_path / "folder" / "metrics.json").read_text())
    assert [x["log"] for x in metrics["logs"]] == [str(p) for p in logs]
    with np.load(tmp_path / "folder" / "grid.npz") as a, \
            np.load(tmp_path / "listed" / "grid.npz") as b:
        np.testing.assert_array_equal(a["log_miss_d"], b["log_miss_d"])
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "notes.txt").write_text("")
    capsys.readouterr()
    assert evaluate(config, tmp_path / "none", tmp_path / "empty") == 2
    err = capsys.readouterr().err
    assert f"{tmp_path / 'empty'}: no flight log in this folder" in err
    assert not (tmp_path / "none").exists()


def test_a_log_given_twice_is_refused(tmp_path, capsys):
    config = write_config(tmp_path, mission_doc())
    logs = write_sorties(tmp_path / "logs", 2)
    assert evaluate(config, tmp_path / "run", logs[0], logs[1], logs[0]) == 2
    assert f"{logs[0]}: given twice" in capsys.readouterr().err
    assert evaluate(config, tmp_path / "run", tmp_path / "logs", logs[1]) == 2
    assert f"{logs[1]}: given twice" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


def test_logs_in_different_enu_frames_are_refused(tmp_path, capsys):
    """Without origin.ground_alt_msl_m each log's origin is its home's: two homes at
    different heights are two frames, and their maps would not line up."""
    doc = mission_doc()
    del doc["origin"]["ground_alt_msl_m"]
    config = write_config(tmp_path, doc)
    higher = Origin(ORIGIN.lat_deg, ORIGIN.lon_deg, ORIGIN.ground_alt_msl_m + 2.0)
    logs = write_sorties(tmp_path / "logs", 3, [ORIGIN, ORIGIN, higher])
    assert evaluate(config, tmp_path / "run", *logs, more=("--jobs", "2")) == 2
    err = capsys.readouterr().err
    assert f"{logs[0]} and {logs[2]} have different ENU origins" in err
    assert "ground 5.00 and 7.00 m MSL" in err and "origin.ground_alt_msl_m" in err
    assert not (tmp_path / "run").exists()
    # Homes at one height: one frame, merged.
    assert evaluate(config, tmp_path / "run", *logs[:2], more=("--jobs", "1")) == 0


@pytest.mark.parametrize("jobs", ["1", "2"])
def test_an_unreadable_log_among_several_ends_the_command(tmp_path, capsys, jobs):
    config = write_config(tmp_path, mission_doc())
    write_sorties(tmp_path / "logs", 3)
    bad = tmp_path / "logs" / "sortie_1b.tlog"
    bad.write_bytes(b"\x00 not a tlog " * 100)
    assert evaluate(config, tmp_path / "run", tmp_path / "logs", more=("--jobs", jobs)) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and "Traceback" not in err
    assert not (tmp_path / "run").exists()  # no map of the others shown as the search's


def test_dask_without_its_extra_names_it(tmp_path, capsys, monkeypatch):
    config = write_config(tmp_path, mission_doc())
    logs = write_sorties(tmp_path / "logs", 2)
    monkeypatch.setitem(sys.modules, "distributed", None)  # as not installed
    assert evaluate(config, tmp_path / "run", *logs,
                    more=("--dask", "tcp://127.0.0.1:1")) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith("pdcov evaluate --dask needs distributed: "
                        "pip install 'pdcov[cluster]'"), err
    assert not (tmp_path / "run").exists()


def test_jobs_need_logs(tmp_path, capsys):
    config = write_config(tmp_path, mission_doc())
    (tmp_path / "poses.csv").write_text("t_s,x_m,y_m,z_m,qw,qx,qy,qz\n")
    assert run("evaluate", "--config", str(config), "--poses", str(tmp_path / "poses.csv"),
               "--out", str(tmp_path / "run"), "--jobs", "2") == 2
    assert "a pose CSV is one input" in capsys.readouterr().err


def _recording(tmp: Path, cfg: Path, seed: int) -> Path:
    """A hover recorded by the daemon's core with a detector's boxes on 16 frames (a person
    near the centre, a car every other frame); ``seed`` varies the boxes (and the bytes)."""
    from pdcov.bus.frames import encode_frames_v2
    from pdcov.core.detections import Box, FrameBoxes
    from tests.support.detections_driver import Driver
    from tests.support.link_feed import Hover, pack

    rng = np.random.default_rng(seed)
    d = Driver(cfg, tmp / f"rec{seed}")
    d.link(b"".join(pack(m, seq=i) for i, m in enumerate(Hover(seconds=4.0).messages())))
    d.frames(encode_frames_v2([FrameBoxes(1.2 + 0.2 * k, (
        Box("person", 0.8, 310 + rng.normal(0, 1.5), 200 + rng.normal(0, 1.5), 18.0, 40.0),
        *((Box("car", 0.6, 500.0, 100.0, 60.0, 30.0),) if k % 2 else ())))
        for k in range(16)]))
    d.core.process()
    d.tick(1.0)
    d.recorder.close()
    return next((tmp / f"rec{seed}").glob("flight-*.tlog"))


def test_detections_of_several_logs_keep_unique_ids_and_uids(tmp_path):
    import yaml

    from pdcov.bus.detections import decode_detections
    from pdcov.config.load import load_mission
    from pdcov.core.grid_snapshot import read_snapshot
    from tests.support.link_feed import FIXED, MISSION

    doc = dict(MISSION, mount=FIXED, vehicle_id="uav7")
    doc["service"] = {"state_dir": str(tmp_path / "state"), "frame_source": "zenoh",
                      "reorder_s": 0.0}
    cfg = tmp_path / "m.yaml"
    cfg.write_text(yaml.safe_dump(doc))
    logs = [_recording(tmp_path, cfg, seed) for seed in (1, 2)]
    for k, log in enumerate(logs):
        assert evaluate(cfg, tmp_path / f"alone{k}", log) == 0
    assert evaluate(cfg, tmp_path / "both", *logs, more=("--jobs", "2")) == 0
    alone = [decode_detections((tmp_path / f"alone{k}" / "detections.json").read_bytes(),
                               vehicle_id="uav7") for k in range(2)]
    both = decode_detections((tmp_path / "both" / "detections.json").read_bytes(),
                             vehicle_id="uav7")
    assert len(both["detections"]) == sum(len(a["detections"]) for a in alone) > 0
    uids = [c["uid"] for c in both["candidates"]]
    assert uids == [c["uid"] for a in alone for c in a["candidates"]]
    assert len(set(uids)) == len(uids) == 4  # the person and the car, in each log
    assert len({c["id"] for c in both["candidates"]}) == len(uids)
    assert {x["uid"] for x in both["detections"]} == set(uids)
    # Each candidate's P_D and P_FA are the merged map's at its cell.
    mission = load_mission(cfg)
    grid = mission.new_mission_grid()
    read_snapshot(tmp_path / "both" / "grid.npz").restore(grid)
    for c in both["candidates"]:
        row, col = grid.geometry.cell_of(c["x_m"], c["y_m"])
        assert c["pd"] == pytest.approx(grid.pd[row, col], abs=1e-12)
        assert c["pfa"] == pytest.approx(grid.pfa[row, col], abs=1e-12)
        assert c["pd"] > max(a["pd"] for a in alone[0]["candidates"] + alone[1]["candidates"]
                             if a["uid"] == c["uid"]) - 1e-12


REAL = Path(__file__).resolve().parents[2].parent / "shared" / "real-logs"


@pytest.mark.skipif(not REAL.is_dir(), reason=f"{REAL} not present")
def test_real_logs_of_two_formats_merge_as_one_by_one(tmp_path):
    """ArduPilot's tlog and its onboard DataFlash log of one CMAC flight (../shared/
    real-logs), each placed about its own home: one frame (the same home), one map."""
    import yaml

    from tests.support.cmac_mission import CMAC

    config = tmp_path / "cmac.yaml"
    config.write_text(yaml.safe_dump(CMAC))
    logs = [REAL / "ardupilot_sitl_servo_gimbal.tlog", REAL / "ardupilot_sitl_servo_gimbal.BIN"]
    assert evaluate(config, tmp_path / "merged", *logs, more=("--jobs", "2")) == 0
    assert_same_map(tmp_path / "merged", one_by_one(config, logs, tmp_path))
    metrics = json.loads((tmp_path / "merged" / "metrics.json").read_text())
    assert [x["log"] for x in metrics["logs"]] == [str(p) for p in logs]
    assert all(x["frames"] > 100 for x in metrics["logs"])


def test_a_prior_scores_the_merged_map(tmp_path):
    config = write_config(tmp_path, mission_doc())
    logs = write_sorties(tmp_path / "logs", 2)
    poa = np.zeros((40, 40))
    poa[:, 5:25] = 1.0 / (40 * 20)
    np.save(tmp_path / "prior.npy", poa)
    assert evaluate(config, tmp_path / "run", *logs,
                    more=("--prior", str(tmp_path / "prior.npy"), "--jobs", "2")) == 0
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    with np.load(tmp_path / "run" / "grid.npz") as z:
        pd, mask = z["pd"], z["mask"]
    assert metrics["probability_of_success"] == pytest.approx((poa * pd * mask).sum())


@pytest.mark.parametrize("looks", ["independent", "correlated"])
def test_two_cameras_merge_per_camera_and_combined(tmp_path, looks):
    """Each camera's grid and the mission's (the cameras combined) merge log by log."""
    import shutil

    from pdcov.config.load import load_mission
    from pdcov.core.grid_snapshot import read_snapshot
    from tests.support import two_camera_flight as tcf
    from tests.support import zoom_flight as zf

    config = tcf.write_mission(tmp_path / "m.yaml", tcf.mission(looks))
    first = zf.write_tlog(tmp_path / "a.tlog", tcf.frames())
    logs = [first, Path(shutil.copyfile(first, tmp_path / "b.tlog"))]  # a second sortie
    assert evaluate(config, tmp_path / "both", *logs, more=("--jobs", "2")) == 0
    for k, log in enumerate(logs):
        assert evaluate(config, tmp_path / f"alone{k}", log) == 0
    mission = load_mission(config)

    def merged(sub: str, new) -> object:
        grids = []
        for k in range(2):
            g = new()
            read_snapshot(tmp_path / f"alone{k}" / sub / "grid.npz").restore(g)
            grids.append(g)
        grids[0].merge(grids[1])
        return grids[0]

    assert_same_map(tmp_path / "both", merged("", mission.new_mission_grid))
    for cam in mission.cameras:
        assert_same_map(tmp_path / "both" / "cameras" / cam.name,
                        merged(f"cameras/{cam.name}", lambda c=cam: mission.new_grid(c)))
