"""Calibration measures of a recognition campaign, over :class:`~jaxrecog.results.TrialResult` lists.

A trial's *confidence* is its exit probability (posterior of the reported
(object, pose)), its outcome ``correct`` (object and pose right).  With equal
width bins ``B_b = ((b-1)/n, b/n]`` over ``[0, 1]`` (the first bin includes 0):

* expected calibration error ``ECE = Σ_b |B_b|/N · |acc(B_b) − conf(B_b)|``;
* reliability diagram: per non-empty bin, mean confidence, accuracy, count;
* confident-error rate: of the trials that stopped on the threshold
  (``stopped`` and ``exit_prob ≥ P_th``), the fraction that are wrong.  A
  calibrated recognizer keeps it ≤ ``1 − P_th``.

Every rate comes with its 95 % Wilson score interval
(:func:`~jaxrecog.results.wilson_interval`).
"""

from __future__ import annotations

import dataclasses
from typing import Sequence

import numpy as np

from .results import TrialResult, wilson_interval

__all__ = [
    "ReliabilityBin",
    "ConfidentErrors",
    "reliability_bins",
    "expected_calibration_error",
    "confident_errors",
    "campaign_metrics",
]


@dataclasses.dataclass(frozen=True)
class ReliabilityBin:
    lo: float
    hi: float
    count: int
    confidence: float  # mean exit probability in the bin
    accuracy: float  # fraction correct in the bin


@dataclasses.dataclass(frozen=True)
class ConfidentErrors:
    """``rate = wrong / stopped`` (0 when nothing stopped) and ``rate_of_all = wrong / trials``."""

    trials: int
    stopped: int
    wrong: int
    rate: float
    rate_of_all: float


def _arrays(results: Sequence[TrialResult]):
    results = list(results)
    if not results:
        raise ValueError("no trial results")
    p = np.array([r.exit_prob for r in results], np.float64)
    if not np.all(np.isfinite(p)) or np.any(p < 0) or np.any(p > 1 + 1e-6):
        bad = next(r for r in results if not (0 <= r.exit_prob <= 1 + 1e-6))
        raise ValueError(f"trial {bad.trial}: exit probability {bad.exit_prob} is not in [0, 1]")
    ok = np.array([r.correct for r in results], bool)
    return np.clip(p, 0.0, 1.0), ok


def reliability_bins(results: Sequence[TrialResult], n_bins: int = 10) -> list[ReliabilityBin]:
    """The non-empty bins of the reliability diagram (module docstring)."""
    if n_bins < 1:
        raise ValueError(f"n_bins must be >= 1, got {n_bins}")
    p, ok = _arrays(results)
    b = np.clip(np.ceil(p * n_bins).astype(int) - 1, 0, n_bins - 1)
    out = []
    for k in range(n_bins):
        sel = b == k
        if sel.any():
            out.append(ReliabilityBin(k / n_bins, (k + 1) / n_bins, int(sel.sum()),
                                      float(p[sel].mean()), float(ok[sel].mean())))
    return out


def expected_calibration_error(results: Sequence[TrialResult], n_bins: int = 10) -> float:
    """``ECE = Σ_b |B_b|/N · |acc(B_b) − conf(B_b)|`` (module docstring)."""
    bins = reliability_bins(results, n_bins)
    n = sum(b.count for b in bins)
    return float(sum(b.count * abs(b.accuracy - b.confidence) for b in bins) / n)


def confident_errors(results: Sequence[TrialResult], p_threshold: float = 0.95) -> ConfidentErrors:
    """Trials stopped at ``exit_prob ≥ p_threshold`` and wrong (module docstring)."""
    if not 0.0 < p_threshold <= 1.0:
        raise ValueError(f"p_threshold must be in (0, 1], got {p_threshold}")
    p, ok = _arrays(results)
    stopped = np.array([r.stopped for r in results], bool) & (p >= p_threshold)
    wrong = int(np.sum(stopped & ~ok))
    n_stop = int(stopped.sum())
    return ConfidentErrors(len(p), n_stop, wrong, wrong / n_stop if n_stop else 0.0, wrong / len(p))


def campaign_metrics(results: Sequence[TrialResult], p_threshold: float = 0.95,
                     n_bins: int = 10) -> dict:
    """Recognition rate (%), mean views, mean exit probability, ECE and the
    confident-error rate (% of stopped trials, and % of all trials: the
    number every results table shows) of one campaign; each rate ``x`` with
    its 95 % Wilson interval ``x_ci = [lo, hi]`` in percent."""
    p, ok = _arrays(results)
    ce = confident_errors(results, p_threshold)

    def pct(k: int, n: int) -> list[float]:
        return [100.0 * x for x in wilson_interval(k, n)]

    return {
        "trials": len(p),
        "recognition_rate": 100.0 * float(ok.mean()),
        "mean_views": float(np.mean([r.steps for r in results])),
        "mean_exit_prob": float(p.mean()),
        "ece": expected_calibration_error(results, n_bins),
        "stopped": ce.stopped,
        "confident_errors": ce.wrong,
        "confident_error_rate": 100.0 * ce.rate,
        "confident_error_pct_of_trials": 100.0 * ce.rate_of_all,
        "recognition_rate_ci": pct(int(ok.sum()), len(p)),
        "confident_error_rate_ci": pct(ce.wrong, ce.stopped),
        "confident_error_pct_of_trials_ci": pct(ce.wrong, len(p)),
    }
