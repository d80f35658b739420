"""The evidence arithmetic of a pin's p_person (detection/pin_evidence.py), by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pdcov.core.looks import QUADRATURE
from pdcov.detection import pin_evidence as ev


def test_a_hit_and_a_miss_by_hand():
    # p = 0.5, lambda = 0.01: (1 - 0.5 e^-0.01) / (1 - e^-0.01) = 0.504975 / 0.00995017.
    assert math.exp(float(ev.hit_log_lr(0.5, 0.01))) == pytest.approx(50.7506, rel=1e-5)
    assert math.exp(float(ev.miss_log_lr(0.5))) == pytest.approx(0.5)
    # Many false boxes expected: a hit says little (p = 0.5, lambda = 5: 1.0034).
    assert math.exp(float(ev.hit_log_lr(0.5, 5.0))) == pytest.approx(
        (1 - 0.5 * math.exp(-5)) / (1 - math.exp(-5)), rel=1e-12)
    # P_D 0: a box is no evidence, a miss neither.
    assert float(ev.hit_log_lr(0.0, 0.3)) == pytest.approx(0.0, abs=1e-15)
    assert float(ev.miss_log_lr(0.0)) == 0.0
    # No false alarms modelled: lambda floored, a hit decisive but finite.
    assert float(ev.hit_log_lr(0.8, 0.0)) == pytest.approx(math.log(0.8 / ev.MIN_LAMBDA), rel=1e-6)
    # A P_D of 1 would make a miss -inf: capped.
    assert math.isfinite(float(ev.miss_log_lr(1.0))) and float(ev.miss_log_lr(1.0)) < -27


def test_the_prior_and_the_posterior():
    # rho 1e-6 per m^2 over 1e4 m^2: P0 = 1 - e^-0.01 = 0.00995017, odds 0.01005017.
    assert ev.prior_log_odds(1e-6, 1e4) == pytest.approx(math.log(0.00995017 / 0.99004983),
                                                      rel=1e-6)
    assert ev.prior_log_odds(0.0, 1.0) == pytest.approx(math.log(1e-12), rel=1e-9)  # floored
    assert ev.p_person(0.0) == 0.5
    assert ev.p_person(math.log(3.0)) == pytest.approx(0.75)
    assert ev.p_person(-800.0) == 0.0 and ev.p_person(800.0) == 1.0
    # Prior odds 1/99, a hit of LR 50.75, a miss of 0.5: odds 0.2563, p 0.2040.
    odds = (1 / 99) * 50.7506 * 0.5
    log_odds = math.log(1 / 99) + float(ev.hit_log_lr(0.5, 0.01) + ev.miss_log_lr(0.5))
    assert ev.p_person(log_odds) == pytest.approx(odds / (1 + odds), rel=1e-5)


def test_quadrature_nodes_combine_with_the_weights():
    J = len(QUADRATURE.q)
    assert ev.log_lr_of_nodes(np.full(J, 2.5)) == pytest.approx(2.5, abs=1e-12)
    assert ev.log_lr_of_nodes(np.full(J, -40.0)) == pytest.approx(-40.0, abs=1e-12)
    # Half the weight at LR e^3, half at e^-3 (nodes split at q = 0.5): cosh(3).
    nodes = np.where(QUADRATURE.q < 0.5, 3.0, -3.0)
    assert QUADRATURE.weights[QUADRATURE.q < 0.5].sum() == pytest.approx(0.5)
    assert ev.log_lr_of_nodes(nodes) == pytest.approx(math.log(math.cosh(3.0)), rel=1e-12)


def test_people_prior_uniform_or_per_cell():
    assert ev.PeoplePrior(2e-6).at(5, 7) == 2e-6
    poa = np.zeros((3, 4))
    poa[1, 2] = 0.5
    prior = ev.PeoplePrior.from_poa(poa, 2.0)  # 0.5 of a person over 4 m^2
    assert prior.at(1, 2) == 0.125 and prior.at(0, 0) == 0.0 and prior.at(9, 9) == 0.0
    with pytest.raises(ValueError, match="prior people per m"):
        ev.PeoplePrior(np.array([-1.0]))
