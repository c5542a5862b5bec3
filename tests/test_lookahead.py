"""Two-step lookahead planner: the kernel against a brute-force NumPy
reference on the same draws, pruning, a constructed model where the myopic
argmax is a dead end, bad input, NaN-freedom, and the planner in the
recognizer (runs, stops, no recompiles)."""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import jax.random as jr
import numpy as np
from builders import random_sensor_model
import pytest
from compiles import count_compiles
from kernel_models import as_jax_belief, gaussians, random_belief, random_model
from oracles import lookahead_ref

from jaxrecog import kernels as K
from jaxrecog.planners import LookaheadMIPlanner, make_planner
from jaxrecog.recognizer import Recognizer

pytestmark = pytest.mark.usefixtures("strict_dtype_promotion")  # numerics: no implicit promotion

MI_TABLES = jax.jit(K.mi_tables, static_argnames=("samples_per_stratum", "store"))
PT = jax.jit(K.pairwise_tables, static_argnames=("kind",))


@functools.partial(jax.jit, static_argnames=("target", "top_k", "transition", "rho", "batch_size"))
def lookahead(tables, pw, prior, draws, *, target="state", top_k, transition="uniform", rho=0.9, batch_size=None):
    score = functools.partial(K.pairwise_mutual_information, pw, target=target)
    return K.lookahead_information(tables, score, prior, draws=draws, top_k=top_k, transition=transition, rho=rho,
                                   batch_size=batch_size)


def _setup(rng, getkey, *, n_classes=3, levels=(2, 2), positions=(2, 2), dims=(2, 1), j=3, n_out=4,
           current=(1, 0), kind="uniform", rho=0.7, concentration=1.0):
    mus, vars = random_model(rng, n_classes, levels, positions, dims, spread=1.5)
    post = random_belief(rng, n_classes, levels, concentration=concentration)
    prior = K.transition_per_position(as_jax_belief(post), current, positions, kind, rho)
    tables = MI_TABLES(gaussians(mus, vars), key=getkey(), samples_per_stratum=j, store="full")
    pw = PT(gaussians(mus, vars), kind="bhattacharyya")
    draws = K.lookahead_draws(getkey(), n_out, j, dtype=jnp.float64)
    return mus, vars, post, prior, tables, pw, draws


@pytest.mark.parametrize("kind", ["uniform", "sticky"])
@pytest.mark.parametrize("target", ["state", "class"])
def test_matches_brute_force_reference_on_the_same_draws(rng, getkey, x64, target, kind):
    rho, current = 0.7, (1, 0)
    mus, vars, post, prior, tables, pw, draws = _setup(rng, getkey, kind=kind, rho=rho, current=current)
    got = np.asarray(lookahead(tables, pw, prior, draws, target=target, top_k=4, transition=kind, rho=rho))
    want, one = lookahead_ref(mus, vars, tables.z, np.asarray(K.log_joint(as_jax_belief(post))), current,
                              float(draws.u), np.asarray(draws.j), target=target, kind=kind, rho=rho)
    # the one-step term is the pairwise kernel's own value
    np.testing.assert_allclose(np.asarray(K.pairwise_mutual_information(pw, prior, target=target)), one, rtol=1e-9, atol=1e-10)
    np.testing.assert_allclose(got, want, rtol=1e-8, atol=1e-9)
    assert np.all(got >= one - 1e-9) or target == "class"  # state: the second term is >= 0
    # chunks of a lax.map agree with the one vmap (not eager: op-by-op dispatch of the vmap costs ~40 s here)
    chunked = lookahead(tables, pw, prior, draws, target=target, top_k=4, transition=kind, rho=rho, batch_size=3)
    np.testing.assert_allclose(np.asarray(chunked), got, rtol=1e-12, atol=1e-12)


def test_outcomes_are_a_systematic_sample(x64):
    """Each stratum of probability p gets floor(pS) or ceil(pS) of the S points, never one of weight 0."""
    p = np.array([0.5, 0.0, 0.125, 0.375, 0.0])
    with np.errstate(divide="ignore"):
        log_w = jnp.asarray(np.log(p))
    for u in (0.0, 0.3, 0.999):
        s = np.asarray(K.outcome_strata(log_w, jnp.asarray(u), 8))
        assert np.array_equal(np.bincount(s, minlength=5), [4, 0, 1, 3, 0]), (u, s)
        s = np.asarray(K.outcome_strata(log_w, jnp.asarray(u), 3))
        counts = np.bincount(s, minlength=5)
        assert np.all(counts >= np.floor(3 * p)) and np.all(counts <= np.ceil(3 * p)) and counts.sum() == 3


