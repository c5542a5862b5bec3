"""The shared view component (``Recognizer(shared_view=True)``,
``kernels/shared_latent.py``): a view mixture's component kept in the state,
one per trial for every camera and step, against a brute-force NumPy joint
over ``(c, m, k_0, k_1)``."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import jax.random as jr
import numpy as np
import pytest
from builders import env_and_recognizer_beliefs, make_database, odd_images, steps_stay_finite
from compiles import count_compiles
from scipy.special import logsumexp

from jaxrecog import ImageDatabase
from jaxrecog import kernels as K
from jaxrecog.features import project
from jaxrecog.planners import FixedPlanner, make_planner
from jaxrecog.recognizer import Recognizer
from jaxrecog.train import train_model

_SHIFTS = ((0, 3), (3, 0), (0, -3))


def _with_jitter(db: ImageDatabase) -> ImageDatabase:
    """``db`` plus three jitter images per training view (the training image
    rolled by each of ``_SHIFTS``: the same "turn" at every view)."""
    rows = np.flatnonzero(db.split == "train")
    extra = [(r, np.roll(db.images[r], s, axis=(0, 1))) for s in _SHIFTS for r in rows]
    cols = [np.concatenate([getattr(db, f), [getattr(db, f)[r] for r, _ in extra]])
            for f in ("camera", "position", "object", "pose")]
    return ImageDatabase.from_arrays(np.concatenate([db.images, np.stack([im for _, im in extra])]), *cols,
                                     np.concatenate([db.split, ["jitter"] * len(extra)]))


@pytest.fixture(scope="module")
def models():
    """Two cameras with 3 and 2 positions, 2 objects x 2 poses (C = 4), DB2,
    M = 4 components; a diagonal and a low-rank mixture and the thesis model."""
    db = make_database(positions=(3, 2), n_objects=2, n_poses=2, image_shape=(16, 20), n_test=1, view_offset=0.3)
    jdb = _with_jitter(db)
    kw = dict(kind="DB2", n_components=3, samples_per_image=10)
    return dict(
        db=db,
        mix=train_model(jdb, likelihood="view-mixture", view_jitter=True, **kw),
        low=train_model(jdb, likelihood="view-mixture-lowrank", likelihood_options={"rank": 2}, view_jitter=True, **kw),
        plain=train_model(db, likelihood="gaussian-diag", **kw),
    )


def _component_logpdf(lik, v, g):
    """``[C, L, M]`` log p_m(g | c, k, v) of a diagonal view mixture (SciPy-free
    closed form in float64), without the weights."""
    mu = np.asarray(lik.mu, np.float64)[v]                                  # [C, L, M, K]
    var = np.asarray(lik.var, np.float64)[v]
    d = np.asarray(g, np.float64) - mu
    return -0.5 * np.sum(d * d / var + np.log(2 * np.pi * var), axis=-1)


def test_extend_then_marginal_is_the_belief(rng, x64):
    C, M, L = 3, 4, 5
    lpc = np.log(rng.dirichlet(np.ones(C)))
    lpk = (np.log(rng.dirichlet(np.ones(L), size=C)), np.log(rng.dirichlet(np.ones(2), size=C)))
    log_pm = np.log(rng.dirichlet(np.ones(M), size=C))
    b = K.Belief(jnp.asarray(lpc), tuple(jnp.asarray(x) for x in lpk))
    x = K.shared_latent.extend(b, log_pm)
    assert x.log_pc.shape == (C * M,) and x.log_pk[0].shape == (C * M, L)
    np.testing.assert_allclose(x.log_pc.reshape(C, M), lpc[:, None] + log_pm, rtol=1e-12)
    back = K.shared_latent.marginal(x, M)
    assert isinstance(back, K.Belief)
    np.testing.assert_allclose(back.log_pc, lpc, atol=1e-12)
    for got, want in zip(back.log_pk, lpk):
        np.testing.assert_allclose(got, want, atol=1e-12)


def test_marginal_of_levels_that_depend_on_the_component(rng, x64):
    """``P_i(k | c) = sum_m P(m | c) P_i(k | c, m)``, also for the per-position
    ``[V, C * M, L]`` form, and a class of zero probability stays finite."""
    C, M, L, V = 2, 3, 4, 5
    pcm = rng.dirichlet(np.ones(C * M)).reshape(C, M)
    pcm[1] = 0.0
    pk = rng.dirichlet(np.ones(L), size=(V, C, M))                         # [V, C, M, L]
    with np.errstate(divide="ignore"):
        b = K.PredictedBelief(jnp.asarray(np.log(pcm).reshape(-1)), (jnp.asarray(np.log(pk).reshape(V, C * M, L)),))
    out = K.shared_latent.marginal(b, M)
    assert isinstance(out, K.PredictedBelief)  # the form is kept
    assert np.all(np.isfinite(np.asarray(out.log_pk[0])))
    np.testing.assert_allclose(np.exp(out.log_pc), pcm.sum(1), atol=1e-12)
    want = np.einsum("cm,vcml->vcl", pcm[:1] / pcm[:1].sum(1, keepdims=True), pk[:, :1])
    np.testing.assert_allclose(np.exp(np.asarray(out.log_pk[0]))[:, :1], want, atol=1e-12)


def test_a_model_without_view_components_is_refused(models):
    with pytest.raises(ValueError, match="no view components"):
        Recognizer(models["plain"], FixedPlanner(6, 0), shared_view=True)
    assert Recognizer(models["mix"], FixedPlanner(6, 0), shared_view=True).n_view_components == 4


def test_the_belief_is_the_brute_force_joint_over_the_shared_component(models, x64):
    """Four steps (moves and stays, chosen by the planner) on off-grid test
    images: the recognizer's class probabilities against the full joint
    P(c, m, k_0, k_1) updated with one component m for both cameras and all
    steps, and the uniform level transition of the cameras that moved; and
    they differ from the per-capture mixture's (the component matters)."""
    model, db = models["mix"], models["db"]
    lik = [cam.likelihood for cam in model.cameras]
    C, L, M = 4, len(model.levels), 4
    rec = Recognizer(model, make_planner("mi-class-pairwise", model, key=jr.PRNGKey(0)), max_steps=9, shared_view=True)
    key = jr.PRNGKey(3)
    state = rec.init(config=(0, 0))
    joint = np.full((C, M, L, L), 1.0 / (C * M * L * L))
    prev, configs = None, []
    truth = (1, 0)                                                           # object 1, pose 0
    for t in range(4):
        config = tuple(int(v) for v in state.config)
        configs.append(config)
        if prev is not None:
            for i in range(2):
                if config[i] != prev[i]:
                    joint = joint.sum(axis=2 + i, keepdims=True) / L * np.ones_like(joint)
        images = []
        for i in range(2):
            (row,) = np.flatnonzero((db.split == "test") & (db.camera == i) & (db.position == config[i])
                                    & (db.object == truth[0]) & (db.pose == truth[1]))
            images.append(db.images[row])
        images = np.stack(images)
        l0 = _component_logpdf(lik[0], config[0], project(model, 0, config[0], images[0]))   # [C, L, M]
        l1 = _component_logpdf(lik[1], config[1], project(model, 1, config[1], images[1]))
        log_j = np.log(joint) + np.transpose(l0, (0, 2, 1))[:, :, :, None] + np.transpose(l1, (0, 2, 1))[:, :, None, :]
        joint = np.exp(log_j - logsumexp(log_j))
        if t == 0:
            first = images
        state, dec = rec.step(state, jnp.asarray(images), jr.fold_in(key, t), trace=True)
        np.testing.assert_allclose(np.asarray(dec.trace.class_probs), joint.sum(axis=(1, 2, 3)), atol=2e-6)
        assert 0.0 <= float(dec.probability) <= 1.0
        assert np.all(np.isfinite(np.asarray(dec.trace.scores)))
        prev = config
    assert any(a[i] == b[i] for a, b in zip(configs, configs[1:]) for i in range(2)), configs   # a stay was tested
    # the per-capture mixture (m marginalised per image) gives another belief from the first images
    per_capture = Recognizer(model, make_planner("mi-class-pairwise", model, key=jr.PRNGKey(0)), max_steps=9)
    _, dec0 = per_capture.step(per_capture.init(config=(0, 0)), jnp.asarray(first), key, trace=True)
    _, dec1 = rec.step(rec.init(config=(0, 0)), jnp.asarray(first), key, trace=True)
    assert np.abs(np.asarray(dec0.trace.class_probs) - np.asarray(dec1.trace.class_probs)).max() > 1e-3


