"""The evidence a candidate's looks give that a person is within its gate (docs/service.md
"Detections"): numbers in, numbers out, no state.

H1: a person is within the gate; H0: none is. One look of the candidate's cell with a
per-look P_D ``p`` and ``lam`` = lambda, the expected number of false boxes in the gate's
area that look (false boxes a Poisson process: the grid's per-look -rate A_cell scaled by
A_gate / A_cell), gives the log-likelihood ratio log P(look | H1) / P(look | H0):

    miss (no box in the gate):  P(miss | H1) = (1 - p) e^-lam, P(miss | H0) = e^-lam,
                                log LR = log(1 - p)           (false alarms cancel)
    hit (a box in the gate):    log LR = log((1 - (1 - p) e^-lam) / (1 - e^-lam))

Hand check: p = 0.5, lam = 0.01: a hit gives (1 - 0.5 e^-0.01) / (1 - e^-0.01) = 50.75, a
miss 0.5. The prior: P0 = 1 - exp(-rho A_gate) (people a Poisson process of rho per m^2),
log-odds log(P0 / (1 - P0)); p_person = sigmoid(prior log-odds + sum of the log LRs).

Correlated looks (core/looks.py): given the person's latent quantile q the looks are
independent, so the H1 log-likelihood is kept at each quadrature node q_j (``p`` the
look's detectability there) and LR = sum_j w_j exp(sum of the looks' log LR at q_j)
(H0 does not depend on q): ``log_lr_of_nodes``.
"""

from __future__ import annotations

import math

import numpy as np

from pdcov.core.looks import log_miss_of_nodes

__all__ = ["MIN_LAMBDA", "MIN_PRIOR", "PeoplePrior", "hit_log_lr", "log_lr_of_nodes", "miss_log_lr",
           "p_person", "prior_log_odds"]

MIN_LAMBDA = 1e-12
"""The least false-box expectation a hit is weighed with: a model without false alarms
makes a hit near-certain (log LR about log(p / 1e-12) = 27.6 + log p), never infinite."""
MIN_PRIOR = 1e-12
"""The least prior probability (a POA map's cells of 0): evidence can still raise it."""
_MAX_P = 1.0 - 1e-12  # a per-look P_D of 1 would make a miss's log LR -inf


def miss_log_lr(p: np.ndarray | float) -> np.ndarray:
    """log LR of a miss with per-look P_D ``p``: log(1 - p) (p capped below 1)."""
    return np.log1p(-np.minimum(np.asarray(p, dtype=np.float64), _MAX_P))


def hit_log_lr(p: np.ndarray | float, lam: np.ndarray | float) -> np.ndarray:
    """log LR of a hit with per-look P_D ``p`` and ``lam`` false boxes expected in the gate
    (at least MIN_LAMBDA): log((1 - (1 - p) e^-lam) / (1 - e^-lam)), computed as
    log(p e^-lam + (1 - e^-lam)) - log(1 - e^-lam) (no cancellation for small lam)."""
    p = np.minimum(np.asarray(p, dtype=np.float64), _MAX_P)
    lam = np.maximum(np.asarray(lam, dtype=np.float64), MIN_LAMBDA)
    fa = -np.expm1(-lam)  # 1 - e^-lam: at least one false box in the gate
    return np.log(p * np.exp(-lam) + fa) - np.log(fa)


def prior_log_odds(people_per_m2: float, gate_area_m2: float) -> float:
    """log-odds of P0 = 1 - exp(-rho A) (at least MIN_PRIOR): rho people per m^2 over the
    gate's ``gate_area_m2``."""
    p0 = max(-math.expm1(-people_per_m2 * gate_area_m2), MIN_PRIOR)
    return math.log(p0) - math.log1p(-p0)


def log_lr_of_nodes(log_lr_nodes: np.ndarray) -> float:
    """log of sum_j w_j exp(L_j) over the ``core.looks.QUADRATURE`` nodes (J,): the looks'
    log LR under correlated looks, L_j their sum at node j."""
    nodes = np.asarray(log_lr_nodes, dtype=np.float64)
    top = float(nodes.max())
    # log_miss_of_nodes caps at 0 (a probability); an LR may exceed 1: shift it below.
    return float(log_miss_of_nodes(nodes - top)) + top


def p_person(log_odds: float) -> float:
    """sigmoid(log_odds), in [0, 1]."""
    if log_odds >= 0:
        return 1.0 / (1.0 + math.exp(-log_odds))
    e = math.exp(log_odds)
    return e / (1.0 + e)


class PeoplePrior:
    """People per m^2 expected on the ground before any look: uniform (``per_m2`` a
    number: ``search.prior_people_per_km2`` / 1e6) or per grid cell (``per_m2`` an
    (n_rows, n_cols) array: a POA map's probability per cell over the cell's area,
    ``from_poa``); 0 outside the grid of a map."""

    def __init__(self, per_m2: float | np.ndarray) -> None:
        a = np.array(per_m2, dtype=np.float64)
        if a.ndim not in (0, 2) or not np.isfinite(a).all() or (a < 0).any():
            raise ValueError(f"prior people per m^2: expected a number or a 2-D array of "
                             f"finite values >= 0, got shape {a.shape}")
        a.setflags(write=False)
        self.per_m2 = a

    @classmethod
    def from_poa(cls, poa: np.ndarray, cell_size_m: float) -> PeoplePrior:
        """From a probability of area per cell (report/outputs.py ``read_prior``): the
        expected people in a cell over its area."""
        return cls(np.asarray(poa, dtype=np.float64) / cell_size_m**2)

    def at(self, row: int, col: int) -> float:
        """People per m^2 at grid cell (row, col)."""
        a = self.per_m2
        if a.ndim == 0:
            return float(a)
        inside = 0 <= row < a.shape[0] and 0 <= col < a.shape[1]
        return float(a[row, col]) if inside else 0.0
