"""A latent shared by every camera and every step: the rendered view of a
view mixture (not in the thesis).

A view mixture (:mod:`.view_mixture`) explains a capture by one of ``M``
components per class and level: ``m = 0`` the training view, ``m = 1 ..``
the object turned by the database's jitter offsets, the *same* offsets at
every position of every camera (``hardware.render.render_db.jitter_offsets``).
Marginalising ``m`` per capture, as ``log_density`` does, lets camera 1 pick
the view turned +15° and camera 2 the one turned -15° for the same object in
the same trial, and lets a camera that stays on its view count the same
systematic deviation twice.  The object has *one* turn per trial, so here
``m`` is part of the state:

    s = (c, m, k_0, k_1, ...),  P(s) = P(c, m) prod_i P_i(k_i | c, m)
    p(g_i | c, m, k_i, v_i) = p_m(g_i | c, k_i, v_i)     (the component, no weight)
    P_0(c, m) = P_0(c) w_m                                (the mixture weights as the prior of m)

The factorised belief of :mod:`.belief` holds this exactly with the
"extended class" ``e = c * M + m``: the likelihood is still a product over
cameras given ``e`` and the level transitions still act per camera, so
:func:`~.belief.update_with_info` and :func:`~.belief.transition_per_position`
run unchanged on ``[C * M]`` rows.  What the rest of the engine sees is the
marginal over ``m`` (:func:`marginal`): ``P(c) = sum_m P(c, m)`` exactly, and
per camera ``P_i(k | c) = sum_m P(m | c) P_i(k | c, m)``, the exact marginal of
each camera's level (their joint given ``c`` no longer factorises; the
planners score on this product of marginals with the marginal mixture
likelihood, an approximation of planning only: the belief itself is exact).
"""

from __future__ import annotations

from typing import TypeVar

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float, Int

from ._grid import lse
from .belief import Belief, PredictedBelief

#: a belief of either form (:func:`marginal` keeps the form)
B = TypeVar("B", Belief, PredictedBelief)

__all__ = ["shared_components", "extend", "marginal", "component_log_likelihoods"]


def shared_components(likelihoods) -> int:
    """``M``, the number of view components every camera's likelihood shares
    (a :class:`~.view_mixture._ViewMixture` per camera with the same ``M``),
    else a ``ValueError`` naming what is missing."""
    ms = []
    for i, lik in enumerate(likelihoods):
        if not getattr(type(lik), "view_components", False):
            raise ValueError(f"shared view: camera {i}'s likelihood {type(lik).kind!r} has no view components "
                             f"(train a view mixture, e.g. --likelihood view-mixture-lowrank with --view-jitter)")
        ms.append(int(lik.log_w.shape[-1]))
    if len(set(ms)) != 1:
        raise ValueError(f"shared view: the cameras' likelihoods have {ms} view components; they must share one set")
    return ms[0]


def extend(belief: Belief, log_pm: Float[ArrayLike, "C M"]) -> Belief:
    """``P(c, m) = P(c) P(m | c)`` and ``P_i(k | c, m) = P_i(k | c)``: a belief
    over ``C`` classes as one over the ``C * M`` extended classes ``c * M + m``.
    ``log_pm``: ``[C, M]`` log P(m | c), every row normalised."""
    log_pm = jnp.asarray(log_pm)
    c, m = log_pm.shape
    log_pc = (belief.log_pc[:, None] + log_pm).reshape(c * m)
    log_pk = tuple(jnp.repeat(lp, m, axis=-2) for lp in belief.log_pk)
    return Belief(log_pc, log_pk)


def marginal(belief: B, n_components: int) -> B:
    """The belief over ``C`` classes from one over ``C * M`` (module docstring):
    ``log P(c) = lse_m log P(c, m)``, ``log P_i(k | c) = lse_m [log P(m | c) +
    log P_i(k | c, m)]``.  A :class:`~.belief.Belief` gives a ``Belief``, a
    :class:`~.belief.PredictedBelief` (level rows ``[V, C * M, L]``,
    :func:`~.belief.transition_per_position`) a ``PredictedBelief``: the
    level rows' leading axes are carried through."""
    m = int(n_components)
    joint = belief.log_pc.reshape(-1, m)                                   # [C, M]
    log_pc = lse(joint, axis=-1)
    finite = jnp.isfinite(log_pc)
    # a class of zero probability keeps uniform weights over m (never NaN)
    log_pm = jnp.where(finite[:, None], joint - jnp.where(finite, log_pc, 0.0)[:, None], -jnp.log(float(m)))
    out = []
    for lp in belief.log_pk:
        sh = lp.shape
        x = lp.reshape(sh[:-2] + (sh[-2] // m, m, sh[-1]))                  # [..., C, M, L]
        out.append(lse(x + log_pm.reshape((1,) * (x.ndim - 3) + log_pm.shape + (1,)), axis=-2))
    return belief._replace(log_pc=log_pc, log_pk=tuple(out))


def component_log_likelihoods(
    gs: tuple[Float[ArrayLike, " _K"], ...],
    config: Int[ArrayLike, " n"],
    likelihoods,
) -> tuple[Float[Array, "CM _L"], ...]:
    """Per camera ``log p_m(g_i | c, k, v_i)`` (the component, without its
    weight) as ``[C * M, L]`` rows of the extended classes ``c * M + m``."""
    out = []
    for i, (lik, g) in enumerate(zip(likelihoods, gs)):
        at = lik.at(config[i])
        ld = at.component_log_density(g) - at.log_w                         # [C, L, M]
        c, l, m = ld.shape
        out.append(jnp.swapaxes(ld, -1, -2).reshape(c * m, l))
    return tuple(out)


def prior_log_weights(likelihood) -> Float[Array, "C M"]:
    """``log P_0(m | c)``: the mixture weights of position 0, level 0 (the
    training fit gives every position and level the same weights; the
    recognizer checks that)."""
    return jnp.asarray(likelihood.log_w)[0, :, 0, :]
