"""Transform consistency: jit vs eager, vmap over beliefs, float32 vs float64,
and no recompilation when only values change."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from compiles import count_compiles
from kernel_models import gaussians, random_belief, random_model

from jaxrecog import kernels as K

pytestmark = pytest.mark.usefixtures("strict_dtype_promotion")  # numerics: no implicit promotion


def _j(x, dtype=None):
    return tuple(jnp.asarray(a, dtype) for a in x)


def _belief(b, dtype=None):
    return K.Belief(jnp.asarray(b.log_pc, dtype), _j(b.log_pk, dtype))


def _predicted(b):
    """The planners' form of a belief on random_model's positions (3, 2): its rows everywhere."""
    return K.at_every_position(b, (3, 2))


@pytest.mark.slow
def test_jit_equals_eager(rng, getkey, x64):
    mus, vars = random_model(rng, 4, (2, 2), (3, 2), (2, 2))
    b = _belief(random_belief(rng, 4, (2, 2)))
    p = _predicted(b)
    tables = K.mi_tables(gaussians(mus, vars), key=getkey(), samples_per_stratum=2)
    key = getkey()
    with jax.disable_jit():
        mi_e = K.mutual_information(tables, p, "class")
        f_e = K.fisher_information(tables, p, key=key, n_objects=2, n_poses=2)
        u_e = K.update(b, (jnp.ones((4, 2)), jnp.zeros((4, 2))))
    mi_j = jax.jit(K.mutual_information, static_argnames="target")(tables, p, target="class")
    f_j = jax.jit(K.fisher_information, static_argnames=("n_objects", "n_poses"))(
        tables, p, key=key, n_objects=2, n_poses=2
    )
    u_j = jax.jit(K.update)(b, (jnp.ones((4, 2)), jnp.zeros((4, 2))))
    np.testing.assert_allclose(mi_j, mi_e, rtol=1e-12)
    np.testing.assert_allclose(f_j, f_e, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(K.joint(u_j), K.joint(u_e), atol=1e-14)


@pytest.mark.slow
def test_vmap_over_beliefs(rng, getkey):
    mus, vars = random_model(rng, 4, (2, 3), (3, 2), (2, 2))
    tables = K.mi_tables(gaussians(mus, vars), key=getkey(), samples_per_stratum=2)
    beliefs = [_belief(random_belief(rng, 4, (2, 3)), jnp.float32) for _ in range(3)]
    stacked = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *beliefs)
    predicted = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *(_predicted(b) for b in beliefs))
    mi = jax.jit(jax.vmap(K.mutual_information, in_axes=(None, 0)))(tables, predicted)
    fis = jax.jit(jax.vmap(lambda b: K.fisher_information(tables, b, key=jax.random.PRNGKey(0), n_objects=2, n_poses=2)))(predicted)
    ups = jax.vmap(K.update, in_axes=(0, None))(stacked, (jnp.ones((4, 2)), jnp.zeros((4, 3))))
    for i, b in enumerate(beliefs):
        np.testing.assert_allclose(mi[i], K.mutual_information(tables, _predicted(b)), rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(
            fis[i], K.fisher_information(tables, _predicted(b), key=jax.random.PRNGKey(0), n_objects=2, n_poses=2),
            rtol=1e-4, atol=1e-5,
        )
        np.testing.assert_allclose(ups.log_pc[i], K.update(b, (jnp.ones((4, 2)), jnp.zeros((4, 3)))).log_pc, rtol=1e-6)


def test_float32_matches_float64(rng, getkey):
    """float32 kernels against the float64 NumPy references on the very same draws
    (float32 and float64 PRNG streams differ, so the draws are passed across)."""
    from oracles import fisher_information_ref, mutual_information_ref

    mus, vars = random_model(rng, 4, (2, 2), (3, 2), (2, 2))
    bn = random_belief(rng, 4, (2, 2))
    fkey = getkey()
    t32 = K.mi_tables(gaussians(mus, vars, dtype=jnp.float32), key=getkey(), samples_per_stratum=2)
    b32 = _predicted(_belief(bn, jnp.float32))
    mi32 = jax.jit(K.mutual_information)(t32, b32)
    f32 = jax.jit(K.fisher_information, static_argnames=("n_objects", "n_poses"))(t32, b32, key=fkey, n_objects=2, n_poses=2)
    assert mi32.dtype == jnp.float32 and f32.dtype == jnp.float32
    mus32 = [np.asarray(m, np.float32) for m in mus]
    vars32 = [np.asarray(v, np.float32) for v in vars]
    lj = np.asarray(K.log_joint(_belief(bn)), np.float64)
    mi64, _ = mutual_information_ref(mus32, vars32, t32.z, lj)
    f64, _ = fisher_information_ref(mus32, vars32, t32.z, K.fisher_draws(fkey, t32), lj, 2, 0.4)
    np.testing.assert_allclose(mi32, mi64, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(f32, f64, rtol=1e-3, atol=1e-4)


def test_no_recompilation_when_only_values_change(rng, getkey):
    mus, vars = random_model(rng, 4, (2, 2), (3, 2), (2, 2))

    def tables_fn(likelihoods, key):
        return K.mi_tables(likelihoods, key=key, samples_per_stratum=2)

    def plan(tables, belief, key):
        mi = K.mutual_information(tables, belief, "class")
        crlb = K.crlb_criterion(K.fisher_information(tables, belief, key=key, n_objects=2, n_poses=2))
        return mi, crlb

    def step(belief, lls, moved):
        return K.update(K.transition(belief, moved, "sticky", 0.8), lls)

    tables_fn, plan, step = jax.jit(tables_fn), jax.jit(plan), jax.jit(step)
    for i in range(3):
        m2, v2 = random_model(rng, 4, (2, 2), (3, 2), (2, 2))
        b = _belief(random_belief(rng, 4, (2, 2)))
        lls = (jnp.asarray(rng.normal(size=(4, 2)), jnp.float32), jnp.asarray(rng.normal(size=(4, 2)), jnp.float32))
        moved = jnp.asarray(rng.random(2) < 0.5)
        keys = getkey(), getkey()
        p = _predicted(b)
        with count_compiles() as compiled:
            tables = tables_fn(gaussians(m2, v2), keys[0])
            mi, crlb = plan(tables, p, keys[1])
            jax.block_until_ready(step(b, lls, moved))
        assert np.all(np.isfinite(mi)) and np.all(np.isfinite(crlb))
        if i == 0:
            assert compiled["tables_fn"] == compiled["plan"] == compiled["step"] == 1, dict(compiled)
        else:
            assert sum(compiled.values()) == 0, dict(compiled)
