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

_GRID_LETTERS = "pqrstuvwxy"


def lse(x, axis):
    """logsumexp that is -inf (not NaN) for an all -inf slice."""
    m = jnp.max(x, axis=axis, keepdims=True)
    m = jnp.where(jnp.isfinite(m), m, 0.0)
    s = jnp.sum(jnp.exp(x - m), axis=axis)
    return jnp.log(s) + jnp.squeeze(m, axis)


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
    floor = math.log(float(finfo.tiny)) / max(int(n_factors), 1)
    return jnp.where(log_p < floor, 0.0, jnp.exp(jnp.maximum(log_p, floor)))


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


def _expand(a, i, n):
    """[C, J, X_i, ...] -> [C, J, 1, .., X_i, .., 1, ...] (X_i at grid slot i of n)."""
    shape = a.shape[:2] + (1,) * i + (a.shape[2],) + (1,) * (n - 1 - i) + a.shape[3:]
    return a.reshape(shape)


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
    mtot = sum(_expand(m, i, n) for i, m in enumerate(ms))
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
            full = full + _expand(t, i, n)
        lz = lse(full, axis=-1)
        w = jnp.exp(full - lz[..., None])
        outs = []
        for cam, f in feats:
            fb = jnp.broadcast_to(f, tabs[cam].shape)
            outs.append(jnp.sum(w * _expand(fb, cam, n), axis=-1))
        return (jnp.where(under, lz, logz), [jnp.where(under, o, mu) for o, mu in zip(outs, means)])

    def fast(_):
        return (logz, means)

    logz, means = jax.lax.cond(n_under > 0, exact, fast, None)
    return logz, means, n_under


__all__ = ["floor_log_probs", "grid_mixture", "lse", "weights"]


def check_belief(tables, belief) -> None:
    """The belief fits the sample tables (number of cameras, C); a clear
    ``ValueError`` otherwise.  Shared by the MI and Fisher kernels."""
    n = len(tables.ld_self)
    if len(belief.log_pk) != n:
        raise ValueError(f"belief over {len(belief.log_pk)} cameras, tables for {n}")
    c = tables.ld_self[0].shape[1]
    if belief.log_pc.shape != (c,):
        raise ValueError(f"belief.log_pc has shape {belief.log_pc.shape}, tables have C = {c}")


def to_grid(t):
    """``[V, C, L, J, ...] -> [C, J, V*L, ...]``: a camera's per-position table
    as the rows of the (v_1, v_2) grid product."""
    v, c, l, j = t.shape[:4]
    t = jnp.moveaxis(t, 3, 1)  # [V, J, C, L, ...]
    t = jnp.moveaxis(t, 2, 0)  # [C, V, J, L, ...]
    t = jnp.moveaxis(t, 2, 1)  # [C, J, V, L, ...]
    return t.reshape((c, j, v * l) + t.shape[4:])
