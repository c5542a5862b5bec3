"""Two-step (non-myopic) lookahead on a one-step information score, for all
configurations in one call (thesis ch. 5 plans one step ahead).

With a one-step score I(x; g | a, P) of configuration a under the predicted
prior P (the myopic planner's value: Monte Carlo or pairwise-distance MI, state
or class target), the two-step value of a first configuration a_1 is

    V(a_1) = I(x_1; g_1 | a_1, P_1)
             + E_{s ~ P_1(. | a_1), g_1 ~ p(g_1 | s, a_1)} [ max_{a_2 != a_1} I(x_2; g_2 | a_2, P_2(g_1)) ]

where

- P_1 is the predicted prior of the next step, per position
  (:func:`.belief.transition_per_position`, what every planner receives), and
  P_1(. | a_1) its value at a_1: P(c) prod_i P_i[v_i](k_i | c);
- P_2(g_1) = transition_per_position(update(P_1(. | a_1), log p(g_1 | ., a_1)), a_1)
  is the prior the recognizer would plan its second move with after seeing g_1
  at a_1: the Bayes update (eq. 3.1) and then the level transition with a_1 as
  the current configuration (eq. 3.7-3.9: a camera that stays keeps its
  updated levels, one that moves re-draws them), ``kind`` / ``rho`` as the
  recognizer's;
- x_t is what the one-step score is about at step t: the state s_t = (c, k_t)
  (``target="state"``; the levels of step 2 are not those of step 1) or the
  class c (``target="class"``, where the sum is exactly the chain rule
  I(c; g_1 | a_1) + E I(c; g_2 | a_2, g_1, a_1) = I(c; g_1, g_2) of the
  adaptive two-step policy when the score is the exact MI);
- the inner max excludes a_2 = a_1 (the recognizer never revisits while an
  unvisited configuration remains; configurations visited *before* a_1 are not
  known to the planner and are not excluded).

So V is the one-step score plus the expected one-step score of the best
second configuration: the Bellman backup of horizon 2 with the myopic
planner's value as the per-step reward.

**Outcomes.** The expectation over (s, g_1) is a systematic (stratified)
sample of ``S`` outcomes per first configuration: strata s = (c, k_0, k_1, ...)
in class-major order, points t_m = (m + u) / S (m = 0 .. S-1, one shared
u ~ U[0, 1)) inverted through the cumulative P_1(s | a_1), so a stratum of
probability p gets floor(p S) or ceil(p S) of the points and each point is
marginally exact (an unbiased estimate with weights 1/S).  Outcome m then
uses sample j_m of its stratum from the Monte Carlo tables
(:func:`.mutual_information.mi_tables`): g_1 = g(v, c, k, j_m) at every camera
and its log-likelihoods under every component are the table's row
LD_i[v_i, c, k_i, j_m, :, :] — no new sampling and no new likelihood
evaluation.  u and the j_m are common to all first configurations (common
random numbers), drawn from the key by :func:`lookahead_draws`.

**Pruning.** Only the ``top_k`` configurations of largest one-step score get
the two-step value (a ``jax.lax.top_k``, static k); the others keep their
one-step order, placed below every evaluated value:
score(a) = min_evaluated V - 1 - (max_pruned I - I(a)), so the recognizer
takes the best evaluated unvisited configuration and falls back to the myopic
order when all ``top_k`` were visited.  ``top_k = A`` evaluates everything.

**Cost.** ``top_k * S`` one-step scores of the whole grid, vmapped over
(first configuration, outcome) and run as a ``jax.lax.map`` over chunks of
``batch_size`` of them (memory bounded by ``batch_size`` one-step calls).
"""

from __future__ import annotations

import math
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import jax.random as jr
from jaxtyping import Array, Float, Int, PRNGKeyArray

from .belief import PredictedBelief, check_predicted, transition_per_position, update
from .config_grid import ConfigGrid
from .mutual_information import MITables

__all__ = ["LookaheadDraws", "lookahead_draws", "lookahead_information", "outcome_strata"]


