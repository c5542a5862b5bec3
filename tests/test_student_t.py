"""The Student-t likelihood (``kernels/student_t.py``) against SciPy: density,
the chi-square quantile sampler and its moments, scaling and the shape
offset, the held-out choice of nu, the model-file checks of its fields, and
the point of it: a feature with one unmodelled deviation does not drive the
posterior to 1 where the Gaussian's goes."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.stats import chi2, multivariate_t, norm
from scipy.stats import t as student

from jaxrecog import kernels as K
from jaxrecog.kernels.student_t import NU_GRID, chi2_from_normal

pytestmark = pytest.mark.usefixtures("strict_dtype_promotion")


def _t(rng, V=2, C=3, L=2, k=3, nu=(3.0, 7.0)):
    mu = rng.normal(size=(V, C, L, k))
    s2 = rng.uniform(0.3, 1.5, size=(V, C, L, k))
    nus = np.broadcast_to(np.asarray(nu, np.float64), (V, L)).copy()
    return K.StudentT(jnp.asarray(mu), jnp.asarray(s2), jnp.asarray(nus)), mu, s2, nus


def test_log_density_against_scipy_for_any_batch(rng, x64):
    lik, mu, s2, nu = _t(rng)
    g = rng.normal(size=(2, 4, 3)) * 2.0
    for v in range(2):
        got = np.asarray(lik.at(v).log_density(jnp.asarray(g)))
        assert got.shape == (2, 4, 3, 2)
        np.testing.assert_allclose(np.asarray(lik.at(v).log_density(jnp.asarray(g[1, 2]))), got[1, 2], rtol=1e-13)
        for c, l in np.ndindex(3, 2):
            want = multivariate_t(mu[v, c, l], np.diag(s2[v, c, l]), df=nu[v, l]).logpdf(g)
            np.testing.assert_allclose(got[..., c, l], want, rtol=1e-12)


def test_large_nu_is_the_diagonal_gaussian(rng, x64):
    lik, mu, s2, _ = _t(rng, nu=(1e6, 1e6))
    gauss = K.DiagonalGaussian(jnp.asarray(mu), jnp.asarray(s2))
    g = jnp.asarray(rng.normal(size=(5, 3)))
    np.testing.assert_allclose(lik.at(0).log_density(g), gauss.at(0).log_density(g), rtol=1e-4)  # O(q^2 / nu)


@pytest.mark.parametrize("nu", [2.5, 3.0, 5.0, 10.0, 50.0, 1e4])
def test_chi2_from_normal_is_the_quantile_transform(x64, nu):
    u = np.linspace(-6.0, 6.0, 49)
    got = np.asarray(chi2_from_normal(jnp.asarray(u), jnp.full(u.shape, nu)))
    np.testing.assert_allclose(got, chi2.ppf(norm.cdf(u), nu), rtol=1e-6)


def test_chi2_from_normal_in_float32_is_finite_and_close():
    u = np.linspace(-7.0, 7.0, 57).astype(np.float32)
    for nu in (2.5, 4.0, 30.0):
        got = np.asarray(chi2_from_normal(jnp.asarray(u), jnp.full(u.shape, nu, jnp.float32)))
        assert np.all(np.isfinite(got)) and np.all(got > 0)
        np.testing.assert_allclose(got, chi2.ppf(norm.cdf(u.astype(np.float64)), nu), rtol=2e-3)


def test_sampler_moments_and_marginals(rng, x64, optimized_xla):
    lik, mu, s2, nu = _t(rng, V=1, C=2, L=2, nu=(6.0, 12.0))
    one = lik.at(0)
    assert one.noise_dim == 4
    np.testing.assert_allclose(one.mean(), mu[0], rtol=1e-14)
    var = s2[0] * (nu[0] / (nu[0] - 2.0))[None, :, None]
    np.testing.assert_allclose(one.variance(), var, rtol=1e-13)
    np.testing.assert_allclose(one.covariance(), var[..., None] * np.eye(3), rtol=1e-13)
    n = 60_000
    g = np.asarray(one.sample(jnp.asarray(rng.normal(size=(2, 2, n, 4)))))
    sd = np.sqrt(var)
    assert np.all(np.abs(g.mean(axis=2) - mu[0]) < 5 * sd / np.sqrt(n))
    # variance within 5 standard errors (the t's kurtosis: var of s^2 is (2 + 6/(nu-4)) sd^4 / n)
    se = np.sqrt((2.0 + 6.0 / (nu[0] - 4.0))[None, :, None] / n) * var
    assert np.all(np.abs(g.var(axis=2) - var) < 5 * se)
    # a one-dimensional marginal is a scaled t_nu: its quantiles match
    x = (g[1, 0, :, 2] - mu[0, 1, 0, 2]) / np.sqrt(s2[0, 1, 0, 2])
    qs = np.array([0.01, 0.05, 0.25, 0.5, 0.75, 0.95, 0.99])
    np.testing.assert_allclose(np.quantile(x, qs), student.ppf(qs, nu[0, 0]), atol=0.06)


def test_sample_is_smooth_common_random_numbers(rng, x64):
    """The same z gives nearby draws for nearby nu (no resampling jumps)."""
    lik, *_ = _t(rng, V=1, C=1, L=1, nu=(5.0,))
    z = jnp.asarray(rng.normal(size=(1, 1, 200, 4)))
    a = np.asarray(lik.at(0).sample(z))
    b = np.asarray(lik.at(0).shape_shifted(jnp.full((1, 1), 1e-4)).sample(z))
    assert np.max(np.abs(a - b)) < 1e-2 and np.max(np.abs(a - b)) > 0


def test_scaled_shape_shifted_and_the_calibration_form(rng, x64):
    lik, mu, s2, nu = _t(rng, V=1)
    one = lik.at(0)
    factor, shape = np.array([3.0, 0.7]), np.array([[0.4], [-0.3]])
    g = rng.normal(size=(5, 3)) * 1.5
    moved = one.scaled(jnp.asarray(factor)).shape_shifted(jnp.asarray(shape))
    got = np.asarray(moved.log_density(jnp.asarray(g)))
    terms = one.scaling_terms(jnp.asarray(g))
    fast = np.asarray(one.calibrated_log_density(terms, jnp.log(factor), jnp.asarray(shape)))
    plain = np.asarray(one.scaled_log_density(terms, jnp.log(factor)))
    new_nu = 2.0 + (nu[0] - 2.0) * np.exp(shape[:, 0])
    np.testing.assert_allclose(moved.nu, new_nu, rtol=1e-14)
    for c, l in np.ndindex(3, 2):
        want = multivariate_t(mu[0, c, l], factor[l] * np.diag(s2[0, c, l]), df=new_nu[l]).logpdf(g)
        np.testing.assert_allclose(got[:, c, l], want, rtol=1e-12)
        np.testing.assert_allclose(fast[:, c, l], want, rtol=1e-12)
        want = multivariate_t(mu[0, c, l], factor[l] * np.diag(s2[0, c, l]), df=nu[0, l]).logpdf(g)
        np.testing.assert_allclose(plain[:, c, l], want, rtol=1e-12)
    # scaled(f) multiplies the covariance by f (the interface's promise)
    np.testing.assert_allclose(one.scaled(jnp.asarray(factor)).covariance(),
                               np.asarray(one.covariance()) * factor[None, :, None, None], rtol=1e-13)


def test_fit_moment_matches_and_chooses_nu_on_held_out_samples(rng):
    c, k = 3, 4
    mean = rng.normal(size=(c, 2, k))
    var = rng.uniform(0.5, 2.0, size=(c, 2, k))
    floor = np.full((c, 2), 1e-6)
    # held-out samples: level 0 heavy tailed (t_3), level 1 Gaussian
    n = 400
    cls = np.tile(np.repeat(np.arange(c), n), 2)
    lev = np.repeat([0, 1], c * n)
    heavy = multivariate_t(np.zeros(k), np.eye(k), df=3.0).rvs(c * n, random_state=rng) / np.sqrt(3.0)
    light = rng.normal(size=(c * n, k))
    z = np.concatenate([heavy, light])
    g = mean[cls, lev] + np.sqrt(var[cls, lev]) * z
    assert K.StudentT.holdout_fraction() == 0.2 and K.StudentT.holdout_fraction(nu=5.0) == 0.0
    fit = K.StudentT.fit(mean, var, floor, holdout=(g, cls, lev))
    nu = np.asarray(fit.nu)
    assert nu[0] <= 4.0 and nu[1] >= 25.0 and set(nu) <= set(NU_GRID)
    np.testing.assert_allclose(np.asarray(fit.scale2) * (nu / (nu - 2))[None, :, None], var, rtol=1e-12)  # moment matched
    np.testing.assert_array_equal(K.StudentT.fit(mean, var, floor).nu, [25.0, 25.0])  # no held-out samples
    np.testing.assert_array_equal(K.StudentT.fit(mean, var, floor, nu=6).nu, [6.0, 6.0])
    for bad in (2.0, -1.0, "many", float("nan")):
        with pytest.raises(ValueError, match="nu must be 'auto' or a number > 2"):
            K.StudentT.fit(mean, var, floor, nu=bad)


def test_problems_name_the_field(rng):
    lik, mu, s2, nu = _t(rng)
    assert lik.problems() == []
    for bad, msg in [(0.0, "has non-positive degrees of freedom"),
                     (1.5, "has degrees of freedom <= 2 (no finite covariance)")]:
        n = nu.copy()
        n[1, 0] = bad
        assert K.StudentT(lik.mu, lik.scale2, jnp.asarray(n)).problems() == [("nu", msg)]
    s = s2.copy()
    s[0, 0, 0, 0] = 0.0
    assert K.StudentT(lik.mu, jnp.asarray(s), lik.nu).problems() == [("scale2", "has non-positive scales")]


def _beliefs(lik, g):
    """Posterior over classes of one feature vector (uniform prior, levels summed)."""
    ld = np.asarray(lik.at(0).log_density(jnp.asarray(g)), np.float64)   # [C, L]
    lc = np.logaddexp.reduce(ld, axis=-1)
    return np.exp(lc - np.logaddexp.reduce(lc))


def test_an_outlier_feature_does_not_drive_the_posterior_to_one():
    """Two classes 1 sd apart in dimension 0; the feature sits between them
    but 40 sd off in dimension 1 (an unmodelled deviation, e.g. an occluder
    edge), slightly nearer class 0 there.  The Gaussian is certain; the t
    (same covariance) stays undecided, as the evidence warrants."""
    k = 4
    mu = np.zeros((1, 2, 1, k), np.float32)
    mu[0, 1, 0, 0] = 1.0
    mu[0, 1, 0, 1] = 0.5                           # class 1 is 0.5 sd further in the outlier direction
    var = np.ones((1, 2, 1, k), np.float32)
    g = np.array([0.5, -40.0, 0.0, 0.0], np.float32)
    gauss = K.DiagonalGaussian(jnp.asarray(mu), jnp.asarray(var))
    nu = 5.0
    t = K.StudentT(jnp.asarray(mu), jnp.asarray(var * (nu - 2) / nu), jnp.full((1, 1), nu, jnp.float32))
    pg, pt = _beliefs(gauss, g), _beliefs(t, g)
    assert pg.max() > 1 - 1e-8                      # the Gaussian: p = 1.0 on 20 nats of "evidence"
    assert 0.5 < pt.max() < 0.7                     # the t: barely more than a coin flip
    # and nothing becomes NaN, however far out (float32)
    for far in (1e3, 1e6, 1e15):
        ld = np.asarray(t.at(0).log_density(jnp.asarray(g * far / 40.0)))
        assert np.all(np.isfinite(ld))
