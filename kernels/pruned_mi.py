"""The pairwise-distance MI over the classes that carry the belief's mass:
planning cost that follows the belief, memory linear in the number of classes.

:func:`~jaxrecog.kernels.pairwise_mutual_information` scores every
configuration from divergence tables ``[V_i, C, L_i, C', L_i']`` built once
per model: memory and time grow with C^2 (C = 512 on the thesis layout:
5.7 GB, 63 ms a step), and a belief on two classes costs as much as a uniform
one.  Here the tables are never built.  At each step the belief P(c) picks
its live set S, the B classes of largest mass, B the smallest *bucket* of
``buckets`` (8, 32; capped at C) whose top-B classes hold at least
``1 - mass``; the live classes' likelihood parameters are gathered and their
B x B divergences computed inside the step, and the same estimator
(:func:`~jaxrecog.kernels.pairwise_mutual_information`, ``fast=False``)
scores the configurations under the renormalised live belief
Q(c) = P(c) / (1 - eps), eps = the pruned mass.  Every bucket is one branch
of a ``lax.switch``: one compiled program, static shapes, only the branch
taken runs.  A belief spread wider than the largest bucket is scored on its
top classes (eps then exceeds ``mass``; :func:`pruning_bound` says by how much
that can change the score).  The first step's belief is uniform over the
classes and over the level rows; its values do not depend on the belief and
are read from a table built once per model (``u_state`` / ``u_class``, up to
``UNIFORM_TABLE_MAX`` classes: its build holds ``[C, V_i L_i, C']`` rows).

Bound (the pruned mass eps changes the score by little).  Write the estimator
on the states s = (c, k), k = (k_0, k_1, ...) of configuration a as
I_D(s) = -sum_s P(s) log Z_P(s), Z_P(s) = sum_s' P(s') Y(s, s'), with
Y(s, s') = exp(-D_a(s, s')) in [0, 1] and Y(s, s) = 1 (the tables clamp
D >= 0 and set D(s, s) = 0).  Split P = (1 - eps) Q + eps R (Q on the live
classes S, R on the pruned ones, each normalised); Z_P = (1 - eps) Z_Q +
eps Z_R for the same kernel Y.

Upper side: Z_P >= (1 - eps) Z_Q on S and Z_P >= eps Z_R on the pruned
states, so I_D,P(s) <= H_b(eps) + (1 - eps) I_D,Q(s) + eps I_D,R(s), with
H_b(eps) = -eps log eps - (1 - eps) log(1 - eps) and I_D,R(s) <= H(R) <=
log((C - B) L) (Z_R(s) >= R(s)), L = prod_i L_i the level states per class.

Lower side: Z_P <= (1 - eps) Z_Q + eps (Z_R <= 1), the pruned states' terms
are >= 0 (Z_P <= 1), and Z_Q(s) >= Q(c) P(k | c) (its own term), so
I_D,P(s) >= (1 - eps) (I_D,Q(s) - G) with

    G = sum_{c in S} Q(c) log(1 - eps + eps L / Q(c))

(Jensen over k under P(k | c): the mean of 1 / P(k | c) is the number of
level states of nonzero weight, <= L; concave log).

Class target: I_D(c) = I_D(s) + sum_c P(c) T(c) with T(c) =
sum_i sum_k P_i(k|c) W_i[v_i, c, k, c] in [-log L, 0] (module
:mod:`.pairwise_mi`), and I_D(c) <= H(c).  With delta = I_D,P - I_D,Q:

    class:  -(eps log B + eps log L + (1 - eps) G)  <=  delta  <=  H_b(eps) + eps log(C - B) + eps log L
    state:  -(eps log(B L) + (1 - eps) G)           <=  delta  <=  H_b(eps) + eps log((C - B) L)

for every configuration (:func:`pruning_bound`: the larger side).  At
eps = 1e-3 with B = 8 of C = 512 classes, L = 36 and Q on two classes:
0.018 above, 0.078 below (G ~ eps L #live); these are worst cases over the
divergences (pruned classes that coincide with every live state), the
measured differences are far smaller (docs/planners.md).  Both hold for the
estimator as computed up to the floors of :mod:`._grid` (belief floored at
e^-61 in float32, strata below the weight floor dropped: < 1e-7 nats).
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from ._grid import check_options, floor_log_probs, lse, own_class, shifted_exp
from .belief import PredictedBelief, check_predicted
from .config_grid import position_rows
from .likelihood import Likelihood, as_likelihoods
from .pairwise_mi import DIVERGENCES, PairwiseTables, minus_divergences, pairwise_mutual_information, uniform_values

__all__ = ["PrunedTables", "pruned_tables", "pruned_pairwise_mutual_information", "pruning_bound",
           "live_buckets", "live_count", "take_classes", "check_mass", "PRUNE_BUCKETS", "DEFAULT_PRUNE_MASS",
           "UNIFORM_TABLE_MAX"]

#: Live-set sizes, one compiled branch each (capped at C; module docstring).
#: The live tables cost ~(B L)^2 V K work a step: at B = 128 on the thesis
#: layout ~0.3 G pair-dimension terms, seconds on the CPU, slower than
#: the tables of every pair; a belief wider than the largest bucket is
#: scored on its top 32 classes (within :func:`pruning_bound`).
PRUNE_BUCKETS = (8, 32)

#: a sum of probabilities within this many float32 epsilons (relative) of
#: ``1 - mass`` counts as holding it (a belief with exactly 99.9 % on 8
#: classes sums to 0.99899995 in float32)
_SLACK = 8

#: Belief mass the live set may leave out (eps): 1e-3.
DEFAULT_PRUNE_MASS = 1e-3

#: The first step's belief-free table is built up to this many classes (its
#: build holds ``[C, V_i L_i, C']`` per camera: ~1 GB at 1024 on the thesis layout).
UNIFORM_TABLE_MAX = 1024


class PrunedTables(NamedTuple):
    """What the pruned planner holds: the likelihoods (memory linear in C)
    and the first step's belief-free values.

    Attributes:
        likelihoods: one per camera, as the model's.
        kind: the divergence, ``"bhattacharyya"`` or ``"kl"`` (static in use).
        u_state, u_class: ``[A]``, I_D(s; g | a) and I_D(c; g | a) under the
            uniform class prior and uniform level rows; ``None``: not built.
    """

    likelihoods: tuple[Likelihood, ...]
    u_state: Float[Array, " A"] | None = None
    u_class: Float[Array, " A"] | None = None


def take_classes(lik: Likelihood, idx: Int[Array, " B"]) -> Likelihood:
    """Camera likelihood ``lik`` restricted to classes ``idx`` (in that order;
    may be traced): every field with a class axis gathered along it."""
    shapes = {**lik.field_shapes, **lik.derived_shapes}
    names = [f for f, spec in shapes.items() if "C" in spec.split()]
    new = [jnp.take(getattr(lik, f), idx, axis=shapes[f].split().index("C")) for f in names]
    return eqx.tree_at(lambda m: [getattr(m, f) for f in names], lik, new)


def pruned_tables(likelihoods: Sequence[Likelihood], *, kind: str = "bhattacharyya",
                  uniform: bool | None = None) -> PrunedTables:
    """The pruned planner's tables: the likelihoods and, where ``uniform``
    (default: C <= ``UNIFORM_TABLE_MAX``), the first step's belief-free values."""
    if kind not in DIVERGENCES:
        raise ValueError(f"pruned_tables: kind must be one of {DIVERGENCES}, got {kind!r}")
    liks = tuple(as_likelihoods(likelihoods, where="pruned_tables"))
    if uniform is None:
        uniform = liks[0].n_classes <= UNIFORM_TABLE_MAX
    if not uniform:
        return PrunedTables(liks)
    u_state, u_class = _uniform_values(liks, kind)
    return PrunedTables(liks, u_state, u_class)


