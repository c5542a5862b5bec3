"""A structured-covariance Gaussian sensor model: low rank plus diagonal
(factor analysis; issue 18), between the thesis's diagonal form and the full one.

    p(g | c, k, v) = N(g; mu, Sigma),   Sigma = W W^T + diag(psi),   W [K, R], R < K

with ``mu = mu[v, c, k]``, ``W = W[v, c, k]``, ``psi = psi[v, c, k]``.  The
pixel shifts and the brightness offset of the augmentation move a view's
features along a few directions: ``W`` holds them, ``psi`` the rest.

Density by the Woodbury identity and the matrix-determinant lemma, with the
``R x R`` capacitance ``M = I + W^T Psi^-1 W = B B^T`` (Cholesky)::

    q       = d^T Psi^-1 d - |B^-1 W^T Psi^-1 d|^2,      d = g - mu
    log|S|  = sum_d log psi_d + 2 sum log diag B
    log p   = -1/2 (q + log|Sigma| + K log 2 pi)                    (eq. 4.22)

never a ``K x K`` inverse or solve.  Draws from ``noise_dim = R + K`` normal
numbers: ``g = mu + W z[:R] + sqrt(psi) z[R:]``.  The Bhattacharyya distance
is the Gaussian closed form, by :class:`~.gaussian_full.FullGaussian` on the
Cholesky factor of ``Sigma`` (one shared formula for every Gaussian).

Fit (:meth:`LowRankGaussian.fit`) from the ``K x K`` sample covariance ``S``
of each component (``second_moments = "full"``): maximum-likelihood factor
analysis by EM (Rubin & Thayer 1982), started from the probabilistic-PCA
closed form (Tipping & Bishop 1999: ``W = U_R (Lambda_R - sigma^2)^1/2``,
``sigma^2`` the mean discarded eigenvalue).  Each EM step keeps

    psi_d >= max(min_uniqueness * S_dd, floor)

(constrained EM, the floor applied inside every step), and so does the
result.  This is what keeps the model from over-tightening the way the full
covariance does at level 0, where ``S`` is nearly singular (a few shift
directions plus tiny pixel noise): ``Sigma >= Psi >= min_uniqueness
diag(S)`` in the PSD order, so for every deviation ``d`` the Mahalanobis term
is at most ``1 / min_uniqueness`` times the diagonal Gaussian's
(``d^T Sigma^-1 d <= d^T diag(S)^-1 d / min_uniqueness``; default
``min_uniqueness = 0.5``, a factor 2), whereas the full covariance's smallest
eigenvalue is only floored at ``var_floor``.  The default was chosen on the
held-out log-likelihood of off-grid views in ``benchmarks/bench_likelihoods.py``
(a small synthetic database: 0.1 / 0.3 / 0.5 gave 14.68 / 15.07 / 15.32 nats
per view, the diagonal Gaussian 14.84): a choice on one small run, to revisit
on the rendered rig.
"""

from __future__ import annotations

import math
from typing import ClassVar

import jax.numpy as jnp
import numpy as np
from jax.scipy.linalg import solve_triangular
from jaxtyping import Array, ArrayLike, Float

from .gaussian_diag import gaussian_scaled_log_density
from .gaussian_full import FullGaussian, cholesky_lower
from .likelihood import Likelihood, register_likelihood

__all__ = ["LowRankGaussian", "DEFAULT_RANK", "DEFAULT_MIN_UNIQUENESS", "factor_analysis"]

DEFAULT_RANK = 4
"""Factors R when none is given (capped at K - 1)."""

DEFAULT_MIN_UNIQUENESS = 0.5
"""Default lower bound of ``psi_d / S_dd`` (module docstring)."""

_LOG_2PI = math.log(2.0 * math.pi)


