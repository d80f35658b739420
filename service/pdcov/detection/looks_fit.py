"""How correlated a detector's looks at one person are: a beta-binomial per size bin.

The paper's recursion P_D(k) = P_D(k-1) + (1 - P_D(k-1)) P_D(s) treats every frame as an
independent trial. A person half hidden, in shadow or dressed like the ground is missed frame
after frame, while an easy one is found at once. Here each person has a latent detectability
p ~ Beta(a, b) in each size bin (mean mu = a / (a + b), intra-person correlation
rho = 1 / (a + b + 1); rho = 0 is the paper's independent looks), and each of the person's
looks in the bin is a hit with probability p. From tracked sequences (each person's looks,
hit or miss, in the size bin of the box) this module estimates mu and rho per bin by maximum
likelihood, with profile-likelihood 95 % intervals, and tests independence with the
likelihood-ratio test against the 50:50 chi-bar-square mixture (rho = 0 is on the boundary of
the parameter space: Self & Liang 1987). Pure: arrays in, results out. The method and what
the numbers mean: docs/detector-statistics.md.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import optimize, special, stats

from pdcov.core.detector import LooksModel
from pdcov.detection.bins import bin_of
from pdcov.detection.matching import MatchCollector, Matches, MatchSettings, TruthStatus
from pdcov.detection.tracks import TrackedFrame

MIN_PEOPLE = 10  # people with at least 2 looks in a bin needed for an estimate
MAX_CURVE_LOOKS = 30  # looks the measured found-after-n curve is written for
TEST_NAME = "lrt-chibar2"
INTERVAL_NAME = "profile-likelihood"
_Q95 = float(stats.chi2.ppf(0.95, 1))  # 3.84: profile interval of one parameter
_RHO_MAX = 1 - 1e-6
_MU_EPS = 1e-9


@dataclass(frozen=True, slots=True)
class TrackedLooks:
    """One row per look, in time order: each counted ground-truth box of a tracked frame
    (missed or detected), the person's index, the box size (detector-input px), and
    whether it was detected."""

    person: np.ndarray
    size_px: np.ndarray
    hit: np.ndarray
    n_people: int


def collect_looks(frames: Iterable[TrackedFrame], n_people: int,
                  settings: MatchSettings) -> tuple[Matches, TrackedLooks]:
    """Match every frame (``detection/matching.py``, per class) and follow each person
    through them: the set's matches, for the per-look P_D and P_FA, and the looks."""
    collector = MatchCollector(settings)
    person, size, hit = [], [], []
    for frame in frames:
        m, size_px = collector.add(frame.truth, frame.detections)
        counted = m.truth_status <= TruthStatus.DETECTED
        person.append(frame.person[counted])
        size.append(size_px[counted])
        hit.append(m.truth_status[counted] == TruthStatus.DETECTED)

    def cat(parts: list[np.ndarray], dtype: type) -> np.ndarray:
        return np.concatenate(parts).astype(dtype) if parts else np.zeros(0, dtype)

    return collector.result(), TrackedLooks(cat(person, int), cat(size, float),
                                            cat(hit, bool), n_people)


@dataclass(frozen=True, slots=True)
class PersonLooks:
    """Per person and size bin: looks (n) and hits (k), both (n_people, n_bins) integers."""

    n: np.ndarray
    k: np.ndarray

    @classmethod
    def from_looks(cls, person: np.ndarray, bin_index: np.ndarray, hit: np.ndarray,
                   n_people: int, n_bins: int) -> PersonLooks:
        """From one row per look: the person's index, the bin (-1: outside, dropped), hit."""
        keep = bin_index >= 0
        flat = person[keep] * n_bins + bin_index[keep]
        size = n_people * n_bins
        n = np.bincount(flat, minlength=size).reshape(n_people, n_bins)
        k = np.bincount(flat, hit[keep].astype(float), minlength=size).reshape(n_people, n_bins)
        return cls(n.astype(int), k.astype(int))


