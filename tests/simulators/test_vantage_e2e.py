"""A vantage plan flown by the simulator evaluates to its prediction (issue 25, "Done
when"): ``pdcov plan --pattern vantage`` on a domain with an obstacle, ``pdcov-sitl fly``
of its mission at full speed, ``pdcov evaluate`` of the frames from reaching its first
waypoint to the end of its last hover (what the prediction flies) against the predicted
grid: a nadir fixed camera with waypoint holds, and an oblique gimbal (-45 deg at eight
earth-frame yaws, DO_GIMBAL_MANAGER_PITCHYAW with YAW_LOCK before each point) with
NAV_LOITER_TIME hovers. The simulator settles about a second longer at each stop than the
mission's hold (its guidance, pdcov_sitl/guidance.py), so the flight has a few more looks
than predicted: never fewer. An oblique frame covers many more cells than a nadir one, so
those extra looks move more cells by more than 0.05 (measured: 90 % of the cells within
0.05, every one of the others above the prediction; predicted with the holds 0.5 s longer,
97 % within 0.05; the greedy's 8-point cover, when the integer program runs out of time,
95 %): the oblique case asks for 85 % two-sided and 99 % one-sided, and flies
the same mission with the yaw lock cleared as a control that must not agree."""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
import yaml

pytest.importorskip("jsbsim")

from pdcov.cli import main as pdcov_main
from pdcov.config.load import load_mission
from pdcov.planning.plan_files import read_plan
from pdcov_sitl.cli import main as sitl_main
from tests.support.evaluate_inputs import survey_poses_csv

AGREE_PD = 0.05
AGREE_SHARE = {"nadir": 0.90, "oblique": 0.85}
"""Shares of cells within AGREE_PD both ways. Nadir: HiGHS's optimal 29-point cover of
the 102 candidates (found within --ilp-time-limit-s on a quiet machine; a loaded one may
fly the greedy's 37) flies 701 frames against 644 predicted, the simulator's longer
settling at each stop: 92.8 % of the cells within 0.05 and 99.0 % not below."""
NOT_BELOW_SHARE = 0.99
"""Cells whose flown P_D is at least the prediction's less AGREE_PD."""
TARGET_PD = 0.3
DETECTOR_SCALE = 0.08
"""The illustrative detector's P_D per look scaled down, so that hovers of 8 looks bring
cells to 0.3 - 0.95 rather than to 1 (where flight and prediction agree trivially)."""


def mission_doc() -> dict:
    det = yaml.safe_load((resources.files("pdcov") / "data"
                          / "illustrative_detector.yaml").read_text())
    det["p_detect"] = [p * DETECTOR_SCALE for p in det["p_detect"]]
    return {"vehicle_id": "sim1",
            "origin": {"lat_deg": 39.35, "lon_deg": -76.33, "ground_alt_msl_m": 5.0},
            "domain": {"polygon_enu_m": [[-20, -15], [20, -15], [20, 15], [-20, 15]],
                       "obstacles_enu_m": [[[4, -4], [12, -4], [12, 5], [4, 5]]],
                       "cell_size_m": 1.0},
            "camera": {"width_px": 640, "height_px": 480,
                       "K": [[457.0, 0.0, 319.5], [0.0, 457.0, 239.5], [0.0, 0.0, 1.0]],
                       "frame_rate_hz": 2},
            "mount": {"type": "fixed", "roll_deg": 0, "pitch_deg": -90, "yaw_deg": 0},
            "detector": det, "thresholds": [TARGET_PD]}


def evaluate(cfg: Path, out: Path, *source: str) -> dict:
    assert pdcov_main(["evaluate", "--config", str(cfg), *source, "--out", str(out),
                       "--no-progress"]) == 0
    with np.load(out / "grid.npz") as z:
        return {k: z[k] for k in z.files}


OBLIQUE = ["--gimbal-pitches-deg", "-45", "--gimbal-yaws", "8", "--hover-item", "loiter-time"]


def flown_survey(tmp_path: Path, cfg: Path, plan: Path, name: str) -> dict:
    """``pdcov-sitl fly`` of ``plan`` and ``pdcov evaluate`` of its frames from reaching the
    first waypoint to the end of the last hover (what the prediction flies): the grid, and
    the survey's duration (s)."""
    out = tmp_path / name
    assert sitl_main(["fly", "--config", str(cfg), "--plan", str(plan), "--out",
                      str(out / "fly"), "--connect", "udpout:127.0.0.1:9", "--speed", "0"]) == 0
    truth = np.loadtxt(out / "fly" / "truth.csv", delimiter=",", skiprows=1)
    wps = read_plan(plan, load_mission(cfg).origin()).waypoints

    def reached(wp, after_s: float) -> float:
        near = (np.hypot(truth[:, 1] - wp.x_enu_m, truth[:, 2] - wp.y_enu_m) < 0.5) \
            & (truth[:, 0] > after_s)
        assert near.any(), f"the flight never came within 0.5 m of {wp}"
        return float(truth[np.argmax(near), 0])

    t0 = reached(wps[0], 0.0)
    t1 = t0 + wps[0].hover_s
    # The stops in order (the last waypoint may lie on an earlier transit), then it.
    for wp in [w for w in wps[1:-1] if w.hover_s > 0] + [wps[-1]]:
        t1 = reached(wp, t1) + wp.hover_s
    survey = survey_poses_csv(cfg, out / "fly" / "flight.tlog", out, t0, t1)
    return {**evaluate(cfg, out / "survey", "--poses", str(survey)), "survey_s": t1 - t0}