@register_likelihood
class LowRankGaussian(Likelihood):
    """N(g; mu[c, k], W W^T + diag(psi)) for every class c and level k.

    Attributes:
        mu: ``[V, C, L, K]`` means (eq. 4.23).
        W: ``[V, C, L, K, R]`` factor loadings.
        psi: ``[V, C, L, K]`` unique variances, strictly positive.
    """

    kind: ClassVar[str] = "gaussian-lowrank"
    field_shapes: ClassVar[dict[str, str]] = {"mu": "V C L K", "W": "V C L K R", "psi": "V C L K"}
    second_moments: ClassVar[str] = "full"
    fit_options: ClassVar[tuple[str, ...]] = ("rank", "min_uniqueness", "iterations")

    mu: Float[ArrayLike, "*V C L K"]
    W: Float[ArrayLike, "*V C L K R"]
    psi: Float[ArrayLike, "*V C L K"]

    @property
    def rank(self) -> int:
        return self.sizes()["R"]

    @property
    def noise_dim(self) -> int:
        """R normal numbers for the factors, K for the unique parts."""
        return self.rank + self.dim

    def _terms(self, g: Float[ArrayLike, "N K"]):
        """``(q [N, C, L], log|2 pi Sigma| [C, L])`` by Woodbury (module docstring)."""
        k = self.dim
        d = g[:, None, None, :] - self.mu[None]                          # [N, C, L, K]
        a = d / self.psi[None]
        wt = jnp.swapaxes(self.W, -1, -2)                                # [C, L, R, K]
        m = wt @ (self.W / self.psi[..., None]) + jnp.eye(self.rank, dtype=self.W.dtype)[None, None]
        b = cholesky_lower(m)                                            # [C, L, R, R]
        u = jnp.einsum("clrk,nclk->clrn", wt, a)
        w = solve_triangular(b, u, lower=True)                           # [C, L, R, N]
        q = jnp.sum(d * a, axis=-1) - jnp.moveaxis(jnp.sum(w * w, axis=-2), -1, 0)
        logdet = (jnp.sum(jnp.log(self.psi), axis=-1)
                  + 2.0 * jnp.sum(jnp.log(jnp.diagonal(b, axis1=-2, axis2=-1)), axis=-1) + k * _LOG_2PI)
        return q, logdet

    def log_density(self, g: Float[ArrayLike, "*B K"]) -> Float[Array, "*B C L"]:
        batch = g.shape[:-1]
        q, logdet = self._terms(g.reshape(math.prod(batch), g.shape[-1]))
        return (-0.5 * (q + logdet[None])).reshape(batch + logdet.shape)

    def sample(self, z: Float[ArrayLike, "C L J Z"]) -> Float[Array, "C L J K"]:
        """g = mu + W z[:R] + sqrt(psi) z[R:]."""
        r = self.rank
        return (self.mu[:, :, None, :] + jnp.einsum("clkr,cljr->cljk", self.W, z[..., :r])
                + jnp.sqrt(self.psi)[:, :, None, :] * z[..., r:])

    def mean(self) -> Float[Array, "C L K"]:
        return self.mu

    def covariance(self) -> Float[Array, "C L K K"]:
        eye = jnp.eye(self.dim, dtype=self.psi.dtype)
        return self.W @ jnp.swapaxes(self.W, -1, -2) + jnp.einsum("...k,kl->...kl", self.psi, eye)

    def variance(self) -> Float[Array, "C L K"]:
        return jnp.sum(self.W * self.W, axis=-1) + self.psi

    def scaled(self, factor: Float[ArrayLike, " L"]) -> "LowRankGaussian":
        """Sigma[c, k] * factor[k]: ``W * sqrt(factor)``, ``psi * factor``."""
        return LowRankGaussian(self.mu, self.W * jnp.sqrt(factor)[None, :, None, None], self.psi * factor[None, :, None])

    def bhattacharyya(self) -> Float[Array, "C L C L"]:
        """The Gaussian closed form (:meth:`FullGaussian.bhattacharyya` on ``chol(Sigma)``)."""
        return FullGaussian(self.mu, cholesky_lower(self.covariance())).bhattacharyya()

    def scaling_terms(self, g: Float[ArrayLike, "N K"]):
        """``(q [N, C, L], log|2 pi Sigma| [C, L])``."""
        return self._terms(g)

    def scaled_log_density(self, terms, log_factor):
        return gaussian_scaled_log_density(*terms, log_factor, self.dim)

    def problems(self) -> list[tuple[str, str]]:
        out = []
        r, k = np.shape(self.W)[-1], np.shape(self.W)[-2]
        if r < 1:
            out.append(("W", "has rank 0 (use the diagonal Gaussian)"))
        elif r > k:
            out.append(("W", f"has rank {r}, larger than K = {k}"))
        if np.any(np.asarray(self.psi) <= 0):
            out.append(("psi", "has non-positive variances"))
        return out

    @classmethod
    def fit(cls, mean, second, floor, *, rank: int | None = None, min_uniqueness: float = DEFAULT_MIN_UNIQUENESS,
            iterations: int = 200) -> "LowRankGaussian":
        """Factor analysis of each component's sample covariance (module docstring).

        Args:
            mean: ``[C, L, K]``; second: ``[C, L, K, K]`` sample covariances;
            floor: ``[C, L]`` variance floor.
            rank: R, ``1 <= R < K`` (default ``min(DEFAULT_RANK, K - 1)``).
            min_uniqueness: lower bound of ``psi_d / S_dd`` in ``[0, 1)``.
            iterations: EM steps.

        Raises:
            ValueError: a rank outside ``1..K-1`` or a bound outside ``[0, 1)``.
        """
        k = np.shape(mean)[-1]
        r = min(DEFAULT_RANK, k - 1) if rank is None else int(rank)
        if not 1 <= r < k:
            raise ValueError(f"gaussian-lowrank: rank must be in 1..K-1 = 1..{k - 1}, got {rank}")
        if not 0.0 <= float(min_uniqueness) < 1.0:
            raise ValueError(f"gaussian-lowrank: min_uniqueness must be in [0, 1), got {min_uniqueness}")
        w, psi = factor_analysis(np.asarray(second, np.float64), r, min_uniqueness=float(min_uniqueness),
                                 floor=np.asarray(floor, np.float64), iterations=int(iterations))
        return cls(np.asarray(mean, np.float64), w, psi)