class BetaBinomialLikelihood:
    """Log-likelihood of (mu, rho) for people with n_i looks and k_i hits, up to the binomial
    coefficients (which do not depend on the parameters).

    Written as products (Prentice 1986) with theta = rho / (1 - rho):
    B(k + a, n - k + b) / B(a, b) = prod_{j<k} (mu + j theta) prod_{j<n-k} (1 - mu + j theta)
    / prod_{j<n} (1 + j theta), exact at rho = 0 (the binomial), where the Beta-function form
    is 0/0. Counts of people with k > j, n - k > j and n > j make it O(max n) per call.
    """

    def __init__(self, n: np.ndarray, k: np.ndarray) -> None:
        n, k = np.asarray(n, dtype=int), np.asarray(k, dtype=int)
        m = int(n.max(initial=0))
        j = np.arange(m)
        self._j = j.astype(float)
        self._a = (k[:, None] > j).sum(axis=0).astype(float)
        self._b = ((n - k)[:, None] > j).sum(axis=0).astype(float)
        self._c = (n[:, None] > j).sum(axis=0).astype(float)

    def __call__(self, mu: float, rho: float) -> float:
        theta = rho / (1 - rho)
        jt = self._j * theta
        with np.errstate(divide="ignore"):
            return float(self._a @ np.log(mu + jt) + self._b @ np.log(1 - mu + jt)
                         - self._c @ np.log1p(jt))

    def d_mu(self, mu: float, rho: float) -> float:
        """dLL / dmu; decreasing in mu, so the profile over mu has one root."""
        jt = self._j * (rho / (1 - rho))
        return float(np.sum(self._a / (mu + jt)) - np.sum(self._b / (1 - mu + jt)))

    def best_mu(self, rho: float) -> float:
        """The mu maximising the likelihood at this rho."""
        lo, hi = _MU_EPS, 1 - _MU_EPS
        if self.d_mu(lo, rho) <= 0:
            return lo
        if self.d_mu(hi, rho) >= 0:
            return hi
        return float(optimize.brentq(lambda m: self.d_mu(m, rho), lo, hi, xtol=1e-12))

    def best_rho(self, mu: float) -> float:
        """The rho in [0, 1) maximising the likelihood at this mu."""
        res = optimize.minimize_scalar(lambda r: -self(mu, r), bounds=(0.0, _RHO_MAX),
                                       method="bounded", options={"xatol": 1e-7})
        rho = float(res.x)
        return 0.0 if self(mu, 0.0) >= self(mu, rho) else rho


@dataclass(frozen=True, slots=True)
class BetaBinomialFit:
    """One bin's estimate. NaN (and ``reason``) where there is none; the intervals are
    profile-likelihood 95 % intervals; ``p_value_independent`` tests rho = 0."""

    n_people: int
    n_looks: int
    n_hits: int
    mean_pd: float = math.nan
    mean_pd_ci95: tuple[float, float] = (math.nan, math.nan)
    correlation: float = math.nan
    correlation_ci95: tuple[float, float] = (math.nan, math.nan)
    p_value_independent: float = math.nan
    reason: str | None = None

    @property
    def estimated(self) -> bool:
        return self.reason is None