@pytest.mark.parametrize("name", ["mix", "low"])
def test_steps_stay_finite_and_do_not_recompile(models, name):
    model, db = models[name], models["db"]
    rec = Recognizer(model, make_planner("mi-class-pairwise", model, key=jr.PRNGKey(0)), max_steps=50, shared_view=True)
    key = jr.PRNGKey(0)
    state = rec.init(config=(1, 1))
    rows = [np.flatnonzero((db.split == "test") & (db.camera == i) & (db.position == 1)
                           & (db.object == 0) & (db.pose == 1))[0] for i in range(2)]
    view = np.stack([db.images[r] for r in rows])
    state, dec = steps_stay_finite(rec, state, [view, odd_images(view)], key)
    jax.block_until_ready(dec)
    with count_compiles() as later:
        state, dec = steps_stay_finite(rec, state, [view, odd_images(view), view], jr.fold_in(key, 9))
    assert sum(later.values()) == 0, dict(later)
    # a NaN image set leaves the (extended) class belief as it was
    new, bad = rec.step(state, jnp.full(view.shape, jnp.nan), key)
    assert not bool(bad.valid)
    np.testing.assert_array_equal(np.asarray(new.prior.log_pc), np.asarray(state.prior.log_pc))


def test_the_env_keeps_the_shared_view_component(models):
    """One belief update for env and recognizer: with ``settings.shared_view``
    the env's belief is the recognizer's over (c, m, k) (it marginalised m per capture), over an
    episode of two image sets from both cameras."""
    pytest.importorskip("gymnasium")
    from jaxrecog.campaigns import Settings
    from jaxrecog.envs import ActiveRecognitionEnv
    from jaxrecog.hardware import DatasetRig

    def beliefs(shared: bool):
        env = ActiveRecognitionEnv(models["mix"], DatasetRig(models["db"], seed=0),
                                   settings=Settings(samples=64, min_per_stratum=2, shared_view=True))
        return env_and_recognizer_beliefs(env, Recognizer(models["mix"], FixedPlanner(1), shared_view=shared), seed=5)

    got, want = beliefs(True)
    np.testing.assert_allclose(got, want, atol=1e-5)
    _, per_capture = beliefs(False)
    assert np.abs(per_capture - want).max() > 1e-3  # the component in the state changes the belief
