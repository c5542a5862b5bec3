"""The tempered pairwise-MI planner (``mi-class-pairwise-robust``):
the kernel against a NumPy brute force, its limits, and the jitted planner
inside the recognizer compiles once."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from builders import random_sensor_model
from compiles import assert_steps_never_recompile
from kernel_models import as_jax, everywhere, gaussians, random_belief, random_model
from oracles import pairwise_mi_ref

from jaxrecog import kernels as K
from jaxrecog.kernels import tempered_mi
from jaxrecog.planners import PLANNERS, PairwiseMIPlanner, TemperedPairwiseMIPlanner, make_planner
from jaxrecog.recognizer import Recognizer

PT = jax.jit(K.pairwise_tables, static_argnames=("kind",))
TMI = jax.jit(tempered_mi.tempered_pairwise_mutual_information, static_argnames=("tau", "target", "levels", "fast"))


def _covs(vars):
    return tuple(v[..., None] * np.eye(v.shape[-1]) for v in vars)


def tempered_ref(log_pc, tau):
    """NumPy: log P_tau(c) = tau log P(c) - log sum_c' P(c')^tau (tau = 0: uniform)."""
    log_pc = np.asarray(log_pc, np.float64)
    t = np.zeros_like(log_pc) if tau == 0 else tau * log_pc
    return t - np.logaddexp.reduce(t)


@pytest.mark.parametrize("tau", [0.0, 0.3, 1.0])
@pytest.mark.parametrize("target", ["state", "class"])
def test_matches_brute_force_reference(rng, x64, tau, target):
    levels, positions, dims = (2, 3), (3, 2), (3, 2)
    mus, vars = random_model(rng, 4, levels, positions, dims, spread=1.5)
    b = random_belief(rng, 4, levels, concentration=0.3)   # a concentrated belief
    rows = [np.stack([random_belief(rng, 4, levels).log_pk[i] for _ in range(v)]) for i, v in enumerate(positions)]
    tables = PT(gaussians(mus, vars), kind="bhattacharyya")
    mi = np.asarray(TMI(tables, K.PredictedBelief(jnp.asarray(b.log_pc), as_jax(rows)), tau, target))
    lpc = tempered_ref(b.log_pc, tau)
    for a, cfg in enumerate(np.ndindex(*positions)):
        single = K.PredictedBelief(jnp.asarray(lpc), as_jax(rows)).at(cfg)
        lj = np.asarray(K.log_joint(single))
        sub = tuple(m[v:v + 1] for m, v in zip(mus, cfg))
        ref = pairwise_mi_ref(sub, tuple(c[v:v + 1] for c, v in zip(_covs(vars), cfg)), lj, "bhattacharyya", target)
        np.testing.assert_allclose(mi[a], ref[0], rtol=1e-10, atol=1e-12)


def test_tempered_belief_limits(x64):
    lpc = np.array([np.log(0.9), np.log(0.1), np.log(1e-300), -np.inf])  # one class of probability 0
    b = K.PredictedBelief(jnp.asarray(lpc), (jnp.zeros((2, 4, 1)),))
    u = tempered_mi.tempered_belief(b, 0.0)
    np.testing.assert_allclose(np.asarray(u.log_pc), np.full(4, -np.log(4)), rtol=0, atol=1e-15)
    assert tempered_mi.tempered_belief(b, 1.0) is b
    half = np.asarray(tempered_mi.tempered_belief(b, 0.5).log_pc)
    np.testing.assert_allclose(half, tempered_ref(lpc, 0.5), rtol=1e-12)
    assert half[3] == -np.inf and np.isfinite(half[:3]).all()
    assert u.log_pk is b.log_pk and isinstance(u, K.PredictedBelief)
    for bad in (-0.1, 1.5, "x", None):
        with pytest.raises(ValueError, match="temper"):
            tempered_mi.check_temper(bad)


def test_uniform_limit_is_belief_free(rng, x64):
    """temper = 0: the same scores for every class belief (the levels' rows fixed)."""
    mus, vars = random_model(rng, 4, (2,), (5,), (3,), spread=1.5)
    tables = PT(gaussians(mus, vars), kind="bhattacharyya")
    rows = (jnp.asarray(random_belief(rng, 4, (2,)).log_pk[0]),)
    outs = [np.asarray(TMI(tables, everywhere(K.Belief(jnp.asarray(random_belief(rng, 4, (2,), 0.2).log_pc), rows), (5,)),
                           0.0, "class"))
            for _ in range(3)]
    np.testing.assert_allclose(outs[0], outs[1], rtol=1e-12)
    np.testing.assert_allclose(outs[0], outs[2], rtol=1e-12)
    uniform = everywhere(K.Belief(jnp.full(4, -np.log(4)), rows), (5,))
    np.testing.assert_allclose(outs[0], np.asarray(K.pairwise_mutual_information(tables, uniform, "class")), rtol=1e-12)


def test_registry_and_options(getkey):
    model = random_sensor_model()
    p = make_planner("mi-class-pairwise-robust", model, key=getkey())
    assert isinstance(p, TemperedPairwiseMIPlanner) and p.temper == 0.0 and p.target == "class"
    assert "mi-class-pairwise-robust" in PLANNERS
    one = make_planner("mi-class-pairwise-robust", model, key=getkey(), temper=1.0)
    plain = PairwiseMIPlanner.from_model(model, target="class")
    prior = everywhere(K.uniform_belief(model.n_classes, tuple(len(model.levels) for _ in model.positions)), model.positions)
    prior = prior._replace(log_pc=jnp.log(jax.nn.softmax(jnp.arange(model.n_classes, dtype=prior.log_pc.dtype) * 2.0)))
    np.testing.assert_allclose(np.asarray(one.scores(prior, getkey())), np.asarray(plain.scores(prior, getkey())), rtol=1e-6)
    with pytest.raises(ValueError, match="temper"):
        make_planner("mi-class-pairwise-robust", model, key=getkey(), temper=2.0)


def test_planner_runs_in_recognizer_and_does_not_recompile(getkey):
    model = random_sensor_model()
    rec = Recognizer(model, make_planner("mi-class-pairwise-robust", model, key=getkey()), p_threshold=0.96787,
                     min_views=2, exclude_visited_positions=True)
    assert_steps_never_recompile(rec, getkey, n_configs=12)
