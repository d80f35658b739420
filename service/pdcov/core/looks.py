"""How one person's looks combine into a cell's cumulative P_D (``coverage.looks``).

The paper's recursion treats every frame as an independent trial (``LooksRule.INDEPENDENT``,
the coverage grid's own log-miss sums). It is not: a person half hidden or dressed like the
ground is missed frame after frame. Two other rules:

* ``CORRELATED`` (measured, the detector model's ``looks`` section): the person has one
  latent quantile q ~ U(0, 1); at size bin i their detectability is the Beta(a_i, b_i)
  quantile ``Q_i(q)``, with mean p_detect[i] and intra-person correlation
  rho_i = 1 / (a_i + b_i + 1) (``detectability_quantile``). The same q at every bin
  (comonotone): a person hard to see at one size is hard at every size. Given q the looks
  are independent, so a cell whose observed looks fell n_i times in bin i has

      P_miss = integral_0^1 prod_i (1 - Q_i(q))^{n_i} dq,

  and the counts n_i are all the grid needs to store (``CorrelatedLooks``). The integral is
  a fixed quadrature (``QUADRATURE``) evaluated when the grid is read. rho_i = 0 gives
  Q_i = p_detect[i] for every q: the paper's product.
* ``VIEWPOINT`` (a rule, not a measurement): looks from nearly the same direction (cell to
  camera: azimuth and elevation bins, ``ViewpointBins``) count as one, the best of them
  (``ViewpointLooks``); the best looks of different viewpoints are independent.

False alarms are events of a frame (the detector's response to that frame's pixels), so
P_FA stays the independent product under every rule.

Pure numeric core: no I/O.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np
from scipy.special import betaincinv

from pdcov.core.detector import DetectorModel

__all__ = ["QUADRATURE", "CorrelatedLooks", "LooksConfig", "LooksRule", "Quadrature",
           "ViewpointBins", "ViewpointLooks", "beta_shape", "detectability_quantile",
           "LooksModel", "log_miss_of_nodes", "looks_model", "pd_of_node_log_miss",
           "same_looks_tables"]



class LooksRule(str, enum.Enum):
    """``coverage.looks``: how one person's looks combine (module docstring)."""

    INDEPENDENT = "independent"
    CORRELATED = "correlated"
    VIEWPOINT = "viewpoint"

    def __str__(self) -> str:
        return str(self.value)


