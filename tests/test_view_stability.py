"""View instability (kernels/view_stability.py) against NumPy, and the planner
``mi-class-pairwise-stable`` built on it."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from builders import random_sensor_model
from compiles import assert_steps_never_recompile

from jaxrecog import kernels as K
from jaxrecog.kernels.view_stability import expected_instability, view_instability
from jaxrecog.planners import PLANNERS, StableViewMIPlanner, TemperedPairwiseMIPlanner, make_planner
from jaxrecog.recipes import ROBUST
from jaxrecog.recognizer import Recognizer


def _mixture_model(positions=(4, 3), m=3, seed=0):
    """random_sensor_model with each camera's Gaussian turned into a view
    mixture of ``m`` components spread around the training view's mean."""
    model = random_sensor_model(positions)
    rng = np.random.default_rng(seed)
    cams = []
    for cam in model.cameras:
        mu = np.asarray(cam.likelihood.mu)[:, :, :, None, :]
        spread = rng.uniform(0.0, 0.5, size=mu.shape[:3] + (1, 1))
        mus = np.concatenate([mu, mu + spread * rng.normal(size=mu.shape[:3] + (m - 1, mu.shape[-1]))], axis=3)
        var = np.repeat(np.asarray(cam.likelihood.var)[:, :, :, None, :], m, axis=3)
        lik = K.ViewMixture(jnp.asarray(mus, jnp.float32), jnp.asarray(var), jnp.full(mus.shape[:4], -np.log(m), jnp.float32))
        cams.append(eqx.tree_at(lambda c: c.likelihood, cam, lik))
    return eqx.tree_at(lambda md: md.cameras, model, tuple(cams))


def test_instability_matches_numpy_and_is_zero_without_view_components():
    model = _mixture_model()
    for cam in model.cameras:
        mu = np.asarray(cam.likelihood.mu, np.float64)[:, :, 0]
        d = np.linalg.norm(mu[:, :, 1:] - mu[:, :, :1], axis=-1).max(-1)
        np.testing.assert_allclose(np.asarray(view_instability(cam.likelihood)), d / d.mean(), rtol=1e-5)
    diag = random_sensor_model((4, 3)).cameras[0].likelihood
    assert np.all(np.asarray(view_instability(diag)) == 0.0)
    # the low-rank mixture's component means are read the same way
    mix = model.cameras[0].likelihood
    v, c, l, m, k = mix.mu.shape
    lowrank = K.LowRankViewMixture(mix.mu, jnp.zeros((v, c, l, m, k, 1), jnp.float32), mix.var, mix.log_w)
    np.testing.assert_allclose(np.asarray(view_instability(lowrank)), np.asarray(view_instability(mix)), rtol=1e-6)


def test_expected_instability_is_the_brute_force_sum_over_cameras_row_major():
    rng = np.random.default_rng(1)
    d = (rng.uniform(size=(4, 6)), rng.uniform(size=(3, 6)), rng.uniform(size=(2, 6)))
    p = rng.dirichlet(np.ones(6))
    got = np.asarray(expected_instability(tuple(jnp.asarray(x) for x in d), jnp.log(jnp.asarray(p))))
    want = [sum(d[i][cfg[i]] @ p for i in range(3)) for cfg in np.ndindex(4, 3, 2)]
    np.testing.assert_allclose(got, want, rtol=1e-6)


def test_planner_is_the_robust_score_minus_the_weighted_expected_instability(getkey):
    model = _mixture_model()
    prior = K.at_every_position(K.uniform_belief(model.n_classes, tuple(len(model.levels) for _ in model.positions)),
                                model.positions)
    prior = prior._replace(log_pc=jax.nn.log_softmax(jnp.arange(model.n_classes, dtype=prior.log_pc.dtype)))
    robust = make_planner("mi-class-pairwise-robust", model, key=getkey(), temper=1.0)
    assert make_planner("mi-class-pairwise-stable", model, key=getkey()).temper == 1.0   # the plain belief by default
    for lam in (0.0, 1.0, 2.5):
        p = make_planner("mi-class-pairwise-stable", model, key=getkey(), stability=lam)
        assert isinstance(p, StableViewMIPlanner) and isinstance(p, TemperedPairwiseMIPlanner)
        inst = tuple(view_instability(lik) for lik in model.likelihoods)
        want = np.asarray(robust.scores(prior, getkey())) - lam * np.asarray(expected_instability(inst, prior.log_pc))
        np.testing.assert_allclose(np.asarray(p.scores(prior, getkey())), want, rtol=1e-5, atol=1e-6)
    # without view components it is the robust planner
    diag = random_sensor_model()
    np.testing.assert_allclose(np.asarray(make_planner("mi-class-pairwise-stable", diag, key=getkey()).scores(prior, getkey())),
                               np.asarray(make_planner("mi-class-pairwise-robust", diag, key=getkey(), temper=1.0)
                                          .scores(prior, getkey())))
    for bad in (-1.0, float("inf"), True):
        with pytest.raises(ValueError, match="stability must be a finite number >= 0"):
            make_planner("mi-class-pairwise-stable", model, key=getkey(), stability=bad)
    assert ROBUST.planner == "mi-class-pairwise-stable" and "mi-class-pairwise-stable" in PLANNERS


def test_runs_in_the_recognizer_with_the_adaptive_scale_without_recompiling(getkey):
    model = _mixture_model()
    rec = Recognizer(model, make_planner("mi-class-pairwise-stable", model, key=getkey()), p_threshold=0.96781,
                     min_views=2, exclude_visited_positions=True, adaptive_scale=32.0)
    assert_steps_never_recompile(rec, getkey, n_configs=12)


def test_component_offsets_at_rounding_level_are_no_instability():
    """A position without neighbouring views (camera 1 here has one) repeats
    its training view in every interpolated slot; the slots' fitted means then
    differ from the training view's only by float32 rounding, and how BLAS
    rounds the same image at different rows of a product depends on its kernel
    and the CPU.  ``d`` is 0 there either way, not rounding normalised to mean 1
    (which moved the planner's score of every configuration by the same 1.0)."""
    model = _mixture_model(positions=(4, 1))
    lik = model.cameras[1].likelihood
    exact = np.repeat(np.asarray(lik.mu)[:, :, :, :1], lik.mu.shape[3], axis=3)
    rounded = exact.copy()
    rounded[:, :, :, 1:] = np.nextafter(np.nextafter(exact[:, :, :, 1:], np.inf), np.inf)   # two ulps off
    assert np.any(rounded != exact)
    d0 = view_instability(model.cameras[0].likelihood)
    uniform = jnp.zeros(model.n_classes, jnp.float32)
    for mu in (exact, rounded):
        d1 = view_instability(eqx.tree_at(lambda x: x.mu, lik, jnp.asarray(mu)))
        assert np.all(np.asarray(d1) == 0.0)
        np.testing.assert_allclose(np.asarray(expected_instability((d0, d1), uniform)),
                                   np.asarray(d0).mean(axis=1), rtol=1e-6)
