"""Plain NumPy references of the low-variance / deterministic CRLB estimators
(pairwise and quasi-Monte Carlo): brute force over every pair of joint
states, one configuration at a time, no shared code with the kernels."""

from __future__ import annotations

import itertools

import numpy as np
from scipy.special import logsumexp

from oracles import pairwise_divergences_ref


def _states(log_joint, n_poses):
    states = list(np.ndindex(*log_joint.shape))
    emb = np.array([[c // n_poses, c % n_poses] + list(ks) for c, *ks in states], float)
    return states, emb


def _expected_posterior_cov(log_p, logd, emb):
    """sum_d P(d) Cov_w(d'|d) with w(d'|d) ~ P(d') exp(-D(d, d')), ``logd[d, d'] = -D``."""
    out = np.zeros((emb.shape[1], emb.shape[1]))
    for s in range(len(log_p)):
        if log_p[s] == -np.inf:
            continue
        lw = log_p + logd[s]
        w = np.exp(lw - logsumexp(lw))
        m = w @ emb
        out += np.exp(log_p[s]) * ((emb - m).T * w) @ (emb - m)
    return out


def pairwise_fisher_ref(mus, covs, log_joint, n_poses, sigma_s, kind="bhattacharyya", ds=None, neg_tol=1e-4):
    """(Sigma_0 - Sigma_g(a)) / sigma_s^4 of kernels/fisher_pairwise.py, eq. (1)-(4),
    for every configuration (``[A, D, D]``); a matrix with an eigenvalue below
    -``neg_tol`` x its largest is projected onto the PSD cone.

    Args:
        mus: per camera ``[V_i, C, L_i, K_i]``; covs: ``[V_i, C, L_i, K_i, K_i]``.
        log_joint: ``[C, L_0, ...]`` log P(d) (one belief for every position).
    """
    log_joint = np.asarray(log_joint, float)
    ds = pairwise_divergences_ref(mus, covs, kind) if ds is None else ds
    kappa = 1.0 / ((8.0 if kind == "bhattacharyya" else 2.0) * sigma_s**2)
    states, emb = _states(log_joint, n_poses)
    log_p = np.array([log_joint[s] for s in states])
    smooth = -kappa * np.sum((emb[:, None] - emb[None]) ** 2, axis=-1)
    sig0 = _expected_posterior_cov(log_p, smooth, emb)
    out = []
    for cfg in itertools.product(*[range(d.shape[0]) for d in ds]):
        dg = np.array([[sum(d[v, s[0], s[i + 1], t[0], t[i + 1]] for i, (d, v) in enumerate(zip(ds, cfg)))
                        for t in states] for s in states])
        sig_g = _expected_posterior_cov(log_p, smooth - np.maximum(dg, 0.0), emb)
        j = (sig0 - sig_g) / sigma_s**4
        j = 0.5 * (j + j.T)
        ev, vec = np.linalg.eigh(j)
        out.append((vec * np.maximum(ev, 0.0)) @ vec.T if ev[0] < -neg_tol * max(ev[-1], 0.0) else j)
    return np.stack(out)
