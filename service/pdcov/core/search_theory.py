"""Search theory on the coverage grid: probability of success and the posterior map.

POA: probability that the missing person is in each cell (the prior; sums to at most 1 over
the grid, the rest of the mass lying outside it). POS = sum(POA * P_D). After an unsuccessful
search, Bayes gives the posterior POA' = POA * (1 - P_D) / (1 - POS) in each cell, the map a
search manager plans the next sortie from; the mass outside the grid grows to
(1 - sum(POA)) / (1 - POS).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, slots=True)
class SearchOutcome:
    """POS of the search, the prior's mass over the grid (free cells and obstacles), and the
    posterior probability of area per cell (same shape as the grid) given that the search
    did not find the person; it sums to 1 less the posterior mass outside the grid."""

    probability_of_success: float
    prior_mass: float
    posterior: np.ndarray


def search_outcome(poa: np.ndarray, pd: np.ndarray, mask: np.ndarray) -> SearchOutcome:
    """POS and posterior for a prior ``poa`` (cells, >= 0) and cumulative ``pd`` per cell.

    Cells outside ``mask`` (obstacles) keep their prior mass in the posterior but cannot be
    searched. Raises ValueError for negative, NaN or all-zero priors, or more than 1 in all.
    When the search was certain to succeed (POS = 1) the posterior is 0 everywhere.
    """
    poa = np.asarray(poa, dtype=float)
    if poa.shape != pd.shape:
        raise ValueError(f"prior shape {poa.shape} != grid shape {pd.shape}")
    if not np.all(np.isfinite(poa)) or np.any(poa < 0):
        raise ValueError("prior probabilities must be finite and >= 0")
    total = poa.sum()
    if total <= 0:
        raise ValueError("prior has no probability mass in the grid")
    if total > 1 + 1e-4:
        raise ValueError(f"prior probabilities sum to {total:.6f} > 1")
    p_d = np.where(mask, pd, 0.0)
    pos = float((poa * p_d).sum())
    remaining = poa * (1.0 - p_d)
    return SearchOutcome(pos, float(total), remaining / max(1.0 - pos, np.finfo(float).tiny))
