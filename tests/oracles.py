"""Plain NumPy references for the kernels, written for clarity (loops allowed).

Used by the tests (as oracles) and by the benchmarks (as the baseline).  The
belief reference works on the *full joint state* (C * prod_i L_i states), not
the factorised form, and the MI / Fisher references enumerate every joint
state and configuration explicitly.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from scipy.linalg import solve_triangular
from scipy.special import logsumexp

_LOG_2PI = math.log(2.0 * math.pi)


# --- likelihood (eq. 4.17-4.22) ---------------------------------------------------------------


def log_likelihood_ref(g, mu, var):
    """log N(g; mu[c, l], diag var[c, l]) -> [C, L], one Gaussian at a time."""
    g, mu, var = np.asarray(g, float), np.asarray(mu, float), np.asarray(var, float)
    out = np.empty(mu.shape[:2])
    for c in range(mu.shape[0]):
        for l in range(mu.shape[1]):
            d = g - mu[c, l]
            out[c, l] = -0.5 * np.sum(d * d / var[c, l] + np.log(2 * np.pi * var[c, l]))
    return out


def log_likelihood_full_ref(g, mu, chol):
    """log N(g; mu[c, l], chol chol^T) -> [C, L] via scipy's triangular solve."""
    g, mu, chol = np.asarray(g, float), np.asarray(mu, float), np.asarray(chol, float)
    k = g.shape[0]
    out = np.empty(mu.shape[:2])
    for c in range(mu.shape[0]):
        for l in range(mu.shape[1]):
            z = solve_triangular(chol[c, l], g - mu[c, l], lower=True)
            out[c, l] = -0.5 * z @ z - np.sum(np.log(np.diag(chol[c, l]))) - 0.5 * k * _LOG_2PI
    return out


def bhattacharyya_ref(mu, cov):
    """D_B between every pair of Gaussian components N(mu[c, l], cov[c, l]) -> [C, L, C, L]:
    1/8 d^T S^-1 d + 1/2 log(det S / sqrt(det S_1 det S_2)), S = (S_1 + S_2) / 2,
    one pair at a time with ``numpy.linalg`` (``cov``: ``[C, L, K, K]``)."""
    mu, cov = np.asarray(mu, float), np.asarray(cov, float)
    c, l = mu.shape[:2]
    out = np.empty((c, l, c, l))
    for a in np.ndindex(c, l):
        for b in np.ndindex(c, l):
            s = 0.5 * (cov[a] + cov[b])
            d = mu[a] - mu[b]
            logdet = [np.linalg.slogdet(x)[1] for x in (s, cov[a], cov[b])]
            out[a + b] = 0.125 * d @ np.linalg.solve(s, d) + 0.5 * (logdet[0] - 0.5 * (logdet[1] + logdet[2]))
    return out


def kl_ref(mu, cov):
    """KL(N(mu[c, l], cov[c, l]) || N(mu[c', l'], cov[c', l'])) for every ordered pair -> [C, L, C, L]:
    1/2 [tr(S_2^-1 S_1) + d^T S_2^-1 d - K + log det S_2 - log det S_1], one pair at a
    time with ``numpy.linalg`` (``cov``: ``[C, L, K, K]``)."""
    mu, cov = np.asarray(mu, float), np.asarray(cov, float)
    c, l, k = mu.shape
    out = np.empty((c, l, c, l))
    for a in np.ndindex(c, l):
        for b in np.ndindex(c, l):
            d = mu[b] - mu[a]
            tr = np.trace(np.linalg.solve(cov[b], cov[a]))
            ld = np.linalg.slogdet(cov[b])[1] - np.linalg.slogdet(cov[a])[1]
            out[a + b] = 0.5 * (tr + d @ np.linalg.solve(cov[b], d) - k + ld)
    return out


# --- full joint-state belief (eq. 3.1, 3.7-3.9) ------------------------------------------------


def joint_uniform_ref(n_classes, levels_per_camera):
    """Uniform log P over all C * prod L_i joint states, shape [C, L_0, L_1, ...]."""
    shape = (n_classes,) + tuple(levels_per_camera)
    return np.full(shape, -math.log(math.prod(shape)))


