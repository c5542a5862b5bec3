"""Gaussian observation log-likelihoods (thesis eq. 4.17-4.22).

For one camera at one position v, the sensor model is
``p(g | c, k, v) = N(g; mu[v, c, k], Sigma[v, c, k])`` (eq. 4.18/4.19, 4.22);
cameras are conditionally independent given the state, so the joint
log-likelihood is the sum over cameras (eq. 4.17).  Everything is in log space.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
from jax.scipy.linalg import solve_triangular
from jaxtyping import Array, Float, Int

_LOG_2PI = math.log(2.0 * math.pi)


def log_likelihood(
    g: Float[Array, " K"], mu: Float[Array, "C L K"], var: Float[Array, "C L K"]
) -> Float[Array, "C L"]:
    """Diagonal-covariance log N(g; mu[c, k], diag(var[c, k])) for every class and level.

    Eq. 4.22 with a diagonal Sigma:
    ``-1/2 sum_d [(g_d - mu_d)^2 / var_d + log(2 pi var_d)]``.

    Args:
        g: feature vector of one camera image, ``[K]``.
        mu: means at the camera's current position, ``[C, L, K]``.
        var: variances (strictly positive), ``[C, L, K]``.

    Returns:
        ``[C, L]`` log-densities.
    """
    d = g[None, None, :] - mu
    return -0.5 * jnp.sum(d * d / var + jnp.log(var) + _LOG_2PI, axis=-1)


def log_likelihood_full(
    g: Float[Array, " K"], mu: Float[Array, "C L K"], chol: Float[Array, "C L K K"]
) -> Float[Array, "C L"]:
    """Full-covariance log N(g; mu[c, k], S S^T) with S = ``chol[c, k]`` lower triangular.

    Eq. 4.22 evaluated with a triangular solve ``z = S^{-1}(g - mu)`` (never an
    explicit inverse): ``-1/2 |z|^2 - sum log diag S - K/2 log 2 pi``.

    Args:
        g: ``[K]``; mu: ``[C, L, K]``; chol: ``[C, L, K, K]`` lower Cholesky factors.

    Returns:
        ``[C, L]`` log-densities.
    """
    k = g.shape[-1]
    d = g[None, None, :] - mu
    z = solve_triangular(chol, d[..., None], lower=True)[..., 0]
    logdet = jnp.sum(jnp.log(jnp.diagonal(chol, axis1=-2, axis2=-1)), axis=-1)
    return -0.5 * jnp.sum(z * z, axis=-1) - logdet - 0.5 * k * _LOG_2PI


def camera_log_likelihoods(
    gs: tuple[Float[Array, " K_i"], ...],
    config: Int[Array, " n"] | tuple[int, ...],
    mus: tuple[Float[Array, "V_i C L_i K_i"], ...],
    vars: tuple[Float[Array, "V_i C L_i K_i"], ...] | None = None,
    chols: tuple[Float[Array, "V_i C L_i K_i K_i"], ...] | None = None,
) -> tuple[Float[Array, "C L_i"], ...]:
    """Per-camera log p(g_i | c, k_i, v_i) at configuration ``config = (v_0, v_1, ...)``.

    The joint log-likelihood of a state is the sum of these over cameras
    (eq. 4.17); :func:`jaxrecog.kernels.update` consumes the tuple directly.
    Give exactly one of ``vars`` (diagonal) or ``chols`` (full covariance).
    ``config`` may be a traced integer array (no recompilation per position).
    """
    if (vars is None) == (chols is None):
        raise ValueError("camera_log_likelihoods: give exactly one of `vars` or `chols`")
    n = len(mus)
    if len(gs) != n:
        raise ValueError(f"camera_log_likelihoods: {len(gs)} feature vectors for {n} cameras")
    out = []
    for i in range(n):
        v = config[i]
        if vars is not None:
            out.append(log_likelihood(gs[i], mus[i][v], vars[i][v]))
        else:
            out.append(log_likelihood_full(gs[i], mus[i][v], chols[i][v]))
    return tuple(out)
