"""Should the planner prefer stable views?  A test on held-out captures.

``mi-class-pairwise-stable`` scores ``I(c; g | a) - w · E[d]``, the expected
view instability ``d`` of the configuration (:mod:`jaxrecog.kernels.view_stability`).
That pays where captures fall *between* the training views: there a capture
at an unstable view is often one no class explains (adaptive scale
``s* > √2``), which costs a step (real photos, 40° grid: 2.43 views against
3.60 for the plain planner).  Where captures fall *on* the training views it
costs rate: on the synthetic rig's case (iii) the one camera-1 view that
tells a look-alike pair apart is an unstable one, and the term steers away
from it (93.5 % against 96.5 %, docs/results.md).

The model alone cannot tell the two situations apart: its instability (or
the gaps between its view components in its own noise units, measured: a
median predicted scale of 1.16 on the rig's DB2 model against 1.11 on the
photos' 40° model) looks the same in both.  Held-out captures of the rig
can.  On them, if instability predicts unexplained captures, an unexplained
capture's ``d[v, c]`` (its position, its true class) is larger than an
explained one's.  The statistic is the area under the curve

    AUC = P(d_unexplained > d_explained) + ½ P(tie) = U / (n_u · n_e)

with ``U`` the Mann-Whitney statistic, and the one-sided test of ``AUC >
½``.  The fitted weight is the planner's measured default ``w = 1`` when the
test rejects at ``alpha`` (0.01) with at least ``min_unexplained`` (5)
unexplained captures, and ``w = 0`` (the plain pairwise MI) otherwise.  On
the photo benchmark's calib splits (5° off the grid) the test rejects at
every grid (AUC 0.80-0.92, p < 1e-6).

Public: :func:`capture_scales`, :func:`auc_test`, :func:`fit_stability`, :func:`with_stability`,
:class:`StabilityFit`.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import numpy as np
from scipy import stats

from .kernels.adaptive_scale import EXPLAINED_SCALE, adaptive_log_density, scale_grid
from .kernels.view_stability import view_instability
from .recipes import AUTO

__all__ = ["StabilityFit", "auc_test", "capture_scales", "fit_stability", "with_stability", "DEFAULT_ALPHA", "DEFAULT_MIN_UNEXPLAINED"]

#: the one-sided test's level
DEFAULT_ALPHA = 0.01
#: fewer unexplained held-out captures than this: no evidence either way, weight 0
DEFAULT_MIN_UNEXPLAINED = 5
_CHUNK = 64   # captures per program call (a view mixture's component set of one capture is ~1 MB)


@dataclasses.dataclass(frozen=True)
class StabilityFit:
    """What :func:`fit_stability` found.

    Attributes:
        weight: the planner's ``stability`` (1.0 or 0.0; module doc).
        auc: ``P(d_unexplained > d_explained)`` (NaN without both kinds).
        p_value: one-sided Mann-Whitney p-value of ``AUC > ½`` (1 without both kinds).
        n: held-out captures; n_unexplained: those with ``s* > √2``.
        alpha, min_unexplained: the test's settings.
    """

    weight: float
    auc: float
    p_value: float
    n: int
    n_unexplained: int
    alpha: float = DEFAULT_ALPHA
    min_unexplained: int = DEFAULT_MIN_UNEXPLAINED

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["auc"] = None if math.isnan(self.auc) else self.auc
        return d

    def summary(self) -> str:
        auc = "n/a" if math.isnan(self.auc) else f"{self.auc:.3f}"
        why = ("instability predicts the unexplained ones" if self.weight else
               "too few unexplained to test" if self.n_unexplained < self.min_unexplained else
               "instability does not predict the unexplained ones")
        return (f"planner stability weight {self.weight:g}: {self.n_unexplained} of {self.n} held-out captures "
                f"unexplained, AUC {auc}, p = {self.p_value:.2g} ({why})")


@functools.partial(jax.jit, static_argnames="scales")
def _chunk_scales(lik, g, v, scales: tuple[float, ...]):
    return jax.vmap(lambda gi, vi: adaptive_log_density(lik.at(vi), gi, scales)[1])(g, v)


def capture_scales(lik, g: np.ndarray, position: np.ndarray, max_scale: float) -> np.ndarray:
    """``s*`` of every capture ``g[n]`` at ``position[n]`` under one camera's
    likelihood (:func:`~jaxrecog.kernels.adaptive_scale.adaptive_log_density`,
    the grid :func:`~jaxrecog.kernels.adaptive_scale.scale_grid` up to
    ``max_scale``), ``float [N]``.  Chunks of a fixed size (the last padded),
    so any ``N`` is one compiled program."""
    scales = scale_grid(max_scale)
    g = np.asarray(g, np.float32)
    position = np.asarray(position, np.int32)
    out = np.empty(len(g), np.float64)
    for i in range(0, len(g), _CHUNK):
        gs, vs = g[i:i + _CHUNK], position[i:i + _CHUNK]
        n = len(gs)
        if n < _CHUNK:
            gs = np.concatenate([gs, np.repeat(gs[-1:], _CHUNK - n, 0)])
            vs = np.concatenate([vs, np.repeat(vs[-1:], _CHUNK - n, 0)])
        out[i:i + n] = np.asarray(_chunk_scales(lik, jax.device_put(gs), jax.device_put(vs), scales))[:n]
    return out


def auc_test(x_unexplained: np.ndarray, x_explained: np.ndarray) -> tuple[float, float]:
    """``(AUC, one-sided p)`` of ``x_unexplained > x_explained`` (Mann-Whitney U;
    ``(nan, 1.0)`` when either group is empty)."""
    if len(x_unexplained) == 0 or len(x_explained) == 0:
        return float("nan"), 1.0
    u = stats.mannwhitneyu(x_unexplained, x_explained, alternative="greater")
    return float(u.statistic) / (len(x_unexplained) * len(x_explained)), float(u.pvalue)


def with_stability(model, recipe, calib=None):
    """``(model with its planner weight, fit or None)``: ``recipe.stability``
    when it is a number, else (``"auto"``) fitted on ``calib`` (held-out
    features, :func:`fit_stability` at the recipe's adaptive scale)."""
    fit = None
    weight = recipe.stability
    if weight == AUTO:
        fit = fit_stability(model, calib, max_scale=recipe.adaptive_scale)
        weight = fit.weight
    return dataclasses.replace(model, stability=float(weight)), fit


def fit_stability(model, calib, *, max_scale: float = 32.0, alpha: float = DEFAULT_ALPHA,
                  min_unexplained: int = DEFAULT_MIN_UNEXPLAINED) -> StabilityFit:
    """The planner's stability weight from held-out captures (module doc).

    Args:
        model: the :class:`~jaxrecog.sensor_model.SensorModel` (calibrated or not:
            the one the recognizer will use).
        calib: its held-out features (:class:`~jaxrecog.calibration_data.CalibrationFeatures`,
            e.g. :func:`~jaxrecog.calibration_data.features_from_database` of the ``calib`` split).
        max_scale: the adaptive scale's largest factor (the recipe's ``adaptive_scale``).
        alpha, min_unexplained: the test (module doc).
    """
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha must lie in (0, 1), got {alpha!r}")
    if len(scale_grid(max_scale)) < 3:
        raise ValueError(f"the stability fit needs an adaptive scale of at least 2 (a capture above √2 is "
                         f"unexplained), got {max_scale!r}")
    d_all, unexplained = [], []
    for cam, f in zip(model.cameras, calib.cameras):
        if len(f.g) == 0:
            continue
        s = capture_scales(cam.likelihood, f.g, f.position, max_scale)
        d = np.asarray(view_instability(cam.likelihood), np.float64)
        d_all.append(d[np.asarray(f.position), np.asarray(f.cls)])
        unexplained.append(s > EXPLAINED_SCALE * (1 + 1e-6))
    if not d_all:
        raise ValueError("no held-out captures to fit the planner's stability weight on")
    d, un = np.concatenate(d_all), np.concatenate(unexplained)
    if not np.all(np.isfinite(d)):
        raise FloatingPointError("view instability is not finite: the model holds non-finite means")
    auc, p = auc_test(d[un], d[~un])
    weight = 1.0 if (un.sum() >= min_unexplained and p < alpha) else 0.0
    return StabilityFit(weight, auc, p, int(len(d)), int(un.sum()), float(alpha), int(min_unexplained))
