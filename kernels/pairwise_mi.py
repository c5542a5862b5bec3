"""Deterministic pairwise-distance Mutual Information for all configurations in
one call (Kolchinsky & Tracey, "Estimating Mixture Entropy with Pairwise
Distances", Entropy 19(7):361, 2017; DESIGN.md §7).

For the mixture p(g | a) = sum_s P(s) p(g | s, a) over the states
s = (c, k_0, k_1, ...) and a divergence D between its components,

    I_D(s; g | a) = - sum_s P(s) log sum_s' P(s') exp(-D_a(s, s'))          (K&T eq. 9-10)

with D = Bhattacharyya a lower bound on I(s; g | a) and D = KL an upper bound
(K&T Theorems 2-3).  Both are exact in the two limits: 0 when all components
coincide (D = 0), H(s) when they are perfectly separated (D -> inf).  No
sampling: no Monte Carlo error and no key.

Components are products over cameras (eq. 4.17), so the divergences add up,
D_a(s, s') = sum_i D_i[v_i](c, k_i; c', k_i') (true for Bhattacharyya and KL),
and with the per-position level rows P_i[v](k|c) of the predicted prior

    W_i[v, c, k, c'] = log sum_k' P_i[v](k'|c') exp(-D_i[v, c, k, c', k'])
    sum_s' P(s') exp(-D_a(s, s')) = sum_c' P(c') exp(sum_i W_i[v_i, c, k_i, c'])

which is the Monte Carlo kernel's T_i table (:mod:`.mutual_information`)
with one "sample" per stratum and log-density -D instead of log p(g_ij | c', k').
The same grid code evaluates it on the whole (v_0, v_1, ...) grid
(:func:`._grid.mixture_information`, shared with the Monte Carlo kernel), and
the same offline trick removes the exps online: the tables hold
M_i = max_k' (-D_i) and E_i = exp(-D_i - M_i), so W_i = M_i + log sum_k' E_i P_i
is a batched matrix product (:func:`._grid.level_tables`, exact fallback on
underflow).

Class target (``target="class"``): I(c; g) = I(s; g) - sum_c P(c) I(k; g | c)
(chain rule, k = (k_0, k_1, ...)).  Given c, the prior over the levels and the
components both factorise over cameras, so the g_i are independent given c
and I(k; g | c) = sum_i I(k_i; g_i | c); each term is estimated by the same
pairwise formula over camera i's levels of class c alone,
I_D(k_i; g_i | c) = - sum_k P_i(k|c) W_i[v_i, c, k, c], so

    I_D(c; g | a) = I_D(s; g | a) + sum_c P(c) sum_i sum_k P_i(k|c) W_i[v_i, c, k, c]

(the Monte Carlo class target's structure, with W_i for T_i).  Exact in both
limits as above (0, and H(c)); being a difference of two estimates of the same
kind, it is not a bound on I(c; g | a), but I_D(c; g | a) <= H(c) always
(sum_s' P(s') exp(-D) >= P(c) sum_k' P(k'|c) exp(-D) term by term); unlike the
state estimate (>= 0) it may be slightly negative.

The divergence tables come from the likelihood family
(:meth:`~jaxrecog.kernels.Likelihood.divergence`): closed forms for the two
Gaussians; a moment-matched Gaussian approximation for a family without one.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ._grid import (
    check_belief_sizes,
    floor_log_probs,
    level_tables,
    lse,
    mixture_information,
    own_class,
)
from .belief import Belief
from .likelihood import as_likelihoods
from .mutual_information import per_position_levels

__all__ = ["PairwiseTables", "pairwise_tables", "pairwise_mutual_information", "DIVERGENCES"]

#: The divergences :func:`pairwise_tables` accepts (the lower and the upper bound).
DIVERGENCES = ("bhattacharyya", "kl")


class PairwiseTables(NamedTuple):
    """Per-camera divergence tables of the pairwise-distance MI (fixed shapes per
    model; built once, belief-free).

    Attributes:
        log_w: per camera ``[V_i, C, L_i, 1, C', L_i']``, minus the divergence,
            -D_i[v, c, k, c', k'] (D(p_ck || p_c'k') for KL), with a unit
            "sample" axis so the Monte Carlo grid code applies unchanged.
        w_max: per camera ``[V_i, C, L_i, 1, C']``, M_i = max_k' (-D_i).
        w_exp: per camera ``[V_i, C', L_i', C, L_i, 1]``, E_i = exp(-D_i - M_i),
            flushed to 0 below the smallest normal float (the axis order of
            :attr:`MITables.ld_exp`).
        t_uniform: per camera ``[V_i, C, L_i, 1, C']``, W_i under uniform
            levels, logsumexp_k' (-D_i) - log L_i.
    """

    log_w: tuple[Float[Array, "_V C _L 1 C _L"], ...]
    w_max: tuple[Float[Array, "_V C _L 1 C"], ...]
    w_exp: tuple[Float[Array, "_V C _L C _L 1"], ...]
    t_uniform: tuple[Float[Array, "_V C _L 1 C"], ...]


def pairwise_tables(
    likelihoods,
    vars: tuple[Float[ArrayLike, "_V C _L _K"], ...] | None = None,
    *,
    kind: str = "bhattacharyya",
    chols: tuple[Float[ArrayLike, "_V C _L _K _K"], ...] | None = None,
) -> PairwiseTables:
    """The offline divergence tables of :func:`pairwise_mutual_information` (once per model).

    Args:
        likelihoods: one :class:`~jaxrecog.kernels.Likelihood` per camera, or
            the Gaussian array form (means with ``vars`` or ``chols``), as
            :func:`~jaxrecog.kernels.mi_tables`.
        kind: ``"bhattacharyya"`` (lower bound) or ``"kl"`` (upper bound).
    """
    if kind not in DIVERGENCES:
        raise ValueError(f"pairwise_tables: kind must be one of {DIVERGENCES}, got {kind!r}")
    liks = as_likelihoods(likelihoods, vars, chols, where="pairwise_tables")
    ws, mxs, exs, tus = [], [], [], []
    for lik in liks:
        d = jax.lax.map(lambda lik_v: lik_v.divergence(kind), lik)  # [V, C, L, C', L']
        # D >= 0 up to rounding and D(s, s) = 0 exactly: keeps W_i[c, k, c] >= log P_i(k|c)
        n_c, n_l = d.shape[1], d.shape[2]
        eye = (jnp.eye(n_c, dtype=bool)[:, None, :, None] & jnp.eye(n_l, dtype=bool)[None, :, None, :])
        d = jnp.where(eye[None], 0.0, jnp.maximum(d, 0.0))
        w = -d[:, :, :, None]  # [V, C, L, 1, C', L']
        m = jnp.max(w, axis=-1)
        floor = math.log(float(jnp.finfo(w.dtype).tiny))
        s = w - m[..., None]
        e = jnp.where(s < floor, 0.0, jnp.exp(jnp.maximum(s, floor)))
        ws.append(w)
        mxs.append(m)
        exs.append(jnp.transpose(e, (0, 4, 5, 1, 2, 3)))
        tus.append(lse(w, axis=-1) - math.log(n_l))
    return PairwiseTables(tuple(ws), tuple(mxs), tuple(exs), tuple(tus))


def pairwise_mutual_information(
    tables: PairwiseTables,
    belief: Belief,
    target: str = "state",
    levels: str = "belief",
) -> Float[Array, " A"]:
    """I_D(s; g | a) (``target="state"``) or I_D(c; g | a) (``"class"``) for every
    configuration a, in nats (see the module docstring for the equations).

    Args:
        tables: from :func:`pairwise_tables` (its ``kind`` decides the bound).
        belief: the predicted prior; level rows ``[C, L_i]`` or per position
            ``[V_i, C, L_i]`` (:func:`jaxrecog.kernels.transition_per_position`).
        target: ``"state"`` or ``"class"`` (static).
        levels: ``"belief"`` (the prior's level rows) or ``"uniform"``
            (P_i(k|c) = 1/L_i everywhere, the belief-free tables; as
            :func:`~jaxrecog.kernels.mutual_information`, exact only where every
            camera moves under the uniform transition).  Static.

    Returns:
        ``[A]`` values, row-major over (v_0, v_1, ...).  Never NaN: a belief
        holding NaN raises a ``ValueError`` when its values are concrete; under
        ``jit`` (values unknown) a NaN estimate is returned as ``-inf`` (a failed
        estimate, ranked last by the recognizer).
    """
    if target not in ("state", "class"):
        raise ValueError(f"pairwise_mutual_information: target must be 'state' or 'class', got {target!r}")
    if levels not in ("belief", "uniform"):
        raise ValueError(f"pairwise_mutual_information: levels must be 'belief' or 'uniform', got {levels!r}")
    check_belief_sizes(len(tables.log_w), tables.log_w[0].shape[1], belief)
    positions = tuple(w.shape[0] for w in tables.log_w)
    n_c = tables.log_w[0].shape[1]
    dtype = tables.log_w[0].dtype
    log_pc = floor_log_probs(belief.log_pc.astype(dtype))  # no subnormals (see _grid)
    if levels == "uniform":
        log_pk = [jnp.full((v, n_c, w.shape[2]), -math.log(w.shape[2]), dtype) for v, w in zip(positions, tables.log_w)]
        ts = list(tables.t_uniform)
    else:
        log_pk = [lp.astype(dtype) for lp in per_position_levels(belief, positions)]
        # inner weights floored (f32: >= e^-61): the shifted sum over k' holds the term
        # E = 1 at its max times P >= e^-61 > tau, so it never underflows (no fallback)
        ts = level_tables(tables.log_w, tables.w_max, tables.w_exp, [floor_log_probs(lp) for lp in log_pk], guard=False)
    # No underflow fallback on the grid either: D(s, s) = 0 gives W_i[c, k, c] >= log P_i(k|c)
    # and W_i <= 0, so the shifted sum over c' of stratum s is >= P(s).  Strata whose weight has
    # a factor below exp(floor) are dropped (weight 0; their share of I is < 1e-7 nats in
    # float32), so every stratum that counts has a sum >= e^(log tau + 1) > tau.
    finfo = jnp.finfo(dtype)
    tau = n_c * float(finfo.tiny) / float(finfo.eps)
    floor = (math.log(tau) + 1.0) / (len(positions) + 1)
    selfs = None if target == "state" else [own_class(t) for t in ts]
    mi = mixture_information(ts, selfs, log_pc, log_pk, weight_floor=floor, guard=False)[0]
    return jnp.where(jnp.isnan(mi), -jnp.inf, mi)
