"""P_D and P_FA as logistic functions of log size (hit/miss analysis of MIL-HDBK-1823A):
the maximum-likelihood curve with its 95 % Wald band, and the ``DetectorModel`` written
from it on fine log-spaced size bins (px)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import optimize, special, stats

from pdcov.core.detector import DetectorModel
from pdcov.detection.bins import CONFIDENCE_LEVEL, bin_of, count_in_bins, interval_pairs
from pdcov.detection.matching import Matches
from pdcov.detection.statistics import model_of_counts
from pdcov.errors import ConfigError, DetectorModelError, InputFileError

__all__ = ["LogisticCurve", "fit_logistic", "fit_logistic_curve"]

_Z95 = float(stats.norm.ppf(0.5 + CONFIDENCE_LEVEL / 2))


@dataclass(frozen=True, slots=True)
class LogisticCurve:
    """P(s) = 1 / (1 + exp(-(b0 + b1 z + ... + b_k z^k))), z = (ln s - log_center) / log_scale,
    s in px; ``covariance`` of the coefficients from the observed information."""

    coefficients: tuple[float, ...]
    covariance: tuple[tuple[float, ...], ...]
    log_center: float
    log_scale: float

    def design(self, size_px: np.ndarray) -> np.ndarray:
        z = (np.log(np.asarray(size_px, dtype=float)) - self.log_center) / self.log_scale
        return np.vander(z, len(self.coefficients), increasing=True)

    def evaluate(self, size_px: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """P and its pointwise 95 % band (Wald on the logit scale) at the sizes."""
        X = self.design(size_px)
        eta = X @ np.asarray(self.coefficients)
        se = np.sqrt(np.einsum("ij,jk,ik->i", X, np.asarray(self.covariance), X))
        return special.expit(eta), special.expit(eta - _Z95 * se), special.expit(eta + _Z95 * se)

    def to_dict(self) -> dict[str, Any]:
        return {"log_center": self.log_center, "log_scale": self.log_scale,
                "coefficients": list(self.coefficients),
                "covariance": [list(r) for r in self.covariance]}


def fit_logistic_curve(size_px: np.ndarray, hit: np.ndarray, degree: int = 1) -> LogisticCurve:
    """Maximum-likelihood logistic regression of hits on a polynomial in log size."""
    s, y = np.asarray(size_px, dtype=float), np.asarray(hit, dtype=float)
    if degree not in (1, 2):
        raise ConfigError(f"--logistic-degree: expected 1 or 2, got {degree}")
    if s.size == 0 or y.sum() < degree + 1 or (1 - y).sum() < degree + 1:
        raise DetectorModelError(
            f"logistic fit needs at least {degree + 1} hits and {degree + 1} misses, got "
            f"{int(y.sum())} and {int((1 - y).sum())}; use the binned model")
    ln = np.log(s)
    curve = LogisticCurve((0.0,) * (degree + 1), (), float(ln.mean()),
                          float(ln.std()) or 1.0)
    X = curve.design(s)

    def nll(b: np.ndarray) -> tuple[float, np.ndarray]:
        eta = X @ b
        return float(np.sum(np.logaddexp(0, eta) - y * eta)), X.T @ (special.expit(eta) - y)

    def hess(b: np.ndarray) -> np.ndarray:
        p = special.expit(X @ b)
        return (X * (p * (1 - p))[:, None]).T @ X

    res = optimize.minimize(nll, np.zeros(degree + 1), jac=True, hess=hess,
                            method="trust-exact")
    H = hess(res.x)
    cov = np.linalg.pinv(H)
    # Where size separates hits from misses the MLE does not exist: the optimiser stops at
    # large coefficients whose standard errors (in units of z) explode.
    if not res.success or np.max(np.sqrt(np.abs(np.diag(cov)))) > 10:
        raise DetectorModelError(
            f"logistic fit is undetermined ({res.message.rstrip('.')}; standard errors "
            f"{np.sqrt(np.abs(np.diag(cov))).round(1).tolist()}): too few objects, or size "
            f"separates hits from misses; use the binned model")
    return LogisticCurve(tuple(float(v) for v in res.x),
                         tuple(tuple(float(v) for v in r) for r in cov),
                         curve.log_center, curve.log_scale)


def fit_logistic(matches: Matches, edges: tuple[float, ...], n_fine: int = 64,
                 degree: int = 1) -> DetectorModel:
    """P_D and P_FA as logistic functions of log size (hit/miss analysis of MIL-HDBK-1823A),
    fitted to the objects and detections inside [edges[0], edges[-1]) and written on
    ``n_fine`` log-spaced bins over that range, valued at each bin's geometric centre."""
    if n_fine < 1:
        raise ConfigError(f"--fine-bins: expected at least 1, got {n_fine}")
    lo = edges[0] if edges[0] > 0 else float(matches.truth_size_px.min(initial=math.inf))
    if not lo < edges[-1]:
        raise InputFileError("no ground-truth object inside the bins to fit")
    fine = tuple(float(v) for v in np.geomspace(lo, edges[-1], n_fine + 1))
    ti = bin_of(matches.truth_size_px, fine) >= 0
    di = bin_of(matches.detection_size_px, fine) >= 0
    pd_curve = fit_logistic_curve(matches.truth_size_px[ti], matches.truth_detected[ti], degree)
    fa_curve = fit_logistic_curve(matches.detection_size_px[di], ~matches.detection_true[di],
                                  degree)
    centres = np.sqrt(np.asarray(fine[:-1]) * np.asarray(fine[1:]))
    p_d, d_lo, d_hi = pd_curve.evaluate(centres)
    p_fa, fa_lo, fa_hi = fa_curve.evaluate(centres)
    c = count_in_bins(matches, fine)
    return model_of_counts(matches, c, p_d, p_fa, {
        "model": "logistic", "interval_method": "wald-logit", "confidence_level":
        CONFIDENCE_LEVEL, "p_detect_ci95": interval_pairs(d_lo, d_hi),
        "p_false_alarm_ci95": interval_pairs(fa_lo, fa_hi),
        "logistic": {"link": "logit", "covariate": "z = (ln(size_px) - log_center) / log_scale",
                     "degree": degree, "fit_range_px": [lo, edges[-1]],
                     "p_detect": pd_curve.to_dict(), "p_false_alarm": fa_curve.to_dict()}})
