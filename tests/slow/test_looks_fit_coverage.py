"""The looks fit over many drawn sets: its intervals cover the truth at their level and
independent looks are not rejected (tests/unit/test_looks_fit.py: single fits)."""

from __future__ import annotations

import numpy as np

from pdcov.detection.looks_fit import fit_beta_binomial
from tests.support.looks_draws import draw


def test_intervals_cover_the_truth_at_their_level():
    """Over 120 drawn sets the profile-likelihood 95 % intervals of mu and rho each hold the
    truth about 95 % of the time (binomial sd 2 %)."""
    reps, cover_mu, cover_rho = 120, 0, 0
    rng = np.random.default_rng(11)
    for _ in range(reps):
        n, k = draw(rng, 200, 0.6, 0.25, max_looks=15)
        fit = fit_beta_binomial(n, k)
        cover_mu += fit.mean_pd_ci95[0] <= 0.6 <= fit.mean_pd_ci95[1]
        cover_rho += fit.correlation_ci95[0] <= 0.25 <= fit.correlation_ci95[1]
    assert 0.89 * reps <= cover_mu <= reps
    assert 0.89 * reps <= cover_rho <= reps


def test_independence_is_not_rejected_for_independent_looks():
    """At rho = 0 the chi-bar-square p-value rejects at 5 % about 5 % of the time, and half
    the estimates sit on the boundary (rho = 0, p = 1)."""
    rng = np.random.default_rng(5)
    p = np.array([fit_beta_binomial(*draw(rng, 300, 0.5, 0.0)).p_value_independent
                  for _ in range(200)])
    assert 0.01 <= np.mean(p < 0.05) <= 0.10
    assert 0.35 <= np.mean(p == 1.0) <= 0.65
    assert np.all((p >= 0) & (p <= 1))
