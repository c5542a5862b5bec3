"""The thesis's sensor model: a Gaussian with diagonal covariance per
(position, class, level) (eq. 4.18-4.19, 4.22), fitted by maximum likelihood
(eq. 4.23-4.24).

    p(g | c, k, v) = N(g; mu[v, c, k], diag(var[v, c, k]))
    log p          = -1/2 sum_d [(g_d - mu_d)^2 / var_d + log(2 pi var_d)]
"""

from __future__ import annotations

import math
from typing import ClassVar

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .likelihood import Likelihood, check_divergence, register_likelihood

__all__ = ["DiagonalGaussian", "log_likelihood", "gaussian_scaled_log_density"]

_LOG_2PI = math.log(2.0 * math.pi)


def _lift(x, n: int):
    """``x`` with ``n`` leading unit axes (explicit broadcasting)."""
    return x.reshape((1,) * n + x.shape)


def gaussian_scaled_log_density(
    q: Float[ArrayLike, "N C L"], logdet: Float[ArrayLike, "C L"], log_factor: Float[ArrayLike, " L"], k: int
) -> Float[Array, "N C L"]:
    """log N(g; mu, s Sigma) in K dimensions from ``q = (g - mu)^T Sigma^-1 (g - mu)``
    and ``log|2 pi Sigma|``, with ``theta = log s`` per level:
    ``-1/2 (q e^-theta + K theta + log|2 pi Sigma|)``.  Shared by every
    Gaussian form (it depends on Sigma only through q and the log-determinant)."""
    return -0.5 * (q * jnp.exp(-log_factor)[None, None, :] + k * log_factor[None, None, :] + logdet[None])


