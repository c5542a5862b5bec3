"""Deterministic pairwise-distance Mutual Information for all configurations in
one call (Kolchinsky & Tracey, "Estimating Mixture Entropy with Pairwise
Distances", Entropy 19(7):361, 2017; docs/design.md §7).

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

Evaluation on the whole (v_0, v_1, ...) grid, x_i = (v_i, k_i) a row of
camera i's table in the grid layout ``[C, X_i = V_i L_i, C']``: with
M_i = max_c' W_i and E_i = exp(W_i - M_i),

    log sum_s' P(s') exp(-D_a(s, s')) = sum_i M_i[c, x_i] + log sum_c' P(c') prod_i E_i[c, x_i, c']

a batched matrix product over c' (16.5 MFLOP at thesis size), then one log
per grid point and the weighted sum over the strata, one fused loop step per
class c (a reduce with broadcast weights over the whole grid is ~5x slower
with XLA on the CPU).

Fast path (the recognizer's predicted prior): under both transitions of
:func:`~jaxrecog.kernels.transition_per_position` a camera's level rows are
uniform, P_i[v](k|c) = 1/L_i, at every position but its current one (a
camera that moves re-draws its levels, eq. 3.9).  For uniform rows W_i, M_i
and E_i do not depend on the belief and are precomputed
(:func:`pairwise_tables`); online only the current position's L_i rows are
computed (W_i = M'_i + log sum_k' E'_i P_i, with M'_i = max_k' (-D_i) and
E'_i = exp(-D_i - M'_i) offline: a small matrix product, no exp over D) and
put in place, for the largest camera by recomputing its rows of the grid
product instead of copying its table.  The kernel checks the precondition
on the belief itself (at most one position per camera whose rows are not
exactly uniform) and otherwise computes W_i at every position, under
``lax.cond`` (only the branch taken runs; under ``vmap`` both run).  Both
paths evaluate the same formula and agree to rounding.

Uniform class prior (the tempered planner at tau = 0,
:mod:`~jaxrecog.kernels.tempered_mi`): where moreover P(c) is exactly
uniform, a configuration with no camera at its current position sees only
uniform rows and the uniform class prior, so its value does not depend on
the belief and is read from the tables (``u_state`` / ``u_class``, computed
with the others); only the slabs v_i = cur_i (one per camera: 38 of 224
configurations at thesis size) are computed online, each a grid of L_i rows
for its camera (~7x less work than the whole grid).  Same formula, equal to
rounding.

Few classes: a class c whose weight P(c) is flushed to 0 (below the
strata's weight floor, e.g. every class but a look-alike pair after a view or
two) adds exactly 0 to the sum over the strata, though it still counts in
every mixture over c'.  When at most ``_FEW_CLASSES`` classes have weight,
a loop over those alone (ascending, so the sum is the same, term by term)
makes each one's grid product over c' and its log, under ``lax.cond``.

No underflow fallback is needed: D(s, s) = 0 gives W_i[c, k, c] >= log P_i(k|c)
and W_i <= 0, so E_i[c, x_i, c] >= P_i(k_i|c) and the shifted sum of stratum s
is >= P(s); strata with a weight factor below exp(floor) are dropped (weight 0;
their share of I is < 1e-7 nats in float32), so every sum that counts is above
the underflow threshold.  Inner level weights are floored (float32: >= e^-61),
so the sum over k' (which holds E' = 1 times P >= e^-61) never underflows
either.

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
(:meth:`~jaxrecog.kernels.Likelihood.divergence`): closed forms for the
Gaussians; a moment-matched Gaussian approximation for a family without one,
and for the view mixtures, whose pairwise-component bound collapses to 0
between look-alikes when neighbouring views overlap (:mod:`.view_mixture`).
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ._grid import check_options, floor_log_probs, flushed_exp, lse, own_class, shifted_exp
from .belief import PredictedBelief, check_predicted
from .config_grid import ConfigGrid, position_rows
from .likelihood import Likelihood, as_likelihoods

__all__ = ["PairwiseTables", "pairwise_tables", "pairwise_mutual_information", "DIVERGENCES"]

#: The divergences :func:`pairwise_tables` accepts (the lower and the upper bound).
DIVERGENCES = ("bhattacharyya", "kl")

_GRID_LETTERS = "pqrstuvwxy"

#: grids of at most this many entries (C x X_0 x X_1 ...) are reduced over
#: the classes in one fusion instead of a loop over c (see :func:`_information`)
_SMALL_GRID = 1 << 16

#: at most this many classes of nonzero weight: a loop over them alone makes
#: the grid (module docstring, "Few classes"; a class's turn costs ~1/25 of
#: the whole grid at thesis size)
_FEW_CLASSES = 8


class PairwiseTables(NamedTuple):
    """Per-camera divergence tables of the pairwise-distance MI (fixed shapes per
    model; built once, belief-free).  X_i = V_i L_i rows (v, k), row-major.

    Attributes:
        log_w: per camera ``[V_i, C, L_i, C', L_i']``, minus the divergence,
            -D_i[v, c, k, c', k'] (D(p_ck || p_c'k') for KL); not used online.
        w_max: per camera ``[C, X_i, C']``, M'_i = max_k' (-D_i).
        w_exp: per camera ``[V_i, C', C, L_i, L_i']``, E'_i = exp(-D_i - M'_i),
            flushed to 0 below the smallest normal float (this axis order
            makes the contraction over k' a batched matrix-vector product).
        u_log: per camera ``[C, X_i, C']``, W_i under uniform levels,
            logsumexp_k' (-D_i) - log L_i.
        u_max: per camera ``[C, X_i]``, M_i = max_c' of ``u_log``.
        u_exp: per camera ``[C, X_i, C']``, E_i = exp(u_log - u_max), flushed
            to 0 below the smallest normal float.
        u_self: per camera ``[C, X_i]``, ``u_log`` at c' = c.
        u_state, u_class: ``[A]``, I_D(s; g | a) and I_D(c; g | a) under the
            uniform class prior and uniform level rows (the values of every
            configuration with no camera at its current position when the
            predicted prior's class part is uniform; ``None``: not built).
    """

    log_w: tuple[Float[Array, "_V C _L C _L"], ...]
    w_max: tuple[Float[Array, "C _X C"], ...]
    w_exp: tuple[Float[Array, "_V C C _L _L"], ...]
    u_log: tuple[Float[Array, "C _X C"], ...]
    u_max: tuple[Float[Array, "C _X"], ...]
    u_exp: tuple[Float[Array, "C _X C"], ...]
    u_self: tuple[Float[Array, "C _X"], ...]
    u_state: Float[Array, " A"] | None = None
    u_class: Float[Array, " A"] | None = None


def pairwise_tables(
    likelihoods: Sequence[Likelihood],
    *,
    kind: str = "bhattacharyya",
) -> PairwiseTables:
    """The offline divergence tables of :func:`pairwise_mutual_information` (once per model).

    Args:
        likelihoods: one :class:`~jaxrecog.kernels.Likelihood` per camera, as
            :func:`~jaxrecog.kernels.mi_tables`.
        kind: ``"bhattacharyya"`` (lower bound) or ``"kl"`` (upper bound).
    """
    if kind not in DIVERGENCES:
        raise ValueError(f"pairwise_tables: kind must be one of {DIVERGENCES}, got {kind!r}")
    liks = as_likelihoods(likelihoods, where="pairwise_tables")
    return _pairwise_tables(tuple(liks), kind)


@functools.partial(jax.jit, static_argnums=1)
def _pairwise_tables(liks, kind: str) -> PairwiseTables:
    """:func:`pairwise_tables` as one compiled program (op by op, the build
    compiled ~200 small programs: 4-6 s for a 4-position model on the 2-core
    CPU, most of ``jaxrecog plan``'s time)."""
    out = {name: [] for name in PairwiseTables._fields if name not in ("u_state", "u_class")}
    for lik in liks:
        w = minus_divergences(lik, kind)  # [V, C, L, C', L']
        n_l = w.shape[2]
        m, e = shifted_exp(w)
        u = position_rows(lse(w, axis=-1) - math.log(n_l))  # [C, X, C']
        um, ue = shifted_exp(u)
        out["log_w"].append(w)
        out["w_max"].append(position_rows(m))
        out["w_exp"].append(jnp.transpose(e, (0, 3, 1, 2, 4)))
        out["u_log"].append(u)
        out["u_max"].append(um)
        out["u_exp"].append(ue)
        out["u_self"].append(own_class(u, 0, 2))
    per_camera = {name: tuple(v) for name, v in out.items()}
    # the uniform-class values (module docstring, "Uniform class prior"), belief-free
    dtype = per_camera["u_exp"][0].dtype
    n_c = per_camera["u_exp"][0].shape[0]
    log_pc = floor_log_probs(jnp.full((n_c,), -math.log(n_c), dtype))
    wks = [jnp.full((n_c, w.shape[0], w.shape[2]), -math.log(w.shape[2]), dtype) for w in per_camera["log_w"]]
    floor = _weight_floor(dtype, n_c, len(wks))
    u_state, u_class = (_information(per_camera["u_exp"], per_camera["u_max"], selfs, log_pc, wks, floor)
                        for selfs in (None, per_camera["u_self"]))
    return PairwiseTables(**per_camera, u_state=u_state, u_class=u_class)


def minus_divergences(lik: Likelihood, kind: str, per_position: bool = True) -> Float[Array, "V C L C L"]:
    """-D_i[v, c, k, c', k'] of one camera's likelihood, every position: D >= 0
    up to rounding and D(s, s) = 0 exactly (keeps W_i[c, k, c] >= log P_i(k|c)).
    ``per_position``: :meth:`~.Likelihood.divergence` one position at a time
    (the tables); ``False``: the family's :meth:`~.Likelihood.camera_divergence`."""
    if per_position:
        d = jax.lax.map(lambda lik_v: lik_v.divergence(kind), lik)  # [V, C, L, C', L']
    else:
        d = lik.camera_divergence(kind)
    n_c, n_l = d.shape[1], d.shape[2]
    eye = (jnp.eye(n_c, dtype=bool)[:, None, :, None] & jnp.eye(n_l, dtype=bool)[None, :, None, :])
    return -jnp.where(eye[None], 0.0, jnp.maximum(d, 0.0))


def uniform_values(u_exp, u_max, u_self, positions, n_levels):
    """``(u_state, u_class)``: I_D(s; g | a) and I_D(c; g | a) under the uniform
    class prior and uniform level rows, from the grid-layout E_i, M_i and S_i
    of those rows (:class:`PairwiseTables`' ``u_exp``, ``u_max``, ``u_self``)."""
    dtype, n_c = u_exp[0].dtype, u_exp[0].shape[0]
    log_pc = floor_log_probs(jnp.full((n_c,), -math.log(n_c), dtype))
    wks = [jnp.full((n_c, v, l), -math.log(l), dtype) for v, l in zip(positions, n_levels)]
    floor = _weight_floor(dtype, n_c, len(wks))
    return tuple(_information(u_exp, u_max, s, log_pc, wks, floor) for s in (None, u_self))


def _weight_floor(dtype, n_c: int, n: int) -> float:
    """Log weight factor below which a stratum is dropped (module docstring)."""
    finfo = jnp.finfo(dtype)
    tau = n_c * float(finfo.tiny) / float(finfo.eps)
    return (math.log(tau) + 1.0) / (n + 1)


def _level_rows(w_exp, w_max, lp):
    """W_i = M'_i + log sum_k' E'_i P_i(k'|c') for the positions in ``lp``
    (``[V, C, L]``, floored log P_i), grid layout ``[C, V*L, C']``; ``w_exp``
    ``[V, C', C, L, L']`` and ``w_max`` ``[C, V*L, C']`` of the same positions."""
    p = jnp.exp(lp)  # lp >= floor_log_probs' floor: no flush needed
    s = jnp.einsum("vCclK,vCK->cvlC", w_exp, p)
    return jnp.log(s.reshape(w_max.shape)) + w_max


def _transition_form(log_pk):
    """Whether every camera's level rows are exactly uniform at all positions
    but at most one (the form of :func:`~jaxrecog.kernels.transition_per_position`),
    and that position per camera (0 when all are uniform)."""
    ok, cur = jnp.ones((), bool), []
    for lp in log_pk:
        u = jnp.asarray(-math.log(lp.shape[-1]), lp.dtype)
        other = jnp.any(lp != u, axis=(1, 2))  # [V]
        ok = ok & (jnp.sum(other.astype(jnp.int32)) <= 1)
        cur.append(jnp.argmax(other).astype(jnp.int32))
    return ok, cur


def _information(es, ms, selfs, log_pc, wks, weight_floor, patch=None, few: bool = False):
    """I_D on the grid from grid-layout E_i ``[C, X_i, C']``, M_i ``[C, X_i]``,
    S_i ``[C, X_i]`` (class target; ``None`` for the state target), floored
    log P(c) and the strata's weight factors ``wks`` ``[C, V_i, L_i]``.

    ``few``: where at most ``_FEW_CLASSES`` classes have weight, loop over
    them alone (module docstring, "Few classes"; off for the belief-free
    tables and the uniform-class slabs, whose classes all have weight).

    ``patch = (big, start, e_rows)``: camera ``big``'s E rows
    ``[start, start + L)`` hold stale values in ``es`` and are replaced by
    ``e_rows`` ``[C, L, C']`` (a copy of one class's rows per step of the loop,
    not of the table).

    One loop over the classes c of the stratum: the grid product over c' for
    that class (``[X_0, X_1, ...]``, it stays in cache), its log and its
    weighted sum; log Z over the whole grid (1 MB at thesis size) is never
    materialised.  Measured on the 2-core CPU: a reduce with broadcast weights
    over the materialised grid cost ~1-2 ms, this loop ~0.4 ms."""
    n = len(es)
    n_c = es[0].shape[0]
    dtype = es[0].dtype
    xs = tuple(e.shape[1] for e in es)
    positions = tuple(w.shape[1] for w in wks)
    n_levels = tuple(w.shape[2] for w in wks)
    grid, row_grid = ConfigGrid(positions), ConfigGrid(xs)  # (v_0, v_1, ...) and (x_0, x_1, ...)
    small = min(range(n), key=lambda i: xs[i])
    pc_inner = jnp.exp(log_pc)  # floored: >= e^-61, no flush
    es = list(es)
    es[small] = es[small] * pc_inner[None, None, :]
    if patch is not None and patch[0] == small:
        patch = (patch[0], patch[1], patch[2] * pc_inner[None, None, :])
    # weights of the strata (c, k_0, ...) per configuration, factors below the floor flushed
    pc = flushed_exp(log_pc, weight_floor)
    ws = [flushed_exp(w, weight_floor) for w in wks]  # [C, V_i, L_i]
    wg = [w.reshape(n_c, -1) for w in ws]  # [C, X_i]
    wg[0] = wg[0] * pc[:, None]
    letters = _GRID_LETTERS[:n]
    spec = ",".join(f"c{l}z" for l in letters) + f"->c{letters}"
    tiny = float(jnp.finfo(dtype).tiny)

    def class_term(z_c, c, wg_o):
        """Class ``c``'s log grid ``z_c`` weighted by its strata's weights
        (only rows of weight 0 can be below tiny, module docstring)."""
        logz = jnp.log(jnp.maximum(z_c, tiny))
        for i, w in enumerate(wg_o):
            logz = logz * row_grid.expand(jax.lax.dynamic_index_in_dim(w, c, 0, keepdims=False), i)
        return logz

    def grid_sum(es_o, wg_o, patch_o):
        """sum over the outer classes given (the leading axis of ``es_o``,
        ``wg_o`` and the patch's rows) of their weighted log grid ``[X_0, ...]``."""
        z = jnp.einsum(spec, *es_o)  # [C_o, X_0, ..., X_{n-1}]
        if patch_o is not None:
            big, start, rows = patch_o
            ops = list(es_o)
            ops[big] = rows
            starts = [jnp.zeros((), jnp.int32)] * (n + 1)
            starts[1 + big] = start
            z = jax.lax.dynamic_update_slice(z, jnp.einsum(spec, *ops), starts)
        n_o = z.shape[0]

        def body(c, acc):
            # one fusion per class: its slice of the grid, log, weights, accumulate
            return acc + class_term(jax.lax.dynamic_index_in_dim(z, c, 0, keepdims=False), c, wg_o)

        if n_o * math.prod(xs) <= _SMALL_GRID:
            # a small grid (a slab of the uniform-class path): one fusion over all
            # classes (the loop's per-iteration cost would dominate)
            logz = jnp.log(jnp.maximum(z, tiny))
            for i, w in enumerate(wg_o):
                logz = logz * row_grid.expand(w, i)
            return jnp.sum(logz, axis=0)
        return jax.lax.fori_loop(0, n_o, body, jnp.zeros(xs, dtype))

    if few and n_c > _FEW_CLASSES and n_c * math.prod(xs) > _SMALL_GRID:
        # a class of weight 0 (P(c) flushed) adds exactly 0 to the sum: when at
        # most _FEW_CLASSES have weight (a belief after a view or two), a loop
        # over those alone makes each one's grid product and log (module
        # docstring, "Few classes")
        live = pc > 0
        spec_c = ",".join(f"{l}z" for l in letters) + f"->{letters}"

        def live_class(j, acc, order):
            c = order[j]
            ops = [jax.lax.dynamic_index_in_dim(e, c, 0, keepdims=False) for e in es]
            z = jnp.einsum(spec_c, *ops)  # [X_0, ..., X_{n-1}]
            if patch is not None:
                big, start, rows = patch
                ops[big] = jax.lax.dynamic_index_in_dim(rows, c, 0, keepdims=False)
                starts = [jnp.zeros((), jnp.int32)] * n
                starts[big] = start
                z = jax.lax.dynamic_update_slice(z, jnp.einsum(spec_c, *ops), starts)
            return acc + class_term(z, c, wg)

        def live_loop(_):
            order = jnp.argsort(~live, stable=True)  # the live classes first, ascending
            return jax.lax.fori_loop(0, jnp.sum(live), functools.partial(live_class, order=order),
                                     jnp.zeros(xs, dtype))

        acc = jax.lax.cond(jnp.sum(live) <= _FEW_CLASSES, live_loop, lambda _: grid_sum(es, wg, patch), None)
    else:
        acc = grid_sum(es, wg, patch)
    split = sum(((v, l) for v, l in zip(positions, n_levels)), ())
    e_logp = jnp.sum(acc.reshape(split), axis=tuple(range(1, 2 * n, 2)))  # [V_0, ..., V_{n-1}]
    # sum_s P(s) sum_i M_i[c, x_i]: small contractions, one per camera
    vs, ks = letters, letters.upper()
    w_in = [f"c{a}{b}" for a, b in zip(vs, ks)]
    for i, m in enumerate(ms):
        e_logp = e_logp + jnp.einsum(",".join(["c"] + w_in + [w_in[i]]) + "->" + vs, pc, *ws, m.reshape(ws[i].shape))
    if selfs is not None:
        for i, (s, w) in enumerate(zip(selfs, ws)):
            e_i = jnp.einsum("c,cvl,cvl->v", pc, w, s.reshape(w.shape))
            e_logp = e_logp - grid.expand(e_i, i)
    return -grid.flatten(e_logp)


def pairwise_mutual_information(
    tables: PairwiseTables,
    belief: PredictedBelief,
    target: str = "state",
    levels: str = "belief",
    fast: bool = True,
) -> Float[Array, " A"]:
    """I_D(s; g | a) (``target="state"``) or I_D(c; g | a) (``"class"``) for every
    configuration a, in nats (see the module docstring for the equations).

    Args:
        tables: from :func:`pairwise_tables` (its ``kind`` decides the bound).
        belief: the predicted prior, level rows per position ``[V_i, C, L_i]``
            (:func:`jaxrecog.kernels.transition_per_position`).
        target: ``"state"`` or ``"class"`` (static).
        levels: ``"belief"`` (the prior's level rows) or ``"uniform"``
            (P_i(k|c) = 1/L_i everywhere, the belief-free tables; as
            :func:`~jaxrecog.kernels.mutual_information`, exact only where every
            camera moves under the uniform transition).  Static.
        fast: with ``levels="belief"``, use the precomputed uniform-level
            tables where the belief has the transition's form (see the module
            docstring; the same value to rounding).  ``False`` always computes
            every position's level rows (for tests and benchmarks).  Static.

    Returns:
        ``[A]`` values, row-major over (v_0, v_1, ...).  Never NaN: a belief
        holding NaN raises a ``ValueError`` when its values are concrete; under
        ``jit`` (values unknown) a NaN estimate is returned as ``-inf`` (a failed
        estimate, ranked last by the recognizer).
    """
    check_options("pairwise_mutual_information", target, levels)
    check_predicted(belief, tables.log_w)
    positions = tuple(w.shape[0] for w in tables.log_w)
    n_levels = tuple(w.shape[2] for w in tables.log_w)
    n = len(positions)
    n_c = tables.log_w[0].shape[1]
    dtype = tables.log_w[0].dtype
    log_pc = floor_log_probs(belief.log_pc.astype(dtype))  # no subnormals (see _grid)
    # strata with a weight factor below exp(floor) are dropped (module docstring)
    floor = _weight_floor(dtype, n_c, n)
    klass = target == "class"

    def grid_weights(lps):
        return [jnp.moveaxis(lp, 1, 0) for lp in lps]  # [C, V, L]

    if levels == "uniform":
        wks = [jnp.full((n_c, v, l), -math.log(l), dtype) for v, l in zip(positions, n_levels)]
        mi = _information(tables.u_exp, tables.u_max, tables.u_self if klass else None, log_pc, wks, floor)
        return jnp.where(jnp.isnan(mi), -jnp.inf, mi)

    log_pk = [floor_log_probs(lp.astype(dtype)) for lp in belief.log_pk]
    wks = grid_weights(log_pk)

    def general(_):
        ws = [_level_rows(e, m, lp) for e, m, lp in zip(tables.w_exp, tables.w_max, log_pk)]
        mes = [shifted_exp(w) for w in ws]
        selfs = [own_class(w, 0, 2) for w in ws] if klass else None
        return _information([e for _, e in mes], [m for m, _ in mes], selfs, log_pc, wks, floor, few=True)

    big = max(range(n), key=lambda i: positions[i] * n_levels[i])
    zero = jnp.zeros((), jnp.int32)

    def current_rows(cur):
        """Per camera, its rows at its current position: (start, M [C, L], E [C, L, C'], S [C, L])."""
        out = []
        for i, (c, l) in enumerate(zip(cur, n_levels)):
            start = c * l
            lp = jax.lax.dynamic_slice_in_dim(log_pk[i], c, 1, axis=0)
            e_rows = jax.lax.dynamic_slice_in_dim(tables.w_exp[i], c, 1, axis=0)
            m_rows = jax.lax.dynamic_slice_in_dim(tables.w_max[i], start, l, axis=1)
            w = _level_rows(e_rows, m_rows, lp)  # [C, L, C']
            m, e = shifted_exp(w)
            out.append((start, m, e, own_class(w, 0, 2) if klass else None))
        return out

    def patched(i, row, patch_e: bool):
        """Camera i's uniform tables with its current rows put in place; E via
        ``_information``'s patch (returned) where ``patch_e``, else copied."""
        start, m, e, own = row
        ms = jax.lax.dynamic_update_slice(tables.u_max[i], m, (zero, start))
        own = jax.lax.dynamic_update_slice(tables.u_self[i], own, (zero, start)) if klass else None
        if patch_e:
            return tables.u_exp[i], ms, own, (i, start, e)
        return jax.lax.dynamic_update_slice(tables.u_exp[i], e, (zero, start, zero)), ms, own, None

    def transition_form(cur):
        es, ms, selfs, patch = [], [], [], None
        for i, row in enumerate(current_rows(cur)):
            e, m, own, p = patched(i, row, i == big)
            es.append(e), ms.append(m), selfs.append(own)
            patch = p or patch
        return _information(es, ms, selfs if klass else None, log_pc, wks, floor, patch, few=True)

    def uniform_class(cur):
        # the class prior is uniform (e.g. the tempered belief at tau = 0) and
        # the rows have the transition's form: a configuration with no camera
        # at its current position has the belief-free value (tables.u_*); the
        # others lie on one slab v_i = cur_i per camera, each computed alone
        rows = current_rows(cur)
        grid = (tables.u_class if klass else tables.u_state).reshape(positions)
        for i in range(n):
            others = [j for j in range(n) if j != i]
            big_j = max(others, key=lambda j: positions[j] * n_levels[j]) if others else None
            es, ms, selfs, ws, patch = [], [], [], [], None
            for j, row in enumerate(rows):
                if j == i:
                    _, m, e, own = row
                    es.append(e), ms.append(m), selfs.append(own)
                    ws.append(jax.lax.dynamic_slice_in_dim(wks[j], cur[j], 1, axis=1))
                else:
                    e, m, own, p = patched(j, row, j == big_j)
                    es.append(e), ms.append(m), selfs.append(own), ws.append(wks[j])
                    patch = p or patch
            slab = _information(es, ms, selfs if klass else None, log_pc, ws, floor, patch)
            shape = tuple(1 if j == i else v for j, v in enumerate(positions))
            starts = tuple(cur[i] if j == i else zero for j in range(n))
            grid = jax.lax.dynamic_update_slice(grid, slab.reshape(shape), starts)
        return grid.reshape(-1)

    if fast:
        ok, cur = _transition_form(log_pk)
        u_tab = tables.u_class if klass else tables.u_state
        if u_tab is None:
            mi = jax.lax.cond(ok, lambda _: transition_form(cur), general, None)
        else:
            uniform_pc = jnp.all(log_pc == floor_log_probs(jnp.full_like(log_pc, -math.log(n_c))))
            branch = jnp.where(ok, jnp.where(uniform_pc, 2, 1), 0)
            mi = jax.lax.switch(branch, [general, lambda _: transition_form(cur), lambda _: uniform_class(cur)], None)
    else:
        mi = general(None)
    return jnp.where(jnp.isnan(mi), -jnp.inf, mi)
