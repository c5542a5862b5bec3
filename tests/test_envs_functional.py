"""The functional (gymnax-style) form: the recognizer's belief on the same
features, pure under jit and vmap, auto-reset, and its feature banks."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import jax.random as jr
import numpy as np
import pytest

from jaxrecog import train_model
from jaxrecog.envs import FunctionalEnv, bank_from_database
from jaxrecog.hardware import DatasetRig
from jaxrecog.planners import make_planner
from jaxrecog.recognizer import Recognizer
from builders import make_database


@pytest.fixture(scope="module")
def small():
    """Two cameras x 3 positions, 3 objects x 2 poses, one test image per view
    (so a bank of S = 1 holds exactly the images the rig replays)."""
    db = make_database(positions=(3, 3), n_objects=3, n_poses=2, image_shape=(24, 32), n_test=1, seed=1)
    return db, train_model(db, kind="DB2", n_components=3, samples_per_image=10)


def _washed_out(db):
    """``db`` with its test images washed out and noisy: captures no class
    explains at the model's own spread (the adaptive scale's case)."""
    rng = np.random.default_rng(3)
    test = db.split == "test"
    images = db.images.astype(np.float32)
    images[test] = 0.5 * images[test] + 90.0 + rng.normal(0.0, 12.0, images[test].shape)
    return dataclasses.replace(db, images=np.clip(images, 0, 255).astype(np.uint8))


@pytest.mark.parametrize("adaptive_scale", [1.0, 8.0])
def test_the_functional_belief_is_the_recognizers_on_the_same_features(small, adaptive_scale):
    db, model = small
    if adaptive_scale > 1:
        db = _washed_out(db)
    bank = bank_from_database(model, db)
    assert bank.samples == 1 and bank.features[0].shape == (3, 6, 1, 3)
    env = FunctionalEnv(model, bank, p_threshold=1.0, max_steps=5, adaptive_scale=adaptive_scale)
    if adaptive_scale > 1:  # the captures are unexplained: the scaled evidence is not the plain one
        plain = FunctionalEnv(model, bank, p_threshold=1.0, max_steps=5)
        assert not np.allclose(env.tables[0], plain.tables[0], rtol=1e-3)
    rec = Recognizer(model, make_planner("mi", model, key=jr.PRNGKey(0), samples=64), p_threshold=1.0, max_steps=5,
                     adaptive_scale=adaptive_scale)
    rig = DatasetRig(db)
    for obj, pose, start in [(0, 1, (0, 2)), (2, 0, (1, 1)), (1, 1, (2, 0))]:
        target = obj * 2 + pose
        state, obs = env.init(target, jnp.asarray(start), jr.PRNGKey(1))
        rstate = rec.init(config=start)
        rig.reset(obj, pose)
        for n in range(4):
            rig.move(tuple(int(v) for v in rstate.config))
            rstate, dec = rec.step(rstate, rig.capture().images, jr.PRNGKey(n), trace=True)
            # the bank's features and the step's host projection agree to float32 rounding
            np.testing.assert_allclose(obs["belief"], dec.trace.class_probs, rtol=1e-4, atol=1e-6)
            for lp_env, lp_rec in zip(state.belief.log_pk, dec.trace.posterior.log_pk):
                np.testing.assert_allclose(jnp.exp(lp_env), jnp.exp(lp_rec), rtol=1e-4, atol=1e-6)
            # follow the recognizer's choice; a prediction that never declares
            state, obs, reward, done, info = env.step(
                state, {"action": dec.next_index, "prediction": jnp.zeros(6)}, jr.PRNGKey(10 + n))
            assert not bool(done) and int(obs["views"]) == n + 2
        # the belief is not trivially uniform: the recognizer learned something
        assert float(jnp.max(dec.trace.class_probs)) > (0.5 if adaptive_scale == 1 else 1 / 6)


def test_step_reward_loss_and_auto_reset(small):
    db, model = small
    env = FunctionalEnv(model, bank_from_database(model, db), max_steps=3, step_cost=0.25)
    state, obs = env.init(4, jnp.asarray((0, 0)), jr.PRNGKey(0))
    blind = {"action": jnp.asarray(1), "prediction": jnp.full(6, 0.3)}
    state, obs, reward, done, info = env.step(state, blind, jr.PRNGKey(1))
    np.testing.assert_allclose(info["prediction"]["loss"], 1.0, rtol=1e-6)  # -log(1/6)/log 6
    np.testing.assert_allclose(reward, -1.25, rtol=1e-6)
    assert int(obs["configuration"]) == 1 and not bool(done)
    state, obs, reward, done, info = env.step(state, blind, jr.PRNGKey(2))
    state, obs, reward, done, info = env.step(state, blind, jr.PRNGKey(3))
    assert bool(done) and bool(info["truncated"]) and int(info["views"]) == 3
    assert int(obs["views"]) == 1  # a fresh episode
    sure = {"action": jnp.asarray(0), "prediction": jax.nn.one_hot(state.target, 6)}
    _, obs, reward, done, info = env.step(state, sure, jr.PRNGKey(4))
    assert bool(done) and bool(info["declared"]) and bool(info["correct"])
    np.testing.assert_allclose(info["prediction"]["loss"], 0.0, atol=1e-6)
    # the episode rule: a wrong declaration at the first view stands for all 3 steps
    state, obs = env.init(4, jnp.asarray((0, 0)), jr.PRNGKey(5))
    wrong = {"action": jnp.asarray(0), "prediction": jax.nn.one_hot(5, 6)}
    _, _, reward, done, info = env.step(state, wrong, jr.PRNGKey(6))
    assert bool(done) and bool(info["declared"]) and int(info["prediction"]["steps"]) == 3
    np.testing.assert_allclose(reward, -0.25 - 3 * np.log(1e12) / np.log(6), rtol=1e-5)


def test_pure_under_jit_and_vmap(small):
    db, model = small
    env = FunctionalEnv(model, bank_from_database(model, db))
    keys = jr.split(jr.PRNGKey(0), 8)
    states, obs = jax.vmap(env.reset)(keys)
    one_state, one_obs = env.reset(keys[3])
    np.testing.assert_allclose(obs["belief"][3], one_obs["belief"], rtol=1e-6)
    acts = {"action": jnp.arange(8) % 9, "prediction": jnp.zeros((8, 6))}
    vstep = jax.jit(jax.vmap(env.step))
    s2, o2, r2, d2, i2 = vstep(states, acts, keys)
    s1, o1, r1, d1, i1 = env.step(one_state, {"action": jnp.asarray(3), "prediction": jnp.zeros(6)}, keys[3])
    np.testing.assert_allclose(o2["belief"][3], o1["belief"], rtol=1e-5, atol=1e-7)
    assert float(r2[3]) == pytest.approx(float(r1), rel=1e-6)
    assert o2["belief"].shape == (8, 6) and np.all(np.isfinite(r2))
    # a rollout under lax.scan: beliefs stay normalised, no NaN
    def body(carry, key):
        s, o = carry
        a = {"action": jr.randint(key, (8,), 0, 9), "prediction": o["belief"]}
        s, o, r, d, _ = jax.vmap(env.step)(s, a, jr.split(key, 8))
        return (s, o), (r, d)
    (_, last), (rewards, dones) = jax.lax.scan(body, (states, obs), jr.split(jr.PRNGKey(5), 20))
    assert np.all(np.isfinite(rewards)) and bool(jnp.any(dones))
    np.testing.assert_allclose(last["belief"].sum(axis=1), 1.0, rtol=1e-5)


def test_bank_checks(small):
    db, model = small
    with pytest.raises(ValueError, match="no usable image of camera 0, position 0, class 0"):
        bank_from_database(model, db, split="nope")
    bank = bank_from_database(model, db)
    wrong = type(bank)(tuple(f[:2] for f in bank.features))
    with pytest.raises(ValueError, match="do not fit"):
        FunctionalEnv(model, wrong)
    with pytest.raises(ValueError, match="adaptive_scale must be a finite number >= 1"):
        FunctionalEnv(model, bank, adaptive_scale=0.5)
