"""Pins scored by person identity (issue 35, "Done when"): the score rules on hand-made
records. Every scenario of ``pdcov_sitl.pin_scenarios`` flown in memory (two seeds each,
about 30 s in all) is tests/slow/test_pins_identity_flights.py; ``python -m benchmarks.pins``
flies four and prints the table of docs/simulator.md."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pdcov.core.detections import Candidate
from pdcov_sitl.detector import FALSE_ALARM_ID
from pdcov_sitl.pin_scenarios import GROUP_SPACING_M, group_people
from pdcov_sitl.pin_score import (
    DetectionOwners,
    calibration,
    found_people,
    found_share,
    merges,
    pin_people,
)

FA = FALSE_ALARM_ID


def pin(cid: int, x: float, y: float, p_person: float = 0.5) -> Candidate:
    return Candidate(cid, "person", np.array([x, y, 0.0]), 0.1, 1, 1, 0.5, 0.0, 0.9, 0.0, 1.0,
                     f"t.{cid}", p_person)


# -- the rules, by hand ----------------------------------------------------------------------

OWNERS = DetectionOwners(  # pin 0: person 0 twice and a false alarm; pin 1: people 1 and 2
    candidate_id=np.array([0, 0, 0, 1, 1, 2, 2]),  # (frame 5 twice); pin 2: false alarms
    frame=np.array([0, 1, 2, 5, 5, 3, 4]),
    person_id=np.array([0, 0, FA, 1, 2, FA, FA]))


def test_pin_people_by_majority_of_boxes():
    is_person, person, n_people = pin_people(OWNERS, np.array([0, 1, 2]))
    assert is_person.tolist() == [True, True, False]  # 2 of 3; 2 of 2; 0 of 2
    assert person.tolist() == [0, 1, FA]              # of a tie, the lower id
    assert n_people.tolist() == [1, 2, 0]


def test_merges_count_two_people_and_two_boxes_of_one_frame():
    m = merges(OWNERS, np.array([0, 1, 2]))
    assert (m.n_pins, m.n_two_people, m.n_two_boxes_one_frame) == (2, 1, 1)
    assert m.two_people_share == 0.5


def test_found_needs_a_box_of_theirs_within_2_m():
    people = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [12.0, 0.0, 0.0], [50.0, 0.0, 0.0]])
    # pin 0 at 1.9 m from person 0; pin 1 at 10 m from person 1 (found) and 2.5 m from 2
    found = found_people(OWNERS, [pin(0, 1.9, 0.0), pin(1, 9.5, 0.0), pin(2, 50.0, 0.0)],
                         people)
    assert found.tolist() == [True, True, False, False]  # 3: only false boxes near them


def test_found_share_sd_is_poisson_binomial():
    f = found_share(np.array([True, True, False, True]), np.array([0.5, 0.5, 0.5, 0.9]))
    assert f.predicted == pytest.approx(0.6)
    assert f.sd == pytest.approx(math.sqrt(3 * 0.25 + 0.09) / 4)  # 0.2291
    assert f.z == pytest.approx((0.75 - 0.6) / 0.22913, abs=1e-4)
    assert f.as_predicted


def test_calibration_shares_and_brier():
    c = calibration(np.array([0.95, 0.9, 0.05, 0.1, 0.5]),
                    np.array([True, False, False, True, True]))
    assert (c.n_high, c.people_high, c.n_low, c.people_low) == (2, 1, 2, 1)
    assert c.brier == pytest.approx((0.05**2 + 0.9**2 + 0.05**2 + 0.9**2 + 0.5**2) / 5)
    assert not c.calibrated
    assert calibration(np.array([0.99, 0.01]), np.array([True, False])).calibrated


def test_groups_stand_1_5_m_apart_and_far_from_each_other():
    people = group_people(60, 60.0, seed=3).r_enu_m[:, :2]
    d = np.hypot(*(people[:, None] - people[None]).transpose(2, 0, 1))
    np.fill_diagonal(d, np.inf)
    assert len(people) >= 60
    assert d.min(axis=1) == pytest.approx(np.full(len(people), GROUP_SPACING_M))
    assert ((people >= 1.5) & (people <= 58.5)).all()


# -- the scenarios ----------------------------------------------------------------------------