class LookaheadDraws(NamedTuple):
    """The outcome draws of :func:`lookahead_information`, shared by all first
    configurations.

    Attributes:
        u: ``[]`` offset of the systematic sample, in [0, 1).
        j: ``[S]`` sample index within its stratum of each outcome, in [0, J).
    """

    u: Float[Array, ""]
    j: Int[Array, " S"]


def lookahead_draws(key: PRNGKeyArray, n_outcomes: int, samples_per_stratum: int, dtype=None) -> LookaheadDraws:
    """The draws :func:`lookahead_information` uses for ``key`` (also for references):
    ``S = n_outcomes`` points and one of the ``J = samples_per_stratum`` samples of
    the tables per point."""
    if int(n_outcomes) < 1 or int(samples_per_stratum) < 1:
        raise ValueError(f"lookahead_draws: n_outcomes and samples_per_stratum must be >= 1, "
                         f"got {n_outcomes}, {samples_per_stratum}")
    k_u, k_j = jr.split(key)
    dtype = jnp.result_type(float) if dtype is None else dtype
    return LookaheadDraws(jr.uniform(k_u, (), dtype), jr.randint(k_j, (int(n_outcomes),), 0, int(samples_per_stratum)))


def outcome_strata(log_w: Float[Array, " N"], u: Float[Array, ""], n_outcomes: int) -> Int[Array, " S"]:
    """Systematic sample of ``n_outcomes`` strata from normalised log weights ``[N]``:
    stratum of point (m + u) / S under the cumulative weights (``searchsorted``
    on the right, so a stratum of zero weight is never drawn)."""
    p = jnp.exp(log_w)
    cdf = jnp.cumsum(p)
    t = (jnp.arange(n_outcomes, dtype=p.dtype) + u) / n_outcomes * cdf[-1]
    return jnp.minimum(jnp.searchsorted(cdf, t, side="right"), log_w.shape[0] - 1)