def agreement(flown: dict, pred: dict) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Flown and predicted P_D of the free cells, the share within AGREE_PD both ways and
    the share not below the prediction by more."""
    mask = flown["mask"]
    np.testing.assert_array_equal(mask, pred["mask"])
    pd_flown = 1 - np.exp(flown["log_miss_d"][mask])
    pd_pred = 1 - np.exp(pred["log_miss_d"][mask])
    share = float((np.abs(pd_flown - pd_pred) <= AGREE_PD).mean())
    return pd_flown, pd_pred, share, float((pd_flown >= pd_pred - AGREE_PD).mean())


@pytest.mark.parametrize("case, mount, extra", [
    ("nadir", {"type": "fixed", "roll_deg": 0, "pitch_deg": -90, "yaw_deg": 0}, []),
    ("oblique", {"type": "gimbal"}, OBLIQUE)], ids=["nadir", "oblique"])
def test_flown_vantage_plan_evaluates_to_its_prediction(tmp_path, case, mount, extra):
    cfg = tmp_path / "m.yaml"
    cfg.write_text(yaml.safe_dump({**mission_doc(), "mount": mount}))
    plan_dir = tmp_path / "plan"
    assert pdcov_main(["plan", "--config", str(cfg), "--pattern", "vantage", "--target-pd",
                       str(TARGET_PD), "--altitudes-m", "10", "--hover-s", "4", "8",
                       "--lattice-m", "6", "--speed-mps", "4", "--ilp-time-limit-s", "5",
                       "--routing-time-s", "1", "--no-figures", "--out", str(plan_dir),
                       *extra]) == 0
    plan = plan_dir / "plan.plan"
    doc = json.loads((plan_dir / "vantage.json").read_text())
    qgc = json.loads(plan.read_text())
    if extra:  # every point oblique, at a locked yaw, each commanded before its hover
        assert {p["gimbal_pitch_deg"] for p in doc["points"]} == {-45.0}
        assert all(p["gimbal_yaw_deg"] is not None for p in doc["points"])
        cmds = [e["command"] for e in qgc["mission"]["items"]]
        assert cmds.count(19) == len(doc["points"])  # the hovers; corners are 16
        assert 1 <= cmds.count(1000) <= len(doc["points"])
    flown = flown_survey(tmp_path, cfg, plan, "flown")
    with np.load(plan_dir / "grid.npz") as z:
        pred = {k: z[k] for k in z.files}
    pd_flown, pd_pred, share, not_below = agreement(flown, pred)
    diff = np.abs(pd_flown - pd_pred)
    print(f"{len(doc['points'])} points; predicted share at {TARGET_PD}: "
          f"{(pd_pred >= TARGET_PD).mean():.3f}, flown {(pd_flown >= TARGET_PD).mean():.3f}; "
          f"flown P_D median {np.median(pd_flown):.2f}; {share:.1%} of cells within "
          f"{AGREE_PD} (p95 |diff| {np.percentile(diff, 95):.3f}), {not_below:.1%} not "
          f"below it by more; "
          f"frames flown {int(flown['frames'])}, predicted {int(pred['frames'])}; survey "
          f"flown in {flown['survey_s']:.1f} s; predicted mission "
          f"{doc['missions'][0]['flight_time_s']} s from take-off to landing")
    assert (pd_pred >= TARGET_PD).all()
    # Not saturated (the comparison says something): a third of the cells below 0.9.
    assert (pd_flown < 0.9).mean() >= 1 / 3
    assert share >= AGREE_SHARE[case]
    assert not_below >= NOT_BELOW_SHARE
    if extra:
        # The control: the same mission with the yaw lock cleared (param5 0: the yaw
        # relative to the vehicle) does not fly what was predicted, so the check above
        # depends on the simulator holding the earth-frame yaw.
        for e in qgc["mission"]["items"]:
            if e["command"] == 1000:
                e["params"][4] = 0
        unlocked = tmp_path / "unlocked.plan"
        unlocked.write_text(json.dumps(qgc))
        _, _, share_u, not_below_u = agreement(
            flown_survey(tmp_path, cfg, unlocked, "unlocked"), pred)
        print(f"without the lock: {share_u:.1%} within {AGREE_PD}, {not_below_u:.1%} not "
              "below it by more")
        assert not_below_u < NOT_BELOW_SHARE - 0.1