def fit_beta_binomial(n: np.ndarray, k: np.ndarray) -> BetaBinomialFit:
    """Maximum-likelihood (mu, rho) of people with n looks and k hits (people with n = 0 are
    dropped); profile-likelihood intervals; the chi-bar-square likelihood-ratio test of
    rho = 0. Too few people, or only hits or only misses, give NaN with the reason."""
    n, k = np.asarray(n, dtype=int), np.asarray(k, dtype=int)
    k, n = k[n > 0], n[n > 0]
    counts = (int(n.size), int(n.sum()), int(k.sum()))
    n_multi = int((n >= 2).sum())
    if n_multi < MIN_PEOPLE:
        return BetaBinomialFit(*counts, reason=f"{n_multi} people with 2 or more looks, "
                                               f"fewer than {MIN_PEOPLE}")
    if k.sum() == 0 or k.sum() == n.sum():
        return BetaBinomialFit(*counts, reason="every look missed" if k.sum() == 0
                               else "every look hit")
    ll = BetaBinomialLikelihood(n, k)
    mu0 = float(k.sum() / n.sum())
    ll0 = ll(mu0, 0.0)
    res = optimize.minimize(lambda x: -ll(x[0], x[1]), np.array([mu0, 0.1]),
                            bounds=[(_MU_EPS, 1 - _MU_EPS), (0.0, _RHO_MAX)], method="L-BFGS-B")
    # Polish: the profile in rho (mu at its best for each rho) from the optimiser's rho.
    rho_hat = _polish_rho(ll, float(res.x[1]))
    mu_hat = ll.best_mu(rho_hat)
    ll_hat = ll(mu_hat, rho_hat)
    if ll0 >= ll_hat:
        rho_hat, mu_hat, ll_hat = 0.0, mu0, ll0
    lr = max(0.0, 2 * (ll_hat - ll0))
    # Under rho = 0 the statistic is 0 with probability 1/2 and chi-square(1) otherwise.
    p_value = 1.0 if lr <= 1e-9 else 0.5 * float(stats.chi2.sf(lr, 1))

    def rho_dev(r: float) -> float:
        return 2 * (ll_hat - ll(ll.best_mu(r), r)) - _Q95

    def mu_dev(m: float) -> float:
        return 2 * (ll_hat - ll(m, ll.best_rho(m))) - _Q95

    rho_ci = (_crossing(rho_dev, rho_hat, 0.0, 0.0), _crossing(rho_dev, rho_hat, _RHO_MAX, 1.0))
    mu_ci = (_crossing(mu_dev, mu_hat, _MU_EPS, 0.0), _crossing(mu_dev, mu_hat, 1 - _MU_EPS, 1.0))
    return BetaBinomialFit(*counts, mean_pd=mu_hat, mean_pd_ci95=mu_ci, correlation=rho_hat,
                           correlation_ci95=rho_ci, p_value_independent=p_value)


def _polish_rho(ll: BetaBinomialLikelihood, rho_start: float) -> float:
    def neg(r: float) -> float:
        return -ll(ll.best_mu(r), r)

    lo, hi = max(0.0, rho_start - 0.05), min(_RHO_MAX, rho_start + 0.05)
    res = optimize.minimize_scalar(neg, bounds=(lo, hi), method="bounded",
                                   options={"xatol": 1e-8})
    return float(res.x) if neg(float(res.x)) <= neg(rho_start) else rho_start


def _crossing(f: Any, estimate: float, end: float, edge: float) -> float:
    """Where f (< 0 at the estimate) crosses 0 between the estimate and ``end``; ``edge``
    when it stays below 0 all the way (that side of the interval reaches the boundary)."""
    if estimate == end or f(end) <= 0:
        return edge
    return float(optimize.brentq(f, min(estimate, end), max(estimate, end), xtol=1e-7))


def found_within(n_looks: np.ndarray | int, mean_pd: float, correlation: float) -> np.ndarray:
    """Share of people found within n looks: 1 - E[(1 - p)^n] = 1 - B(a, b + n) / B(a, b)
    with p ~ Beta(a, b) of this mean and correlation; 1 - (1 - mean)^n at rho = 0."""
    n = np.asarray(n_looks, dtype=float)
    if correlation <= 0:
        return 1 - (1 - mean_pd) ** n
    s = 1 / correlation - 1
    a, b = mean_pd * s, (1 - mean_pd) * s
    return 1 - np.exp(special.betaln(a, b + n) - special.betaln(a, b))