@pytest.mark.parametrize("target", ["state", "class"])
def test_top_k_keeps_values_and_orders_the_pruned_below(rng, getkey, x64, target):
    _, _, _, prior, tables, pw, draws = _setup(rng, getkey, n_classes=4, positions=(3, 2))
    full = np.asarray(lookahead(tables, pw, prior, draws, target=target, top_k=6))
    one = np.asarray(K.pairwise_mutual_information(pw, prior, target=target))
    for k in (2,):  # each k is a compile (static)
        pruned = np.asarray(lookahead(tables, pw, prior, draws, target=target, top_k=k))
        kept = np.argsort(-one, kind="stable")[:k]
        rest = np.setdiff1d(np.arange(6), kept)
        np.testing.assert_allclose(pruned[kept], full[kept], rtol=1e-12, atol=1e-12)
        assert np.all(pruned[rest] < pruned[kept].min())
        assert np.array_equal(np.argsort(-pruned[rest], kind="stable"), np.argsort(-one[rest], kind="stable"))
    # top_k = A evaluates every configuration (checked against the reference above): the unpruned value


def _dead_end_model():
    """Four classes (c = object * 2 + pose) seen by camera 0 at four positions, one feature each:

    - 0 "blurred": means 0, 2.5, 5, 7.5 (sd 1): a little about everything,
      the largest one-step value (pairwise ~0.85 nats > log 2);
    - 1 "object": exactly the object (means 0, 0, 100, 100), log 2;
    - 2 "pose": exactly the pose (means 0, 100, 0, 100), log 2;
    - 3 nothing.

    Camera 1 has one uninformative position.  After the blurred view no single
    view resolves what is left (the pose and object views split the pairs
    only partly confused by it), while object then pose (or pose then object)
    identifies the class: 2 log 2.  Myopic MI takes the blurred view; the
    lookahead takes the object or the pose view.
    """
    d = 2.5
    mu0 = np.array([[0.0, d, 2 * d, 3 * d], [0.0, 0.0, 100.0, 100.0], [0.0, 100.0, 0.0, 100.0], [0.0, 0.0, 0.0, 0.0]])
    mus = (mu0[:, :, None, None], np.zeros((1, 4, 1, 1)))
    vars = (np.ones((4, 4, 1, 1)), np.ones((1, 4, 1, 1)))
    return mus, vars


@pytest.mark.parametrize("target", ["state", "class"])
def test_lookahead_leaves_the_myopic_dead_end(getkey, x64, target):
    mus, vars = _dead_end_model()
    tables = MI_TABLES(gaussians(mus, vars), key=getkey(), samples_per_stratum=16, store="full")
    pw = PT(gaussians(mus, vars), kind="bhattacharyya")
    prior = K.transition_per_position(K.uniform_belief(4, (1, 1), dtype=jnp.float64), (3, 0), (4, 1))
    one = np.asarray(K.pairwise_mutual_information(pw, prior, target=target))
    assert int(np.argmax(one)) == 0 and one[0] > math.log(2) + 0.1
    np.testing.assert_allclose(one[1:3], math.log(2), rtol=1e-9)
    for seed in range(3):
        draws = K.lookahead_draws(jr.PRNGKey(seed), 32, 16, dtype=jnp.float64)
        two = np.asarray(lookahead(tables, pw, prior, draws, target=target, top_k=4))
        assert int(np.argmax(two)) in (1, 2), two
        # the decisive pair is worth all of H(c) = 2 log 2, the dead end clearly less
        np.testing.assert_allclose(two[1:3], 2 * math.log(2), rtol=1e-9)
        assert two[0] < 2 * math.log(2) - 0.05, two
        # pruned to the myopic top 3 (blurred, object, pose) the choice is the same
        assert int(np.argmax(np.asarray(lookahead(tables, pw, prior, draws, target=target, top_k=3)))) in (1, 2)


