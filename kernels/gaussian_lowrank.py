"""A structured-covariance Gaussian sensor model: low rank plus diagonal
(factor analysis), between the thesis's diagonal form and the full one.

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
is the Gaussian closed form (the formula of
:meth:`~.gaussian_full.FullGaussian.bhattacharyya`), again by Woodbury: the
average of two components is low rank plus diagonal too,

    Sigma = (Sigma_1 + Sigma_2) / 2 = D + U U^T,   D = diag((psi_1 + psi_2) / 2),
    U = [W_1, W_2] / sqrt 2   (K x 2R)

so with ``V = D^-1/2 U``, ``e = D^-1/2 (mu_1 - mu_2)`` and the ``2R x 2R``
capacitance ``I + V^T V = B B^T``::

    d^T Sigma^-1 d = |e|^2 - |B^-1 V^T e|^2
    log|Sigma|     = sum log D + 2 sum log diag B

and ``log|Sigma_i|`` from each component's own ``R x R`` capacitance: no
``K x K`` matrix per pair (:meth:`LowRankGaussian.bhattacharyya`).

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

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.linalg import solve_triangular
from jaxtyping import Array, ArrayLike, Float

from .gaussian_diag import gaussian_scaled_log_density
from .gaussian_full import cholesky_lower
from .likelihood import Likelihood, register_likelihood

__all__ = ["LowRankGaussian", "DEFAULT_RANK", "DEFAULT_MIN_UNIQUENESS", "factor_analysis"]

DEFAULT_RANK = 4
"""Factors R when none is given (capped at K - 1)."""

DEFAULT_MIN_UNIQUENESS = 0.5
"""Default lower bound of ``psi_d / S_dd`` (module docstring)."""

_LOG_2PI = math.log(2.0 * math.pi)

_PAIR_CHUNK_BYTES = 4 * 2**20
"""Rough size of the temporaries of one chunk of rows of
:meth:`LowRankGaussian.bhattacharyya` on the CPU (cache-sized chunks were the
fastest there: 4 MiB beat 16 and 64 MiB at C*L = 960, K = 20, R = 4)."""

_PAIR_CHUNK_BYTES_ACCELERATOR = 256 * 2**20
"""The same on a GPU / TPU: few large chunks (each ``lax.map`` step is many kernels)."""

_UNROLL_MAX_RANK = 8
"""Up to this R, :meth:`LowRankGaussian.bhattacharyya` writes its ``(2R+1)``-square
Cholesky out entry by entry (about ``(2R+1)^3 / 6`` vector operations to compile)."""

_HIGHEST = jax.lax.Precision.HIGHEST   # no TF32 / bf16 passes: c - b^T M^-1 b cancels


def _pair_chunk_bytes() -> int:
    return _PAIR_CHUNK_BYTES if jax.default_backend() == "cpu" else _PAIR_CHUNK_BYTES_ACCELERATOR


def _cholesky_schur(entry, p: int):
    """Cholesky factor ``L`` of a symmetric ``[p, p]`` matrix given entry by entry
    (``entry(i, j)``, ``i >= j``, each a batch of values), unblocked and unrolled:
    returns ``(sum_{j < p-1} log L_jj, s)`` with ``s = L_{p-1,p-1}^2``, the Schur
    complement of the leading ``p-1`` block (left unsquare-rooted, so ``s`` may be
    0 or a rounding below it)."""
    low, half = {}, 0.0
    for j in range(p):
        for i in range(j, p):
            s = entry(i, j)
            for m in range(j):
                s = s - low[i, m] * low[j, m]
            if i == j == p - 1:
                return half, s
            if i == j:
                low[j, j] = jnp.sqrt(s)
                half = half + jnp.log(low[j, j])
                inv = 1.0 / low[j, j]
            else:
                low[i, j] = s * inv
    raise ValueError("_cholesky_schur: p must be >= 1")


def whiten(W, psi):
    """``(A [..., R, K], sum log diag B [...])`` with ``B B^T = I + W^T Psi^-1 W``
    (lower Cholesky) and ``A = B^-1 W^T Psi^-1``: ``d^T Sigma^-1 d = d^T Psi^-1 d
    - |A d|^2`` and ``log|Sigma| = sum log psi + 2 sum log diag B``.  NumPy for
    NumPy input (a fit, a model file), JAX otherwise.  A non-positive or
    non-finite entry of ``psi`` / ``W`` gives meaningless values here, never an
    exception: the model file rejects it by name (:meth:`LowRankGaussian.problems`)."""
    if isinstance(W, np.ndarray) and isinstance(psi, np.ndarray):
        with np.errstate(all="ignore"):
            p = np.where(np.isfinite(psi) & (psi > 0), psi, 1.0)
            w = np.where(np.isfinite(W), W, 0.0)
            wt = np.swapaxes(w, -1, -2)
            b = np.linalg.cholesky(wt @ (w / p[..., None]) + np.eye(w.shape[-1]))
            a = np.linalg.solve(b, wt / p[..., None, :])
            half = np.sum(np.log(np.diagonal(b, axis1=-2, axis2=-1)), axis=-1)
        dtype = np.result_type(W, psi)
        return a.astype(dtype), half.astype(dtype)
    return _whiten_jax(jnp.asarray(W), jnp.asarray(psi))


@jax.jit
def _whiten_jax(W, psi):
    """:func:`whiten` of JAX arrays, compiled as one program (op by op it
    compiled ~25 small programs per shape, seconds per trained or loaded model)."""
    wt = jnp.swapaxes(W, -1, -2)
    eye = jnp.eye(W.shape[-1], dtype=W.dtype).reshape((1,) * (W.ndim - 2) + (W.shape[-1],) * 2)
    b = cholesky_lower(wt @ (W / psi[..., None]) + eye)
    a = solve_triangular(b, wt / psi[..., None, :], lower=True)
    return a, jnp.sum(jnp.log(jnp.diagonal(b, axis1=-2, axis2=-1)), axis=-1)


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
    #: derived from ``W`` and ``psi`` when the set is built, never stored
    #: (:func:`whiten`): the density of a capture is then two multiply-reduces
    whitened: Float[ArrayLike, "*V C L R K"]
    half_logdet_capacitance: Float[ArrayLike, "*V C L"]

    derived_shapes: ClassVar[dict[str, str]] = {"whitened": "V C L R K", "half_logdet_capacitance": "V C L"}

    def __init__(self, mu, W, psi, whitened=None, half_logdet_capacitance=None):
        self.mu, self.W, self.psi = mu, W, psi
        if whitened is None or half_logdet_capacitance is None:
            whitened, half_logdet_capacitance = whiten(W, psi)
        self.whitened, self.half_logdet_capacitance = whitened, half_logdet_capacitance

    @property
    def rank(self) -> int:
        return self.sizes()["R"]

    @property
    def noise_dim(self) -> int:
        """R normal numbers for the factors, K for the unique parts."""
        return self.rank + self.dim

    def _terms(self, g: Float[ArrayLike, "N K"]):
        """``(q [N, C, L], log|2 pi Sigma| [C, L])`` from the whitened loadings
        (:func:`whiten`): ``q = d^T Psi^-1 d - |A d|^2``, ``d = g - mu``."""
        d = g[:, None, None, :] - self.mu[None]                          # [N, C, L, K]
        z = jnp.einsum("clrk,nclk->nclr", self.whitened, d)               # [N, C, L, R]
        q = jnp.sum(d * d / self.psi[None], axis=-1) - jnp.sum(z * z, axis=-1)
        return q, jnp.sum(jnp.log(self.psi), axis=-1) + 2.0 * self.half_logdet_capacitance + self.dim * _LOG_2PI

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
        """The Gaussian closed form
        ``1/8 d^T Sigma^-1 d + 1/2 log|Sigma| - 1/4 (log|Sigma_1| + log|Sigma_2|)``,
        ``Sigma = (Sigma_1 + Sigma_2) / 2``, by Woodbury and the determinant
        lemma on ``Sigma = D + U U^T`` (module docstring): one ``2R x 2R``
        Cholesky per pair, never a ``K x K`` matrix.

        Per pair, with ``h = 1 / (psi_1 + psi_2) = D^-1 / 2`` and ``t = h d``, the
        capacitance is ``M = I + [W_1 W_2]^T diag(h) [W_1 W_2]`` and the Cholesky
        factor of ``[[M, b], [b^T, c]]`` (``b = [W_1 W_2]^T t``, ``c = t^T d``)
        gives both ``log|M|`` and, as the Schur complement of its last entry,
        ``c - b^T M^-1 b = d^T Sigma^-1 d / 2``.  The blocks of ``M`` are GEMMs
        against ``h`` (``W_i W_i^T`` and ``W_1 W_2^T`` per feature; no ``[K, 2R]``
        factor per pair), and for ``R <= _UNROLL_MAX_RANK`` the ``(2R+1)``-square
        Cholesky is written out entry by entry, vectorised over the pairs
        (much faster than a batched LAPACK call per tiny matrix); larger ranks
        take ``cholesky`` and a triangular solve.  The log-determinant part
        ``sum_k [log D_k - 1/2 log psi_1k - 1/2 log psi_2k]`` is summed per
        feature (each term >= 0); on the diagonal every term but the
        capacitances' is exactly 0.

        Rows of first components go through ``lax.map`` in chunks (``batch_size``,
        a ``vmap`` over each chunk) of about ``_pair_chunk_bytes()`` of
        temporaries.  For ``2R >= K`` this is no cheaper than the full form, but
        it is the same value.
        """
        c, l, k = self.mu.shape
        r, n = self.rank, c * l
        mu = self.mu.reshape(n, k)
        w = self.W.reshape(n, k, r)
        psi = self.psi.reshape(n, k)
        log_psi = jnp.log(psi)
        cap = self.half_logdet_capacitance.reshape(n)
        ri, si = np.triu_indices(r)                                      # the R (R + 1) / 2 distinct products
        tri = np.zeros((r, r), dtype=int)
        tri[ri, si] = tri[si, ri] = np.arange(ri.size)
        outer = w[..., ri] * w[..., si]                                  # W_2 W_2^T per feature  [n, K, Q]
        p = 2 * r + 1

        def row(args):                                                   # one first component against all n
            mu1, w1, psi1, log_psi1, cap1 = args
            h = 1.0 / (psi1[None] + psi)                                 # D^-1 / 2     [n, K]
            d = mu1[None] - mu
            t = h * d
            m11 = jnp.einsum("nk,kq->nq", h, w1[:, ri] * w1[:, si], precision=_HIGHEST)   # [n, Q]
            m22 = jnp.einsum("nk,nkq->nq", h, outer, precision=_HIGHEST)                  # [n, Q]
            m12 = jnp.einsum("nks,kr->nrs", h[..., None] * w, w1, precision=_HIGHEST)     # [n, R, R]
            b1 = jnp.einsum("nk,kr->nr", t, w1, precision=_HIGHEST)
            b2 = jnp.einsum("nk,nkr->nr", t, w, precision=_HIGHEST)
            cc = jnp.sum(t * d, -1)
            if r <= _UNROLL_MAX_RANK:
                def entry(i, j):                                         # [[M, b], [b^T, c]][i, j], i >= j
                    if i == p - 1:
                        return cc if j == p - 1 else (b1[:, j] if j < r else b2[:, j - r])
                    if i >= r > j:
                        return m12[:, j, i - r]
                    x = m11[:, tri[i, j]] if i < r else m22[:, tri[i - r, j - r]]
                    return 1.0 + x if i == j else x

                half, schur = _cholesky_schur(entry, p)
            else:
                eye = jnp.eye(r, dtype=h.dtype)[None]
                m = jnp.concatenate([jnp.concatenate([eye + m11[:, tri], m12], -1),
                                     jnp.concatenate([jnp.swapaxes(m12, -1, -2), eye + m22[:, tri]], -1)], -2)
                chol = cholesky_lower(m)                                 # [n, 2R, 2R]
                z = solve_triangular(chol, jnp.concatenate([b1, b2], -1)[..., None], lower=True)[..., 0]
                half = jnp.sum(jnp.log(jnp.diagonal(chol, axis1=-2, axis2=-1)), -1)
                schur = cc - jnp.sum(z * z, -1)
            logdet = 0.5 * jnp.sum(jnp.log(0.5 * (psi1[None] + psi)) - 0.5 * (log_psi1[None] + log_psi), -1)
            return 0.25 * schur + logdet + half - 0.5 * (cap1 + cap)

        per_row = n * (k * (r + 3) + 2 * ri.size + r * r + p * p) * w.dtype.itemsize
        batch = max(1, min(n, _pair_chunk_bytes() // max(per_row, 1)))
        rows = jax.lax.map(row, (mu, w, psi, log_psi, cap), batch_size=batch)
        return rows.reshape(c, l, c, l)

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


def _spd_solve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a^-1 b`` for symmetric positive definite ``a [..., R, R]`` and ``b [..., R, P]``
    (NumPy): Cholesky ``a = L L^T`` and the two triangular solves, each row of
    ``L`` computed for the whole batch at once.  For the small ``R`` of factor
    analysis this is ~10x faster than ``np.linalg.solve``, whose cost is one
    LAPACK call per matrix."""
    r = a.shape[-1]
    low = np.zeros_like(a)
    for j in range(r):
        lj = low[..., j:j + 1, :j]                                          # [..., 1, j]
        low[..., j, j] = np.sqrt(a[..., j, j] - np.sum(lj[..., 0, :] ** 2, axis=-1))
        if j + 1 < r:
            below = a[..., j + 1:, j:j + 1] - low[..., j + 1:, :j] @ np.swapaxes(lj, -1, -2)
            low[..., j + 1:, j] = below[..., 0] / low[..., j, j][..., None]
    y = np.empty(np.broadcast_shapes(a.shape[:-2], b.shape[:-2]) + b.shape[-2:], np.result_type(a, b))
    for i in range(r):                                                      # L y = b
        y[..., i, :] = (b[..., i, :] - (low[..., i:i + 1, :i] @ y[..., :i, :])[..., 0, :]) / low[..., i, i][..., None]
    for i in reversed(range(r)):                                            # L^T x = y (in place)
        upper = np.swapaxes(low[..., i + 1:, i:i + 1], -1, -2)              # [..., 1, r-i-1]
        y[..., i, :] = (y[..., i, :] - (upper @ y[..., i + 1:, :])[..., 0, :]) / low[..., i, i][..., None]
    return y


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
        beta = _spd_solve(m, np.swapaxes(wp, -1, -2))             # [..., R, K]
        bs = beta @ s                                             # [..., R, K]
        ezz = _spd_solve(m, np.broadcast_to(eye, m.shape)) + bs @ np.swapaxes(beta, -1, -2)  # I - beta W = M^-1
        w = np.swapaxes(_spd_solve(ezz, bs), -1, -2)              # S beta^T Ezz^-1 (Ezz symmetric)
        psi = np.maximum(diag - np.sum(w * bs.swapaxes(-1, -2), axis=-1), low)
    return w, psi