def joint_update_ref(log_p, logliks):
    """Bayes rule (eq. 3.1) over every joint state (c, k_0, k_1, ...), one state at a time."""
    out = np.empty_like(log_p)
    for idx in np.ndindex(*log_p.shape):
        c, ks = idx[0], idx[1:]
        out[idx] = log_p[idx] + sum(ll[c, k] for ll, k in zip(logliks, ks))
    return out - logsumexp(out)


def level_transition_matrix_ref(n_levels, moved, kind, rho):
    """T[k_new, k_old] for one camera (eq. 3.9 uniform; sticky mixes rho * identity)."""
    uniform = np.full((n_levels, n_levels), 1.0 / n_levels)
    if moved:
        return uniform
    if kind == "uniform":
        return np.eye(n_levels)
    return rho * np.eye(n_levels) + (1 - rho) * uniform


def joint_transition_ref(log_p, moved, kind="uniform", rho=0.9):
    """Eq. 3.7-3.8 with the full state-to-state matrix (class never changes)."""
    shape = log_p.shape
    mats = [level_transition_matrix_ref(l, bool(m), kind, rho) for l, m in zip(shape[1:], moved)]
    states = list(np.ndindex(*shape))
    p_old = np.exp(log_p)
    p_new = np.zeros(shape)
    for new in states:
        acc = 0.0
        for old in states:
            if old[0] != new[0]:
                continue
            t = 1.0
            for m, kn, ko in zip(mats, new[1:], old[1:]):
                t *= m[kn, ko]
            acc += t * p_old[old]
        p_new[new] = acc
    with np.errstate(divide="ignore"):
        return np.log(p_new)


# --- Mutual Information (eq. 5.5-5.13) -------------------------------------------------------


def _camera_loglik_ref(g, mus, vars, chols, i, v):
    """log p(g_i | c', k', v) -> [C, L_i], diagonal (``vars``) or full (``chols``) covariance."""
    if chols is not None:
        return log_likelihood_full_ref(g, mus[i][v], chols[i][v])
    return log_likelihood_ref(g, mus[i][v], vars[i][v])


def _joint_logliks(gs, cfg, mus, vars, chols=None):
    """log p(g | s', a) for every joint state s' -> [C, L_0, L_1, ...]."""
    lls = [_camera_loglik_ref(g, mus, vars, chols, i, v) for i, (g, v) in enumerate(zip(gs, cfg))]
    c = lls[0].shape[0]
    out = np.zeros((c,) + tuple(ll.shape[1] for ll in lls))
    for idx in np.ndindex(*out.shape):
        out[idx] = sum(ll[idx[0], k] for ll, k in zip(lls, idx[1:]))
    return out


def _sample_ref(mus, vars, chols, zs, i, v, c, k, j):
    """g_i = mu_i[v, c, k] + sqrt(var_i[v, c, k]) * z (diagonal) or + L_i[v, c, k] @ z (full)."""
    z = zs[i][c, k, j]
    if chols is not None:
        return mus[i][v, c, k] + chols[i][v, c, k] @ z
    return mus[i][v, c, k] + np.sqrt(vars[i][v, c, k]) * z


def _as_float_arrays(arrays):
    return None if arrays is None else [np.asarray(a, float) for a in arrays]


def _stratified_samples(cfg, mus, vars, zs, log_joint, chols=None):
    """Every (state s, P(s), replicate j, features g) of the stratified Monte Carlo
    at configuration ``cfg``: g_i = mu_i[v_i, c, k_i] + sqrt(var_i) * z_i[c, k_i, j]
    (full covariance: + L_i[v_i, c, k_i] @ z_i[c, k_i, j]), the kernels' common
    random numbers; states with P(s) = 0 are skipped."""
    for s in np.ndindex(*log_joint.shape):
        p_s = math.exp(log_joint[s])
        if p_s == 0.0:
            continue
        c, ks = s[0], s[1:]
        for j in range(zs[0].shape[2]):
            gs = [_sample_ref(mus, vars, chols, zs, i, cfg[i], c, ks[i], j) for i in range(len(mus))]
            yield s, p_s, j, gs


