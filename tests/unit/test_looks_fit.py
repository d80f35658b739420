"""The beta-binomial statistics of a person's looks (detection/looks_fit.py), on counts drawn
with a known per-person detectability; the likelihood against scipy's beta-binomial, the
test against Tarone's score test."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml
from scipy import special, stats

from pdcov.core.detector import DetectorModel
from pdcov.detection.looks_fit import (
    MIN_PEOPLE,
    BetaBinomialLikelihood,
    LooksFit,
    PersonLooks,
    fit_beta_binomial,
    found_within,
    measured_found_within,
)
from pdcov.errors import DetectorModelError
from tests.support.looks_draws import draw


def tarone_p(n: np.ndarray, k: np.ndarray) -> float:
    """Tarone's (1979) score test of binomial against beta-binomial overdispersion, one-sided:
    an independent check of the likelihood-ratio test."""
    p = k.sum() / n.sum()
    s = np.sum((k - n * p) ** 2) / (p * (1 - p))
    z = (s - n.sum()) / math.sqrt(2 * np.sum(n * (n - 1)))
    return float(stats.norm.sf(z))


def test_likelihood_is_scipys_beta_binomial_and_the_binomial_at_rho_0():
    rng = np.random.default_rng(3)
    n, k = draw(rng, 50, 0.4, 0.2)
    ll = BetaBinomialLikelihood(n, k)
    log_choose = float(np.sum(special.gammaln(n + 1) - special.gammaln(k + 1)
                              - special.gammaln(n - k + 1)))
    for mu, rho in ((0.4, 0.2), (0.7, 0.05), (0.2, 0.9)):
        s = 1 / rho - 1
        ref = stats.betabinom.logpmf(k, n, mu * s, (1 - mu) * s).sum()
        assert ll(mu, rho) + log_choose == pytest.approx(ref, rel=1e-10)
    assert ll(0.4, 0.0) + log_choose == pytest.approx(stats.binom.logpmf(k, n, 0.4).sum(),
                                                      rel=1e-12)


def test_found_within_by_hand():
    # Independent looks at P_D 0.5: 1 - 0.5^20. Beta(1, 1) (mu 0.5, rho 1/3):
    # E[(1 - p)^n] = 1 / (n + 1), so 20 looks find 20/21 of the people.
    assert found_within(20, 0.5, 0.0) == pytest.approx(1 - 0.5 ** 20)
    assert found_within(20, 0.5, 1 / 3) == pytest.approx(20 / 21)
    assert found_within(1, 0.3, 0.6) == pytest.approx(0.3)  # one look: the mean
    f = found_within(np.arange(1, 50), 0.5, 0.3)
    assert np.all(np.diff(f) > 0) and f[-1] < found_within(49, 0.5, 0.0)


@pytest.mark.parametrize("mu, rho", [(0.3, 0.3), (0.6, 0.3), (0.85, 0.3), (0.5, 0.1)])
def test_recovers_mean_and_correlation(mu, rho):
    for seed in range(3):
        n, k = draw(np.random.default_rng(seed), 1500, mu, rho)
        fit = fit_beta_binomial(n, k)
        assert abs(fit.mean_pd - mu) < 0.02
        assert abs(fit.correlation - rho) < 0.25 * rho
        assert fit.p_value_independent < 1e-6
        assert tarone_p(n, k) < 1e-6


def test_no_estimate_without_enough_people_or_with_only_hits():
    few = fit_beta_binomial(np.full(MIN_PEOPLE - 1, 5), np.full(MIN_PEOPLE - 1, 2))
    assert not few.estimated and math.isnan(few.correlation)
    assert f"fewer than {MIN_PEOPLE}" in (few.reason or "")
    ones = fit_beta_binomial(np.ones(100, int), np.zeros(100, int))  # one look each
    assert not ones.estimated
    all_hit = fit_beta_binomial(np.full(30, 4), np.full(30, 4))
    assert all_hit.reason == "every look hit" and all_hit.n_looks == 120


def test_people_always_or_never_seen_give_rho_near_1_and_a_valid_model():
    n = np.full(40, 10)
    k = np.r_[np.zeros(20, int), np.full(20, 10)]
    fit = fit_beta_binomial(n, k)
    assert fit.correlation > 0.99 and fit.correlation_ci95[1] == 1.0
    assert fit.mean_pd == pytest.approx(0.5, abs=1e-6)
    looks = LooksFit((fit,), np.zeros((1, 3)), np.ones((1, 3), int), 0).to_model()
    assert looks.correlation[0] < 1
    DetectorModel((8.0, 16.0), (0.5,), (0.1,), looks=looks)  # in [0, 1): accepted


def test_counts_and_measured_curve_by_hand():
    # Rows in time order: person 0 misses, person 1 misses, person 0 hits, person 2 hits
    # (bin 1), person 0 misses, person 1 misses, a look outside the bins.
    person = np.array([0, 1, 0, 2, 0, 1, 2])
    bins = np.array([0, 0, 0, 1, 0, 0, -1])
    hit = np.array([0, 0, 1, 1, 0, 0, 1], bool)
    c = PersonLooks.from_looks(person, bins, hit, 3, 2)
    assert c.n.tolist() == [[3, 0], [2, 0], [0, 1]]
    assert c.k.tolist() == [[1, 0], [0, 0], [0, 1]]
    share, people = measured_found_within(person, bins, hit, 2, max_looks=3)
    assert people.tolist() == [[2, 2, 1], [1, 0, 0]]
    assert share[0].tolist() == [0.0, 0.5, 1.0]
    assert share[1, 0] == 1.0 and np.isnan(share[1, 1])


def test_model_section_round_trip_and_fallback():
    rng = np.random.default_rng(2)
    good = fit_beta_binomial(*draw(rng, 300, 0.5, 0.3))
    none = fit_beta_binomial(np.full(3, 5), np.full(3, 2))
    share, people = np.zeros((2, 3)), np.ones((2, 3), int)
    looks = LooksFit((good, none), share, people, 0).to_model({"format": "mot"})
    assert looks.correlation == (round(good.correlation, 6), 0.0)  # 0: independent
    model = DetectorModel((8.0, 16.0, 32.0), (0.5, 0.4), (0.1, 0.1), looks=looks)
    doc = yaml.safe_load(model.to_yaml())
    assert doc["version"] == 2
    assert doc["looks"]["estimated"] == [True, False]
    assert doc["looks"]["correlation_mle"][1] is None
    assert "fewer than" in doc["looks"]["no_estimate_reason"][1]
    again = DetectorModel.from_dict(doc, "m.yaml")
    assert again.looks is not None and again.looks.correlation == looks.correlation
    doc["looks"]["p_value_indep"] = [0.1, 0.2]
    with pytest.raises(DetectorModelError, match="p_value_indep.*p_value_independent"):
        DetectorModel.from_dict(doc, "m.yaml")
