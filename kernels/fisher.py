"""Cramér-Rao planner: the Fisher information J_g(a) of the observation for
every configuration (thesis eq. 5.14-5.28).

The discrete state d = (object, pose, k_0, ..., k_{n-1}) is embedded in
R^(2+n) (integer coordinates) and smoothed (eq. 5.22-5.24):

    p(s_c)          = sum_d P(d) N(s_c; d, sigma_s^2 I)
    p(g, s_c | a)   = sum_d P(d) N(s_c; d, sigma_s^2 I) p(g | d, a)

The Fisher information of the observation (eq. 5.26-5.28) is

    J_g(a) = E[(grad log p(g, s_c|a) - grad log p(s_c))(...)^T]
           = E[(m_g - m_0)(m_g - m_0)^T] / sigma_s^4,

since both scores are posterior means of (d - s_c)/sigma_s^2:
m_g = E[d | s_c, g, a] and m_0 = E[d | s_c] (s_c cancels).  The joint
(d, s_c, g) is sampled exactly: d stratified over (c, k_0, k_1, ...) with J
samples per stratum (weights P(d)/J), s_c = d + sigma_s eps, g from the MI
tables (common random numbers across configurations).  Given c' the mixture
factorises per camera: with q_i(k') = log N(s_occ_i; k', sigma_s),

    log A_i[v, c, k, j, c'] = logsumexp_k' (log P_i(k'|c') + q_i(k') + LD_i[v, c, k, j, c', k'])
    B_i[v, c, k, j, c']     = E[k' | c', s_occ_i, g_i]

and the posterior over c' is a softmax of
log P(c') + log N(s_obj; obj(c')) + log N(s_pose; pose(c')) + sum_i log A_i,
evaluated on the (v_0, v_1, ...) grid by the shifted matrix product of
:mod:`._grid`.

Default sigma_s = 0.4: below 0.5 (half the unit spacing) the smoothed density
stays multimodal, so s_c still identifies its discrete state as the thesis
asks ("sigma_s chosen small"); well above ~0.25 neighbouring states overlap
enough that the score difference, hence J_g, is not exponentially small and
its Monte Carlo estimate is not dominated by rare samples.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import jax.random as jr
from jax.scipy.linalg import solve_triangular
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray

from ._grid import FEW_CLASSES, floor_log_probs, grid_mixture, live_chunks, lse, weights
from .belief import PredictedBelief, check_predicted
from .config_grid import position_rows
from .mutual_information import MITables

DEFAULT_SIGMA_S = 0.4

#: at most this many classes of nonzero weight: the strata are theirs alone
#: (:func:`fisher_from_draws`, :data:`._grid.FEW_CLASSES`)
_FEW_CLASSES = FEW_CLASSES


class FisherDraws(NamedTuple):
    """Standard-normal smoothing draws: s_c = d + sigma_s * eps.

    ``eps_obj``, ``eps_pose``: ``[C, J]``; ``eps_occ``: per camera ``[C, L_i, J]``.
    """

    eps_obj: Float[Array, "C J"]
    eps_pose: Float[Array, "C J"]
    eps_occ: tuple[Float[Array, "C _L J"], ...]


def fisher_draws(key: PRNGKeyArray, tables: MITables) -> FisherDraws:
    """The eps draws :func:`fisher_information` uses for ``key`` (for references)."""
    n = len(tables.ld_self)
    n_c, j = tables.ld_self[0].shape[1], tables.ld_self[0].shape[3]
    dtype = tables.ld_self[0].dtype
    keys = jr.split(key, n + 2)
    return FisherDraws(
        jr.normal(keys[0], (n_c, j), dtype),
        jr.normal(keys[1], (n_c, j), dtype),
        tuple(jr.normal(keys[2 + i], (n_c, t.shape[2], j), dtype) for i, t in enumerate(tables.ld_self)),
    )


def fisher_information(
    tables: MITables,
    belief: PredictedBelief,
    *,
    key: PRNGKeyArray,
    n_objects: int,
    n_poses: int,
    sigma_s: float = DEFAULT_SIGMA_S,
    levels: str = "belief",
    with_stderr: bool = False,
):
    """J_g(a) (eq. 5.26-5.28) for every configuration, ``D = 2 + n_cameras``.

    Args:
        tables: from :func:`jaxrecog.kernels.mi_tables` (needs ``tables.ld``).
        belief: the predicted prior, level rows per position ``[V_i, C, L_i]``.
        key: PRNG key for the smoothing noise eps (shared by all configurations).
        n_objects, n_poses: with ``C = n_objects * n_poses``, c = object * n_poses + pose.
        sigma_s: smoothing width (static).
        levels: ``"belief"`` or ``"uniform"`` (P_i(k|c) = 1/L_i for every
            camera at every position, the belief's level rows ignored: as for
            :func:`jaxrecog.kernels.mutual_information`, exact for the uniform
            transition only where every camera moves, since a camera that
            stays keeps its levels).
        with_stderr: also return the elementwise Monte Carlo standard error
            from the J independent replicates (J >= 2).  Static.

    Returns:
        ``[A, D, D]`` symmetric PSD matrices, coordinates (object, pose, k_0, ...);
        with ``with_stderr`` a pair ``(J, stderr [A, D, D])``.
    """
    check_predicted(belief, tables.ld_self)
    if tables.ld is None:
        raise ValueError("fisher_information: needs tables built with store='full' or 'both'")
    n_c, j = tables.ld[0].shape[1], tables.ld[0].shape[3]
    if n_objects * n_poses != n_c:
        raise ValueError(f"fisher_information: n_objects * n_poses = {n_objects * n_poses} != C = {n_c}")
    if not sigma_s > 0:
        raise ValueError(f"fisher_information: sigma_s must be > 0, got {sigma_s}")
    if levels not in ("belief", "uniform"):
        raise ValueError(f"fisher_information: levels must be 'belief' or 'uniform', got {levels!r}")
    if with_stderr and j < 2:
        raise ValueError("fisher_information: with_stderr needs samples_per_stratum >= 2")
    return _fisher_information(tables, belief, key, n_objects, n_poses, float(sigma_s), levels, with_stderr)


@functools.partial(jax.jit, static_argnames=("n_objects", "n_poses", "sigma_s", "levels", "with_stderr"))
def _fisher_information(tables: MITables, belief: PredictedBelief, key: PRNGKeyArray, n_objects: int, n_poses: int,
                        sigma_s: float, levels: str, with_stderr: bool):
    """The body of :func:`fisher_information` (arguments checked), compiled as
    one program (one XLA compilation per shape when called eagerly, instead of
    one per operation)."""
    return fisher_from_draws(tables, belief, fisher_draws(key, tables), n_objects, n_poses, sigma_s, levels, with_stderr)


def fisher_from_draws(tables: MITables, belief: PredictedBelief, draws: FisherDraws, n_objects: int, n_poses: int,
                      sigma_s: float, levels: str = "belief", with_stderr: bool = False):
    """:func:`fisher_information` on given smoothing draws (arguments not
    checked; traceable, for callers that make their own draws, e.g. the
    quasi-Monte Carlo estimator of :mod:`.fisher_qmc`): the J-sample average
    of eq. 5.28's score outer products with s_c = d + sigma_s eps."""
    n = len(tables.ld)
    positions = tuple(t.shape[0] for t in tables.ld)
    n_c, j = tables.ld[0].shape[1], tables.ld[0].shape[3]
    dtype = tables.ld[0].dtype
    s2 = float(sigma_s) ** 2
    log_pc = floor_log_probs(belief.log_pc.astype(dtype))  # no subnormals (see _grid)
    if levels == "uniform":
        log_pk = [jnp.full((v, n_c, t.shape[2]), -math.log(t.shape[2]), dtype) for v, t in zip(positions, tables.ld)]
    else:
        log_pk = [lp.astype(dtype) for lp in belief.log_pk]

    cls = jnp.arange(n_c)
    obj = (cls // n_poses).astype(dtype)
    pose = (cls % n_poses).astype(dtype)

    def contributions(outer):
        """The score outer products summed over the strata of the classes
        ``outer = (keep, valid)`` (``None``: every class; the mixtures over c'
        keep every class; :func:`._grid.live_chunks`)."""
        keep = None if outer is None else outer[0]
        rows = (lambda x, axis=0: x) if keep is None else (lambda x, axis=0: jnp.take(x, keep, axis=axis))
        o_s, p_s = rows(obj), rows(pose)
        s_obj = o_s[:, None] + sigma_s * rows(draws.eps_obj)  # [C, J]
        s_pose = p_s[:, None] + sigma_s * rows(draws.eps_pose)
        extra = (
            log_pc[None, None, :]
            - 0.5 * (s_obj[:, :, None] - obj[None, None, :]) ** 2 / s2
            - 0.5 * (s_pose[:, :, None] - pose[None, None, :]) ** 2 / s2
        )  # [C, J, C']

        tabs_g, tabs_0, b_g, b_0 = [], [], [], []
        for i, ld in enumerate(tables.ld):
            ld = rows(ld, axis=1)
            n_l = ld.shape[2]
            lev = jnp.arange(n_l, dtype=dtype)
            s_occ = lev[None, :, None] + sigma_s * rows(draws.eps_occ[i])  # [C, L, J]
            q = -0.5 * (s_occ[..., None] - lev[None, None, None, :]) ** 2 / s2  # [C, L, J, L']
            lp = log_pk[i]  # [V, C', L']
            x0 = lp[:, None, None, None] + q[None, :, :, :, None, :]  # [V, C, L, J, C', L']
            x = x0 + ld
            la = lse(x, axis=-1)
            levb = lev.reshape((1,) * 5 + (n_l,))
            ba = jnp.sum(jnp.exp(x - la[..., None]) * levb, axis=-1)
            la0 = lse(x0, axis=-1)
            ba0 = jnp.sum(jnp.exp(x0 - la0[..., None]) * levb, axis=-1)
            for acc, t in zip((tabs_g, b_g, tabs_0, b_0), (la, ba, la0, ba0)):
                acc.append(position_rows(t, front=(1, 3)))  # [C, J, X_i, ...]: the rows of the grid product

        fo = obj[None, None, None, :]
        fp = pose[None, None, None, :]
        _, means_g, _ = grid_mixture(tabs_g, extra, [(0, fo), (0, fp)] + [(i, b) for i, b in enumerate(b_g)])
        _, means_0, _ = grid_mixture(tabs_0, extra, [(0, fo), (0, fp)] + [(i, b) for i, b in enumerate(b_0)])
        delta = jnp.stack([mg - m0 for mg, m0 in zip(means_g, means_0)], axis=-1) / s2  # [C, J, X.., D]

        pc = rows(weights(log_pc, n + 1))
        if outer is not None:
            pc = jnp.where(outer[1], pc, 0.0)
        pk = [rows(weights(lp, n + 1), axis=1) for lp in log_pk]
        n_o = pc.shape[0]
        if keep is not None:  # a padded class of weight 0 adds 0, whatever its rows hold
            delta = jnp.where((pc > 0).reshape((n_o,) + (1,) * (delta.ndim - 1)), delta, 0.0)
        letters = "pqrstuvwxy"[:n]
        caps = "PQRSTUVWXY"[:n]
        shaped = delta.reshape((n_o, j) + sum(((v, t.shape[2]) for v, t in zip(positions, tables.ld)), ()) + (n + 2,))
        grid_w = "c" + "".join(a + b for a, b in zip(letters, caps))
        grid_in = "cj" + grid_w[1:]
        # the stratum weights P(c) prod_i P_i[v_i](k_i | c) on the grid first, then one
        # contraction with the score outer products (all five operands in one einsum
        # were contracted in a slower order: 0.8x the time at J = 1 and 4, thesis size)
        w = jnp.einsum("c," + ",".join(f"{a}c{b}" for a, b in zip(letters, caps)) + "->" + grid_w, pc, *pk)
        spec = f"{grid_w},{grid_in}d,{grid_in}e->" + ("j" if with_stderr else "") + letters + "de"
        return jnp.einsum(spec, w, shaped, shaped)

    # the strata of the classes of nonzero weight alone, _FEW_CLASSES at a time
    # (as the MI's, :mod:`.mutual_information`, "Few classes")
    shape = ((j,) if with_stderr else ()) + positions + (n + 2, n + 2)
    fis = live_chunks(log_pc, n + 1, contributions, jnp.zeros(shape, dtype), size=_FEW_CLASSES)
    if not with_stderr:
        fis = (fis / j).reshape((-1, n + 2, n + 2))
        return 0.5 * (fis + jnp.swapaxes(fis, -1, -2))
    reps = fis.reshape((j, -1, n + 2, n + 2))
    return jnp.mean(reps, axis=0), jnp.std(reps, axis=0, ddof=1) / math.sqrt(j)


def crlb_criterion(
    fisher: Float[ArrayLike, "A D D"], kind: str = "trace", jitter: float = 1e-6
) -> Float[Array, " A"]:
    """Scalar criterion on the bound J^{-1} (eq. 5.15, 5.25); smaller is better.

    ``J + eps I`` is factorised by Cholesky with
    ``eps = jitter * max(trace(J)/D, 1)`` (a floor, so a singular J, e.g. a
    coordinate the observation says nothing about, gives a large finite value):

      * ``"trace"``  (A-optimal, default): trace(J^{-1}) = ||L^{-1}||_F^2;
      * ``"logdet"`` (D-optimal): log det J^{-1} = -2 sum log diag L;
      * ``"maxeig"`` (E-optimal): largest eigenvalue of J^{-1}.
    """
    d = fisher.shape[-1]
    eye = jnp.eye(d, dtype=fisher.dtype)
    tr = jnp.trace(fisher, axis1=-2, axis2=-1)
    eps = jitter * jnp.maximum(tr / d, 1.0)
    sym = 0.5 * (fisher + jnp.swapaxes(fisher, -1, -2)) + eps[:, None, None] * eye[None]
    chol = jnp.linalg.cholesky(sym)
    if kind == "trace":
        linv = solve_triangular(chol, jnp.broadcast_to(eye, sym.shape), lower=True)
        return jnp.sum(linv * linv, axis=(-2, -1))
    if kind == "logdet":
        return -2.0 * jnp.sum(jnp.log(jnp.diagonal(chol, axis1=-2, axis2=-1)), axis=-1)
    if kind == "maxeig":
        return 1.0 / jnp.linalg.eigvalsh(sym)[..., 0]
    raise ValueError(f"crlb_criterion: kind must be 'trace', 'logdet' or 'maxeig', got {kind!r}")
