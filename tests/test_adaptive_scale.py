"""The adaptive scale (kernels/adaptive_scale.py): the profile over a shared
per-capture variance factor against a NumPy reference, the thesis's evidence
kept for an explained capture, and the recognizer's stop rule counting only
explained image sets."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from builders import random_sensor_model
from compiles import assert_steps_never_recompile
from scipy.special import logsumexp
from test_recognizer import separated_model

from jaxrecog import kernels as K
from jaxrecog.kernels.adaptive_scale import EXPLAINED_SCALE, adaptive_log_density, scale_grid
from jaxrecog.planners import RandomPlanner
from jaxrecog.recognizer import Recognizer


def test_scale_grid():
    assert scale_grid(1) == (1.0,)
    g = scale_grid(32)
    assert len(g) == 11 and g[0] == 1.0 and g[1] == pytest.approx(math.sqrt(2)) and g[-1] == pytest.approx(32.0)
    assert scale_grid(3.0)[-1] == pytest.approx(2 * math.sqrt(2))
    for bad in (0.5, math.inf, math.nan, -1):
        with pytest.raises(ValueError, match="adaptive_scale must be a finite number >= 1"):
            scale_grid(bad)


def _reference(mu, var, log_w, g, scales):
    """NumPy: ll_s[c, k] = logsumexp_m (log w - ½ Σ_d [(g - μ)² / (s v) + log(2π s v)]);
    s* = argmax_s max_{c,k} ll_s."""
    lls = []
    for s in scales:
        comp = -0.5 * np.sum((g - mu) ** 2 / (s * var) + np.log(2 * np.pi * s * var), axis=-1)   # [C, L, M]
        lls.append(logsumexp(comp + log_w, axis=-1))
    lls = np.stack(lls)
    j = int(np.argmax(lls.reshape(len(scales), -1).max(1)))
    return lls[j], scales[j]


@pytest.mark.parametrize("family", ["gaussian-diag", "view-mixture"])
@pytest.mark.parametrize("offset", [0.0, 0.7, 3.0, 20.0])
def test_profile_matches_numpy(family, offset):
    """Captures ever farther from every class: s* climbs the grid, and the
    densities at s* are the reference's."""
    rng = np.random.default_rng(3)
    V, C, L, M, D = 2, 5, 2, 3 if family == "view-mixture" else 1, 4
    mu = rng.normal(size=(V, C, L, M, D)).astype(np.float32)
    var = rng.uniform(0.05, 0.2, size=(V, C, L, M, D)).astype(np.float32)
    log_w = np.log(rng.dirichlet(np.ones(M), size=(V, C, L))).astype(np.float32)
    if family == "view-mixture":
        lik = K.ViewMixture(mu=jnp.asarray(mu), var=jnp.asarray(var), log_w=jnp.asarray(log_w))
    else:
        lik = K.DiagonalGaussian(jnp.asarray(mu[..., 0, :]), jnp.asarray(var[..., 0, :]))
        log_w = np.zeros((V, C, L, 1), np.float32)
    scales = scale_grid(64)
    g = (mu[1, 2, 1, 0] + offset * rng.normal(size=D)).astype(np.float32)
    ll, s = jax.jit(adaptive_log_density, static_argnums=2)(lik.at(1), jnp.asarray(g), scales)
    want_ll, want_s = _reference(mu[1].astype(np.float64), var[1].astype(np.float64), log_w[1], g.astype(np.float64), scales)
    assert float(s) == pytest.approx(want_s, rel=1e-6)
    np.testing.assert_allclose(np.asarray(ll), want_ll, rtol=2e-5, atol=2e-3)
    if offset == 0.0:      # a capture on a class's mean: the thesis's evidence, exactly
        assert float(s) == 1.0
        np.testing.assert_allclose(np.asarray(ll), np.asarray(lik.at(1).log_density(jnp.asarray(g))), rtol=1e-6)
    if offset == 20.0:
        assert float(s) > 8 * EXPLAINED_SCALE


def test_off_is_the_thesis_step_bit_for_bit(getkey):
    model, images = separated_model(llr=5.0)
    a, b = Recognizer(model, RandomPlanner(3)), Recognizer(model, RandomPlanner(3), adaptive_scale=1.0)
    sa, sb = a.init(config=(1,)), b.init(config=(1,))
    for v in (1, 0, 2):
        k = getkey()
        sa, da = a.step(sa, images[v, 1][None], k)
        sb, db = b.step(sb, images[v, 1][None], k)
        assert float(da.probability) == float(db.probability) and bool(da.stop) == bool(db.stop)


def test_only_explained_image_sets_count_toward_min_views(getkey):
    """An explained capture (features on a class mean) keeps the thesis's
    evidence and stops at once; a capture far from every class is weakened and,
    even where its weakened evidence reaches P_th, no stop follows until an
    explained image set comes."""
    model, images = separated_model(llr=5.0)
    rec = Recognizer(model, RandomPlanner(3), adaptive_scale=32.0)
    thesis = Recognizer(model, RandomPlanner(3))
    state = rec.init(config=(1,))
    s1, d1 = rec.step(state, images[1, 1][None], getkey())
    _, dt = thesis.step(thesis.init(config=(1,)), images[1, 1][None], getkey())
    assert float(d1.probability) == pytest.approx(float(dt.probability), rel=1e-6)
    assert bool(d1.stop) and int(s1.explained) == 1
    # an image far from both classes (its features beyond the class means' spread)
    far = np.clip(images[1, 1].astype(np.int32) * 0 + np.arange(48).reshape(6, 8) * 5, 1, 255).astype(np.uint8)
    rec_low = Recognizer(model, RandomPlanner(3), adaptive_scale=32.0, p_threshold=0.5)
    s, d = rec_low.step(rec_low.init(config=(1,)), far[None], getkey())
    assert bool(d.valid) and bool(d.reached) and not bool(d.stop) and int(s.explained) == 0
    s, d = rec_low.step(s, images[int(s.config[0]), int(d.object)][None], getkey())
    assert bool(d.stop) and int(s.explained) == 1 and int(s.steps) == 2
    # the thesis on the same far image stops at once
    _, d = Recognizer(model, RandomPlanner(3), p_threshold=0.5).step(thesis.init(config=(1,)), far[None], getkey())
    assert bool(d.stop)


def test_bad_values_and_combinations_are_refused():
    model = random_sensor_model()
    with pytest.raises(ValueError, match="adaptive_scale must be a finite number >= 1"):
        Recognizer(model, RandomPlanner(12), adaptive_scale=0.5)


def test_steps_never_recompile(getkey):
    model = random_sensor_model()
    rec = Recognizer(model, RandomPlanner(12), adaptive_scale=16.0, min_views=2, p_threshold=0.9312)
    assert_steps_never_recompile(rec, getkey, 12)


def test_an_image_set_is_explained_when_some_camera_explains_its_capture():
    rng = np.random.default_rng(5)
    mu = rng.normal(size=(2, 3, 1, 4)).astype(np.float32)
    lik = K.DiagonalGaussian(jnp.asarray(mu), jnp.full(mu.shape, 0.01, jnp.float32))
    near, far = jnp.asarray(mu[0, 1, 0]), jnp.asarray(mu[0, 1, 0] + 5.0)
    f = jax.jit(K.adaptive_scale.adaptive_camera_log_likelihoods, static_argnums=3)
    for gs, want in (((near, near), True), ((near, far), True), ((far, near), True), ((far, far), False)):
        _, ok = f(gs, jnp.zeros(2, jnp.int32), (lik, lik), scale_grid(32))
        assert bool(ok) == want