@dataclass(frozen=True, slots=True)
class ViewpointBins:
    """``coverage.viewpoint``: the viewpoint bins of ``LooksRule.VIEWPOINT``.

    The direction from a cell's centre to the camera is binned by elevation into
    ``elevation_bins`` equal bins over 0..90 deg, and, below the top one, by azimuth
    (compass, from north through east) into ``azimuth_bins`` equal bins starting at north.
    The top elevation bin is one cap: near the nadir azimuth means nothing (a hover's jitter
    would swing it through every bin).
    """

    azimuth_bins: int = 8
    elevation_bins: int = 3

    def __post_init__(self) -> None:
        for name, hi in (("azimuth_bins", 64), ("elevation_bins", 16)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= hi:
                raise ValueError(f"{name}: expected an integer in 1..{hi}, got {v!r}")

    @property
    def n_bins(self) -> int:
        """Viewpoint bins per cell: azimuth x elevation below the cap, and the cap."""
        return self.azimuth_bins * (self.elevation_bins - 1) + 1

    def bin_of(self, d_east_m: np.ndarray, d_north_m: np.ndarray, d_up_m: np.ndarray
               ) -> np.ndarray:
        """Viewpoint bin (int64, 0..n_bins - 1) of the directions (ENU metres, from the cell
        to the camera): elevation bin e * azimuth_bins + azimuth bin, the cap last."""
        # Elevation bins by the tangent (no arctan): tan(elevation) = up / horizontal.
        with np.errstate(divide="ignore", invalid="ignore"):
            tan_el = d_up_m / np.sqrt(d_east_m * d_east_m + d_north_m * d_north_m)
        edges = np.tan(np.arange(1, self.elevation_bins) * (0.5 * math.pi
                                                            / self.elevation_bins))
        e = np.searchsorted(edges, tan_el, side="right")
        azimuth = np.arctan2(d_east_m, d_north_m)  # -pi..pi, from north through east
        a = np.floor(azimuth * (self.azimuth_bins / (2.0 * math.pi))).astype(np.int64)
        a %= self.azimuth_bins
        return np.where(e >= self.elevation_bins - 1, self.n_bins - 1,
                        e * self.azimuth_bins + a)


@dataclass(frozen=True, slots=True)
class LooksConfig:
    """The grid's looks rule and, for ``VIEWPOINT``, its bins."""

    rule: LooksRule = LooksRule.INDEPENDENT
    viewpoint: ViewpointBins = ViewpointBins()

    @property
    def summary(self) -> str:
        """One line for a run's summary: the rule and what it assumes."""
        if self.rule is LooksRule.CORRELATED:
            return ("correlated (the detector model's per-person correlation; one latent "
                    "detectability per person across sizes)")
        if self.rule is LooksRule.VIEWPOINT:
            v = self.viewpoint
            return (f"viewpoint (a rule: the best look per viewpoint bin, {v.azimuth_bins} "
                    f"azimuth x {v.elevation_bins} elevation bins)")
        return "independent (the paper: every counted frame an independent trial)"


# -- the latent detectability ---------------------------------------------------------------

_CHUNK_CELLS = 2048  # cells per block of the quadrature on read
_MIN_RHO = 1e-16  # below it the Beta's shapes exceed 1e16: the quantiles are the mean

def beta_shape(mean: np.ndarray, rho: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Beta (a, b) of the given mean and intra-person correlation rho = 1 / (a + b + 1)
    (0 < mean < 1, 0 < rho < 1)."""
    mean, rho = np.asarray(mean, dtype=float), np.asarray(rho, dtype=float)
    total = 1.0 / rho - 1.0
    return mean * total, (1.0 - mean) * total


def detectability_quantile(mean: np.ndarray, rho: np.ndarray, q: np.ndarray) -> np.ndarray:
    """A person's detectability at latent quantile ``q`` in [0, 1]: the q-quantile of
    Beta(a, b) with this ``mean`` and correlation ``rho`` (broadcast together). rho = 0, or
    a mean of 0 or 1, gives the mean for every q; so does rho below 1e-16, where the
    quantiles lie within 1e-8 of the mean (and scipy's inverse fails for such shapes)."""
    mean, rho, q = np.broadcast_arrays(np.asarray(mean, float), np.asarray(rho, float),
                                       np.asarray(q, float))
    out = mean.copy()
    beta = (rho > _MIN_RHO) & (mean > 0) & (mean < 1)
    if beta.any():
        a, b = beta_shape(mean[beta], rho[beta])
        out[beta] = betaincinv(a, b, q[beta])
    return out


@dataclass(frozen=True, slots=True)
class Quadrature:
    """Nodes q (J,) in (0, 1) and weights (J,) summing to 1 for integrals over the latent
    quantile."""

    q: np.ndarray
    weights: np.ndarray

    @classmethod
    def composite(cls, n_uniform: int, ratio: float, n_geometric: int, order: int
                  ) -> Quadrature:
        """Gauss-Legendre of ``order`` points on each interval of a partition of [0, 1]:
        ``n_uniform`` equal intervals, the two end ones split geometrically (``ratio``,
        ``n_geometric`` times) towards 0 and towards 1. Many looks make the integrand a
        step near q = 0 (a person hard to see dominates), and a small shape a < 1 makes
        Q(q) rise like q^(1/a): both need the fine end intervals."""
        x, w = np.polynomial.legendre.leggauss(order)
        h = 1.0 / n_uniform
        geometric = h * ratio ** np.arange(n_geometric, 0, -1.0)
        edges = np.concatenate(([0.0], geometric, np.linspace(h, 1.0 - h, n_uniform - 1),
                                1.0 - geometric[::-1], [1.0]))
        lo, width = edges[:-1, None], np.diff(edges)[:, None]
        return cls((lo + 0.5 * width * (x + 1.0)).ravel(), (0.5 * width * w).ravel())


# 144 nodes; against the exact beta-binomial 1 - B(a, b + n) / B(a, b) its P_D errs by at
# most 1.2e-4 over a in 0.05..100, b in 0.05..100, n in 1..108,000 (tests/unit/test_looks.py).
QUADRATURE = Quadrature.composite(n_uniform=32, ratio=0.25, n_geometric=8, order=3)
# log(1 - p) for p = 1 (a bin the model calls certain) would be -inf, and 0 looks * -inf
# NaN in the matrix product: this finite floor gives exp(n * floor) = 0 for any n >= 1.
_LOG_MISS_FLOOR = -1e300


def pd_of_node_log_miss(log_miss_nodes: np.ndarray) -> np.ndarray:
    """Cumulative P_D (float64) from log-misses at the ``QUADRATURE`` nodes (..., J):
    1 - sum_j w_j exp(L_j). Sum the node log-misses of several grids (cameras, detectors)
    first to combine them for one person."""
    return 0.0 - np.expm1(log_miss_of_nodes(log_miss_nodes))


def log_miss_of_nodes(log_miss_nodes: np.ndarray) -> np.ndarray:
    """log P_miss (float64, <= 0) from log-misses at the ``QUADRATURE`` nodes (..., J):
    log sum_j w_j exp(L_j), shifted by the largest L_j (row by row, so a row's value does
    not depend on the others)."""
    nodes = np.array(log_miss_nodes, dtype=np.float64)  # a copy, worked on in place
    top = nodes.max(axis=-1, keepdims=True)
    top[~np.isfinite(top)] = 0.0  # all -inf: a certain detection
    nodes -= top
    np.exp(nodes, out=nodes)
    nodes *= QUADRATURE.weights
    with np.errstate(divide="ignore"):
        out = np.log(nodes.sum(axis=-1)) + top[..., 0]
    result: np.ndarray = np.minimum(out, 0.0)
    return result


# -- what the grid stores per cell ----------------------------------------------------------

class CorrelatedLooks:
    """The state ``CORRELATED`` keeps per cell: the number of its counted looks in each bin
    of the detector model, ``counts`` uint32 (rows, cols, K) (the grid's, tile by tile;
    ``dtype`` and ``depth``). The sufficient statistic: given the latent q the looks are
    independent, so P_miss depends only on how many fell in each bin, not on their order,
    time or vehicle; grids merge by adding counts (``combined``).

    The bins are those of the kernel's table (``DetectorModel.padded_tables_by_blur``): the
    N size bins (K = N), and with blur bins also each (blur bin, size bin) pair
    (K = N (M + 1): the size-only row for frames of unknown blur, then the M blur rows). A
    look's detectability in a blur row has that row's mean and its size bin's correlation.

    uint32 holds 4.29e9 looks of one cell in one bin: 4.5 years of a 30 fps camera hovering
    over it (uint16 would overflow after 36 minutes of such a hover).
    """

    dtype = np.dtype(np.uint32)

    def __init__(self, detector: DetectorModel) -> None:
        if detector.looks is None:
            raise ValueError(f"coverage.looks: correlated needs the detector model's looks "
                             f"section (looks.correlation, written by pdcov detector fit); "
                             f"{detector.source or 'the detector model'} has none")
        pd, _ = detector.padded_tables_by_blur()
        n_pad = detector.n_bins + 2
        size_bin, row = np.arange(len(pd)) % n_pad, np.arange(len(pd)) // n_pad
        # Table rows holding bins: all but the last (beyond the last blur edge) with blur.
        is_bin = (size_bin >= 1) & (size_bin <= detector.n_bins) & (
            row < max(1, detector.n_table_rows - 1))
        self.n_bins = int(is_bin.sum())
        # Slot in ``counts`` of each table index, -1 for indices that are not bins.
        self.slot = np.full(len(pd), -1, dtype=np.int64)
        self.slot[is_bin] = np.arange(self.n_bins)
        # log(1 - Q_k(q_j)): (K, J), the bins' detectability at the quadrature nodes.
        rho = np.asarray(detector.looks.correlation)[size_bin[is_bin] - 1]
        p = detectability_quantile(pd[is_bin][:, None], rho[:, None], QUADRATURE.q[None, :])
        with np.errstate(divide="ignore"):
            self.log1m_nodes = np.maximum(np.log1p(-p), _LOG_MISS_FLOOR)

    @property
    def depth(self) -> tuple[int]:
        return (self.n_bins,)

    def add(self, counts: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """Count one look in ``counts`` (rows, cols, K; written in place) per cell whose
        table index ``idx`` (rows, cols; the kernel's: 0 for cells not counted) is a bin;
        returns those cells (bool, (rows, cols))."""
        slot = self.slot.take(idx)
        counted = slot >= 0
        rows, cols = np.nonzero(counted)
        # One look per cell: the targets are distinct, so a fancy += counts each once.
        counts[rows, cols, slot[rows, cols]] += np.uint32(1)
        return counted

    def log_miss_nodes(self, counts: np.ndarray) -> np.ndarray:
        """Per cell of ``counts`` (rows, cols, K), log P_miss given q at each node:
        (rows, cols, J) float64, sum_i n_i log(1 - Q_i(q_j))."""
        out: np.ndarray = np.einsum("rci,ij->rcj", counts.astype(np.float64),
                                    self.log1m_nodes)
        return out

    def log_miss_of(self, counts: np.ndarray) -> np.ndarray:
        """log P_miss (float64, (k,)) of cells with these counts ((k, K), one row a cell):
        0 where no look was counted. Each cell's value depends on its counts only, not on
        which other cells are computed with it (a fixed order of operations): the daemon,
        reading windows as frames come, and ``pdcov evaluate``, reading once, get the same
        bits. The counts of two grids of this detector model added give the P_miss of one
        person seen by both."""
        seen = counts.any(axis=1)
        out = np.zeros(len(counts))
        at = np.flatnonzero(seen)
        # In chunks, so the (cells, J) temporaries stay in cache (and memory small); einsum's
        # own loop (not BLAS) sums each cell's bins in one fixed order.
        for start in range(0, len(at), _CHUNK_CELLS):
            k = at[start:start + _CHUNK_CELLS]
            nodes = np.einsum("ki,ij->kj", counts[k].astype(np.float64), self.log1m_nodes)
            out[k] = log_miss_of_nodes(nodes)
        return out

    @staticmethod
    def combined(states: list[np.ndarray]) -> np.ndarray:
        """The counts of one person seen in all of ``states`` (the same cells): their sum."""
        return np.asarray(np.sum(states, axis=0, dtype=np.uint32))


class ViewpointLooks:
    """The state ``VIEWPOINT`` keeps per cell and viewpoint bin: the best look, ``best``
    uint8 (rows, cols, V), the rank by P_D of its padded bin index (0: none); grids merge
    by the maximum (``combined``). The cumulative P_D is 1 - prod over viewpoint bins of
    (1 - P_D of the best look)."""

    dtype = np.dtype(np.uint8)

    def __init__(self, detector: DetectorModel, bins: ViewpointBins) -> None:
        pd, _ = detector.padded_tables_by_blur()
        if len(pd) > 255:
            raise ValueError(f"coverage.looks: viewpoint ranks bins in uint8; the detector "
                             f"model's table has {len(pd)} entries (size bins + 2, times "
                             f"the blur rows), at most 255")
        self.bins = bins
        # Ranks 1.. in order of P_D of the bins with P_D > 0; 0 (no look) for the others.
        order = np.argsort(pd, kind="stable")
        ranked = order[pd[order] > 0]
        self.rank = np.zeros(len(pd), dtype=np.uint8)
        self.rank[ranked] = np.arange(1, len(ranked) + 1)
        self.log1m_by_rank = np.zeros(len(ranked) + 1)
        with np.errstate(divide="ignore"):
            self.log1m_by_rank[1:] = np.log1p(-pd[ranked])

    @property
    def depth(self) -> tuple[int]:
        return (self.bins.n_bins,)

    def add(self, best: np.ndarray, idx: np.ndarray, x_m: np.ndarray, y_m: np.ndarray,
            z_m: np.ndarray | float, r_cam_enu: np.ndarray) -> np.ndarray:
        """Keep in ``best`` (rows, cols, V; written in place), per cell and viewpoint bin,
        the better of its best look and this one (padded bin index ``idx``, 0 for cells not
        counted); x_m (cols,), y_m (rows,) and z_m (rows, cols or scalar): the cells'
        centres (ENU m). Returns the cells with a look of P_D > 0 (bool, (rows, cols))."""
        rank = self.rank.take(idx)
        counted = rank != 0
        rows, cols = np.nonzero(counted)
        if len(rows) == 0:
            return counted
        z = z_m if np.ndim(z_m) == 0 else np.asarray(z_m)[rows, cols]
        v = self.bins.bin_of(r_cam_enu[0] - x_m[cols], r_cam_enu[1] - y_m[rows],
                             r_cam_enu[2] - z)
        best[rows, cols, v] = np.maximum(best[rows, cols, v], rank[rows, cols])
        return counted

    def log_miss_of(self, best: np.ndarray) -> np.ndarray:
        """log P_miss (float64, (k,)) of cells with these best ranks ((k, V), one row a
        cell): the maximum of two grids' ranks of this detector model is the best look of
        one person seen by both."""
        out: np.ndarray = self.log1m_by_rank.take(best).sum(axis=1)
        return out

    @staticmethod
    def combined(states: list[np.ndarray]) -> np.ndarray:
        """The best looks of one person seen in all of ``states`` (the same cells)."""
        return np.asarray(np.maximum.reduce(states))


LooksModel = CorrelatedLooks | ViewpointLooks


def looks_model(config: LooksConfig, detector: DetectorModel) -> LooksModel | None:
    """The model of the per-cell looks state a rule keeps (None: independent, the
    log-miss sums)."""
    if config.rule is LooksRule.CORRELATED:
        return CorrelatedLooks(detector)
    if config.rule is LooksRule.VIEWPOINT:
        return ViewpointLooks(detector, config.viewpoint)
    return None


def same_looks_tables(a: DetectorModel, b: DetectorModel) -> bool:
    """Whether two detector models give a look in each bin the same meaning for the looks
    state: the same P_D and correlation per bin."""
    rho = [None if m.looks is None else m.looks.correlation for m in (a, b)]
    return a.p_detect == b.p_detect and rho[0] == rho[1]