@functools.partial(jax.jit, static_argnums=1)
def _uniform_values(liks, kind: str):
    """I_D(s; g | a) and I_D(c; g | a) under the uniform class prior and level
    rows (:mod:`.pairwise_mi`'s ``u_state`` / ``u_class``), one position's
    ``[C, L, C', L']`` divergences at a time."""
    es, ms, selfs = [], [], []
    for lik in liks:
        n_l = lik.n_levels
        u = jax.lax.map(lambda lik_v: lse(minus_divergences(_one(lik_v), kind)[0], axis=-1) - math.log(n_l), lik)
        u = position_rows(u)  # [C, X, C']
        m, e = shifted_exp(u)
        es.append(e), ms.append(m), selfs.append(own_class(u, 0, 2))
    return uniform_values(es, ms, selfs, [lik.n_positions for lik in liks], [lik.n_levels for lik in liks])


def _one(lik_v: Likelihood) -> Likelihood:
    """One position's component set as a one-position camera likelihood."""
    return jax.tree.map(lambda x: x[None], lik_v)


def live_buckets(n_classes: int, buckets: Sequence[int] = PRUNE_BUCKETS) -> tuple[int, ...]:
    """The live-set sizes for C classes: the buckets below C, then C itself
    where C is at most the largest bucket."""
    bs = sorted({int(b) for b in buckets})
    if not bs or bs[0] < 1:
        raise ValueError(f"buckets must be positive sizes, got {tuple(buckets)}")
    out = tuple(b for b in bs if b < n_classes)
    return out + (n_classes,) if n_classes <= bs[-1] else out


