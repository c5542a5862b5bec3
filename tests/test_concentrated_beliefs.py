"""Concentrated beliefs (classes at P ~ 1e-40, below the smallest normal
float32) must give the same planner scores as the same belief with those
classes removed: the kernels floor tiny probabilities to keep subnormal floats
out of their exponentials (a 7x slowdown on x86 CPUs otherwise), and that
floor must not change the answer."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from jaxrecog import kernels as K
from kernel_models import gaussians, random_model

pytestmark = pytest.mark.usefixtures("strict_dtype_promotion")  # numerics: no implicit promotion


def _beliefs(n_classes, levels):
    log_pc = np.full(n_classes, -90.0)  # P ~ 1e-39: subnormal in float32
    log_pc[:2] = np.log(0.5)
    tiny = K.Belief(jnp.asarray(log_pc, jnp.float32), tuple(jnp.full((n_classes, l), -np.log(l), jnp.float32) for l in levels))
    gone = K.Belief(jnp.asarray(np.where(log_pc < -50, -np.inf, log_pc), jnp.float32), tiny.log_pk)
    return tuple(K.at_every_position(x, (3, 2)) for x in (tiny, gone))  # random_model's positions


@pytest.mark.parametrize("target", ["state", "class"])
def test_mi_ignores_subnormal_classes(target, rng, getkey):
    levels = (2, 3)
    mus, vars = random_model(rng, n_classes=6, levels=levels, spread=3.0)
    tables = K.mi_tables(gaussians(mus, vars, dtype=jnp.float32), key=getkey(), samples_per_stratum=4)
    tiny, gone = _beliefs(6, levels)
    a = np.asarray(K.mutual_information(tables, tiny, target=target))
    b = np.asarray(K.mutual_information(tables, gone, target=target))
    assert np.all(np.isfinite(a))
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)


def test_fisher_ignores_subnormal_classes(rng, getkey):
    levels = (2, 3)
    mus, vars = random_model(rng, n_classes=6, levels=levels, spread=3.0)
    tables = K.mi_tables(gaussians(mus, vars, dtype=jnp.float32), key=getkey(), samples_per_stratum=4)
    tiny, gone = _beliefs(6, levels)
    key = getkey()
    a = np.asarray(K.fisher_information(tables, tiny, key=key, n_objects=3, n_poses=2))
    b = np.asarray(K.fisher_information(tables, gone, key=key, n_objects=3, n_poses=2))
    assert np.all(np.isfinite(a))
    np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-6)
