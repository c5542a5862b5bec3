"""Likelihood kernels against the NumPy reference (eq. 4.17-4.22)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from kernel_models import random_chols, random_model
from oracles import log_likelihood_full_ref, log_likelihood_ref

from jaxrecog.kernels import camera_log_likelihoods, gaussian_likelihoods, log_likelihood, log_likelihood_full

pytestmark = pytest.mark.usefixtures("strict_dtype_promotion")  # numerics: no implicit promotion


def test_diagonal_matches_reference(rng, x64):
    mus, vars = random_model(rng, n_classes=5, levels=(3,), positions=(2,), dims=(4,))
    g = rng.normal(size=4)
    out = log_likelihood(jnp.asarray(g), jnp.asarray(mus[0][1]), jnp.asarray(vars[0][1]))
    np.testing.assert_allclose(out, log_likelihood_ref(g, mus[0][1], vars[0][1]), rtol=1e-12, atol=1e-12)


def test_full_matches_reference_and_diagonal_special_case(rng, x64):
    chols = random_chols(rng, 4, (2,), (1,), (3,))[0][0]
    mu = rng.normal(size=(4, 2, 3))
    g = rng.normal(size=3)
    out = log_likelihood_full(jnp.asarray(g), jnp.asarray(mu), jnp.asarray(chols))
    np.testing.assert_allclose(out, log_likelihood_full_ref(g, mu, chols), rtol=1e-12, atol=1e-12)
    # a diagonal Cholesky factor must reproduce the diagonal kernel
    var = rng.uniform(0.2, 2.0, size=(4, 2, 3))
    diag_chol = np.sqrt(var)[..., None] * np.eye(3)
    np.testing.assert_allclose(
        log_likelihood_full(jnp.asarray(g), jnp.asarray(mu), jnp.asarray(diag_chol)),
        log_likelihood(jnp.asarray(g), jnp.asarray(mu), jnp.asarray(var)),
        rtol=1e-12,
    )


def test_full_against_scipy_density(rng, x64):
    from scipy.stats import multivariate_normal

    chol = random_chols(rng, 1, (1,), (1,), (3,))[0][0]
    mu = rng.normal(size=(1, 1, 3))
    g = rng.normal(size=3)
    want = multivariate_normal(mu[0, 0], chol[0, 0] @ chol[0, 0].T).logpdf(g)
    got = log_likelihood_full(jnp.asarray(g), jnp.asarray(mu), jnp.asarray(chol))
    np.testing.assert_allclose(got[0, 0], want, rtol=1e-12)


def test_camera_log_likelihoods_select_position_and_sum_is_eq_4_17(rng, x64):
    mus, vars = random_model(rng)
    gs = tuple(jnp.asarray(rng.normal(size=m.shape[-1])) for m in mus)
    cfg = jnp.array([2, 1])
    lls = jax.jit(camera_log_likelihoods)(gs, cfg, gaussian_likelihoods(tuple(map(jnp.asarray, mus)), tuple(map(jnp.asarray, vars))))
    for i in range(2):
        np.testing.assert_allclose(
            lls[i], log_likelihood_ref(np.asarray(gs[i]), mus[i][int(cfg[i])], vars[i][int(cfg[i])]), rtol=1e-12
        )


def test_camera_log_likelihoods_rejects_bad_arguments(rng):
    mus, vars = random_model(rng)
    gs = (jnp.zeros(3),)
    with pytest.raises(ValueError, match="feature vectors"):
        camera_log_likelihoods(gs, (0, 0), gaussian_likelihoods(mus, vars))
    with pytest.raises(TypeError, match="one Likelihood per camera"):  # the arrays: one input form, likelihoods
        camera_log_likelihoods(gs, (0, 0), mus)