def factor_analysis(s: np.ndarray, rank: int, *, min_uniqueness: float = DEFAULT_MIN_UNIQUENESS,
                    floor: np.ndarray | float = 0.0, iterations: int = 200) -> tuple[np.ndarray, np.ndarray]:
    """ML factor analysis ``S ~ W W^T + diag(psi)`` of covariances ``s [..., K, K]``
    (NumPy float64): PPCA start, then ``iterations`` EM steps, each with
    ``psi >= max(min_uniqueness diag(S), floor)``.  Returns ``(W [..., K, R], psi [..., K])``."""
    s = 0.5 * (s + np.swapaxes(s, -1, -2))
    k = s.shape[-1]
    diag = np.diagonal(s, axis1=-2, axis2=-1)
    low = np.maximum(min_uniqueness * diag, np.asarray(floor)[..., None])
    low = np.maximum(low, 1e-12 * np.maximum(diag.max(axis=-1, keepdims=True), 1e-300))  # never exactly 0
    lam, u = np.linalg.eigh(s)                                   # ascending
    lam, u = lam[..., ::-1], u[..., ::-1]
    sigma2 = np.mean(lam[..., rank:], axis=-1, keepdims=True)
    w = u[..., :rank] * np.sqrt(np.maximum(lam[..., :rank] - sigma2, 0.0))[..., None, :]
    psi = np.maximum(diag - np.sum(w * w, axis=-1), low)
    eye = np.eye(rank)
    for _ in range(iterations):
        # E step through the R x R capacitance: beta = W^T Sigma^-1 = M^-1 W^T Psi^-1
        wp = w / psi[..., :, None]                                # Psi^-1 W  [..., K, R]
        m = eye + np.swapaxes(w, -1, -2) @ wp                     # [..., R, R]
        beta = np.linalg.solve(m, np.swapaxes(wp, -1, -2))        # [..., R, K]
        bs = beta @ s                                             # [..., R, K]
        ezz = np.linalg.solve(m, np.broadcast_to(eye, m.shape)) + bs @ np.swapaxes(beta, -1, -2)  # I - beta W = M^-1
        w = np.swapaxes(np.linalg.solve(ezz, bs), -1, -2)         # S beta^T Ezz^-1 (Ezz symmetric)
        psi = np.maximum(diag - np.sum(w * bs.swapaxes(-1, -2), axis=-1), low)
    return w, psi
