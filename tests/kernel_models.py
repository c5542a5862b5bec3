"""Small random sensor models and beliefs shared by the kernel tests."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from jaxrecog.kernels import Belief


def random_model(rng, n_classes=4, levels=(2, 3), positions=(3, 2), dims=(3, 2), spread=1.0):
    """Per-camera (mus, vars) with means ~ N(0, spread^2) and variances in [0.3, 1.2]."""
    mus, vars = [], []
    for l, v, k in zip(levels, positions, dims):
        mus.append(spread * rng.normal(size=(v, n_classes, l, k)))
        vars.append(rng.uniform(0.3, 1.2, size=(v, n_classes, l, k)))
    return tuple(mus), tuple(vars)


def random_chols(rng, n_classes, levels, positions, dims, scale=0.3):
    """Per-camera lower Cholesky factors of A A^T + 0.5 I, A ~ N(0, scale^2) entries
    (``scale=1`` gives strongly correlated, far from diagonal covariances)."""
    out = []
    for l, v, k in zip(levels, positions, dims):
        a = rng.normal(size=(v, n_classes, l, k, k)) * scale
        cov = a @ np.swapaxes(a, -1, -2) + 0.5 * np.eye(k)
        out.append(np.linalg.cholesky(cov))
    return tuple(out)


def random_belief(rng, n_classes=4, levels=(2, 3), concentration=1.0):
    """A random normalised factorised belief (Dirichlet rows), as NumPy log arrays."""
    pc = rng.dirichlet(np.full(n_classes, concentration))
    pk = tuple(rng.dirichlet(np.full(l, concentration), size=n_classes) for l in levels)
    return Belief(np.log(pc), tuple(np.log(p) for p in pk))


def jitted():
    """Jitted kernels for the tests (eager dispatch of the many small ops is slow)."""
    import jax

    from jaxrecog import kernels as K

    return (
        jax.jit(K.mi_tables, static_argnames=("samples_per_stratum", "store")),
        jax.jit(K.mutual_information, static_argnames=("target", "levels", "with_stderr")),
        jax.jit(K.fisher_information, static_argnames=("n_objects", "n_poses", "sigma_s", "levels", "with_stderr")),
    )


def as_jax(arrays):
    """A tuple of NumPy arrays (one per camera) as JAX arrays."""
    return tuple(jnp.asarray(a) for a in arrays)


def as_jax_belief(b: Belief) -> Belief:
    """A belief of NumPy arrays (as :func:`random_belief` makes) as JAX arrays."""
    return Belief(jnp.asarray(b.log_pc), as_jax(b.log_pk))