def mutual_information_ref(mus, vars, zs, log_joint, target="state", chols=None):
    """MI for every configuration from the *same* stratified samples as the kernel.

    Args:
        mus, vars: per camera ``[V_i, C, L_i, K_i]`` (``vars`` may be ``None``
            when ``chols`` is given).
        zs: per camera ``[C, L_i, J, K_i]`` standard-normal draws
            (``MITables.z``); sample j of state (c, k_0, ...) at configuration
            (v_0, ...) is g_i = mu_i[v_i, c, k_i] + sqrt(var_i) * z_i[c, k_i, j].
        log_joint: ``[C, L_0, ...]`` log P(s) (the full joint belief).
        target: ``"state"`` (I(s; g)) or ``"class"`` (I(c; g)).
        chols: per camera ``[V_i, C, L_i, K_i, K_i]`` lower Cholesky factors
            (full covariance; then g_i = mu_i + L_i @ z_i and ``vars`` is ignored).

    Returns:
        ``(mi [A], per-replicate estimates [J, A])``.
    """
    mus = [np.asarray(m, float) for m in mus]
    vars, chols = _as_float_arrays(vars), _as_float_arrays(chols)
    zs = [np.asarray(z, float) for z in zs]
    log_joint = np.asarray(log_joint, float)
    positions = [m.shape[0] for m in mus]
    j_count = zs[0].shape[2]
    log_pc = logsumexp(log_joint, axis=tuple(range(1, log_joint.ndim)))
    configs = list(itertools.product(*[range(v) for v in positions]))
    reps = np.zeros((j_count, len(configs)))
    for a, cfg in enumerate(configs):
        for s, p_s, j, gs in _stratified_samples(cfg, mus, vars, zs, log_joint, chols):
            c = s[0]
            ll = _joint_logliks(gs, cfg, mus, vars, chols)
            log_pg = logsumexp(log_joint + ll)
            if target == "state":
                log_self = ll[s]
            else:
                log_self = logsumexp(log_joint[c] + ll[c]) - log_pc[c]
            reps[j, a] += p_s * (log_self - log_pg)
    return reps.mean(axis=0), reps


def mutual_information_quadrature(mus, vars, log_joint, cfg, target="state", n_grid=2001, width=10.0):
    """I(s; g | a) by exhaustive quadrature on a fine grid, for 1-D or 2-D g.

    Feature dimensions in total (sum_i K_i) must be 1 or 2.  The grid spans
    every component mean +- ``width`` standard deviations (trapezoid rule).
    """
    mus = [np.asarray(m, float)[v] for m, v in zip(mus, cfg)]
    vars = [np.asarray(x, float)[v] for x, v in zip(vars, cfg)]
    dims = [(i, d) for i, m in enumerate(mus) for d in range(m.shape[-1])]
    if len(dims) not in (1, 2):
        raise ValueError("quadrature needs 1 or 2 feature dimensions in total")
    axes = []
    for i, d in dims:
        lo = np.min(mus[i][..., d] - width * np.sqrt(vars[i][..., d]))
        hi = np.max(mus[i][..., d] + width * np.sqrt(vars[i][..., d]))
        axes.append(np.linspace(lo, hi, n_grid))
    mesh = np.meshgrid(*axes, indexing="ij")
    pts = np.stack([m.ravel() for m in mesh], axis=-1)  # [P, dims]
    log_joint = np.asarray(log_joint, float)
    # log p(g | s) for every grid point and state
    ll = np.zeros((pts.shape[0],) + log_joint.shape)
    for s in np.ndindex(*log_joint.shape):
        c, ks = s[0], s[1:]
        tot = np.zeros(pts.shape[0])
        col = 0
        for i in range(len(mus)):
            kdim = mus[i].shape[-1]
            x = pts[:, col:col + kdim]
            m, v = mus[i][c, ks[i]], vars[i][c, ks[i]]
            tot += -0.5 * np.sum((x - m) ** 2 / v + np.log(2 * np.pi * v), axis=-1)
            col += kdim
        ll[(slice(None),) + s] = tot
    axes_sum = tuple(range(1, ll.ndim))
    log_pg = logsumexp(ll + log_joint[None], axis=axes_sum)  # [P]
    if target == "state":
        log_self = ll
    else:
        log_pc = logsumexp(log_joint, axis=tuple(range(1, log_joint.ndim)))
        lvl_axes = tuple(range(2, ll.ndim))
        lc = logsumexp(ll + log_joint[None], axis=lvl_axes) - log_pc[None]  # [P, C]
        log_self = lc.reshape(lc.shape + (1,) * (ll.ndim - 2))
    p_joint = np.exp(ll + log_joint[None])
    integrand = np.sum(p_joint * (log_self - log_pg.reshape((-1,) + (1,) * (ll.ndim - 1))), axis=axes_sum)
    integrand = integrand.reshape([n_grid] * len(dims))
    for ax in reversed(axes):
        integrand = np.trapezoid(integrand, ax, axis=-1)
    return float(integrand)


