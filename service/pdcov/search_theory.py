"""Search theory on the coverage grid: probability of success and the posterior map.

POA: probability that the missing person is in each cell (the prior; sums to at most 1 over
the grid). POS = sum(POA * P_D). After an unsuccessful search, Bayes gives the posterior
POA' = POA * (1 - P_D) / (1 - POS), the map a search manager plans the next sortie from;
``search_outcome`` conditions it on the person being in the grid (it sums to 1 over the grid).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, slots=True)
class SearchOutcome:
    """POS of the search, the prior's mass over the grid (free cells and obstacles), and the
    posterior (same shape as the grid), renormalised to sum to 1 over the grid: the
    probability of area given that the person is in the grid and was not found."""

    probability_of_success: float
    prior_mass: float
    posterior: np.ndarray


def search_outcome(poa: np.ndarray, pd: np.ndarray, mask: np.ndarray) -> SearchOutcome:
    """POS and posterior for a prior ``poa`` (cells, >= 0) and cumulative ``pd`` per cell.

    Cells outside ``mask`` (obstacles) keep their prior mass in the posterior but cannot be
    searched. Raises ValueError for negative, NaN or all-zero priors.
    """
    poa = np.asarray(poa, dtype=float)
    if poa.shape != pd.shape:
        raise ValueError(f"prior shape {poa.shape} != grid shape {pd.shape}")
    if not np.all(np.isfinite(poa)) or np.any(poa < 0):
        raise ValueError("prior probabilities must be finite and >= 0")
    total = poa.sum()
    if total <= 0:
        raise ValueError("prior has no probability mass in the grid")
    p_d = np.where(mask, pd, 0.0)
    pos = float((poa * p_d).sum())
    remaining = poa * (1.0 - p_d)
    return SearchOutcome(pos, float(total), remaining / remaining.sum())