def lookahead_information(
    tables: MITables,
    score: Callable[[PredictedBelief], Float[Array, " A"]],
    prior: PredictedBelief,
    *,
    draws: LookaheadDraws,
    top_k: int,
    transition: str = "uniform",
    rho: float = 0.9,
    batch_size: int | None = None,
) -> Float[Array, " A"]:
    """The two-step value V(a_1) of every configuration (see the module doc).

    Args:
        tables: :func:`~jaxrecog.kernels.mi_tables` of the model (needs
            ``tables.ld``: the outcomes' log-likelihoods; ``ld_exp`` / ``ld_max``
            are not read).
        score: the one-step score, :class:`~jaxrecog.kernels.PredictedBelief`
            -> ``[A]`` (higher = better; a failed estimate
            ``-inf``, never NaN), e.g. a ``functools.partial`` of
            :func:`~jaxrecog.kernels.pairwise_mutual_information`.  It is
            evaluated ``top_k * S + 1`` times (all but one under the vmap):
            the cost of a call is about that many one-step calls.
        prior: the predicted prior, level rows per position ``[V_i, C, L_i]``
            (:func:`~jaxrecog.kernels.transition_per_position`).
        draws: :func:`lookahead_draws` (``S = draws.j.shape[0]`` outcomes).
        top_k: first configurations evaluated two steps deep, 1 <= top_k <= A (static).
        transition, rho: the level transition between the two steps, as the
            recognizer's (static).
        batch_size: one-step calls per chunk of the ``lax.map`` (static;
            ``None``: all ``top_k * S`` in one vmap).

    Returns:
        ``[A]`` scores, row-major over (v_0, v_1, ...), never NaN: V(a) on the
        ``top_k`` best one-step configurations, the pruned ones below them in
        one-step order (module doc).
    """
    check_predicted(prior, tables.ld_self)
    if tables.ld is None:
        raise ValueError("lookahead_information: needs tables built with store='full' or 'both'")
    if transition not in ("uniform", "sticky"):
        raise ValueError(f"lookahead_information: transition must be 'uniform' or 'sticky', got {transition!r}")
    positions = tuple(t.shape[0] for t in tables.ld)
    levels = tuple(t.shape[2] for t in tables.ld)
    n_configs = math.prod(positions)
    n_c = tables.ld[0].shape[1]
    k = int(top_k)
    if not 1 <= k <= n_configs:
        raise ValueError(f"lookahead_information: top_k = {top_k} first configurations, but there are "
                         f"A = {n_configs} (need 1 <= top_k <= A)")
    if draws.j.ndim != 1 or draws.j.shape[0] < 1:
        raise ValueError(f"lookahead_information: draws.j must be [S] with S >= 1, got shape {draws.j.shape}")
    if batch_size is not None and int(batch_size) < 1:
        raise ValueError(f"lookahead_information: batch_size must be >= 1 or None, got {batch_size}")
    n_out = draws.j.shape[0]
    dtype = tables.ld[0].dtype
    log_pc = prior.log_pc.astype(dtype)
    log_pk = [lp.astype(dtype) for lp in prior.log_pk]  # [V_i, C, L_i]
    prior = PredictedBelief(log_pc, tuple(log_pk))

    one = score(prior)
    one = jnp.where(jnp.isfinite(one), one, -jnp.inf)  # [A]
    if k == n_configs:
        first = jnp.arange(n_configs, dtype=jnp.int32)
    else:
        first = jax.lax.top_k(one, k)[1]  # [k]

    grid = ConfigGrid(positions)  # first configurations a = (v_0, v_1, ...)
    level_grid = ConfigGrid(levels)  # (k_0, k_1, ...)
    stratum_grid = ConfigGrid((n_c,) + levels)  # outcome strata s = (c, k_0, k_1, ...)

    def config_of(a):
        return grid.configuration(a)

    def strata_of(a):  # [S] flat stratum indices at first configuration a
        v = config_of(a)
        log_w = log_pc.reshape((n_c,) + (1,) * len(positions))
        for i, lp in enumerate(log_pk):
            log_w = log_w + level_grid.expand(lp[v[i]], i)  # [C, L_i] at level slot i
        return outcome_strata(stratum_grid.flatten(log_w), draws.u.astype(dtype), n_out)

    strata = jax.vmap(strata_of)(first)  # [k, S]
    pair_a = jnp.repeat(first, n_out)  # [k * S]
    pair_s = strata.reshape(-1)
    pair_j = jnp.tile(draws.j, k)

    def second(x):
        """max_{a_2 != a} of the one-step score after outcome (stratum, j) at a."""
        a, s, j = x
        v = config_of(a)
        c, *ks = stratum_grid.configuration(s)
        here = prior.at(v)
        logliks = tuple(ld[vi, c, ki, j] for ld, vi, ki in zip(tables.ld, v, ks))  # [C, L_i] each
        post = update(here, logliks)
        current = jnp.stack(v).astype(jnp.result_type(int))  # the default int, as transition_per_position's arange
        nxt = transition_per_position(post, current, positions, kind=transition, rho=rho)
        s2 = score(nxt)
        s2 = jnp.where(jnp.isfinite(s2) & (jnp.arange(n_configs, dtype=a.dtype) != a), s2, -jnp.inf)
        best = jnp.max(s2)
        return jnp.where(jnp.isfinite(best), best, 0.0)  # nothing left (A = 1) or every estimate failed: 0

    xs = (pair_a, pair_s, pair_j)
    if batch_size is None:
        best = jax.vmap(second)(xs)
    else:
        best = jax.lax.map(second, xs, batch_size=min(int(batch_size), k * n_out))
    vals = one[first] + jnp.mean(best.reshape(k, n_out), axis=1)  # [k]

    evaluated = jnp.zeros((n_configs,), bool).at[first].set(True)
    out = jnp.zeros((n_configs,), dtype).at[first].set(vals)
    if k < n_configs:
        floor = jnp.min(jnp.where(jnp.isfinite(vals), vals, jnp.inf))
        floor = jnp.where(jnp.isfinite(floor), floor, 0.0)
        ok = ~evaluated & jnp.isfinite(one)
        top_pruned = jnp.max(jnp.where(ok, one, -jnp.inf))
        low = jnp.where(ok, floor - 1.0 - (top_pruned - one), -jnp.inf)
        out = jnp.where(evaluated, out, low)
    return jnp.where(jnp.isnan(out), -jnp.inf, out)
