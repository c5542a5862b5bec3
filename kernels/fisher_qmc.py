"""Randomised quasi-Monte Carlo estimate of the GM-smoothed Fisher information
J_g(a) (thesis eq. 5.22-5.28): the Monte Carlo kernel of
:mod:`.fisher` on low-discrepancy draws instead of pseudo-random ones.

The estimator is unchanged,

    J_g(a) ~= sum_d P(d) (1/J) sum_j (m_g - m_0)(m_g - m_0)^T / sigma_s^4,
    s_c = e(d) + sigma_s eps_j,  g_i = mu_i + chol_i z_ij                      (5.28)

(the score difference of :mod:`.fisher`); only the J points (eps_j, z_j) of
each stratum change.  For class c they are the J points of one scrambled
Sobol sequence (Owen's scrambling with a digital shift, ``scipy.stats.qmc``)
in ``2 + sum_i (1 + K_i)`` dimensions, mapped through the normal quantile
Phi^-1: coordinates (eps_obj, eps_pose, then per camera eps_occ_i and the
K_i noise coordinates z_i), shared by the levels k of every camera (common
random numbers across levels, as across configurations).  The z part is
fixed offline (it is baked into the log-density tables LD_i, like the Monte
Carlo tables); the smoothing part is re-randomised at every call by a
Cranley-Patterson rotation u -> frac(u + U), U ~ U(0,1) per class and
coordinate from ``key``, which keeps every point uniform, hence the
estimate unbiased for each key.  Scrambled Sobol points need J a power of 2.

Cost: that of :func:`.fisher.fisher_information` at the same J (the same
kernel).  A replicate standard error needs independent randomisations
(several keys), not the J points of one call (they are not independent).
"""

from __future__ import annotations

import functools
from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
import jax.random as jr
import numpy as np
from jax.scipy.special import ndtri
from jaxtyping import Array, Float, PRNGKeyArray

from .belief import PredictedBelief, check_predicted
from .fisher import DEFAULT_SIGMA_S, FisherDraws, fisher_from_draws
from .likelihood import Likelihood, as_likelihoods
from .mutual_information import MITables, camera_log_densities

__all__ = ["QMCFisherTables", "qmc_fisher_tables", "qmc_fisher_draws", "qmc_fisher_information", "sobol_normal_points"]


class QMCFisherTables(NamedTuple):
    """Offline tables of :func:`qmc_fisher_information`.

    Attributes:
        tables: :class:`~jaxrecog.kernels.MITables` whose ``z`` (``[C, L_i, J, K_i]``)
            are Phi^-1 of the Sobol coordinates (``ld`` and ``ld_self`` from them;
            no uniform-level or shifted tables).
        u_obj, u_pose: ``[C, J]`` the Sobol coordinates in (0, 1) of eps_obj, eps_pose.
        u_occ: per camera ``[C, J]`` those of eps_occ_i (shared by the levels).
    """

    tables: MITables
    u_obj: Float[Array, "C J"]
    u_pose: Float[Array, "C J"]
    u_occ: tuple[Float[Array, "C J"], ...]


def sobol_normal_points(n_classes: int, j: int, dims: int, seed: int) -> np.ndarray:
    """``[C, J, dims]`` uniform points: per class c a scrambled Sobol sequence
    (``scipy.stats.qmc.Sobol(dims, scramble=True)``, seed ``(seed, c)``), its
    first J points (J a power of 2).  Plain NumPy, offline."""
    from scipy.stats import qmc

    if j < 1 or j & (j - 1):
        raise ValueError(f"quasi-Monte Carlo: samples_per_stratum must be a power of 2, got {j}")
    m = int(j).bit_length() - 1
    return np.stack([qmc.Sobol(dims, scramble=True, seed=np.random.default_rng([seed, c])).random_base2(m)
                     for c in range(n_classes)])


