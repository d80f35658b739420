"""Probability of success and the Bayesian posterior, by hand."""

import numpy as np
import pytest

from pdcov.core.search_theory import search_outcome


def test_two_cells_by_hand():
    poa = np.array([[0.5, 0.3]])  # 0.2 of the mass lies outside the grid
    pd = np.array([[0.8, 0.0]])
    out = search_outcome(poa, pd, np.ones((1, 2), bool))
    assert out.probability_of_success == pytest.approx(0.4)
    # Not found: 0.5 * 0.2 / 0.6, 0.3 / 0.6; the outside mass grows to 0.2 / 0.6.
    np.testing.assert_allclose(out.posterior, [[0.1 / 0.6, 0.3 / 0.6]])
    assert out.posterior.sum() + 0.2 / 0.6 == pytest.approx(1.0)


def test_obstacle_cells_are_not_searched_and_certain_success_gives_zero():
    out = search_outcome(np.array([[0.5, 0.5]]), np.array([[1.0, 1.0]]),
                         np.array([[True, False]]))
    assert out.probability_of_success == pytest.approx(0.5)
    np.testing.assert_allclose(out.posterior, [[0.0, 1.0]])
    certain = search_outcome(np.array([[1.0]]), np.array([[1.0]]), np.ones((1, 1), bool))
    assert certain.probability_of_success == 1.0 and np.all(certain.posterior == 0)


def test_bad_priors():
    with pytest.raises(ValueError, match="sum"):
        search_outcome(np.ones((2, 2)), np.zeros((2, 2)), np.ones((2, 2), bool))
    with pytest.raises(ValueError):
        search_outcome(np.array([[-0.1, 0.5]]), np.zeros((1, 2)), np.ones((1, 2), bool))
