"""The full-covariance Gaussian sensor model (docs/design.md §3, the option beside
the thesis's diagonal form):

    p(g | c, k, v) = N(g; mu[v, c, k], S S^T),   S = chol[v, c, k] lower triangular
    log p          = -1/2 |S^-1 (g - mu)|^2 - sum log diag S - K/2 log 2 pi     (eq. 4.22)

always through a triangular solve, never an explicit inverse.
"""

from __future__ import annotations

import math
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.linalg import solve_triangular
from jaxtyping import Array, ArrayLike, Float

from .gaussian_diag import gaussian_scaled_log_density
from .likelihood import Likelihood, register_likelihood

__all__ = ["FullGaussian", "log_likelihood_full"]

_LOG_2PI = math.log(2.0 * math.pi)


def _half_logdet(chol):
    """log |S| = sum log diag S (= 1/2 log |S S^T|)."""
    return jnp.sum(jnp.log(jnp.diagonal(chol, axis1=-2, axis2=-1)), axis=-1)


def cholesky_lower(a):
    """Lower Cholesky factor of symmetric positive-definite ``a`` (symmetrised first)."""
    return jnp.linalg.cholesky(0.5 * (a + jnp.swapaxes(a, -1, -2)))


@register_likelihood
class FullGaussian(Likelihood):
    """N(g; mu[c, k], S S^T) with S = ``chol[c, k]`` for every class c and level k.

    Attributes:
        mu: ``[V, C, L, K]`` means (eq. 4.23).
        chol: ``[V, C, L, K, K]`` lower Cholesky factors of the floored ML covariance.
        var: ``[V, C, L, K]`` its diagonal (reports and the model file; the
            density uses ``chol`` only).  Computed from ``chol`` when not given.
    """

    kind: ClassVar[str] = "full"
    summary_words: ClassVar[tuple[str, str]] = ("covariance", "Gaussians")
    name: ClassVar[str] = "gaussian-full"
    field_shapes: ClassVar[dict[str, str]] = {"mu": "V C L K", "var": "V C L K", "chol": "V C L K K"}
    second_moments: ClassVar[str] = "full"

    mu: Float[ArrayLike, "*V C L K"]
    var: Float[ArrayLike, "*V C L K"]
    chol: Float[ArrayLike, "*V C L K K"]

    def __init__(self, mu, chol, var=None):
        self.mu = mu
        self.chol = chol
        self.var = jnp.sum(chol * chol, axis=-1) if var is None else var

    @classmethod
    def from_moments(cls, mean: Float[ArrayLike, "*V C L K"], covariance: Float[ArrayLike, "*V C L K K"]) -> "FullGaussian":
        """N(mean, covariance) per component: the moment-matched Gaussian that
        :meth:`Likelihood.divergence` falls back on for a family without a
        closed form (found in the registry as ``"full"``)."""
        return cls(mean, cholesky_lower(covariance))

    def log_density(self, g: Float[ArrayLike, "*B K"]) -> Float[Array, "*B C L"]:
        """Eq. 4.22: ``-1/2 |z|^2 - sum log diag S - K/2 log 2 pi`` with
        ``z = S^-1 (g - mu)`` by one batched triangular solve per component."""
        batch, k = g.shape[:-1], g.shape[-1]
        n = math.prod(batch)
        d = g.reshape(1, 1, n, k) - self.mu[:, :, None, :]  # [C, L, N, K]
        w = solve_triangular(self.chol, jnp.swapaxes(d, -1, -2), lower=True)  # [C, L, K, N]
        ld = -0.5 * jnp.sum(w * w, -2) - _half_logdet(self.chol)[..., None] - 0.5 * k * _LOG_2PI  # [C, L, N]
        return jnp.moveaxis(ld.reshape(ld.shape[:2] + batch), (0, 1), (-2, -1))

    def sample(self, z: Float[ArrayLike, "C L J K"]) -> Float[Array, "C L J K"]:
        """g = mu[c, k] + S[c, k] z[c, k, j]."""
        return self.mu[:, :, None, :] + jnp.einsum("clkm,cljm->cljk", self.chol, z)

    def mean(self) -> Float[Array, "C L K"]:
        return self.mu

    def covariance(self) -> Float[Array, "C L K K"]:
        return self.chol @ jnp.swapaxes(self.chol, -1, -2)

    def variance(self) -> Float[Array, "C L K"]:
        return self.var

    def scaled(self, factor: Float[ArrayLike, " L"]) -> "FullGaussian":
        """Sigma[c, k] * factor[k]: ``chol * sqrt(factor)``, ``var * factor``."""
        return FullGaussian(self.mu, self.chol * jnp.sqrt(factor)[None, :, None, None], self.var * factor[None, :, None])

    def bhattacharyya(self) -> Float[Array, "C L C L"]:
        """Between N(mu_1, Sigma_1) and N(mu_2, Sigma_2), with Sigma = (Sigma_1 + Sigma_2) / 2:
        ``1/8 (mu_1 - mu_2)^T Sigma^-1 (mu_1 - mu_2) + 1/2 log |Sigma| - 1/4 (log |Sigma_1| + log |Sigma_2|)``
        (Cholesky of Sigma, one row of components at a time)."""
        cov = self.covariance()
        c, l, k = self.mu.shape
        half = _half_logdet(self.chol)  # [C, L]

        def row(args):
            mu1, cov1, half1 = args
            s = cholesky_lower(0.5 * (cov1[None, None] + cov))  # [C, L, K, K]
            w = solve_triangular(s, (mu1[None, None] - self.mu)[..., None], lower=True)[..., 0]
            return 0.125 * jnp.sum(w * w, -1) + _half_logdet(s) - 0.5 * (half1 + half)

        rows = jax.lax.map(row, (self.mu.reshape(c * l, k), cov.reshape(c * l, k, k), half.reshape(c * l)))
        return rows.reshape(c, l, c, l)

    def kl(self) -> Float[Array, "C L C L"]:
        """KL(N(mu_1, S_1 S_1^T) || N(mu_2, S_2 S_2^T)) =
        ``1/2 [|S_2^-1 S_1|_F^2 + |S_2^-1 (mu_1 - mu_2)|^2 - K] + log|S_2| - log|S_1|``
        (triangular solves with S_2, one row of first components at a time)."""
        c, l, k = self.mu.shape
        half = _half_logdet(self.chol)  # [C, L]

        def row(args):
            mu1, chol1, half1 = args
            a = solve_triangular(self.chol, jnp.broadcast_to(chol1, self.chol.shape), lower=True)  # [C, L, K, K]
            w = solve_triangular(self.chol, (mu1[None, None] - self.mu)[..., None], lower=True)[..., 0]
            return 0.5 * (jnp.sum(a * a, (-2, -1)) + jnp.sum(w * w, -1) - k) + half - half1

        rows = jax.lax.map(row, (self.mu.reshape(c * l, k), self.chol.reshape(c * l, k, k), half.reshape(c * l)))
        return rows.reshape(c, l, c, l)

    def scaling_terms(self, g: Float[ArrayLike, "N K"]):
        """``(q [N, C, L], log|2 pi Sigma| [C, L])`` by triangular solves."""
        k = self.mu.shape[-1]
        d = g[:, None, None, :] - self.mu[None]  # [N, C, L, K]
        solve = jax.vmap(jax.vmap(lambda s, dc: solve_triangular(s, dc.T, lower=True).T, in_axes=(0, 1), out_axes=1),
                         in_axes=(0, 1), out_axes=1)
        z = solve(self.chol, d)  # [N, C, L, K]
        return jnp.sum(z * z, axis=-1), 2.0 * _half_logdet(self.chol) + k * _LOG_2PI

    def scaled_log_density(self, terms, log_factor):
        return gaussian_scaled_log_density(*terms, log_factor, self.dim)

    def problems(self) -> list[tuple[str, str]]:
        out = []
        if np.any(np.asarray(self.var) <= 0):
            out.append(("var", "has non-positive variances"))
        if np.any(np.diagonal(np.asarray(self.chol), axis1=-2, axis2=-1) <= 0):
            out.append(("chol", "has a non-positive diagonal"))
        return out

    @classmethod
    def fit(cls, mean, second, floor) -> "FullGaussian":
        """ML (eq. 4.23-4.24): ``Sigma = Sigma_ML + floor I``, ``chol = cholesky(Sigma)``,
        ``var = diag(Sigma)``."""
        k = second.shape[-1]
        cov = second + np.asarray(floor)[..., None, None] * np.eye(k)
        return cls(mean, np.linalg.cholesky(cov), np.diagonal(cov, axis1=-2, axis2=-1).copy())


def log_likelihood_full(
    g: Float[ArrayLike, " K"], mu: Float[ArrayLike, "C L K"], chol: Float[ArrayLike, "C L K K"]
) -> Float[Array, "C L"]:
    """:meth:`FullGaussian.log_density` of one position's arrays (eq. 4.22)."""
    return FullGaussian(mu, chol).log_density(g)