# --- pairwise-distance MI (Kolchinsky & Tracey 2017) ------------------------------------------


def pairwise_divergences_ref(mus, covs, kind="bhattacharyya"):
    """Per camera ``[V_i, C, L_i, C, L_i]`` divergences from the NumPy closed forms."""
    ref = bhattacharyya_ref if kind == "bhattacharyya" else kl_ref
    return [np.stack([ref(m[v], cv[v]) for v in range(m.shape[0])])
            for m, cv in zip((np.asarray(m, float) for m in mus), (np.asarray(c, float) for c in covs))]


def pairwise_mi_ref(mus, covs, log_joint, kind="bhattacharyya", target="state", ds=None):
    """The pairwise-distance MI estimate for every configuration by brute force:
    every pair of joint states (s, s'), D_a(s, s') = sum_i D_i[v_i](c, k_i; c', k_i')
    from the NumPy closed forms (:func:`bhattacharyya_ref` / :func:`kl_ref`), and

        I_D(s; g | a) = - sum_s P(s) log sum_s' P(s') exp(-D_a(s, s'))

    ``target="class"``: I_D(s; g) - sum_c P(c) I_D(k; g | c), the within-class
    term by the same formula over the *joint* levels k = (k_0, k_1, ...) of each
    class (no factorisation over cameras assumed).

    Args:
        mus: per camera ``[V_i, C, L_i, K_i]``; covs: per camera ``[V_i, C, L_i, K_i, K_i]``.
        log_joint: ``[C, L_0, ...]`` log P(s).
        ds: the divergences of :func:`pairwise_divergences_ref`, if already computed.
    """
    log_joint = np.asarray(log_joint, float)
    ds = pairwise_divergences_ref(mus, covs, kind) if ds is None else ds
    states = list(np.ndindex(*log_joint.shape))
    configs = list(itertools.product(*[range(d.shape[0]) for d in ds]))
    out = np.zeros(len(configs))
    for a, cfg in enumerate(configs):
        def dist(s, t):
            return sum(d[v, s[0], s[i + 1], t[0], t[i + 1]] for i, (d, v) in enumerate(zip(ds, cfg)))

        total = 0.0
        for s in states:
            if log_joint[s] == -np.inf:
                continue
            inner = logsumexp([log_joint[t] - dist(s, t) for t in states])
            total -= math.exp(log_joint[s]) * inner
        if target == "class":
            for c in range(log_joint.shape[0]):
                log_pc = logsumexp(log_joint[c])
                if log_pc == -np.inf:
                    continue
                within = 0.0
                ks = list(np.ndindex(*log_joint.shape[1:]))
                for k in ks:
                    if log_joint[(c,) + k] == -np.inf:
                        continue
                    inner = logsumexp([log_joint[(c,) + q] - log_pc - dist((c,) + k, (c,) + q) for q in ks])
                    within -= math.exp(log_joint[(c,) + k] - log_pc) * inner
                total -= math.exp(log_pc) * within
        out[a] = total
    return out


