"""Evidence that knows when a capture is unlike every training view: a
per-capture variance scale chosen by profile likelihood.

A sensor model fitted to augmented copies of the training views (eq.
4.23-4.24), even calibrated on views 5° off the grid, is far too sure on a
capture it has not seen the like of: a real capture 20° between training
views is explained *badly by every class*, and the class that happens to be
least bad wins by tens of nats, so two such captures stop a trial wrong at
P = 0.999 (docs/results.md, "Real photos").  What tells such a capture apart
is the absolute fit of its best class: on the photo benchmark's 40° grid the
best class's log-likelihood of a capture the model gets wrong is ~20 nats
below that of one it gets right.

The adaptive scale inflates every class's covariance of one capture ``g`` at
camera position ``v`` by one common factor ``s``, the one under which the
capture is explained best (a profile likelihood over ``s`` on a geometric
grid ``S = {1, √2, 2, ..., s_max}``)::

    s*(g, v)     = argmax_{s in S}  max_{c, k}  log p_s(g | c, k, v)
    log p*(g | c, k, v) = log p_{s*}(g | c, k, v)

where ``p_s`` is the likelihood with covariance ``s · Σ`` (for the
Gaussians ``-q / (2 s) - K/2 log s - ½ log|2πΣ|``, i.e. a temperature
``1/s`` on every class's quadratic term; :meth:`Likelihood.scaled`).  A
capture the model explains (``s* = 1``) keeps the thesis's evidence
exactly; a capture ``s*`` times worse than the model's own spread gives
evidence ``s*`` times weaker, for every class alike, so it can no longer
drive the belief to 1 on its own.  Unlike the Student-t (a scale per class,
which lets a wrong class that fits better keep its lead) the scale is
shared: the ranking of the classes under one capture is unchanged, only the
capture's weight in the belief.

``explained``: ``s* <= EXPLAINED_SCALE`` (√2, the grid's first step).  The
recognizer counts only explained image sets toward ``min_views``
(:class:`jaxrecog.recognizer.Recognizer` ``adaptive_scale``), so a trial
whose captures all fall between the training views looks again instead of
stopping.  An image set is explained when *some* camera's capture is: a
camera whose capture is not already weighs less, and asking every camera
(measured on the synthetic two-camera rig with cardboard occluders, an
uncalibrated model: camera 2's occluded captures sit at ``s* = 2`` step
after step) would hold a trial to the step limit while camera 1 explains
every view.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Int

__all__ = ["EXPLAINED_SCALE", "scale_grid", "adaptive_log_density", "adaptive_camera_log_likelihoods"]

#: a capture is "explained" when its profile scale is at most this (the grid's first step above 1)
EXPLAINED_SCALE = math.sqrt(2.0)


def scale_grid(max_scale: float) -> tuple[float, ...]:
    """``(1, √2, 2, 2√2, ...)`` up to ``max_scale`` (>= 1): the scales the
    profile chooses from.  ``max_scale = 1`` is ``(1,)`` (no adaptation)."""
    if not (isinstance(max_scale, (int, float)) and math.isfinite(max_scale) and max_scale >= 1.0):
        raise ValueError(f"adaptive_scale must be a finite number >= 1 (1 = off), got {max_scale!r}")
    n = int(math.floor(2.0 * math.log2(max_scale) + 1e-9))
    return tuple(2.0 ** (j / 2.0) for j in range(n + 1))


def adaptive_log_density(lik, g: Float[ArrayLike, " K"], scales: tuple[float, ...]
                         ) -> tuple[Float[Array, "C L"], Float[Array, ""]]:
    """``(log p*(g | c, k), s*)`` of one capture under one position's
    likelihood ``lik`` (module doc).  ``scales`` is static (a tuple from
    :func:`scale_grid`); with ``(1,)`` this is ``lik.log_density(g)``, ``s* = 1``.

    The family's ``scaling_terms`` are computed once and evaluated at every
    scale (``scaled_log_density``), so the profile costs one density
    evaluation plus ``len(scales)`` cheap rescalings."""
    g = jnp.asarray(g)
    if len(scales) == 1 and scales[0] == 1.0:
        return lik.log_density(g), jnp.ones((), g.dtype)
    n_levels = lik.n_levels
    terms = lik.scaling_terms(g[None])
    log_s = jnp.log(jnp.asarray(scales, g.dtype))
    lls = jnp.stack([lik.scaled_log_density(terms, jnp.full((n_levels,), ls, g.dtype))[0]
                     for ls in log_s])                                             # [S, C, L]
    fit = jnp.max(jnp.where(jnp.isnan(lls), -jnp.inf, lls).reshape(len(scales), -1), axis=1)
    j = jnp.argmax(fit)
    return lls[j], jnp.exp(log_s[j])


def adaptive_camera_log_likelihoods(gs: tuple[Float[ArrayLike, " _K"], ...], config: Int[ArrayLike, " n"],
                                    likelihoods, scales: tuple[float, ...]
                                    ) -> tuple[tuple[Float[Array, "C _L"], ...], Bool[Array, ""]]:
    """Per-camera ``log p*(g_i | c, k_i, v_i)`` (as
    :func:`~jaxrecog.kernels.camera_log_likelihoods`, each camera's capture
    with its own ``s*``) and whether some camera's capture was explained
    (``s* <= EXPLAINED_SCALE``; module doc)."""
    out, ok = [], []
    for i, (lik, g) in enumerate(zip(likelihoods, gs)):
        ll, s = adaptive_log_density(lik.at(config[i]), g, scales)
        out.append(ll)
        ok.append(s <= EXPLAINED_SCALE * (1 + 1e-6))
    return tuple(out), jnp.any(jnp.stack(ok))
