"""Factorised belief against the brute-force full joint state (the oracle test)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from kernel_models import random_belief
from oracles import (
    joint_transition_ref,
    joint_uniform_ref,
    joint_update_ref,
)

from jaxrecog import kernels as K

pytestmark = pytest.mark.usefixtures("strict_dtype_promotion")  # numerics: no implicit promotion


def _to_jax(b):
    return K.Belief(jnp.asarray(b.log_pc), tuple(jnp.asarray(x) for x in b.log_pk))


@pytest.mark.parametrize("levels", [(3,), (2, 3), (2, 2, 3)])
@pytest.mark.parametrize("kind", ["uniform", "sticky"])
def test_factorised_matches_full_joint_over_steps(rng, x64, levels, kind):
    n_c = 6
    belief = K.uniform_belief(n_c, levels)
    ref = joint_uniform_ref(n_c, levels)
    np.testing.assert_allclose(K.log_joint(belief), ref, atol=1e-12)
    update = jax.jit(K.update)
    transition = jax.jit(K.transition, static_argnames="kind")
    for step in range(4):
        moved = rng.random(len(levels)) < 0.5
        belief = transition(belief, jnp.asarray(moved), kind=kind, rho=0.7)
        ref = joint_transition_ref(ref, moved, kind, 0.7)
        # sharp likelihoods so that the belief moves a lot
        lls = tuple(rng.normal(scale=4.0, size=(n_c, l)) for l in levels)
        belief = update(belief, tuple(map(jnp.asarray, lls)))
        ref = joint_update_ref(ref, lls)
        np.testing.assert_allclose(K.joint(belief), np.exp(ref), atol=1e-10, err_msg=f"step {step}")
        np.testing.assert_allclose(jax.scipy.special.logsumexp(belief.log_pc), 0.0, atol=1e-12)
        for lp in belief.log_pk:
            np.testing.assert_allclose(jax.scipy.special.logsumexp(lp, axis=-1), 0.0, atol=1e-12)


def test_random_factorised_prior_matches_joint(rng, x64):
    b = random_belief(rng, 5, (2, 3))
    ref = np.asarray(K.log_joint(_to_jax(b)))
    lls = (rng.normal(size=(5, 2)), rng.normal(size=(5, 3)))
    out = K.update(_to_jax(b), tuple(map(jnp.asarray, lls)))
    np.testing.assert_allclose(K.joint(out), np.exp(joint_update_ref(ref, lls)), atol=1e-12)


def test_transition_kinds(x64, rng):
    b = _to_jax(random_belief(rng, 3, (4, 2)))
    u = K.transition(b, jnp.array([True, False]), kind="uniform")
    np.testing.assert_allclose(jnp.exp(u.log_pk[0]), 0.25)
    np.testing.assert_allclose(u.log_pk[1], b.log_pk[1])
    s = K.transition(b, jnp.array([False, True]), kind="sticky", rho=0.6)
    np.testing.assert_allclose(jnp.exp(s.log_pk[0]), 0.6 * jnp.exp(b.log_pk[0]) + 0.4 / 4, atol=1e-12)
    np.testing.assert_allclose(jnp.exp(s.log_pk[1]), 0.5)
    # rho = 1 keeps the levels exactly, rho = 0 is uniform
    np.testing.assert_allclose(K.transition(b, jnp.array([False, False]), "sticky", 1.0).log_pk[0], b.log_pk[0])
    np.testing.assert_allclose(jnp.exp(K.transition(b, jnp.array([False, False]), "sticky", 0.0).log_pk[0]), 0.25)
    with pytest.raises(ValueError, match="kind"):
        K.transition(b, jnp.array([False, False]), "bogus")
    with pytest.raises(ValueError, match="moved"):
        K.transition(b, jnp.array([False]), "uniform")


def test_transition_per_position(x64, rng):
    b = _to_jax(random_belief(rng, 3, (2, 3)))
    p = K.transition_per_position(b, (1, 0), (3, 2), kind="sticky", rho=0.8)
    assert isinstance(p, K.PredictedBelief) and p.positions == (3, 2)
    assert p.log_pk[0].shape == (3, 3, 2) and p.log_pk[1].shape == (2, 3, 3)
    for v in range(3):
        want = K.transition(b, jnp.array([v != 1, False]), "sticky", 0.8).log_pk[0]
        np.testing.assert_allclose(p.log_pk[0][v], want, atol=1e-12)
    # the prior at one configuration (v_0, v_1) is transition's with moved = (v_0 != 1, v_1 != 0)
    for v0, v1 in np.ndindex(3, 2):
        at = p.at((v0, v1))
        want = K.transition(b, jnp.array([v0 != 1, v1 != 0]), "sticky", 0.8)
        assert isinstance(at, K.Belief) and at.log_pc is p.log_pc
        for got, w in zip(at.log_pk, want.log_pk):
            np.testing.assert_allclose(got, w, atol=1e-12)
    # a belief as it is, at every position: the same rows everywhere (a broadcast)
    e = K.at_every_position(b, (3, 2))
    assert isinstance(e, K.PredictedBelief) and e.positions == (3, 2)
    for lp, rows in zip(b.log_pk, e.log_pk):
        assert all(np.array_equal(r, lp) for r in np.asarray(rows))
    with pytest.raises(ValueError, match="3 position counts for 2 cameras"):
        K.at_every_position(b, (3, 2, 2))


def test_marginals(x64, rng):
    b = _to_jax(random_belief(rng, 6, (2, 3)))
    pj = np.asarray(K.joint(b))
    np.testing.assert_allclose(K.class_marginal(b), pj.sum(axis=(1, 2)), atol=1e-12)
    op = pj.sum(axis=(1, 2)).reshape(3, 2)
    np.testing.assert_allclose(K.object_marginal(b, 3, 2), op.sum(1), atol=1e-12)
    np.testing.assert_allclose(K.pose_marginal(b, 3, 2), op.sum(0), atol=1e-12)
    np.testing.assert_allclose(K.object_pose_marginal(b, 3, 2), op, atol=1e-12)
    np.testing.assert_allclose(K.level_marginal(b, 1), pj.sum(axis=(0, 1)), atol=1e-12)
    h = -np.sum(pj * np.log(pj))
    np.testing.assert_allclose(K.entropy(b), h, atol=1e-12)
    with pytest.raises(ValueError, match="n_objects"):
        K.object_marginal(b, 4, 2)


def test_degenerate_logliks_leave_belief_unchanged_and_flag(rng):
    b = _to_jax(random_belief(rng, 4, (2, 3)))
    for bad in (jnp.full((4, 2), -jnp.inf), jnp.full((4, 2), jnp.nan), jnp.full((4, 2), jnp.inf)):
        out, info = jax.jit(K.update_with_info)(b, (bad, jnp.zeros((4, 3))))
        assert not bool(info.ok)
        np.testing.assert_array_equal(out.log_pc, b.log_pc)
        for x, y in zip(out.log_pk, b.log_pk):
            np.testing.assert_array_equal(x, y)
    good, info = K.update_with_info(b, (jnp.zeros((4, 2)), jnp.zeros((4, 3))))
    assert bool(info.ok) and np.isfinite(info.log_evidence)


def test_a_class_ruled_out_gives_no_nan(rng):
    b = _to_jax(random_belief(rng, 4, (2, 3)))
    ll0 = jnp.zeros((4, 2)).at[1].set(-jnp.inf)  # class 1 impossible
    out, info = K.update_with_info(b, (ll0, jnp.zeros((4, 3))))
    assert bool(info.ok)
    assert out.log_pc[1] == -jnp.inf
    for x in (out.log_pc, *out.log_pk):
        assert not np.any(np.isnan(x))
    # and the next step is still well defined
    out2 = K.update(K.transition(out, jnp.array([True, True])), (jnp.zeros((4, 2)), jnp.ones((4, 3))))
    assert not np.any(np.isnan(out2.log_pc))


def test_update_rejects_mismatched_shapes():
    b = K.uniform_belief(4, (2, 3))
    with pytest.raises(ValueError, match="cameras"):
        K.update(b, (jnp.zeros((4, 2)),))
    with pytest.raises(ValueError, match="shape"):
        K.update(b, (jnp.zeros((4, 2)), jnp.zeros((4, 2))))
    with pytest.raises(ValueError):
        K.uniform_belief(0, (2,))
