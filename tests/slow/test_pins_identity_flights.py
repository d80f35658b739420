"""Pins over every scenario of ``pdcov_sitl.pin_scenarios`` flown in memory (two seeds each):
the share found within 3 sd of the prediction, distinct groups 1.5 m apart, one box per pin
and frame, a restart keeps them, P(person) calibrated (tests/unit/test_pins_identity.py: the
score rules on hand-made records)."""

from __future__ import annotations

import dataclasses

import pytest

from pdcov_sitl.pin_scenarios import (
    RESTART_WITHIN_M,
    Scores,
    fly_scenario,
    pin_scenarios,
    score_flights,
)
from pdcov_sitl.pin_score import MAX_TWO_PEOPLE_SHARE

SEEDS = (1, 2)


@pytest.fixture(scope="module")
def scores() -> dict[str, Scores]:
    out, everything = {}, []
    for name, sc in pin_scenarios().items():
        poses = sc.poses()
        records = [fly_scenario(sc, seed, poses) for seed in SEEDS]
        out[name] = score_flights(records)
        everything += records
    out["all"] = score_flights(everything)
    return out


SCENARIOS = ("sparse", "dense groups", "oblique", "restart", "noisy detector")


@pytest.mark.parametrize("name", SCENARIOS)
def test_share_found_within_3_sd_of_prediction(scores, name):
    f = scores[name].found
    assert f.as_predicted, f"{name}: found {f.share:.3f} vs {f.predicted:.3f}, z {f.z:+.2f}"


@pytest.mark.parametrize("name", SCENARIOS)
def test_no_pin_holds_two_boxes_of_one_frame_and_hits_never_exceed_looks(scores, name):
    s = scores[name]
    assert s.n_pins > 100
    assert s.merges.n_two_boxes_one_frame == 0
    assert s.n_hits_over_looks == 0


def test_groups_1_5_m_apart_stay_distinct(scores):
    m = scores["dense groups"].merges
    assert m.n_pins > 200
    assert m.two_people_share <= MAX_TWO_PEOPLE_SHARE, m


def test_restart_keeps_every_candidate_in_place(scores):
    restarts = scores["restart"].restarts
    assert restarts is not None and len(restarts) == len(SEEDS)
    for r in restarts:
        assert r.n_candidates > 30
        assert r.n_kept == r.n_candidates and r.max_move_m <= RESTART_WITHIN_M, r
        assert r.n_kept_at_end == r.n_candidates, r
    # The restart is the sparse flight with the tracker reloaded halfway: nothing changes.
    same = dataclasses.replace(scores["restart"], restarts=None)
    assert same == scores["sparse"]


def test_p_person_calibrated_over_all_pins(scores):
    c = scores["all"].calibration
    assert c.n_high > 100 and c.n_low > 20, c
    assert c.calibrated, (f"p >= 0.9: {c.high_share:.3f} people; p <= 0.1: {c.low_share:.3f};"
                          f" Brier {c.brier:.4f}")