@register_likelihood
class DiagonalGaussian(Likelihood):
    """N(g; mu[c, k], diag(var[c, k])) for every class c and level k.

    Attributes:
        mu: ``[V, C, L, K]`` means (eq. 4.23).
        var: ``[V, C, L, K]`` variances, strictly positive (eq. 4.24, floored).
    """

    kind: ClassVar[str] = "diag"
    summary_words: ClassVar[tuple[str, str]] = ("covariance", "Gaussians")
    name: ClassVar[str] = "gaussian-diag"
    field_shapes: ClassVar[dict[str, str]] = {"mu": "V C L K", "var": "V C L K"}
    second_moments: ClassVar[str] = "diag"

    mu: Float[ArrayLike, "*V C L K"]
    var: Float[ArrayLike, "*V C L K"]

    def log_density(self, g: Float[ArrayLike, "*B K"]) -> Float[Array, "*B C L"]:
        """Eq. 4.22 with a diagonal Sigma: ``-1/2 sum_d [(g_d - mu_d)^2 / var_d + log(2 pi var_d)]``."""
        n = g.ndim - 1
        d = g[..., None, None, :] - _lift(self.mu, n)
        return -0.5 * jnp.sum(d * d / _lift(self.var, n) + _lift(jnp.log(self.var), n) + _LOG_2PI, axis=-1)

    def sample(self, z: Float[ArrayLike, "C L J K"]) -> Float[Array, "C L J K"]:
        """g = mu[c, k] + sqrt(var[c, k]) * z[c, k, j]."""
        return self.mu[:, :, None, :] + jnp.sqrt(self.var)[:, :, None, :] * z

    def mean(self) -> Float[Array, "C L K"]:
        return self.mu

    def covariance(self) -> Float[Array, "C L K K"]:
        return jnp.einsum("...k,kl->...kl", self.var, jnp.eye(self.var.shape[-1], dtype=self.var.dtype))

    def variance(self) -> Float[Array, "C L K"]:
        return self.var

    def scaled(self, factor: Float[ArrayLike, " L"]) -> "DiagonalGaussian":
        """var[c, k] * factor[k]."""
        return DiagonalGaussian(self.mu, self.var * factor[None, :, None])

    def bhattacharyya(self) -> Float[Array, "C L C L"]:
        """Between N(mu_1, diag v_1) and N(mu_2, diag v_2), with v = (v_1 + v_2) / 2:
        ``sum_d [(mu_1 - mu_2)^2 / (8 v) + 1/2 log v - 1/4 (log v_1 + log v_2)]``."""
        m1, m2 = self.mu[:, :, None, None, :], self.mu[None, None]
        v1, v2 = self.var[:, :, None, None, :], self.var[None, None]
        v = 0.5 * (v1 + v2)
        d = m1 - m2
        return jnp.sum(0.125 * d * d / v + 0.5 * jnp.log(v) - 0.25 * (jnp.log(v1) + jnp.log(v2)), axis=-1)

    def kl(self) -> Float[Array, "C L C L"]:
        """KL(N(mu_1, diag v_1) || N(mu_2, diag v_2)):
        ``1/2 sum_d [v_1 / v_2 + (mu_1 - mu_2)^2 / v_2 - 1 + log v_2 - log v_1]``."""
        m1, m2 = self.mu[:, :, None, None, :], self.mu[None, None]
        v1, v2 = self.var[:, :, None, None, :], self.var[None, None]
        d = m1 - m2
        return 0.5 * jnp.sum(v1 / v2 + d * d / v2 - 1.0 + jnp.log(v2) - jnp.log(v1), axis=-1)

    def camera_divergence(self, kind: str) -> Float[Array, "V C L C L"]:
        """:meth:`bhattacharyya` / :meth:`kl` at every position at once, the
        components flattened and the features first (``[V, K, N, N']``, the
        pair axis innermost: ~2x faster than per position on the CPU).  Equal
        to the per-position forms to rounding."""
        check_divergence(kind)
        v, c, l, k = self.mu.shape
        mu = jnp.swapaxes(jnp.reshape(self.mu, (v, c * l, k)), 1, 2)[:, :, :, None]   # [V, K, N, 1]
        var = jnp.swapaxes(jnp.reshape(self.var, (v, c * l, k)), 1, 2)[:, :, :, None]
        mu2, var2 = jnp.swapaxes(mu, 2, 3), jnp.swapaxes(var, 2, 3)                    # [V, K, 1, N']
        d2 = (mu - mu2) ** 2
        log_v = jnp.sum(jnp.log(var), axis=1)  # [V, N, 1]
        if kind == "bhattacharyya":
            vm = 0.5 * (var + var2)
            out = jnp.sum(0.125 * d2 / vm + 0.5 * jnp.log(vm), axis=1) - 0.25 * (log_v + jnp.swapaxes(log_v, 1, 2))
        else:
            out = 0.5 * (jnp.sum((var + d2) / var2, axis=1) - k + jnp.swapaxes(log_v, 1, 2) - log_v)
        return jnp.reshape(out, (v, c, l, c, l))

    def scaling_terms(self, g: Float[ArrayLike, "N K"]):
        """``(q [N, C, L], log|2 pi Sigma| [C, L])``, Sigma = diag(var)."""
        k = self.mu.shape[-1]
        d = g[:, None, None, :] - self.mu[None]
        q = jnp.sum(d * d / self.var[None], axis=-1)
        return q, jnp.sum(jnp.log(self.var), axis=-1) + k * _LOG_2PI

    def scaled_log_density(self, terms, log_factor):
        return gaussian_scaled_log_density(*terms, log_factor, self.dim)

    def problems(self) -> list[tuple[str, str]]:
        return [("var", "has non-positive variances")] if np.any(np.asarray(self.var) <= 0) else []

    @classmethod
    def fit(cls, mean, second, floor) -> "DiagonalGaussian":
        """ML (eq. 4.23-4.24): ``mu = mean``, ``var = max(var_ML, floor)``."""
        return cls(mean, np.maximum(second, np.asarray(floor)[..., None]))


def log_likelihood(
    g: Float[ArrayLike, " K"], mu: Float[ArrayLike, "C L K"], var: Float[ArrayLike, "C L K"]
) -> Float[Array, "C L"]:
    """:meth:`DiagonalGaussian.log_density` of one position's arrays (eq. 4.22)."""
    return DiagonalGaussian(mu, var).log_density(g)
