"""Mutual Information planner: I(s; g | a) for all configurations in one call
(thesis eq. 5.3-5.13).

    I(s; g | a) = sum_s P(s) E_{g ~ p(g|s,a)} [log p(g|s,a) - log p(g|a)]   (eq. 5.5, 5.10)
    p(g | a)    = sum_s P(s) p(g|s,a)                                       (eq. 5.7)

p(g|a) is exact over the discrete states; the expectation over g is Monte
Carlo, *stratified*: every state stratum (c, k_0, k_1, ...) gets J samples, so
the outer expectation over the discrete state is exact (weights
P(c) prod_i P_i(k_i|c) / J).  Noise is shared across positions (common random
numbers): camera i's sample j of stratum (c, k) at position v is drawn by its
likelihood (:meth:`~jaxrecog.kernels.Likelihood.sample`) from the same
standard-normal numbers z_i[c, k, j] at every position, e.g. for the Gaussian

    g_i(v, c, k, j) = mu_i[v, c, k] + sqrt(var_i[v, c, k]) * z_i[c, k, j].

Offline (:func:`mi_tables`, once per model and key) each camera gets the
component log-density table (:meth:`~jaxrecog.kernels.Likelihood.log_density`)

    LD_i[v, c, k, j, c', k'] = log p(g_i(v, c, k, j) | c', k', v).

Online (:func:`mutual_information`) with the belief:

    T_i[v, c, k, j, c'] = logsumexp_k' (LD_i + log P_i(k'|c'))
    log p(g | a)        = logsumexp_c' (log P(c') + sum_i T_i[v_i, c, k_i, j, c'])

evaluated on the whole (v_0, v_1, ...) grid with a shifted batched matrix
product (see :mod:`._grid`).  T_i needs no exp over LD_i online: the tables
also hold M_i = max_k' LD_i and E_i = exp(LD_i - M_i), and
T_i = M_i + log sum_k' E_i P_i(k'|c') (a batched matrix product), with an
exact fallback where that sum underflows (:func:`belief_level_tables`).  Targets: ``"state"`` (thesis, I(s; g)) uses
log p(g|s) = sum_i LD_i[v_i, c, k_i, j, c, k_i]; ``"class"`` (I(c; g), levels
marginalised) uses log p(g|c) = sum_i T_i[v_i, c, k_i, j, c].

With P_i(k'|c') = 1/L_i for every camera and position, T_i does not depend on
the belief: ``mi_tables(..., store="uniform")`` precomputes it (the thesis's
offline trick, eq. 5.12-5.13) and ``mutual_information(..., levels="uniform")``
uses it.  That variant treats every camera's levels as re-drawn uniformly at
every step, *including a camera that stays where it is*.  Under the thesis's
uniform transition (eq. 3.9: P_alpha = 1/L only for a camera that moves; a
camera that does not move keeps its levels) it is therefore exact only on
configurations where every camera moves; on a configuration where some camera
keeps its position it ignores that camera's kept level rows and is an
approximation.  The exact value for every configuration is ``levels="belief"``
with the predicted prior of :func:`jaxrecog.kernels.transition_per_position`.

Few classes: a class whose weight P(c) is flushed to 0 (below
``tiny ** (1 / (n + 1))``, :func:`._grid.weights`) adds nothing to the sum
over the strata, though it stays in every mixture over c'.  With more than
twice ``_FEW_CLASSES`` classes the strata are summed over the classes of nonzero
weight alone, ``_FEW_CLASSES`` at a time (:func:`._grid.live_chunks`; their
rows of the tables gathered): the same value to rounding, and after a view or
two (a few live classes) one chunk, an eighth of the strata at C = 32.

Samples per configuration: C * prod_i L_i * J (see :func:`samples_per_configuration`).
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.random as jr
from jaxtyping import Array, Float, PRNGKeyArray

from ._grid import (FEW_CLASSES, check_options, floor_log_probs, level_tables, lse, mixture_information, own_class,
                    live_chunks, shifted_exp, weights)
from .belief import PredictedBelief, check_predicted
from .likelihood import Likelihood, as_likelihoods


class MITables(NamedTuple):
    """Per-camera sample tables for the planners (fixed shapes per model and J).

    Attributes:
        ld: per camera ``[V_i, C, L_i, J, C, L_i]`` component log-densities
            LD_i (``None`` when built with ``store="uniform"``).
        ld_self: per camera ``[V_i, C, L_i, J]``, log p(g_i | c, k, v) of each
            sample under its own component (the diagonal of LD_i).
        t_uniform: per camera ``[V_i, C, L_i, J, C]``,
            logsumexp_k' LD_i - log L_i (``None`` with ``store="full"``).
        z: per camera ``[C, L_i, J, Z_i]`` the standard-normal draws
            (``Z_i`` = the likelihood's ``noise_dim``, K_i for a Gaussian).
        ld_max: per camera ``[V_i, C, L_i, J, C]``, M_i = max_k' LD_i (0 where
            that is not finite); ``None`` when built with ``store="uniform"``.
        ld_exp: per camera ``[V_i, C', L_i', C, L_i, J]`` (this axis order makes
            the online contraction over k' a fast batched matrix product),
            E_i = exp(LD_i - M_i) with values below the smallest normal float
            flushed to 0; ``None`` when built with ``store="uniform"``.  With
            these the belief path needs no exp over LD (see
            :func:`mutual_information`).
    """

    ld: tuple[Float[Array, "_V C _L J C _L"], ...] | None
    ld_self: tuple[Float[Array, "_V C _L J"], ...]
    t_uniform: tuple[Float[Array, "_V C _L J C"], ...] | None
    z: tuple[Float[Array, "C _L J _K"], ...]
    ld_max: tuple[Float[Array, "_V C _L J C"], ...] | None = None
    ld_exp: tuple[Float[Array, "_V C _L C _L J"], ...] | None = None


def samples_per_configuration(tables: MITables) -> int:
    """C * prod_i L_i * J: the Monte Carlo samples behind each configuration's value."""
    c, j = tables.ld_self[0].shape[1], tables.ld_self[0].shape[3]
    return c * j * math.prod(t.shape[2] for t in tables.ld_self)


def camera_log_densities(lik: Likelihood, z):
    """LD [V, C, L, J, C', L'] for one camera: every sample of every component
    under every component of the same position (``lax.map`` over positions)."""
    return jax.lax.map(lambda lik_v: lik_v.log_density(lik_v.sample(z)), lik)


def mi_tables(
    likelihoods: Sequence[Likelihood],
    *,
    key: PRNGKeyArray,
    samples_per_stratum: int,
    store: str = "both",
) -> MITables:
    """Offline sample tables (per model and key) for :func:`mutual_information`
    and :func:`jaxrecog.kernels.fisher_information`.

    Args:
        likelihoods: one :class:`~jaxrecog.kernels.Likelihood` per camera (over
            its positions; :func:`~jaxrecog.kernels.gaussian_likelihoods`
            builds the Gaussians from their arrays).
        key: PRNG key; camera i uses ``fold_in(key, i)``.
        samples_per_stratum: J (static; fixes the shapes).
        store: ``"full"`` (LD tables, any belief), ``"uniform"`` (only the
            belief-free uniform-level tables T_i), or ``"both"``.
    """
    liks = as_likelihoods(likelihoods, where="mi_tables")
    if store not in ("full", "uniform", "both"):
        raise ValueError(f"mi_tables: store must be 'full', 'uniform' or 'both', got {store!r}")
    j = int(samples_per_stratum)
    if j < 1:
        raise ValueError(f"mi_tables: samples_per_stratum must be >= 1, got {samples_per_stratum}")
    return _mi_tables(tuple(liks), key, j, store)


@eqx.filter_jit
def _mi_tables(liks: tuple[Likelihood, ...], key: PRNGKeyArray, j: int, store: str) -> MITables:
    """The body of :func:`mi_tables` (arguments checked), compiled as one
    program (the likelihoods' arrays traced, ``j`` and ``store`` static)."""
    lds, selfs, tus, zs, mxs, exs = [], [], [], [], [], []
    for i, lik in enumerate(liks):
        c, l = lik.n_classes, lik.n_levels
        z = jr.normal(jr.fold_in(key, i), (c, l, j, lik.noise_dim), lik.dtype)
        ld = camera_log_densities(lik, z)
        # diagonal LD[v, c, k, j, c, k]
        d1 = jnp.diagonal(ld, axis1=1, axis2=4)  # [V, L, J, L', C]
        d2 = jnp.diagonal(d1, axis1=1, axis2=3)  # [V, J, C, L]
        selfs.append(jnp.transpose(d2, (0, 2, 3, 1)))
        if store != "uniform":
            lds.append(ld)
            mx, ex = shifted_exp(ld)
            mxs.append(mx)
            exs.append(jnp.transpose(ex, (0, 4, 5, 1, 2, 3)))  # [V, C', L', C, L, J] (MITables.ld_exp)
        if store != "full":
            tus.append(lse(ld, axis=-1) - math.log(l))
        zs.append(z)
    return MITables(
        tuple(lds) if store != "uniform" else None,
        tuple(selfs),
        tuple(tus) if store != "full" else None,
        tuple(zs),
        tuple(mxs) if store != "uniform" else None,
        tuple(exs) if store != "uniform" else None,
    )


#: at most this many classes of nonzero weight: the strata are theirs alone
#: (:func:`mutual_information`; module docstring, "Few classes")
_FEW_CLASSES = FEW_CLASSES


def _outer_rows(tables: MITables, keep) -> MITables:
    """The tables of the strata of classes ``keep`` (the samples' class axis;
    the components' c' axes whole) for :func:`belief_level_tables`."""
    return tables._replace(ld=tuple(t[:, keep] for t in tables.ld),
                           ld_max=None if tables.ld_max is None else tuple(t[:, keep] for t in tables.ld_max),
                           ld_exp=None if tables.ld_exp is None else tuple(t[:, :, :, keep] for t in tables.ld_exp))


def belief_level_tables(tables: MITables, log_pk):
    """T_i = logsumexp_k' (LD_i + log P_i(k'|c')) per camera, ``[V_i, C, L_i, J, C]``
    (:func:`._grid.level_tables` on the sample tables: a batched product with
    the offline E_i = exp(LD_i - M_i), exact logsumexp where that underflows)."""
    return level_tables(tables.ld, tables.ld_max, tables.ld_exp, log_pk)


def mutual_information(
    tables: MITables,
    belief: PredictedBelief,
    target: str = "state",
    levels: str = "belief",
    with_stderr: bool = False,
):
    """I(s; g | a) (``target="state"``, eq. 5.5/5.10) or I(c; g | a)
    (``target="class"``) for every configuration a, in nats.

    Args:
        tables: from :func:`mi_tables` (same model, fixed J).
        belief: the predicted prior, level rows per position ``[V_i, C, L_i]``
            (:func:`jaxrecog.kernels.transition_per_position`).
        target: ``"state"`` or ``"class"`` (static).
        levels: ``"belief"`` uses the belief's P_i(k|c) (needs ``tables.ld``;
            exact for any transition when given the per-position prediction).
            ``"uniform"`` uses P_i(k|c) = 1/L_i for every camera at every
            position and the precomputed ``tables.t_uniform``; the belief's
            level rows are ignored (only P(c) is used).  This is the value
            under "every camera's levels are re-drawn": equal to the
            ``"belief"`` value of the uniform-transition prediction on
            configurations where every camera moves, an approximation on those
            where some camera stays (it keeps its levels under eq. 3.9; see the
            module docstring).  Static.
        with_stderr: also return the Monte Carlo standard error, from the J
            independent replicates (needs J >= 2).  Static.

    Returns:
        ``[A]`` values, A = prod_i V_i, row-major over (v_0, v_1, ...)
        (a = 7 v_0 + v_1 on the thesis grid); with ``with_stderr`` a pair
        ``(mi [A], stderr [A])``.  Estimates are not clipped at 0.
    """
    check_options("mutual_information", target, levels)
    check_predicted(belief, tables.ld_self)
    j = tables.ld_self[0].shape[3]
    if with_stderr and j < 2:
        raise ValueError("mutual_information: with_stderr needs samples_per_stratum >= 2")
    return _mutual_information(tables, belief, target, levels, with_stderr)


@functools.partial(jax.jit, static_argnames=("target", "levels", "with_stderr"))
def _mutual_information(tables: MITables, belief: PredictedBelief, target: str, levels: str, with_stderr: bool):
    """The body of :func:`mutual_information` (arguments checked), compiled as
    one program: called eagerly, it costs one XLA compilation per shape
    instead of one per operation (~70 here)."""
    positions = tuple(t.shape[0] for t in tables.ld_self)
    n_c, j = tables.ld_self[0].shape[1], tables.ld_self[0].shape[3]
    dtype = tables.ld_self[0].dtype
    log_pc = floor_log_probs(belief.log_pc.astype(dtype))  # no subnormals (see _grid)
    if levels == "uniform":
        if tables.t_uniform is None:
            raise ValueError("mutual_information: levels='uniform' needs tables built with store='uniform' or 'both'")
        log_pk = [
            jnp.full((v, n_c, t.shape[2]), -math.log(t.shape[2]), dtype)
            for v, t in zip(positions, tables.ld_self)
        ]
    else:
        if tables.ld is None:
            raise ValueError("mutual_information: levels='belief' needs tables built with store='full' or 'both'")
        log_pk = [lp.astype(dtype) for lp in belief.log_pk]

    def information(outer):
        """E_s E_g [log p(g|s,a) - log p(g|a)] per replicate ``[J, A]`` on the
        (v_0, v_1, ...) grid, the strata's classes ``outer`` (``None``: all;
        :func:`._grid.mixture_information`)."""
        keep = None if outer is None else outer[0]
        if levels == "uniform":
            ts = [t if keep is None else t[:, keep] for t in tables.t_uniform]
        else:
            ts = belief_level_tables(tables if keep is None else _outer_rows(tables, keep), log_pk)
        if target == "state":
            selfs = [t if keep is None else t[:, keep] for t in tables.ld_self]
        elif keep is None:
            selfs = [own_class(t, 1, 4) for t in ts]
        else:  # row m is class keep[m]: its own entry is c' = keep[m]
            selfs = [jnp.take_along_axis(t, keep[None, :, None, None, None], axis=4)[..., 0] for t in ts]
        return mixture_information(ts, selfs, log_pc, log_pk, outer=outer)

    # the strata of the classes of nonzero weight alone, _FEW_CLASSES at a
    # time (module docstring, "Few classes"; with few classes in all, the
    # whole computation)
    reps = live_chunks(log_pc, len(positions) + 1, information, jnp.zeros((j, math.prod(positions)), dtype),
                       size=_FEW_CLASSES)
    mi = jnp.mean(reps, axis=0)
    if not with_stderr:
        return mi
    se = jnp.std(reps, axis=0, ddof=1) / math.sqrt(j)
    return mi, se