def live_count(log_pc, mass: float = DEFAULT_PRUNE_MASS, buckets: Sequence[int] = PRUNE_BUCKETS) -> int:
    """The live-set size B the kernel takes for the class belief ``log_pc`` (NumPy)."""
    lp = np.asarray(log_pc, float)
    p = np.sort(np.exp(lp - np.logaddexp.reduce(lp)))[::-1]
    sizes = live_buckets(len(p), buckets)
    for b in sizes:
        if np.sum(p[:b]) >= (1.0 - mass) * (1.0 - _SLACK * float(np.finfo(np.float32).eps)):
            return b
    return sizes[-1]


def check_mass(mass: float) -> float:
    if isinstance(mass, bool) or not isinstance(mass, (int, float)) or not 0.0 <= mass < 1.0:
        raise ValueError(f"mass (the belief mass pruning may leave out) must be in [0, 1), got {mass!r}")
    return float(mass)


def pruned_pairwise_mutual_information(
    tables: PrunedTables,
    belief: PredictedBelief,
    *,
    kind: str = "bhattacharyya",
    target: str = "class",
    mass: float = DEFAULT_PRUNE_MASS,
    buckets: Sequence[int] = PRUNE_BUCKETS,
) -> Float[Array, " A"]:
    """I_D(s; g | a) or I_D(c; g | a) on the live classes of ``belief`` (module
    docstring), every configuration, in nats; within :func:`pruning_bound` of
    :func:`~jaxrecog.kernels.pairwise_mutual_information` on all classes.

    ``kind``, ``target``, ``mass`` (the belief mass the live set may leave out)
    and ``buckets`` are static.  Never NaN (as the unpruned kernel)."""
    check_options("pruned_pairwise_mutual_information", target, "belief")
    if kind not in DIVERGENCES:
        raise ValueError(f"pruned_pairwise_mutual_information: kind must be one of {DIVERGENCES}, got {kind!r}")
    mass = check_mass(mass)
    liks = tables.likelihoods
    check_predicted(belief, [jax.ShapeDtypeStruct((lik.n_positions, lik.n_classes, lik.n_levels), lik.dtype)
                             for lik in liks])
    dtype = liks[0].dtype
    n_c = liks[0].n_classes
    sizes = live_buckets(n_c, buckets)
    log_pc = belief.log_pc.astype(dtype)
    log_pc = log_pc - lse(log_pc, axis=-1)
    top, idx = jax.lax.top_k(log_pc, sizes[-1])
    kept = jnp.cumsum(jnp.exp(top))[jnp.asarray(sizes) - 1]
    ok = kept >= (1.0 - mass) * (1.0 - _SLACK * float(jnp.finfo(dtype).eps))  # rounding of the sum
    branch = jnp.where(jnp.any(ok), jnp.argmax(ok), len(sizes) - 1)

    def live(b, _):
        sel = idx[:b]
        sub = tuple(take_classes(lik, sel) for lik in liks)
        ws = [minus_divergences(lik, kind, per_position=False) for lik in sub]
        mes = [shifted_exp(w) for w in ws]
        t = PairwiseTables(tuple(ws), tuple(position_rows(m) for m, _ in mes),
                           tuple(jnp.transpose(e, (0, 3, 1, 2, 4)) for _, e in mes), (), (), (), ())
        lq = log_pc[sel] - lse(log_pc[sel], axis=-1)
        rows = tuple(jnp.take(lp.astype(dtype), sel, axis=1) for lp in belief.log_pk)
        return pairwise_mutual_information(t, PredictedBelief(lq, rows), target, fast=False)

    branches = [functools.partial(live, b) for b in sizes]
    u_tab = tables.u_class if target == "class" else tables.u_state
    if u_tab is not None:  # the first step: uniform classes and level rows (module docstring)
        uniform = jnp.all(floor_log_probs(log_pc) == floor_log_probs(jnp.full_like(log_pc, -math.log(n_c))))
        for lp in belief.log_pk:
            uniform = uniform & jnp.all(lp == jnp.asarray(-math.log(lp.shape[-1]), lp.dtype))
        branches.append(lambda _: u_tab.astype(dtype))
        branch = jnp.where(uniform, len(branches) - 1, branch)
    mi = jax.lax.switch(branch, branches, None)
    return jnp.where(jnp.isnan(mi), -jnp.inf, mi)


