"""Small random sensor models and beliefs shared by the kernel tests."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from jaxrecog.kernels import Belief, PredictedBelief, at_every_position, gaussian_likelihoods


def random_model(rng, n_classes=4, levels=(2, 3), positions=(3, 2), dims=(3, 2), spread=1.0):
    """Per-camera (mus, vars) with means ~ N(0, spread^2) and variances in [0.3, 1.2]
    (NumPy, for the oracles; :func:`gaussians` makes the kernels' likelihoods)."""
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


def as_jax(arrays, dtype=None):
    """A tuple of NumPy arrays (one per camera) as JAX arrays."""
    return tuple(jnp.asarray(a, dtype) for a in arrays)


def gaussians(mus, vars=None, chols=None, dtype=None):
    """Per-camera Gaussian likelihoods (what the kernels take) from the NumPy
    arrays of :func:`random_model` / :func:`random_chols`: means with the
    diagonal variances ``vars`` or the Cholesky factors ``chols``, as JAX
    arrays of ``dtype`` (default: JAX's for the input)."""
    cast = lambda xs: None if xs is None else as_jax(xs, dtype)  # noqa: E731
    return gaussian_likelihoods(cast(mus), cast(vars), cast(chols))


def as_jax_belief(b):
    """A belief of NumPy arrays (as :func:`random_belief` makes) as JAX arrays,
    of the same form (:class:`Belief` or :class:`PredictedBelief`)."""
    return type(b)(jnp.asarray(b.log_pc), as_jax(b.log_pk))


def everywhere(b: Belief, positions) -> PredictedBelief:
    """A belief (NumPy or JAX arrays) as the planners' predicted prior with the
    same level rows at every position (:func:`~jaxrecog.kernels.at_every_position`),
    JAX arrays: what the NumPy oracles score (one belief for every configuration)."""
    return at_every_position(as_jax_belief(b), positions)