def qmc_fisher_tables(likelihoods: Sequence[Likelihood], *, seed: int, samples_per_stratum: int) -> QMCFisherTables:
    """The offline tables (once per model and seed): Sobol points per class,
    the noise coordinates mapped to z = Phi^-1(u) and the log-density tables
    LD_i on them (:func:`~jaxrecog.kernels.mi_tables`'s ``store="full"`` part).

    Args:
        likelihoods: one :class:`~jaxrecog.kernels.Likelihood` per camera.
        seed: the scrambling seed (an int: the points are made by NumPy).
        samples_per_stratum: J, a power of 2.
    """
    liks = as_likelihoods(likelihoods, where="qmc_fisher_tables")
    j = int(samples_per_stratum)
    n_c = liks[0].n_classes
    dims = 2 + sum(1 + lik.noise_dim for lik in liks)
    u = sobol_normal_points(n_c, j, dims, int(seed))  # [C, J, dims]
    u = np.clip(u, 0.5 / 2**30, 1 - 0.5 / 2**30)  # Phi^-1 finite (Sobol's 0)
    dtype = liks[0].dtype
    lds, selfs, zs, u_occ = [], [], [], []
    col = 2
    for lik in liks:
        u_occ.append(jnp.asarray(u[:, :, col], dtype))
        zc = jnp.asarray(ndtri(jnp.asarray(u[:, :, col + 1: col + 1 + lik.noise_dim])), dtype)  # [C, J, K]
        col += 1 + lik.noise_dim
        z = jnp.broadcast_to(zc[:, None], (n_c, lik.n_levels) + zc.shape[1:])  # shared by the levels
        ld = camera_log_densities(lik, z)
        d1 = jnp.diagonal(ld, axis1=1, axis2=4)  # [V, L, J, L', C]
        d2 = jnp.diagonal(d1, axis1=1, axis2=3)  # [V, J, C, L]
        selfs.append(jnp.transpose(d2, (0, 2, 3, 1)))
        lds.append(ld)
        zs.append(z)
    tables = MITables(tuple(lds), tuple(selfs), None, tuple(zs))
    return QMCFisherTables(tables, jnp.asarray(u[:, :, 0], dtype), jnp.asarray(u[:, :, 1], dtype), tuple(u_occ))


def qmc_fisher_draws(key: PRNGKeyArray, qt: QMCFisherTables) -> FisherDraws:
    """The smoothing draws of one call: eps = Phi^-1(frac(u + U)), U ~ U(0, 1) per
    class and coordinate from ``key`` (Cranley-Patterson rotation), eps_occ_i
    broadcast over the levels: ``FisherDraws`` as :func:`~jaxrecog.kernels.fisher_draws`."""
    n_c = qt.u_obj.shape[0]
    dtype = qt.u_obj.dtype
    shift = jr.uniform(key, (n_c, 2 + len(qt.u_occ)), dtype)
    lo = jnp.asarray(0.5 / 2**24, dtype)

    def rot(u, s):
        return ndtri(jnp.clip(jnp.mod(u + s[:, None], 1.0), lo, 1.0 - lo))

    occ = tuple(jnp.broadcast_to(rot(u, shift[:, 2 + i])[:, None], (n_c, ld.shape[2], u.shape[1]))
                for i, (u, ld) in enumerate(zip(qt.u_occ, qt.tables.ld)))
    return FisherDraws(rot(qt.u_obj, shift[:, 0]), rot(qt.u_pose, shift[:, 1]), occ)


def qmc_fisher_information(
    qt: QMCFisherTables,
    belief: PredictedBelief,
    *,
    key: PRNGKeyArray,
    n_objects: int,
    n_poses: int,
    sigma_s: float = DEFAULT_SIGMA_S,
) -> Float[Array, "A D D"]:
    """Eq. 5.28 on the randomised Sobol points (module doc) for every
    configuration: ``[A, D, D]``, D = 2 + n_cameras, as
    :func:`~jaxrecog.kernels.fisher_information` (levels of the belief)."""
    check_predicted(belief, qt.tables.ld_self)
    n_c = qt.u_obj.shape[0]
    if n_objects * n_poses != n_c:
        raise ValueError(f"qmc_fisher_information: n_objects * n_poses = {n_objects * n_poses} != C = {n_c}")
    if not sigma_s > 0:
        raise ValueError(f"qmc_fisher_information: sigma_s must be > 0, got {sigma_s}")
    return _qmc_fisher(qt, belief, key, n_objects, n_poses, float(sigma_s))


@functools.partial(jax.jit, static_argnames=("n_objects", "n_poses", "sigma_s"))
def _qmc_fisher(qt, belief, key, n_objects: int, n_poses: int, sigma_s: float):
    """The body of :func:`qmc_fisher_information`, one program."""
    return fisher_from_draws(qt.tables, belief, qmc_fisher_draws(key, qt), n_objects, n_poses, sigma_s)