def pruned_pairwise_mi_ref(mus, covs, log_pc, log_pk_rows, buckets, mass, kind="bhattacharyya", target="class"):
    """The pruned pairwise MI by brute force: the smallest bucket B (of
    ``buckets``, the last where none holds it) whose B classes of largest mass
    hold ``1 - mass``, those classes' components alone, the class belief
    renormalised over them, and :func:`pairwise_mi_ref` for every configuration.

    Args:
        mus, covs: per camera ``[V_i, C, L_i, K_i]`` / ``[V_i, C, L_i, K_i, K_i]``.
        log_pc: ``[C]``; log_pk_rows: per camera ``[V_i, C, L_i]`` level rows.
    """
    p = np.exp(np.asarray(log_pc, float))
    order = np.argsort(-p, kind="stable")
    b = next((b for b in buckets if np.sum(p[order[:b]]) >= 1.0 - mass), buckets[-1])
    live = order[:b]
    lq = np.log(p[live] / np.sum(p[live]))
    positions = [m.shape[0] for m in mus]
    out = []
    for cfg in itertools.product(*[range(v) for v in positions]):
        lj = lq.reshape((-1,) + (1,) * len(mus))
        for i, (rows, v) in enumerate(zip(log_pk_rows, cfg)):
            shape = [b] + [1] * len(mus)
            shape[i + 1] = rows.shape[-1]
            lj = lj + np.asarray(rows, float)[v][live].reshape(shape)
        sub_mu = tuple(np.asarray(m, float)[v:v + 1][:, live] for m, v in zip(mus, cfg))
        sub_cov = tuple(np.asarray(c, float)[v:v + 1][:, live] for c, v in zip(covs, cfg))
        out.append(pairwise_mi_ref(sub_mu, sub_cov, lj, kind, target)[0])
    return np.asarray(out), b


# --- two-step lookahead ---------------------------------------------------------------------


def lookahead_ref(mus, vars, zs, log_posterior, current, u, js, *, target="state", kind="uniform", rho=0.9,
                  divergence="bhattacharyya", chols=None):
    """The two-step value of every first configuration by brute force on the full joint
    state, with the pairwise-distance MI (:func:`pairwise_mi_ref`) as the one-step score:

        V(a_1) = I_D(a_1 | P_1) + (1/S) sum_m max_{a_2 != a_1} I_D(a_2 | P_2(m))

    P_1 = the joint transition (:func:`joint_transition_ref`) of ``log_posterior``
    from ``current`` to a_1 (a camera moves where a_1 differs); outcome m: the
    stratum of point (m + u) / S of the cumulative P_1 over the joint states in
    C order (c, k_0, k_1, ...), its sample ``js[m]`` from the kernels' standard
    draws ``zs`` (as :func:`mutual_information_ref`), the full-joint Bayes update
    (:func:`joint_update_ref`) of P_1 with that sample's log-likelihoods and the
    joint transition from a_1 to each a_2.

    Returns:
        ``(V [A], one-step scores [A])``.
    """
    mus = [np.asarray(m, float) for m in mus]
    vars, chols = _as_float_arrays(vars), _as_float_arrays(chols)
    zs = [np.asarray(z, float) for z in zs]
    covs = [c @ np.swapaxes(c, -1, -2) for c in chols] if chols is not None else [v[..., None] * np.eye(v.shape[-1]) for v in vars]
    ds = pairwise_divergences_ref(mus, covs, divergence)
    positions = [m.shape[0] for m in mus]
    configs = list(itertools.product(*[range(v) for v in positions]))
    n_out = len(js)

    def predicted(log_joint, cur, cfg):
        return joint_transition_ref(log_joint, [a != b for a, b in zip(cfg, cur)], kind, rho)

    def one_step(log_joint, cur):
        return np.array([pairwise_mi_ref(mus, covs, predicted(log_joint, cur, cfg), divergence, target, ds=ds)[a]
                         for a, cfg in enumerate(configs)])

    log_posterior = np.asarray(log_posterior, float)
    one = one_step(log_posterior, current)
    value = np.zeros(len(configs))
    for a, cfg in enumerate(configs):
        lj = predicted(log_posterior, current, cfg)
        p = np.exp(lj).ravel()
        cdf = np.cumsum(p)
        t = (np.arange(n_out) + u) / n_out * cdf[-1]
        flat = np.minimum(np.searchsorted(cdf, t, side="right"), p.size - 1)
        best = []
        for m, f in enumerate(flat):
            s = np.unravel_index(f, lj.shape)
            c, ks = s[0], s[1:]
            gs = [_sample_ref(mus, vars, chols, zs, i, cfg[i], c, ks[i], js[m]) for i in range(len(mus))]
            lls = [_camera_loglik_ref(g, mus, vars, chols, i, v) for i, (g, v) in enumerate(zip(gs, cfg))]
            post = joint_update_ref(lj, lls)
            inner = one_step(post, cfg)
            inner[a] = -np.inf
            best.append(inner.max() if len(configs) > 1 else 0.0)
        value[a] = one[a] + np.mean(best)
    return value, one