def test_bad_input_is_a_clear_error(rng, getkey, x64):
    _, _, post, prior, tables, pw, draws = _setup(rng, getkey)
    score = functools.partial(K.pairwise_mutual_information, pw)
    with pytest.raises(ValueError, match=r"top_k = 5 first configurations, but there are A = 4"):
        K.lookahead_information(tables, score, prior, draws=draws, top_k=5)
    with pytest.raises(ValueError, match="top_k"):
        K.lookahead_information(tables, score, prior, draws=draws, top_k=0)
    nan = prior._replace(log_pc=prior.log_pc.at[1].set(jnp.nan))
    with pytest.raises(ValueError, match="NaN"):
        K.lookahead_information(tables, score, nan, draws=draws, top_k=2)
    with pytest.raises(TypeError, match="PredictedBelief"):
        K.lookahead_information(tables, score, prior.at((0, 0)), draws=draws, top_k=2)
    with pytest.raises(ValueError, match="transition"):
        K.lookahead_information(tables, score, prior, draws=draws, top_k=2, transition="teleport")
    uniform_only = tables._replace(ld=None)
    with pytest.raises(ValueError, match="store='full'"):
        K.lookahead_information(uniform_only, score, prior, draws=draws, top_k=2)
    with pytest.raises(ValueError, match="n_outcomes"):
        K.lookahead_draws(getkey(), 0, 3)


def test_planner_rejects_more_first_moves_than_configurations(getkey):
    model = _recognizer_model((4, 3))
    with pytest.raises(ValueError, match=r"top_k = 13: a lookahead over more first configurations than exist \(A = 12\)"):
        make_planner("mi-lookahead", model, key=getkey(), samples=16, top_k=13)
    p = make_planner("mi-lookahead", model, key=getkey(), samples=16)
    assert p.top_k == 8 and p.tables.ld_exp is None
    assert make_planner("mi-class-lookahead", _recognizer_model((2, 2)), key=getkey(), samples=16).top_k == 4


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_never_nan_on_concentrated_and_degenerate_beliefs(rng, getkey, x64, dtype):
    mus, vars = random_model(rng, 4, (2, 3), (3, 2), (2, 2), spread=4.0)
    liks = gaussians(mus, vars, dtype=dtype)
    tables = MI_TABLES(liks, key=getkey(), samples_per_stratum=2, store="full")
    pw = PT(liks, kind="bhattacharyya")
    draws = K.lookahead_draws(getkey(), 8, 2, dtype=jnp.dtype(dtype))
    certain = np.full(4, -np.inf)
    certain[2] = 0.0
    nearly = np.log(np.array([1 - 3e-30, 1e-30, 1e-30, 1e-30]))
    for log_pc in (certain, nearly, np.log(np.full(4, 0.25))):
        with np.errstate(divide="ignore"):  # level probabilities of exactly 0 are wanted here
            b = random_belief(rng, 4, (2, 3), concentration=0.05)
        b = K.Belief(jnp.asarray(log_pc, dtype), tuple(jnp.asarray(x, dtype) for x in b.log_pk))
        prior = K.transition_per_position(b, (0, 1), (3, 2))
        for target in ("state", "class"):
            out = np.asarray(lookahead(tables, pw, prior, draws, target=target, top_k=3))
            assert not np.any(np.isnan(out)), out
            assert np.all(np.isfinite(out)), out


_recognizer_model = random_sensor_model


@pytest.mark.parametrize("name,transition", [("mi-lookahead", "uniform"), ("mi-class-lookahead", "sticky")])
def test_recognizer_runs_stops_and_never_recompiles(getkey, name, transition):
    model = _recognizer_model()
    planner = make_planner(name, model, key=getkey(), samples=32, top_k=4, outcomes=4)
    assert isinstance(planner, LookaheadMIPlanner)
    # the recognizer plans with its own transition between the two steps
    assert planner.with_transition("sticky", 0.8).transition == "sticky" and planner.with_transition("uniform", 0.9) is planner
    # a threshold no other test uses: the first step must compile here, exactly once
    rec = Recognizer(model, planner, p_threshold=0.96543, max_steps=4, transition=transition)

    def images():
        return jr.randint(getkey(), (2, 6, 8), 1, 255).astype(jnp.uint8)

    images()
    state = rec.init(getkey())
    with count_compiles() as first:
        state, dec = rec.step(state, images(), getkey(), trace=True)
        jax.block_until_ready(dec)
    assert first["step"] == 1 and bool(dec.valid), dict(first)
    stops = 0
    with count_compiles() as later:
        for _ in range(11):
            if bool(dec.stop):
                stops += 1
                state = rec.init(getkey())
            else:  # never a configuration already used (numpy: no eager jax op to compile here)
                assert not np.asarray(state.visited)[int(dec.next_index)]
            state, dec = rec.step(state, images(), getkey(), trace=True)
            scores = np.asarray(dec.trace.scores)
            assert bool(dec.valid) and scores.shape == (12,) and not np.any(np.isnan(scores))
            assert 0 <= int(dec.next_index) < 12
    assert sum(later.values()) == 0, dict(later)
    assert stops >= 2  # max_steps = 4: every trial stops within 4 steps
