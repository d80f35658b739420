"""Looks and hits of people drawn from a Beta-binomial, for the tests of the looks fit."""

from __future__ import annotations

import numpy as np


def draw(rng: np.random.Generator, n_people: int, mu: float, rho: float,
         max_looks: int = 30) -> tuple[np.ndarray, np.ndarray]:
    """Looks n ~ U{2..max_looks} and hits k of people with p ~ Beta(mu, rho) (p = mu at 0)."""
    n = rng.integers(2, max_looks + 1, n_people)
    if rho > 0:
        s = 1 / rho - 1
        p = rng.beta(mu * s, (1 - mu) * s, n_people)
    else:
        p = np.full(n_people, mu)
    return n, rng.binomial(n, p)