# --- Fisher information (eq. 5.22-5.28) ------------------------------------------------------


def fisher_score_difference_ref(s_c, gs, cfg, mus, vars, log_joint, n_poses, sigma_s, chols=None):
    """(grad log p(g, s_c) - grad log p(s_c)) = (E[d|s_c,g] - E[d|s_c]) / sigma_s^2,
    enumerating every joint state d = (object, pose, k_0, ...)."""
    log_joint = np.asarray(log_joint, float)
    ll = _joint_logliks(gs, cfg, mus, vars, chols)
    states = list(np.ndindex(*log_joint.shape))
    d = np.array([[c // n_poses, c % n_poses] + list(ks) for c, *ks in states], float)
    logw0 = np.array([log_joint[s] for s in states]) - 0.5 * np.sum((s_c[None] - d) ** 2, -1) / sigma_s**2
    logwg = logw0 + np.array([ll[s] for s in states])
    w0 = np.exp(logw0 - logsumexp(logw0))
    wg = np.exp(logwg - logsumexp(logwg))
    return (wg @ d - w0 @ d) / sigma_s**2


def fisher_information_ref(mus, vars, zs, draws, log_joint, n_poses, sigma_s, chols=None):
    """J_g(a) for every configuration from the same samples as the kernel.

    Args:
        zs: ``MITables.z``; draws: ``(eps_obj [C, J], eps_pose [C, J], eps_occ per camera
            [C, L_i, J])`` (``FisherDraws``).
        chols: full-covariance Cholesky factors instead of ``vars`` (as in
            :func:`mutual_information_ref`).

    Returns:
        ``(J [A, D, D], per-replicate [J_samples, A, D, D])``.
    """
    mus = [np.asarray(m, float) for m in mus]
    vars, chols = _as_float_arrays(vars), _as_float_arrays(chols)
    zs = [np.asarray(z, float) for z in zs]
    eps_obj, eps_pose = np.asarray(draws[0], float), np.asarray(draws[1], float)
    eps_occ = [np.asarray(e, float) for e in draws[2]]
    log_joint = np.asarray(log_joint, float)
    positions = [m.shape[0] for m in mus]
    n = len(mus)
    j_count = zs[0].shape[2]
    configs = list(itertools.product(*[range(v) for v in positions]))
    reps = np.zeros((j_count, len(configs), n + 2, n + 2))
    for a, cfg in enumerate(configs):
        for s, p_s, j, gs in _stratified_samples(cfg, mus, vars, zs, log_joint, chols):
            c, ks = s[0], s[1:]
            s_c = np.array(
                [c // n_poses + sigma_s * eps_obj[c, j], c % n_poses + sigma_s * eps_pose[c, j]]
                + [ks[i] + sigma_s * eps_occ[i][c, ks[i], j] for i in range(n)]
            )
            delta = fisher_score_difference_ref(s_c, gs, cfg, mus, vars, log_joint, n_poses, sigma_s, chols)
            reps[j, a] += p_s * np.outer(delta, delta)
    return reps.mean(axis=0), reps


def crlb_criterion_ref(fisher, kind="trace"):
    """trace / logdet / max eigenvalue of J^{-1} by eigen-decomposition (no jitter)."""
    ev = np.linalg.eigvalsh(np.asarray(fisher, float))
    if kind == "trace":
        return np.sum(1.0 / ev, axis=-1)
    if kind == "logdet":
        return -np.sum(np.log(ev), axis=-1)
    return 1.0 / ev[..., 0]
