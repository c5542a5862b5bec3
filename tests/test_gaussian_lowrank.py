"""The low-rank-plus-diagonal Gaussian (``kernels/gaussian_lowrank.py``) against
SciPy / NumPy: Woodbury density, sampler, Bhattacharyya, scaling; the factor
analysis fit recovers a planted ``W W^T + diag(psi)``; the uniqueness floor
bounds how much tighter than the diagonal model it can be (the full
covariance's level-0 failure); the field checks."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest
from oracles import bhattacharyya_ref
from scipy.stats import multivariate_normal

from jaxrecog import kernels as K
from jaxrecog.kernels.gaussian_full import cholesky_lower
from jaxrecog.kernels.gaussian_lowrank import factor_analysis

pytestmark = pytest.mark.usefixtures("strict_dtype_promotion")


def _lowrank(rng, V=2, C=3, L=2, k=4, r=2):
    mu = rng.normal(size=(V, C, L, k))
    w = rng.normal(size=(V, C, L, k, r)) * 0.8
    psi = rng.uniform(0.2, 1.0, size=(V, C, L, k))
    cov = w @ np.swapaxes(w, -1, -2) + psi[..., None] * np.eye(k)
    return K.LowRankGaussian(jnp.asarray(mu), jnp.asarray(w), jnp.asarray(psi)), mu, w, psi, cov


def test_log_density_against_scipy_for_any_batch(rng, x64):
    lik, mu, w, psi, cov = _lowrank(rng)
    assert (lik.rank, lik.noise_dim) == (2, 6)
    g = rng.normal(size=(2, 4, 4)) * 1.5
    for v in range(2):
        got = np.asarray(lik.at(v).log_density(jnp.asarray(g)))
        assert got.shape == (2, 4, 3, 2)
        np.testing.assert_allclose(np.asarray(lik.at(v).log_density(jnp.asarray(g[0, 3]))), got[0, 3], rtol=1e-13)
        for c, l in np.ndindex(3, 2):
            np.testing.assert_allclose(got[..., c, l], multivariate_normal(mu[v, c, l], cov[v, c, l]).logpdf(g),
                                       rtol=1e-12)


def test_moments_sampler_and_the_full_form(rng, x64):
    lik, mu, w, psi, cov = _lowrank(rng, V=1, C=2, L=2)
    one = lik.at(0)
    np.testing.assert_allclose(one.covariance(), cov[0], rtol=1e-13)
    np.testing.assert_allclose(one.variance(), np.diagonal(cov[0], axis1=-2, axis2=-1), rtol=1e-13)
    z = rng.normal(size=(2, 2, 5, 6))
    want = mu[0][:, :, None, :] + np.einsum("clkr,cljr->cljk", w[0], z[..., :2]) + np.sqrt(psi[0])[:, :, None, :] * z[..., 2:]
    np.testing.assert_allclose(one.sample(jnp.asarray(z)), want, rtol=1e-12, atol=1e-13)
    n = 40_000
    g = np.asarray(one.sample(jnp.asarray(rng.normal(size=(2, 2, n, 6)))))
    sd = np.sqrt(np.diagonal(cov[0], axis1=-2, axis2=-1))
    assert np.all(np.abs(g.mean(axis=2) - mu[0]) < 5 * sd / np.sqrt(n))
    d = g - g.mean(2, keepdims=True)
    emp = np.einsum("cljk,cljm->clkm", d, d) / n
    assert np.all(np.abs(emp - cov[0]) < 5 * np.sqrt(2.0 / n) * sd[..., :, None] * sd[..., None, :])
    # the same density as the full-covariance family on chol(W W^T + psi)
    full = K.FullGaussian(jnp.asarray(mu), jnp.asarray(np.linalg.cholesky(cov)))
    x = jnp.asarray(rng.normal(size=(7, 4)))
    np.testing.assert_allclose(lik.at(0).log_density(x), full.at(0).log_density(x), rtol=1e-12)


def test_bhattacharyya_and_scaling(rng, x64):
    lik, mu, w, psi, cov = _lowrank(rng)
    for v in range(2):
        np.testing.assert_allclose(lik.at(v).bhattacharyya(), bhattacharyya_ref(mu[v], cov[v]), rtol=1e-10, atol=1e-12)
    factor = np.array([3.0, 0.7])
    g = rng.normal(size=(5, 4))
    one = lik.at(1)
    got = np.asarray(one.scaled(jnp.asarray(factor)).log_density(jnp.asarray(g)))
    fast = np.asarray(one.scaled_log_density(one.scaling_terms(jnp.asarray(g)), jnp.log(factor)))
    for c, l in np.ndindex(3, 2):
        want = multivariate_normal(mu[1, c, l], factor[l] * cov[1, c, l]).logpdf(g)
        np.testing.assert_allclose(got[:, c, l], want, rtol=1e-12)
        np.testing.assert_allclose(fast[:, c, l], want, rtol=1e-12)


def test_factor_analysis_recovers_a_planted_model(rng):
    k, r = 8, 2
    w = rng.normal(size=(3, k, r))
    psi = rng.uniform(0.3, 1.2, size=(3, k))                     # heteroscedastic: not PPCA's sigma^2 I
    s = w @ np.swapaxes(w, -1, -2) + psi[..., None] * np.eye(k)
    w_fit, psi_fit = factor_analysis(s, r, min_uniqueness=0.0, iterations=2000)
    np.testing.assert_allclose(w_fit @ np.swapaxes(w_fit, -1, -2), w @ np.swapaxes(w, -1, -2), atol=2e-4)
    np.testing.assert_allclose(psi_fit, psi, atol=2e-4)
    # isotropic psi: PPCA is already exact at the start
    s_iso = w @ np.swapaxes(w, -1, -2) + 0.5 * np.eye(k)
    w0, psi0 = factor_analysis(s_iso, r, min_uniqueness=0.0, iterations=0)
    np.testing.assert_allclose(w0 @ np.swapaxes(w0, -1, -2) + psi0[..., None] * np.eye(k), s_iso, atol=1e-10)
    # from sample moments through the family's fit (the training path), on planted draws
    n = 20_000
    x = np.einsum("kr,nr->nk", w[0], rng.normal(size=(n, r))) + np.sqrt(psi[0]) * rng.normal(size=(n, k))
    emp = np.cov(x.T, bias=True)
    fit = K.LowRankGaussian.fit(x.mean(0)[None, None], emp[None, None], np.zeros((1, 1)), rank=r, min_uniqueness=0.0)
    cov = np.asarray(fit.W)[0, 0] @ np.asarray(fit.W)[0, 0].T + np.diag(np.asarray(fit.psi)[0, 0])
    assert np.max(np.abs(cov - s[0])) < 0.1 * np.max(np.abs(s[0]))


@pytest.mark.parametrize("r", [1, 4, 7])
def test_spd_solve_is_numpy_solve(rng, r):
    """The batched Cholesky solve of factor analysis against ``np.linalg.solve``,
    with a broadcast right-hand side (the identity of the E step)."""
    from jaxrecog.kernels.gaussian_lowrank import _spd_solve

    a = rng.normal(size=(3, 5, r, r + 2))
    m = a @ np.swapaxes(a, -1, -2) + 0.1 * np.eye(r)
    b = rng.normal(size=(3, 5, r, 6))
    np.testing.assert_allclose(_spd_solve(m, b), np.linalg.solve(m, b), rtol=1e-10, atol=1e-12)
    eye = np.broadcast_to(np.eye(r), m.shape)
    np.testing.assert_allclose(_spd_solve(m, eye), np.linalg.inv(m), rtol=1e-10, atol=1e-12)


def test_uniqueness_floor_bounds_the_tightening_at_a_near_singular_level_0(rng, x64):
    """Level-0-like moments: two shift directions plus tiny noise.  The full
    covariance's Mahalanobis distance of an off-grid deviation is huge; the
    low-rank one's is at most 1/min_uniqueness times the diagonal model's."""
    k = 6
    a = rng.normal(size=(1, 1, k, 2))
    s = a @ np.swapaxes(a, -1, -2) + 1e-6 * np.eye(k)
    mean, floor = np.zeros((1, 1, k)), np.full((1, 1), 1e-8)
    low = K.LowRankGaussian.fit(mean, s, floor, rank=2, min_uniqueness=0.1)
    psi = np.asarray(low.psi)
    assert np.all(psi >= 0.1 * np.diagonal(s, axis1=-2, axis2=-1) - 1e-15)
    lr = K.LowRankGaussian(jnp.asarray(mean[None]), jnp.asarray(np.asarray(low.W)[None]), jnp.asarray(psi[None])).at(0)
    full = K.FullGaussian(jnp.asarray(mean[None]), jnp.asarray(np.linalg.cholesky(s)[None])).at(0)
    diag = K.DiagonalGaussian(jnp.asarray(mean[None]), jnp.asarray(np.diagonal(s, axis1=-2, axis2=-1)[None])).at(0)
    d = jnp.asarray(rng.normal(size=(200, k)) * np.sqrt(np.diag(s[0, 0])))     # deviations off the shift plane
    q_low, q_full, q_diag = (-2.0 * (m.log_density(d) - m.log_density(jnp.zeros((1, k)))) for m in (lr, full, diag))
    assert np.all(np.asarray(q_low) <= np.asarray(q_diag) / 0.1 + 1e-9)
    assert np.median(np.asarray(q_full) / np.asarray(q_low)) > 100


def test_fit_and_field_errors(rng):
    mean, s, floor = np.zeros((1, 1, 3)), np.eye(3)[None, None], np.zeros((1, 1))
    for rank in (0, 3, 5):
        with pytest.raises(ValueError, match=r"rank must be in 1..K-1 = 1..2"):
            K.LowRankGaussian.fit(mean, s, floor, rank=rank)
    with pytest.raises(ValueError, match="min_uniqueness"):
        K.LowRankGaussian.fit(mean, s, floor, rank=1, min_uniqueness=1.0)
    assert np.asarray(K.LowRankGaussian.fit(mean, s, floor).W).shape[-1] == 2      # default min(4, K - 1)
    lik, *_ = _lowrank(rng, k=3, r=2)
    assert lik.problems() == []
    wide = K.LowRankGaussian(lik.mu, jnp.concatenate([lik.W, lik.W], axis=-1), lik.psi)
    assert wide.problems() == [("W", "has rank 4, larger than K = 3")]
    bad = K.LowRankGaussian(lik.mu, lik.W, lik.psi.at[0, 0, 0, 0].set(0.0))
    assert bad.problems() == [("psi", "has non-positive variances")]


def _pair_model(rng, C, L, k, r, dtype=np.float64):
    mu = rng.normal(size=(C, L, k)) * 1.5
    w = rng.normal(size=(C, L, k, r)) * rng.uniform(0.2, 1.5, size=(C, L, 1, r))
    psi = rng.uniform(0.1, 1.0, size=(C, L, k))
    cov = w @ np.swapaxes(w, -1, -2) + psi[..., None] * np.eye(k)
    lik = K.LowRankGaussian(*(jnp.asarray(x.astype(dtype)) for x in (mu, w, psi)))
    return lik, mu, cov


@pytest.mark.parametrize("unrolled", [True, False], ids=["unrolled", "lapack"])
@pytest.mark.parametrize("k, r", [(5, 1), (5, 2), (5, 4), (8, 7), (2, 1)])
def test_bhattacharyya_woodbury_is_the_full_form(rng, x64, monkeypatch, k, r, unrolled):
    """The 2R x 2R Woodbury form equals FullGaussian's K x K Cholesky form and
    the NumPy reference, rank 1 to K - 1 (2R > K included), by the unrolled
    Cholesky and by the LAPACK one; symmetric, 0 on the diagonal."""
    from jaxrecog.kernels import gaussian_lowrank

    monkeypatch.setattr(gaussian_lowrank, "_UNROLL_MAX_RANK", 64 if unrolled else 0)
    lik, mu, cov = _pair_model(rng, 3, 2, k, r)
    got = np.asarray(lik.bhattacharyya())
    assert got.shape == (3, 2, 3, 2) and got.dtype == np.float64
    full = np.asarray(K.FullGaussian(lik.mu, cholesky_lower(lik.covariance())).bhattacharyya())
    np.testing.assert_allclose(got, full, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(got, bhattacharyya_ref(mu, cov), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(got, np.transpose(got, (2, 3, 0, 1)), rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(np.diagonal(got.reshape(6, 6)), 0.0, atol=1e-13)
    off = got.reshape(6, 6)[~np.eye(6, dtype=bool)]
    assert np.all(off > 0)


def test_bhattacharyya_chunks_with_a_remainder(rng, x64, monkeypatch):
    """Rows of first components in chunks that do not divide C * L give the same table."""
    from jaxrecog.kernels import gaussian_lowrank

    lik, mu, cov = _pair_model(rng, 3, 3, 4, 2)
    whole = np.asarray(lik.bhattacharyya())
    per_row = 9 * (4 * (2 + 3) + 2 * 3 + 2 * 2 + 5 * 5) * 8                 # the kernel's estimate, float64
    for budget in (4 * per_row, 1):                                        # chunks of 4 + 4 + 1 rows; one row at a time
        monkeypatch.setattr(gaussian_lowrank, "_pair_chunk_bytes", lambda: budget)
        np.testing.assert_allclose(np.asarray(lik.bhattacharyya()), whole, rtol=1e-13, atol=1e-14)
    np.testing.assert_allclose(whole, bhattacharyya_ref(mu, cov), rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("k, r", [(6, 1), (12, 4), (6, 5), (20, 10)])
def test_bhattacharyya_float32(rng, k, r):
    """Single precision (both Cholesky paths: R = 10 > _UNROLL_MAX_RANK): finite,
    float32, close to the float64 reference, symmetric, ~0 on the diagonal."""
    lik, mu, cov = _pair_model(rng, 4, 3, k, r, dtype=np.float32)
    got = np.asarray(lik.bhattacharyya())
    assert got.dtype == np.float32 and np.all(np.isfinite(got))
    w, psi = np.asarray(lik.W, np.float64), np.asarray(lik.psi, np.float64)        # the float32 model, exactly
    want = bhattacharyya_ref(np.asarray(lik.mu, np.float64), w @ np.swapaxes(w, -1, -2) + psi[..., None] * np.eye(k))
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(got, np.transpose(got, (2, 3, 0, 1)), rtol=1e-5, atol=1e-5)
    assert np.max(np.abs(np.diagonal(got.reshape(12, 12)))) < 1e-5


def test_log_density_above_the_unrolled_rank_against_scipy(rng, x64):
    """Above the Bhattacharyya distance's unrolled rank the whitened density still matches SciPy."""
    from jaxrecog.kernels.gaussian_lowrank import _UNROLL_MAX_RANK

    r = _UNROLL_MAX_RANK + 2
    lik, mu, w, psi, cov = _lowrank(rng, V=1, C=2, L=2, k=r + 2, r=r)
    g = rng.normal(size=(3, r + 2))
    got = np.asarray(lik.at(0).log_density(jnp.asarray(g)))
    for c, l in np.ndindex(2, 2):
        np.testing.assert_allclose(got[:, c, l], multivariate_normal(mu[0, c, l], cov[0, c, l]).logpdf(g), rtol=1e-11)
