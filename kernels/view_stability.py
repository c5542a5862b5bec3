"""How fast a class's appearance changes around a training view: where a
capture between the training views is modelled worst.

With the adaptive scale (:mod:`~jaxrecog.kernels.adaptive_scale`) a capture
that no class explains weighs little and does not count toward the stop, so
a view the model cannot explain costs a step.  Which views those are is in
the model itself: a view-mixture likelihood holds, per training view, the
components of the views interpolated toward each neighbouring position
(``m = 1 .. M-1``, :mod:`jaxrecog.view_interpolation`).  Where they lie far
from the training view's own component (``m = 0``), the appearance changes
fast between the training views and a capture between them is poorly
covered.  The instability of view ``v`` of class ``c`` (camera ``i``, level
0, in the position's eigenspace) is

    d_i[v, c] = max_m || mu_i[v, c, 0, m] - mu_i[v, c, 0, 0] || / mean_{v', c'} (same)

(normalised to mean 1 per camera; 0 everywhere for a family without view
components).  An offset below ``ROUND_TOL`` times the camera's mean
``||mu_i[v, c, 0, 0]||`` is rounding and counts as 0: a position without
neighbouring views (a camera with one position, say) repeats its training
view in every slot, and the slots' means then differ from it only by how the
float32 products of training round (OpenBLAS rounds the same image
differently at different rows of a product, by kernel and CPU); normalised
to mean 1, that rounding would be read as instability and shift every
configuration's score by the same amount.  On the photo benchmark's 40 deg
grid the quarter of test captures with the largest ``d`` is explained
(``s* <= √2``) 49 % of the time, the half with the smallest 98 %.

The expected instability of configuration ``a = (v_0, v_1, ...)`` under the
belief is ``sum_i E_{c ~ P(c)} d_i[v_i, c]``, row-major over the
configurations (:func:`expected_instability`); the planner
``mi-class-pairwise-stable`` subtracts it, times a weight, from the robust
pairwise MI.
"""

from __future__ import annotations

import operator

import jax.numpy as jnp
from jaxtyping import Array, Float

from ._grid import lse
from .config_grid import ConfigGrid

__all__ = ["ROUND_TOL", "view_instability", "expected_instability"]

#: a component offset below this fraction of the camera's mean feature norm is
#: rounding (module doc): on the tutorial's model the rounding offsets are below
#: 1e-7 of it and the smallest offset between real views is 0.16 of it
ROUND_TOL = 1e-4


def view_instability(lik) -> Float[Array, "V C"]:
    """``d[v, c]`` of one camera's likelihood (module doc); zeros for a family
    without view components, and where the offsets are rounding."""
    if not getattr(lik, "view_components", False):
        return jnp.zeros((lik.n_positions, lik.n_classes), lik.dtype)
    mu = jnp.asarray(lik.mu)[:, :, 0]                                   # [V, C, M, K]
    d = jnp.max(jnp.linalg.norm(mu[:, :, 1:] - mu[:, :, :1], axis=-1), axis=-1)   # [V, C]
    d = jnp.where(d > ROUND_TOL * jnp.mean(jnp.linalg.norm(mu[:, :, 0], axis=-1)), d, 0.0)
    return d / jnp.maximum(jnp.mean(d), jnp.finfo(d.dtype).tiny)


def expected_instability(instability: tuple[Float[Array, "_V C"], ...], log_pc: Float[Array, " C"]
                         ) -> Float[Array, " A"]:
    """``sum_i E_{c ~ P(c)} d_i[v_i, c]`` for every configuration (row-major)."""
    p = jnp.exp(log_pc - lse(log_pc, axis=-1))
    grid = ConfigGrid(tuple(d.shape[0] for d in instability))
    return grid.combine(operator.add, [d @ p for d in instability], jnp.zeros(grid.positions, p.dtype))
