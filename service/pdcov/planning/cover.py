"""Covering a grid to a target P_D with a few of many candidate looks: the set cover behind
vantage-point plans (planning/vantage.py).

Evidence: a candidate j adds ``e_ij = -log(1 - P_ij) >= 0`` to cell i (its frames' log-miss
sums, negated: independent looks add), so a chosen set x reaches ``P`` in cell i when
``sum_j e_ij x_j >= tau = -log(1 - P)``. A cell may need several candidates to reach it, so
this is a covering integer program, not plain set cover:

    minimise  sum_j c_j x_j   subject to   E x >= tau y,  sum_i y_i >= n_required,
              x_j, y_i in {0, 1}

(with ``n_required`` all cells, y = 1 and the second constraint goes). Evidence is capped at
tau first (a cell needs no more; it tightens the relaxation without changing the solutions).

``greedy_cover``: repeatedly the candidate with the largest reduction of the remaining deficit
``sum_i max(0, tau - s_i)`` per unit cost, with lazy gains (a gain only shrinks as the
deficit does, so a stale gain is an upper bound: re-evaluate the top of the heap until it
stays on top). ``exact_cover``: the integer program through scipy.optimize.milp (HiGHS).
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.optimize import Bounds, LinearConstraint, milp

_EPS = 1e-9
TAU_MARGIN = 1e-5
"""Added to tau: the solver's feasibility tolerance (1e-7) and the float32 grid's rounding
must not leave a chosen cover just short of the target."""
_TOL = 1e-6


@dataclass(frozen=True, slots=True)
class CoverProblem:
    """evidence: sparse (n_cells, n_candidates) of e_ij >= 0 (capped at tau); cost (n_cand,)
    > 0; tau = -log(1 - target P_D) > 0; n_required: how many cells must reach tau."""

    evidence: sparse.csc_matrix
    cost: np.ndarray
    tau: float
    n_required: int

    @classmethod
    def of(cls, evidence: sparse.spmatrix, cost: np.ndarray, target_pd: float,
           n_required: int | None = None) -> CoverProblem:
        if not 0.0 < target_pd < 1.0:
            raise ValueError(f"target P_D must be in (0, 1), got {target_pd}")
        tau = -math.log1p(-target_pd) + TAU_MARGIN
        e = sparse.csc_matrix(evidence, dtype=np.float64)
        e.data = np.minimum(e.data, tau)
        e.eliminate_zeros()
        cost = np.asarray(cost, dtype=np.float64)
        if cost.shape != (e.shape[1],) or not np.all(cost > 0):
            raise ValueError("cost: one positive value per candidate")
        n = e.shape[0] if n_required is None else int(n_required)
        return cls(e, cost, tau, n)

    def reached(self, chosen: np.ndarray) -> np.ndarray:
        """bool (n_cells,): cells the chosen candidates (indices) bring to tau."""
        s = np.asarray(self.evidence[:, chosen].sum(axis=1)).ravel()
        return s >= self.tau - _TOL

    def reachable(self) -> np.ndarray:
        """bool (n_cells,): cells that all candidates together bring to tau."""
        return self.reached(np.arange(self.evidence.shape[1]))


@dataclass(frozen=True, slots=True)
class Cover:
    """Chosen candidate indices, their total cost, and whether the cover is proven optimal
    (exact) with the solver's relative MIP gap (0 when optimal; NaN for greedy)."""

    chosen: np.ndarray
    cost: float
    optimal: bool = False
    mip_gap: float = math.nan


def greedy_cover(problem: CoverProblem) -> Cover | None:
    """The lazy greedy cover; None when the candidates cannot reach ``n_required`` cells."""
    e = problem.evidence
    tau = problem.tau
    deficit = np.full(e.shape[0], tau)
    indptr, indices, data = e.indptr, e.indices, e.data

    def gain(j: int) -> float:
        rows = indices[indptr[j]:indptr[j + 1]]
        return float(np.minimum(deficit[rows], data[indptr[j]:indptr[j + 1]]).sum())

    heap = [(-gain(j) / problem.cost[j], j) for j in range(e.shape[1])]
    heapq.heapify(heap)
    chosen: list[int] = []
    n_done = 0
    while n_done < problem.n_required and heap:
        _, j = heapq.heappop(heap)
        g = gain(j)
        if g <= _EPS:
            continue  # gains only shrink: this candidate will never help again
        if heap and g / problem.cost[j] < -heap[0][0] - _EPS:
            heapq.heappush(heap, (-g / problem.cost[j], j))
            continue
        chosen.append(j)
        rows = indices[indptr[j]:indptr[j + 1]]
        deficit[rows] = np.maximum(deficit[rows] - data[indptr[j]:indptr[j + 1]], 0.0)
        n_done = int((deficit <= _TOL).sum())
    if n_done < problem.n_required:
        return None
    idx = np.array(sorted(chosen), dtype=np.int64)
    return Cover(idx, float(problem.cost[idx].sum()))


def exact_cover(problem: CoverProblem, time_limit_s: float) -> Cover | None:
    """The integer program (module doc) by HiGHS within ``time_limit_s``; None when it
    found no feasible cover in that time (or there is none)."""
    e = problem.evidence
    n_cells, n_cand = e.shape
    all_cells = problem.n_required >= n_cells
    if all_cells:
        c = problem.cost
        cons = [LinearConstraint(e, lb=problem.tau, ub=np.inf)]
        n_var = n_cand
    else:
        c = np.concatenate([problem.cost, np.zeros(n_cells)])
        a = sparse.hstack([e, -problem.tau * sparse.identity(n_cells)], format="csr")
        share = sparse.csr_matrix(np.concatenate([np.zeros(n_cand), np.ones(n_cells)]))
        cons = [LinearConstraint(a, lb=0.0, ub=np.inf),
                LinearConstraint(share, lb=problem.n_required, ub=np.inf)]
        n_var = n_cand + n_cells
    res = milp(c, constraints=cons, integrality=np.ones(n_var), bounds=Bounds(0, 1),
               options={"time_limit": float(time_limit_s), "disp": False})
    if res.x is None:
        return None
    chosen = np.flatnonzero(res.x[:n_cand] > 0.5)
    gap = float(getattr(res, "mip_gap", math.nan) or 0.0)
    return Cover(chosen, float(problem.cost[chosen].sum()), optimal=res.status == 0,
                 mip_gap=0.0 if res.status == 0 else gap)
