"""Deterministic pairwise-distance estimate of the GM-smoothed Fisher
information J_g(a) (thesis eq. 5.22-5.28) for every configuration in one
call: no samples, no key (the CRLB counterpart of
:mod:`.pairwise_mi`).

Identity.  With the score difference of :mod:`.fisher`,
J_g(a) = E[(m_g - m_0)(m_g - m_0)^T] / sigma_s^4, m_g = E[d | s_c, g, a] and
m_0 = E[d | s_c].  Since E[m_g | s_c] = m_0 (tower rule), the law of total
covariance gives

    J_g(a) = (Sigma_0 - Sigma_g(a)) / sigma_s^4,
    Sigma_0 = E[Cov(d | s_c)],   Sigma_g(a) = E[Cov(d | s_c, g, a)]              (1)

(the expected posterior covariances: the minimum mean-square error of d
without and with the observation).

Pairwise approximation.  The joint observation y = (s_c, g) has the mixture
density sum_d P(d) p(y | d) with components p(y | d) = N(s_c; e(d),
sigma_s^2 I) prod_i p_i(g_i | c, k_i, v_i), e(d) = (object, pose, k_0, ...).
For y drawn from component d the posterior weight of d' is replaced by its
pairwise value (Kolchinsky & Tracey 2017's device for the mixture entropy,
applied to the posterior moments):

    w(d' | d) = P(d') exp(-D(d, d')) / sum_d'' P(d'') exp(-D(d, d''))          (2)
    D(d, d')  = kappa |e(d) - e(d')|^2 + sum_i D_i[v_i](c, k_i; c', k_i')      (3)

with kappa = 1 / (8 sigma_s^2) and D_i the Bhattacharyya distance of camera i
(``kind="bhattacharyya"``; both terms are the Bhattacharyya distance of the
product components, exactly additive), or kappa = 1 / (2 sigma_s^2) and D_i
the KL divergence (``kind="kl"``).  Then

    Sigma_g(a) ~= sum_d P(d) sum_d' w(d' | d) (e(d') - mbar_d)(e(d') - mbar_d)^T,
    mbar_d = sum_d' w(d' | d) e(d'),                                           (4)

and Sigma_0 the same with D_i = 0 (the smoothing term alone).  The estimate
(Sigma_0 - Sigma_g) / sigma_s^4 of (1), symmetrised, is returned (PSD up to
rounding in every case measured; not by construction, so a clearly
indefinite one is projected onto the PSD cone).  Exact
in both limits: 0 when no camera separates any pair of states (D_i = 0), and
Sigma_0 / sigma_s^4 (to (4)'s approximation of Sigma_0) when every camera
separates every pair (D_i -> inf, Sigma_g = 0).  Being the same functional
of the same divergences on both sides, the error of (2) in the smoothing
term largely cancels in the difference.

Evaluation.  Given c' the weights (2) factorise over cameras (the prior's
level rows and the components do), so per camera, in the grid layout
``[C, X_i = V_i L_i, C']`` of :mod:`.pairwise_mi`,

    A_i[c, (v, k), c'] = log sum_k' P_i[v](k'|c') exp(-kappa (k - k')^2 - D_i[v](c, k; c', k'))
    B_i, S_i           = the first and second moments of k' under those weights,

computed online as small matrix products over k' with the offline
E'_i = exp(-kappa (k - k')^2 - D_i - M'_i), M'_i = max_k' of the exponent
(:func:`pairwise_fisher_tables`; no exp over the divergences online), and the
moments of e(d') under (2) are mixtures over c' with weights
P(c') exp(-kappa |(o, p) - (o', p')|^2 + sum_i A_i): batched matrix products
on the (x_0, x_1, ...) grid, one per power (1, k'_i, k'_i^2) of the further
cameras, whose camera-0 operand stacks the features it needs (1, o', p',
o'^2, o'p', p'^2, B_0, o'B_0, p'B_0, S_0), as
:func:`.fisher.fisher_information`'s posterior means but with second moments
and one "sample" per stratum.  The smoothing-only
side Sigma_0 takes the same path with D_i = 0 (its level tables do not depend
on c).  Underflow: D(d, d) = 0 keeps the self term c' = c of every sum at or
above P(d) times the shifts; strata of flushed weight (:func:`._grid.weights`)
are dropped, and a sum that still underflows contributes 0.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._grid import floor_log_probs, weights
from .belief import PredictedBelief, check_predicted
from .config_grid import ConfigGrid, position_rows
from .fisher import DEFAULT_SIGMA_S
from .likelihood import Likelihood, as_likelihoods
from .pairwise_mi import DIVERGENCES

__all__ = ["PairwiseFisherTables", "pairwise_fisher_tables", "pairwise_fisher_information", "smoothing_kappa", "transition_form"]

_LETTERS = "pqrstuvwxy"

#: Relative size of a negative eigenvalue of the estimate that is projected away
#: (see :func:`pairwise_fisher_information`).
NEG_TOL = 1e-4


class PairwiseFisherTables(NamedTuple):
    """Offline tables of :func:`pairwise_fisher_information` (belief-free, once
    per model, ``kind`` and ``sigma_s``).

    Attributes:
        w_max: per camera ``[V_i, C, L_i, C']``, M'_i = max_k' (-kappa (k - k')^2 - D_i[v](c, k; c', k')).
        w_exp: per camera ``[V_i, C', C, L_i, L_i']``, E'_i = exp(-kappa (k - k')^2 - D_i - M'_i)
            (values below the smallest normal float flushed to 0).
        kappa: ``[]``, eq. (3)'s smoothing coefficient.
        sigma_s: ``[]``, the smoothing width.
    """

    w_max: tuple[Float[Array, "_V C _L C"], ...]
    w_exp: tuple[Float[Array, "_V C C _L _L"], ...]
    kappa: Float[Array, ""]
    sigma_s: Float[Array, ""]


def smoothing_kappa(sigma_s: float, kind: str) -> float:
    """kappa of eq. (3): the divergence between two smoothing components
    N(e, sigma_s^2 I) and N(e', sigma_s^2 I) is kappa |e - e'|^2
    (Bhattacharyya 1 / (8 sigma_s^2), KL 1 / (2 sigma_s^2))."""
    return 1.0 / ((8.0 if kind == "bhattacharyya" else 2.0) * float(sigma_s) ** 2)


def pairwise_fisher_tables(
    likelihoods: Sequence[Likelihood],
    *,
    kind: str = "bhattacharyya",
    sigma_s: float = DEFAULT_SIGMA_S,
) -> PairwiseFisherTables:
    """The offline tables of :func:`pairwise_fisher_information` (once per model).

    Args:
        likelihoods: one :class:`~jaxrecog.kernels.Likelihood` per camera, as
            :func:`~jaxrecog.kernels.pairwise_tables`.
        kind: ``"bhattacharyya"`` (default) or ``"kl"``: the divergence of eq. (3)
            (:meth:`~jaxrecog.kernels.Likelihood.divergence`, and the smoothing term's).
        sigma_s: smoothing width, > 0.
    """
    if kind not in DIVERGENCES:
        raise ValueError(f"pairwise_fisher_tables: kind must be one of {DIVERGENCES}, got {kind!r}")
    if not sigma_s > 0:
        raise ValueError(f"pairwise_fisher_tables: sigma_s must be > 0, got {sigma_s}")
    liks = as_likelihoods(likelihoods, where="pairwise_fisher_tables")
    kappa = smoothing_kappa(sigma_s, kind)
    w_max, w_exp = [], []
    for lik in liks:
        d = jax.lax.map(lambda lik_v: lik_v.divergence(kind), lik)  # [V, C, L, C', L']
        n_c, n_l = d.shape[1], d.shape[2]
        eye = jnp.eye(n_c, dtype=bool)[:, None, :, None] & jnp.eye(n_l, dtype=bool)[None, :, None, :]
        lev = jnp.arange(n_l, dtype=d.dtype)
        q = -kappa * (lev[:, None] - lev[None, :]) ** 2  # [L, L']
        w = q[None, None, :, None, :] - jnp.where(eye[None], 0.0, jnp.maximum(d, 0.0))  # D(d, d) = 0 exactly
        m = jnp.max(w, axis=-1)
        s = w - m[..., None]
        floor = math.log(float(jnp.finfo(w.dtype).tiny))
        e = jnp.where(s < floor, 0.0, jnp.exp(jnp.maximum(s, floor)))
        w_max.append(m)
        w_exp.append(jnp.transpose(e, (0, 3, 1, 2, 4)))
    dtype = w_max[0].dtype
    return PairwiseFisherTables(tuple(w_max), tuple(w_exp), jnp.asarray(kappa, dtype), jnp.asarray(sigma_s, dtype))


def pairwise_fisher_information(
    tables: PairwiseFisherTables,
    belief: PredictedBelief,
    *,
    n_objects: int,
    n_poses: int,
    fast: bool = True,
) -> Float[Array, "A D D"]:
    """The pairwise-distance estimate (Sigma_0 - Sigma_g(a)) / sigma_s^4 of
    J_g(a) (module doc, eq. 1-4) for every configuration, ``D = 2 + n_cameras``.

    Args:
        tables: from :func:`pairwise_fisher_tables` (the divergence and sigma_s are theirs).
        belief: the predicted prior, level rows per position ``[V_i, C, L_i]``.
        n_objects, n_poses: with ``C = n_objects * n_poses``, c = object * n_poses + pose.
        fast: the prior's level rows are equal at all positions of each camera
            but at most one, as :func:`~jaxrecog.kernels.transition_per_position`
            makes them (either kind; the recognizer's predicted prior): the
            smoothing side is then computed at two positions per camera.  Not
            checkable under ``jit`` (a traced belief is taken to have the form);
            a concrete belief without it takes the general path.  ``False``:
            every position's rows (any belief).  Static.

    Returns:
        ``[A, D, D]`` symmetric matrices, coordinates (object, pose, k_0, ...),
        PSD up to rounding (a matrix with an eigenvalue below -:data:`NEG_TOL`
        times its largest is projected onto the PSD cone).
    """
    n_c = tables.w_max[0].shape[1]
    check_predicted(belief, tables.w_max)
    if n_objects * n_poses != n_c:
        raise ValueError(f"pairwise_fisher_information: n_objects * n_poses = {n_objects * n_poses} != C = {n_c}")
    if fast and not any(isinstance(x, jax.core.Tracer) for x in (belief.log_pc, *belief.log_pk)):
        fast = transition_form(belief)
    return _pairwise_fisher(tables, belief, n_objects, n_poses, bool(fast))


def _level_moments(w_exp, w_max, p):
    """Per camera, grid layout ``[C, X_i, C']``: (A_i, B_i, S_i) of the module doc
    from E'_i ``[V, C', C|1, L, L']``, M'_i ``[V, C|1, L, C']`` and the level
    weights ``p`` ``[V, C', L']`` (floored, no zeros); B_i and S_i are the moments
    of k' - k, centred on the row's own level k (no cancellation in float32)."""
    n_l = p.shape[-1]
    lev = jnp.arange(n_l, dtype=p.dtype)
    delta = lev[None, :] - lev[:, None]  # [L, L']: k' - k
    s0 = jnp.einsum("vCclK,vCK->vclC", w_exp, p)
    s1 = jnp.einsum("vCclK,vCK,lK->vclC", w_exp, p, delta)
    s2 = jnp.einsum("vCclK,vCK,lK->vclC", w_exp, p, delta * delta)
    return position_rows(jnp.log(s0) + w_max), position_rows(s1 / s0), position_rows(s2 / s0)


_CAM0_ORDER = {"o": 0, "p": 1, 0: 2}


def _feature_groups(n: int):
    """The moments of e(d') = (o', p', k'_0, ..., k'_{n-1}) the covariance needs
    (1, every coordinate, every product of two), each split into its camera-0
    factor (a product of o', p', k'_0: the c'- and camera-0 part) and the
    power r_i in {0, 1, 2} of k'_i for every further camera (1, B_i, S_i).
    Grouped by (r_1, ..., r_{n-1}): one grid product per group.

    Returns ``(terms, groups, where)``: the moments (sorted tuples of
    coordinates), ``groups`` mapping r to its camera-0 factors (in order) and
    ``where`` mapping each moment to (r, slot)."""
    coords = ["o", "p"] + list(range(n))
    terms = [()] + [(a,) for a in coords] + [(a, b) for i, a in enumerate(coords) for b in coords[i:]]
    groups: dict = {}
    where = {}
    for term in terms:
        first = tuple(sorted((t for t in term if t in _CAM0_ORDER), key=_CAM0_ORDER.__getitem__))
        r = tuple(sum(1 for t in term if t == i) for i in range(1, n))
        slots = groups.setdefault(r, [])
        if first not in slots:
            slots.append(first)
        where[term] = (r, slots.index(first))
    return terms, groups, where


def _cam0_factor(key, dobj, dpose, b0, s0):
    """The camera-0 factor of a moment, broadcastable to ``[C, X_0, C']``
    (``dobj``, ``dpose``: ``[C, C']`` o' - o, p' - p)."""
    if key == (0, 0):
        return s0
    f = {"o": dobj[:, None, :], "p": dpose[:, None, :], 0: b0}
    out = jnp.ones((1, 1, 1), dobj.dtype)
    for t in key:
        out = out * f[t]
    return out


def _expected_covariance(tabs, bs, ss, extra, dobj, dpose, strata_w):
    """sum over strata of weight x Cov under (2) at every grid point, ``[D, D, X_0, ..., X_{n-1}]``,
    from the moments of e(d') - e(d) (centred on the stratum: the covariance is
    the same, without float32 cancellation in a direction the posterior hardly spreads).

    ``tabs``/``bs``/``ss``: per camera ``[C, X_i, C']``; ``extra`` ``[C, C']``;
    ``strata_w``: ``[C, X_0, ..., X_{n-1}]`` P(c) prod_i P_i[v_i](k_i | c)."""
    n = len(tabs)
    ts = [tabs[0] + extra[:, None, :]] + list(tabs[1:])
    es = []
    for t in ts:
        m = jnp.max(t, axis=-1, keepdims=True)
        es.append(jnp.exp(t - m))  # tables are finite: floored level weights, E' = 1 somewhere per row
    terms, groups, where = _feature_groups(n)
    grid = _LETTERS[:n]
    spec = ",".join(f"c{g}z" for g in grid) + f"->c{grid}"
    n_c, x0 = es[0].shape[:2]
    moments = {}
    for r, keys in groups.items():
        first = jnp.concatenate([jnp.broadcast_to(es[0] * _cam0_factor(k, dobj, dpose, bs[0], ss[0]), es[0].shape)
                                 for k in keys], axis=1)  # [C, F X_0, C']: one batched product per group
        others = [e * b if ri == 1 else e * s if ri == 2 else e for e, b, s, ri in zip(es[1:], bs[1:], ss[1:], r)]
        out = jnp.einsum(spec, first, *others)
        moments[r] = out.reshape((n_c, len(keys), x0) + out.shape[2:])

    def get(term):
        r, slot = where[term]
        return moments[r][:, slot]

    coords = ["o", "p"] + list(range(n))
    d = len(coords)
    z = get(())
    ok = z > 0
    inv = jnp.where(ok, 1.0 / jnp.where(ok, z, 1.0), 0.0)
    sw = strata_w * inv  # stratum weight / Z, 0 where Z underflows
    sw2 = sw * inv
    mean = [get((a,)) for a in coords]  # unnormalised
    out = [[None] * d for _ in range(d)]
    for i, a in enumerate(coords):
        for j in range(i, d):
            v = jnp.sum(sw * get((a, coords[j])) - sw2 * mean[i] * mean[j], axis=0)  # [X_0, ...]
            out[i][j] = out[j][i] = v
    return jnp.stack([jnp.stack(row) for row in out])  # [D, D, X_0, ...]


def _side(tabs, log_pk, extra, dobj, dpose, log_pc, kappa):
    """sum over strata of P(d) Cov under (2) per configuration, ``[D, D, V_0, ..., V_{n-1}]``,
    for the positions of ``log_pk`` (per camera ``[V_i, C, L_i]``, raw log rows).

    ``tabs``: per camera (E'_i, M'_i) of :class:`PairwiseFisherTables` at the
    same positions (the observation side, Sigma_g), or ``None`` for the
    smoothing side (Sigma_0: D_i = 0, tables independent of c)."""
    n = len(log_pk)
    n_c = log_pc.shape[0]
    dtype = log_pc.dtype
    ts, bs, ss = [], [], []
    for i, lp in enumerate(log_pk):
        n_l = lp.shape[-1]
        p = jnp.exp(floor_log_probs(lp))  # floored: no zeros, no subnormals
        if tabs is None:
            lev = jnp.arange(n_l, dtype=dtype)
            q = -kappa * (lev[:, None] - lev[None, :]) ** 2  # [L, L']: max 0 at k' = k
            ex, mx = jnp.exp(q)[None, None, None], jnp.zeros((1, 1, n_l, 1), dtype)
        else:
            ex, mx = tabs[i]
        for acc, t in zip((ts, bs, ss), _level_moments(ex, mx, p)):
            acc.append(jnp.broadcast_to(t, (n_c,) + t.shape[1:]))
    # stratum weights P(c) prod_i P_i[v_i](k_i|c) on the grid [C, X_0, ..., X_{n-1}]
    row_grid = ConfigGrid(tuple(lp.shape[0] * lp.shape[2] for lp in log_pk))  # (x_0, x_1, ...)
    strata = weights(log_pc, n + 1).reshape((n_c,) + (1,) * n)
    for i, lp in enumerate(log_pk):
        pk = position_rows(weights(lp, n + 1))  # [C, X_i]
        strata = strata * row_grid.expand(pk, i, axis=1)
    cov = _expected_covariance(ts, bs, ss, extra, dobj, dpose, strata)  # [D, D, X_0, ...]
    d = n + 2
    split = sum(((lp.shape[0], lp.shape[2]) for lp in log_pk), ())
    return jnp.sum(cov.reshape((d, d) + split), axis=tuple(3 + 2 * i for i in range(n)))


def _representatives(log_pk):
    """Per camera, for rows equal at all positions but at most one (the form
    of :func:`~jaxrecog.kernels.transition_per_position`, either kind: the
    moved rows are the same wherever the camera goes): that position and
    another (the same where V_i = 1).  Traceable; assumes the form."""
    cur, other = [], []
    for lp in log_pk:
        n_v = lp.shape[0]
        d0 = jnp.any(lp != lp[:1], axis=(1, 2))  # [V]: differs from position 0
        c = jnp.where(jnp.sum(d0.astype(jnp.int32)) == 1, jnp.argmax(d0), 0).astype(jnp.int32)
        cur.append(c)
        other.append(jnp.where(c == 0, 1 % n_v, 0).astype(jnp.int32))
    return cur, other


def transition_form(belief: PredictedBelief) -> bool:
    """Whether a concrete belief's level rows are equal at all positions of
    each camera but at most one (what ``fast=True`` of
    :func:`pairwise_fisher_information` needs).  Host-side NumPy."""
    for lp in belief.log_pk:
        lp = np.asarray(lp)
        if lp.shape[0] > 2:
            d0 = np.any(lp != lp[:1], axis=(1, 2))
            d1 = np.any(lp != lp[1:2], axis=(1, 2))
            if d0.sum() > 1 and d1.sum() > 1:
                return False
    return True


@functools.partial(jax.jit, static_argnames=("n_objects", "n_poses", "fast"))
def _pairwise_fisher(tables: PairwiseFisherTables, belief: PredictedBelief, n_objects: int, n_poses: int, fast: bool):
    """The body of :func:`pairwise_fisher_information` (arguments checked), one program.

    The smoothing side Sigma_0 depends on the configuration only through the
    level rows; with ``fast`` (rows equal at all positions of a camera but
    one) it is computed at two positions per camera and broadcast.  (A
    ``lax.cond`` between the two paths cost 2x the whole kernel on the 2-core
    CPU even when the general branch was not taken, hence the static switch.)"""
    n = len(tables.w_max)
    positions = tuple(t.shape[0] for t in tables.w_max)
    n_c = tables.w_max[0].shape[1]
    dtype = tables.w_max[0].dtype
    kappa = tables.kappa.astype(dtype)
    log_pc = floor_log_probs(belief.log_pc.astype(dtype))
    log_pk = [lp.astype(dtype) for lp in belief.log_pk]

    cls = jnp.arange(n_c)
    obj = (cls // n_poses).astype(dtype)
    pose = (cls % n_poses).astype(dtype)
    dobj, dpose = obj[None, :] - obj[:, None], pose[None, :] - pose[:, None]  # [C, C']: o' - o, p' - p
    extra = log_pc[None, :] - kappa * (dobj**2 + dpose**2)
    side = functools.partial(_side, extra=extra, dobj=dobj, dpose=dpose, log_pc=log_pc, kappa=kappa)

    sig_g = side(tuple(zip(tables.w_exp, tables.w_max)), log_pk)
    if fast:
        cur, other = _representatives(log_pk)
        sig_0 = side(None, [jnp.stack([lp[c], lp[o]]) for lp, c, o in zip(log_pk, cur, other)])  # [D, D, 2, ...]
        for i, (v, c) in enumerate(zip(positions, cur)):
            sig_0 = jnp.take(sig_0, jnp.where(jnp.arange(v, dtype=jnp.int32) == c, 0, 1), axis=2 + i)
    else:
        sig_0 = side(None, log_pk)
    d = n + 2
    fis = jnp.moveaxis((sig_0 - sig_g).reshape((d, d, -1)), -1, 0) / tables.sigma_s.astype(dtype) ** 4
    fis = 0.5 * (fis + jnp.swapaxes(fis, -1, -2))
    # (1)-(4) is PSD up to rounding on every case measured, but not by
    # construction: a matrix with an eigenvalue below -NEG_TOL x the largest is
    # projected onto the PSD cone (eigenvalues clipped at 0).  Rounding-level
    # negatives are left as they are (the criterion's jitter absorbs them): a
    # float32 eigen-reconstruction would put ~eps |J| into exact zeros (e.g. a
    # coordinate the prior does not spread), which the jitter-sized criterion sees.
    ev, vec = jnp.linalg.eigh(fis)
    bad = ev[:, 0] < -NEG_TOL * jnp.maximum(ev[:, -1], 0.0)
    proj = jnp.einsum("ade,ae,afe->adf", vec, jnp.maximum(ev, 0.0), vec)
    return jnp.where(bad[:, None, None], proj, fis)
