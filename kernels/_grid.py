"""Shared machinery: mixtures over classes c' on the product grid of camera positions.

Both planners need, for every stratum (c, j) and every point of the product
grid x = (x_0, x_1, ...) with x_i = (v_i, k_i),

    log Z[c, j, x] = log sum_c' exp(extra[c, j, c'] + sum_i tab_i[c, j, x_i, c'])

and posterior means of features over c'.  Shifting each camera's table by its
maximum over c' turns the sum over c' into a batched matrix product
(an einsum for n cameras) instead of a logsumexp over the materialised
[C, J, X_0, X_1, ..., C'] array.  Where the shifted sum underflows (a row's sum
below ``tau``), the exact logsumexp over the materialised array is used
instead, under ``lax.cond`` so it costs nothing when no row underflows.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from .config_grid import ConfigGrid, position_rows

_GRID_LETTERS = "pqrstuvwxy"


def lse(x, axis):
    """logsumexp that is -inf (not NaN) for an all -inf slice."""
    m = jnp.max(x, axis=axis, keepdims=True)
    m = jnp.where(jnp.isfinite(m), m, 0.0)
    s = jnp.sum(jnp.exp(x - m), axis=axis)
    return jnp.log(s) + jnp.squeeze(m, axis)


def flushed_exp(x, floor: float):
    """``exp(x)`` with every value below ``exp(floor)`` flushed to exactly 0
    (``floor`` at or above ``log(tiny)``: no subnormal float comes out; they
    are ~100x slower on x86 CPUs)."""
    return jnp.where(x < floor, 0.0, jnp.exp(jnp.maximum(x, floor)))


def shifted_exp(x):
    """``(M, E)`` over the last axis: M = max (0 where not finite, as in
    :func:`lse`) and E = exp(x - M[..., None]), flushed to 0 below the
    smallest normal float (:func:`flushed_exp`).  The offline tables of the
    Monte Carlo and the pairwise MI hold such pairs, so their online sums over
    the last axis are batched matrix products without an exp."""
    m = jnp.max(x, axis=-1)
    m = jnp.where(jnp.isfinite(m), m, 0.0)
    return m, flushed_exp(x - m[..., None], math.log(float(jnp.finfo(x.dtype).tiny)))


#: Classes per chunk of the strata (:func:`live_chunks`): the Monte Carlo
#: kernels sum over the strata of the classes of nonzero weight alone, this
#: many at a time (a class whose weight is flushed to 0 adds exactly 0 to that
#: sum; it stays in every mixture over c').  A belief after a view or two has
#: a few such classes.  Case (iii)'s campaigns (800 trials; mi / mi-class /
#: crlb, s) took 18 / 14 / 32 with chunks of 4, 22 / 17 / 44 with 8, 29 / 20 /
#: 65 with 16 and 23 / 17 / 29 with 2.
FEW_CLASSES = 4


def weights(log_p, n_factors: int = 1):
    """``exp(log_p)`` with values that a product of ``n_factors`` such weights
    could take below the smallest normal float flushed to exactly 0.

    Subnormal floats are ~100x slower on x86 CPUs: a concentrated belief
    (classes at P ~ 1e-40) made the Fisher contraction 7x slower (25 -> 180 ms
    at thesis size).  A weight below ``tiny ** (1 / n_factors)`` (f32: 2e-13
    for three factors, f64: 3e-103) changes an expectation by less than that
    weight times the largest term, which is negligible for planning.
    """
    finfo = jnp.finfo(log_p.dtype)
    return flushed_exp(log_p, math.log(float(finfo.tiny)) / max(int(n_factors), 1))


def floor_log_probs(log_p):
    """Raise log-probabilities below ``0.7 log(tiny)`` (f32: -61, f64: -496) to
    that floor before they enter a mixture.

    A concentrated belief (classes at P ~ 1e-40) otherwise fills the shifted
    exponentials with subnormal floats, which are ~100x slower on x86 CPUs
    (thesis-sized CRLB: 25 -> 180 ms).  Raising P from below e^-61 to e^-61
    changes p(g | a) by at most C e^-61 times a likelihood ratio: negligible for
    planning.  The belief itself is untouched.
    """
    floor = 0.7 * math.log(float(jnp.finfo(log_p.dtype).tiny))
    return jnp.maximum(log_p, floor)


def grid_mixture(tabs, extra, feats=()):
    """log Z and posterior means over c' on the product grid (see module doc).

    Args:
        tabs: per camera ``[C, J, X_i, C']``.
        extra: ``[C, J, C']`` added once (e.g. log P(c')).
        feats: ``(camera, f)`` pairs, ``f`` a rank-4 array broadcastable to
            ``[C, J, X_camera, C']``;
            returns the mean of f under the posterior w(c') = exp(...) / Z.

    Returns:
        ``(logZ [C, J, X_0, ..., X_{n-1}], [mean [C, J, X_0, ...] per feat], n_underflow)``.
    """
    n = len(tabs)
    grid = ConfigGrid(tuple(t.shape[2] for t in tabs))  # x = (x_0, x_1, ...); expand(., i, axis=2): X_i at slot i
    dtype = tabs[0].dtype
    finfo = jnp.finfo(dtype)
    n_c = tabs[0].shape[-1]
    tau = n_c * float(finfo.tiny) / float(finfo.eps)
    ts = [tabs[0] + extra[:, :, None, :]] + list(tabs[1:])
    ms = []
    es = []
    for t in ts:
        m = jnp.max(t, axis=-1)
        m = jnp.where(jnp.isfinite(m), m, 0.0)
        ms.append(m)
        es.append(jnp.exp(t - m[..., None]))
    letters = _GRID_LETTERS[:n]
    spec = ",".join(f"cj{l}z" for l in letters) + f"->cj{letters}"

    def contract(ops):
        return jnp.einsum(spec, *ops)

    z = contract(es)
    mtot = sum(grid.expand(m, i, axis=2) for i, m in enumerate(ms))
    logz = jnp.log(z) + mtot
    means = []
    for cam, f in feats:
        ops = list(es)
        ops[cam] = es[cam] * f
        means.append(contract(ops) / jnp.where(z > 0, z, 1.0))
    under = ~(z >= tau)
    n_under = jnp.sum(under)

    def exact(_):
        full = extra.reshape(extra.shape[:2] + (1,) * n + extra.shape[2:])
        for i, t in enumerate(tabs):
            full = full + grid.expand(t, i, axis=2)
        lz = lse(full, axis=-1)
        w = jnp.exp(full - lz[..., None])
        outs = []
        for cam, f in feats:
            fb = jnp.broadcast_to(f, tabs[cam].shape)
            outs.append(jnp.sum(w * grid.expand(fb, cam, axis=2), axis=-1))
        return (jnp.where(under, lz, logz), [jnp.where(under, o, mu) for o, mu in zip(outs, means)])

    def fast(_):
        return (logz, means)

    logz, means = jax.lax.cond(n_under > 0, exact, fast, None)
    return logz, means, n_under


def level_tables(lds, ld_max, ld_exp, log_pk):
    """T_i = logsumexp_k' (LD_i + log P_i(k'|c')) per camera, ``[V_i, C, L_i, J, C]``,
    from per-camera ``lds`` ``[V_i, C, L_i, J, C, L_i]`` (any table of log
    component weights: sample log-densities for the Monte Carlo MI, minus
    pairwise divergences for the pairwise MI) and the belief's per-position
    level rows ``log_pk`` ``[V_i, C, L_i]``.

    Fast path (``ld_max`` / ``ld_exp`` given, built offline): with
    M_i = max_k' LD_i and E_i = exp(LD_i - M_i) (``[V_i, C', L_i', C, L_i, J]``),

        T_i = M_i + log sum_k' E_i[..., k'] P_i(k'|c')

    (a batched matrix product over k', no exp over the LD entries online;
    P_i = ``weights(log P_i)``, values below the smallest normal float flushed
    to 0).  Guard: the shift M_i ignores the belief, so where the belief puts
    ~all its mass on levels whose E_i is tiny or flushed (e.g. P_i ~ 0 on the
    level holding the max of LD_i), the sum underflows and loses precision.
    If any sum in any camera is below ``tau = L_i * tiny / eps`` (or not a
    number), the whole call uses the exact logsumexp over LD_i instead, under
    ``lax.cond`` (nothing is paid for it when no sum underflows; under
    ``vmap`` both branches run).  Above ``tau`` the flushed terms (each below
    ``tiny``) change the sum by at most a relative ``eps``, so the two paths
    agree to rounding.
    """
    def exact(_):
        return [lse(ld + lp[:, None, None, None], axis=-1) for ld, lp in zip(lds, log_pk)]

    if ld_max is None or ld_exp is None:
        return exact(None)
    finfo = jnp.finfo(lds[0].dtype)
    fast, under = [], jnp.zeros((), bool)
    for mx, ex, lp in zip(ld_max, ld_exp, log_pk):
        tau = lp.shape[-1] * float(finfo.tiny) / float(finfo.eps)
        s = jnp.einsum("vCKclj,vCK->vcljC", ex, weights(lp))
        under = under | jnp.any(~(s >= tau))
        fast.append(jnp.log(s) + mx)
    return jax.lax.cond(under, exact, lambda _: fast, None)


def check_options(kernel: str, target: str, levels: str) -> None:
    """The ``target`` / ``levels`` arguments both MI kernels take, checked
    with one message form (``kernel`` names the caller)."""
    if target not in ("state", "class"):
        raise ValueError(f"{kernel}: target must be 'state' or 'class', got {target!r}")
    if levels not in ("belief", "uniform"):
        raise ValueError(f"{kernel}: levels must be 'belief' or 'uniform', got {levels!r}")


def own_class(t, class_axis: int, other_class_axis: int):
    """The entries at c' = c (the table of a sample's own class): the diagonal
    of axes ``class_axis`` (c) and ``other_class_axis`` (c'), put where c was,
    e.g. ``[V, C, L, J, C'] -> [V, C, L, J]`` with axes (1, 4) or
    ``[C, X, C'] -> [C, X]`` with axes (0, 2)."""
    return jnp.moveaxis(jnp.diagonal(t, axis1=class_axis, axis2=other_class_axis), -1, class_axis)


def live_chunks(log_pc, n_factors: int, body, init, size: int = FEW_CLASSES):
    """The sum over the strata by classes: ``body(None)`` (every class at
    once) where there are at most ``2 * size`` classes, else ``init + sum_k
    body((keep_k, valid_k))`` over chunks of ``size`` class indices, the
    classes of nonzero weight (:func:`weights` with ``n_factors``) first:
    ``keep_k`` ``[size]`` indices, ``valid_k`` whether each is one of them
    (padding and dead classes are not).  A loop of ceil(live / size) steps: a
    belief after a view or two runs one.  ``body`` must give 0 for the
    invalid entries (weight them by 0)."""
    n_c = log_pc.shape[0]
    m = int(size)
    if n_c <= 2 * m:
        return body(None)
    live = weights(log_pc, n_factors) > 0
    n_live = jnp.sum(live)
    order = jnp.argsort(~live, stable=True)  # the live classes first, ascending
    chunks = -(-n_c // m)
    order = jnp.concatenate([order, jnp.zeros(chunks * m - n_c, order.dtype)])
    valid = jnp.arange(chunks * m) < n_live

    def step(k, acc):
        keep = jax.lax.dynamic_slice_in_dim(order, k * m, m)
        return acc + body((keep, jax.lax.dynamic_slice_in_dim(valid, k * m, m)))

    return jax.lax.fori_loop(0, (n_live + m - 1) // m, step, init)


def mixture_information(ts, selfs, log_pc, log_pk, outer=None):
    """Per-replicate information ``[J, A]`` on the (v_0, v_1, ...) grid, the part
    the Monte Carlo MI and the pairwise-distance MI share:

        sum_{c, k_0, k_1, ...} P(c) prod_i P_i(k_i|c) [ sum_i S_i[v_i, c, k_i, j]
            - log sum_c' P(c') exp(sum_i T_i[v_i, c, k_i, j, c']) ]

    Args:
        ts: per camera ``[V_i, C, L_i, J, C']`` level tables T_i (see
            :func:`level_tables`; for the pairwise MI J = 1 and T_i = W_i).
        selfs: per camera ``[V_i, C, L_i, J]`` tables S_i of the conditional
            term, or ``None`` for 0 (the pairwise state target).
        log_pc: ``[C]`` log P(c) (already floored, :func:`floor_log_probs`).
        log_pk: per camera ``[V_i, C, L_i]`` log P_i(k|c) per position
            (factors below the smallest normal float are flushed to 0,
            :func:`weights`).
        outer: ``(keep [M], valid [M])``: the strata's classes c are those
            of ``keep`` where ``valid`` (``ts`` and ``selfs`` hold the rows of
            ``keep`` on the c axis, in its order; the mixture over c' keeps
            every class; :func:`live_chunks`).  The others and a class of
            weight 0 add 0, whatever their rows hold.  ``None``: every class.

    Returns:
        ``[J, A]``, A = prod_i V_i row-major; the mean over J is the estimate.
    """
    n = len(ts)
    positions = tuple(t.shape[0] for t in ts)
    grid = ConfigGrid(positions)
    n_o, j = ts[0].shape[1], ts[0].shape[3]
    n_c = log_pc.shape[0]
    dtype = ts[0].dtype
    # E_s log sum_c' ...: mixture over c' on the (v_0, v_1, ...) grid.
    grid_tabs = [position_rows(t, front=(1, 3)) for t in ts]  # [C, J, X_i, C']
    extra = jnp.broadcast_to(log_pc[None, None, :], (n_o, j, n_c))
    logp, _, _ = grid_mixture(grid_tabs, extra)  # [C, J, X_0, ..., X_{n-1}]
    pc = weights(log_pc, n + 1)
    pk = [weights(lp, n + 1) for lp in log_pk]  # [V_i, C, L_i]
    if outer is not None:
        keep, valid = outer
        pc, pk = jnp.where(valid, pc[keep], 0.0), [p[:, keep] for p in pk]
        live = pc > 0
        logp = jnp.where(live.reshape((n_o,) + (1,) * (logp.ndim - 1)), logp, 0.0)
        if selfs is not None:
            selfs = [jnp.where(live[None, :, None, None], s, 0.0) for s in selfs]
    letters = _GRID_LETTERS[:n]
    caps = letters.upper()
    shaped = logp.reshape((n_o, j) + sum(((v, t.shape[2]) for v, t in zip(positions, ts)), ()))
    grid_in = "cj" + "".join(a + b for a, b in zip(letters, caps))
    spec = "c," + grid_in + "," + ",".join(f"{a}c{b}" for a, b in zip(letters, caps)) + "->j" + letters
    e_logp = jnp.einsum(spec, pc, shaped, *pk)  # [J, V_0, ..., V_{n-1}]
    e_self = jnp.zeros((j,) + positions, dtype)
    if selfs is not None:
        for i, s in enumerate(selfs):
            e_i = jnp.einsum("c,vcl,vclj->jv", pc, pk[i], s)
            e_self = e_self + grid.expand(e_i, i)
    return grid.flatten(e_self - e_logp)


__all__ = ["FEW_CLASSES", "live_chunks", "check_options", "floor_log_probs", "flushed_exp", "grid_mixture", "level_tables", "lse", "mixture_information",
           "own_class", "shifted_exp", "weights"]