def pruning_bound(log_pc, n_live: int, n_level_states: int, target: str = "class") -> float:
    """The largest change the pruning to the ``n_live`` classes of largest mass
    can make to any configuration's score (module docstring), in nats.

    Args:
        log_pc: ``[C]`` the class belief the planner scores (after tempering).
        n_live: B, the live classes.
        n_level_states: L = prod_i L_i.
        target: ``"class"`` or ``"state"``."""
    lp = np.asarray(log_pc, float)
    p = np.sort(np.exp(lp - np.logaddexp.reduce(lp)))[::-1]
    n_c, b, n_l = len(p), int(n_live), int(n_level_states)
    if not 1 <= b <= n_c:
        raise ValueError(f"n_live must be in [1, C = {n_c}], got {n_live}")
    eps = float(min(max(1.0 - np.sum(p[:b]), 0.0), 1.0))
    if eps == 0.0 or b == n_c:
        return 0.0
    q = p[:b] / (1.0 - eps) if eps < 1.0 else np.full(b, 1.0 / b)
    q = q[q > 0]
    g = float(np.sum(q * np.log(1.0 - eps + eps * n_l / q)))
    h_b = -eps * math.log(eps) - ((1.0 - eps) * math.log(1.0 - eps) if eps < 1.0 else 0.0)
    if target == "class":
        up = h_b + eps * (math.log(n_c - b) + math.log(n_l))
        low = eps * (math.log(b) + math.log(n_l)) + (1.0 - eps) * g
    elif target == "state":
        up = h_b + eps * math.log((n_c - b) * n_l)
        low = eps * math.log(b * n_l) + (1.0 - eps) * g
    else:
        raise ValueError(f"target must be 'state' or 'class', got {target!r}")
    return max(up, low)
