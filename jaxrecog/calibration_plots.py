"""Reliability diagram of one or more campaigns (matplotlib, Agg, PNG)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from ._files import check_output_file
from .metrics import expected_calibration_error, reliability_bins
from .results import TrialResult

__all__ = ["reliability_plot"]


def reliability_plot(campaigns: Mapping[str, Sequence[TrialResult]], path: str | os.PathLike, *,
                     n_bins: int = 10, p_threshold: float | None = 0.95,
                     title: str = "Reliability of the exit probability") -> Path:
    """Write a reliability diagram (accuracy vs. mean exit probability per bin,
    one line per campaign, ECE in the legend; trial counts per bin below) as PNG.

    Args:
        campaigns: label -> trial results (e.g. ``{"uncalibrated": ..., "calibrated": ...}``).
        path: the PNG to write.
        n_bins: equal-width confidence bins.
        p_threshold: draws the stop threshold P_th (``None`` = not drawn).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not campaigns:
        raise ValueError("no campaigns to plot")
    fig, (ax, axc) = plt.subplots(2, 1, figsize=(5.5, 6.5), sharex=True,
                                  gridspec_kw={"height_ratios": [3, 1]})
    ax.plot([0, 1], [0, 1], color="0.6", lw=1, ls="--", label="perfect calibration")
    width = 1.0 / n_bins / (len(campaigns) + 1)
    markers = "osD^v<>"
    for j, (label, results) in enumerate(campaigns.items()):
        bins = reliability_bins(results, n_bins)
        ece = expected_calibration_error(results, n_bins)
        conf = np.array([b.confidence for b in bins])
        acc = np.array([b.accuracy for b in bins])
        cnt = np.array([b.count for b in bins])
        line, = ax.plot(conf, acc, marker=markers[j % len(markers)], lw=1.5,
                        label=f"{label} (ECE {ece:.3f}, n={cnt.sum()})")
        lo = np.array([b.lo for b in bins])
        axc.bar(lo + (j + 0.5) * width, cnt, width=width, color=line.get_color(), align="edge")
    if p_threshold is not None:
        for a in (ax, axc):
            a.axvline(p_threshold, color="0.3", lw=0.8, ls=":")
        ax.text(p_threshold, 0.02, f" P_th={p_threshold:g}", fontsize=8, ha="right", rotation=90,
                va="bottom")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1.02)
    ax.set_ylabel("accuracy (correct object and pose)")
    ax.set_title(title)
    ax.legend(loc="upper left", fontsize=8)
    ax.grid(alpha=0.3)
    axc.set_xlabel("exit probability (confidence)")
    axc.set_ylabel("trials")
    axc.set_yscale("symlog", linthresh=1)
    axc.grid(alpha=0.3)
    fig.tight_layout()
    path = check_output_file(path, "plot")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