def measured_found_within(person: np.ndarray, bin_index: np.ndarray, hit: np.ndarray,
                          n_bins: int, max_looks: int = MAX_CURVE_LOOKS
                          ) -> tuple[np.ndarray, np.ndarray]:
    """Per bin and n = 1..max_looks: among people with at least n looks in the bin, the share
    with a hit among their first n looks there, and how many such people. Rows are looks in
    time order. Returns (share (n_bins, max_looks), NaN without people; people, same)."""
    keep = bin_index >= 0
    person, bin_index, hit = person[keep], bin_index[keep], hit[keep].astype(bool)
    share = np.full((n_bins, max_looks), math.nan)
    people = np.zeros((n_bins, max_looks), int)
    if person.size == 0:
        return share, people
    key = person.astype(np.int64) * n_bins + bin_index
    order = np.argsort(key, kind="stable")  # stable: keeps time order within a person
    key, hit, bins = key[order], hit[order], bin_index[order]
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    counts = np.diff(np.r_[starts, key.size])
    rank = np.arange(key.size) - np.repeat(starts, counts)  # look number within the group
    first_hit = np.full(starts.size, np.iinfo(np.int64).max)
    np.minimum.at(first_hit, np.repeat(np.arange(starts.size), counts)[hit], rank[hit])
    group_bin = bins[starts]
    for n in range(1, max_looks + 1):
        has_n = counts >= n
        found = has_n & (first_hit < n)
        people[:, n - 1] = np.bincount(group_bin[has_n], minlength=n_bins)
        f = np.bincount(group_bin[found], minlength=n_bins)
        with np.errstate(invalid="ignore", divide="ignore"):
            share[:, n - 1] = np.where(people[:, n - 1] > 0, f / people[:, n - 1], math.nan)
    return share, people


@dataclass(frozen=True, slots=True)
class LooksFit:
    """The per-bin beta-binomial fits and the measured found-after-n curves of a tracked
    set, and what it becomes in the model (``to_model``)."""

    bins: tuple[BetaBinomialFit, ...]
    found_share: np.ndarray  # (n_bins, MAX_CURVE_LOOKS)
    found_people: np.ndarray
    looks_outside_bins: int

    def to_model(self, record: dict[str, Any] | None = None) -> LooksModel:
        """The model's ``looks`` section: ``correlation`` (0 where there is no estimate: the
        engine takes those bins' looks as independent) and the fit's keys."""
        def num(v: float) -> float | None:
            return None if math.isnan(v) else round(float(v), 6)

        def pair(v: tuple[float, float]) -> list[float | None] | None:
            return None if math.isnan(v[0]) else [num(v[0]), num(v[1])]

        extra: dict[str, Any] = {
            "model": "beta_binomial",
            "estimated": [b.estimated for b in self.bins],
            "no_estimate_reason": [b.reason for b in self.bins],
            "correlation_mle": [num(b.correlation) for b in self.bins],
            "correlation_ci95": [pair(b.correlation_ci95) for b in self.bins],
            "mean_pd": [num(b.mean_pd) for b in self.bins],
            "mean_pd_ci95": [pair(b.mean_pd_ci95) for b in self.bins],
            "interval_method": INTERVAL_NAME,
            "test": TEST_NAME,
            "min_people": MIN_PEOPLE,
            "p_value_independent": [None if math.isnan(b.p_value_independent)
                                    else float(f"{b.p_value_independent:.4g}")
                                    for b in self.bins],
            "n_people": [b.n_people for b in self.bins],
            "n_looks": [b.n_looks for b in self.bins],
            "n_hits": [b.n_hits for b in self.bins],
            "found_within": {
                "share": [[num(v) for v in row] for row in self.found_share],
                "n_people": [[int(v) for v in row] for row in self.found_people]},
        }
        if record:
            extra["tracks"] = record
        # The engine takes rho in [0, 1): a fit at the bound (people always or never seen)
        # stays just below 1 after rounding.
        rho = tuple(min(round(float(b.correlation), 6), 0.999999) if b.estimated else 0.0
                    for b in self.bins)
        return LooksModel(rho, extra)


def fit_looks(looks: TrackedLooks, edges_px: tuple[float, ...]) -> LooksFit:
    """Fit every bin [edge_i, edge_i+1) px of the looks (those outside all bins dropped)."""
    n_bins = len(edges_px) - 1
    bins = bin_of(looks.size_px, edges_px)
    per_person = PersonLooks.from_looks(looks.person, bins, looks.hit, looks.n_people, n_bins)
    fits = tuple(fit_beta_binomial(per_person.n[:, i], per_person.k[:, i])
                 for i in range(n_bins))
    share, people = measured_found_within(looks.person, bins, looks.hit, n_bins)
    return LooksFit(fits, share, people, int((bins < 0).sum()))
