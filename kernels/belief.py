"""Factorised Bayesian belief over (class, occlusion level per camera)
(thesis eq. 3.1-3.9).

State ``s = (c, k_0, ..., k_{n-1})`` with class ``c = object * n_poses + pose``
and one occlusion level ``k_i`` per camera.  The belief is kept in the
factorised form

    P(s) = P(c) * prod_i P_i(k_i | c),

stored in log space as :class:`Belief`.  This form is *exact* here: the
likelihood is a product over cameras given c (eq. 4.17), and each camera's
level transition acts on its own level only (eq. 3.7-3.9), so a prior of this
form yields a posterior (and a predicted prior) of the same form.  The belief
costs C + C * sum_i L_i numbers instead of C * prod_i L_i.

The planners score the *predicted* prior of the next step, which depends on
where each camera goes: :class:`PredictedBelief` holds it per candidate
position (level rows ``[V_i, C, L_i]``), made by
:func:`transition_per_position` (or :func:`at_every_position` for a belief
scored as it is); ``predicted.at(config)`` is the :class:`Belief` at one
configuration.
"""

from __future__ import annotations

import math
from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from ._grid import lse as _lse


class Belief(NamedTuple):
    """Factorised belief P(c) * prod_i P_i(k_i | c), in log space.

    Attributes:
        log_pc: ``[C]`` log P(c), normalised (logsumexp = 0).
        log_pk: one ``[C, L_i]`` array per camera, log P_i(k_i | c); every row
            normalised.
    """

    log_pc: Float[ArrayLike, " C"]
    log_pk: tuple[Float[ArrayLike, "C _L"], ...]


class PredictedBelief(NamedTuple):
    """The predicted prior of the next step for every candidate position of
    every camera (what the planners score, eq. 3.7-3.9 and 5.3):

        P_a(s) = P(c) * prod_i P_i[v_i](k_i | c),    a = (v_0, v_1, ...).

    Whether camera i's levels are kept or re-drawn depends only on its own
    next position v_i, so the prediction still factorises, with one
    ``[C, L_i]`` block of level rows per position (:func:`transition_per_position`).

    Attributes:
        log_pc: ``[C]`` log P(c), normalised (the transition never changes it).
        log_pk: one ``[V_i, C, L_i]`` array per camera, log P_i[v](k | c);
            every row normalised.
    """

    log_pc: Float[ArrayLike, " C"]
    log_pk: tuple[Float[ArrayLike, "_V C _L"], ...]

    @property
    def positions(self) -> tuple[int, ...]:
        """``(V_0, V_1, ...)``: the candidate positions of each camera."""
        return tuple(int(lp.shape[0]) for lp in self.log_pk)

    def at(self, config: Int[ArrayLike, " n"] | Sequence[Int[ArrayLike, ""]]) -> Belief:
        """The prior at one configuration ``(v_0, v_1, ...)`` (may be traced):
        level rows ``log_pk[i][v_i]``."""
        return Belief(self.log_pc, tuple(lp[v] for lp, v in zip(self.log_pk, config)))


class UpdateInfo(NamedTuple):
    """Diagnostics of one Bayes update (not carried).

    Attributes:
        ok: ``True`` when the update was applied.  ``False`` when the
            log-likelihoods contained NaN or +inf, or were -inf for every state
            with non-zero prior (zero evidence); the belief is then returned
            unchanged.
        log_evidence: log p(g | past) = logsumexp_s [log P(s) + log p(g | s)]
            (the denominator of eq. 3.1); -inf / NaN when ``ok`` is False.
    """

    ok: Bool[Array, ""]
    log_evidence: Float[Array, ""]


def uniform_belief(n_classes: int, levels_per_camera: tuple[int, ...], dtype=None) -> Belief:
    """The uniform prior of the thesis (no a-priori knowledge, section 3.3).

    Args:
        n_classes: C.
        levels_per_camera: ``(L_0, L_1, ...)``, one entry per camera.
        dtype: float dtype (default: JAX's default float).
    """
    if n_classes < 1 or any(int(l) < 1 for l in levels_per_camera):
        raise ValueError(
            f"uniform_belief: need n_classes >= 1 and every level count >= 1, got "
            f"{n_classes}, {levels_per_camera}"
        )
    dtype = jnp.result_type(float) if dtype is None else dtype
    log_pc = jnp.full((n_classes,), -math.log(n_classes), dtype)
    log_pk = tuple(
        jnp.full((n_classes, int(l)), -math.log(int(l)), dtype) for l in levels_per_camera
    )
    return Belief(log_pc, log_pk)


def _check_logliks(belief: Belief, logliks) -> None:
    if len(logliks) != len(belief.log_pk):
        raise ValueError(
            f"update: {len(logliks)} log-likelihood arrays for a belief over "
            f"{len(belief.log_pk)} cameras"
        )
    for i, (ll, lp) in enumerate(zip(logliks, belief.log_pk)):
        if ll.shape != lp.shape:
            raise ValueError(
                f"update: logliks[{i}] has shape {ll.shape}, the belief's camera {i} "
                f"levels have shape {lp.shape}"
            )


def update_with_info(
    belief: Belief, logliks: tuple[Float[ArrayLike, "C _L"], ...], valid: Bool[ArrayLike, ""] | bool = True
) -> tuple[Belief, UpdateInfo]:
    """Bayes rule in log space (eq. 3.1) on the factorised belief, with diagnostics.

    With ``l_i[c, k] = log p(g_i | c, k, v_i)`` (eq. 4.17-4.19):

        m_i[c]          = logsumexp_k (log P_i(k|c) + l_i[c, k])
        log P_i'(k|c)   = log P_i(k|c) + l_i[c, k] - m_i[c]
        log P'(c)       = log P(c) + sum_i m_i[c] - log_evidence

    Guard (branch-free): if ``valid`` is False (the caller could not use the
    images: black, constant, not finite), if any log-likelihood is NaN or
    +inf, or if the evidence is zero (every state with non-zero prior has -inf
    log-likelihood), the belief is returned unchanged and ``info.ok`` is False.  A class whose
    posterior becomes zero keeps its (irrelevant) previous level rows, so no
    NaN ever enters the belief.

    Args:
        belief: the prior (after :func:`transition`).
        logliks: one ``[C, L_i]`` array per camera (see
            :func:`jaxrecog.kernels.camera_log_likelihoods`).
        valid: a scalar mask; False skips the update (no sentinel values in
            ``logliks`` needed).

    Returns:
        ``(posterior, UpdateInfo)``.
    """
    _check_logliks(belief, logliks)
    bad = jnp.zeros((), bool)
    for ll in logliks:
        bad = bad | jnp.any(jnp.isnan(ll) | (ll == jnp.inf))
    new_pk = []
    log_pc = belief.log_pc
    for lp, ll in zip(belief.log_pk, logliks):
        ll = jnp.where(jnp.isnan(ll) | (ll == jnp.inf), 0.0, ll).astype(lp.dtype)
        joint = lp + ll
        m = _lse(joint, axis=-1)  # [C]
        finite = jnp.isfinite(m)
        row = jnp.where(finite[:, None], joint - jnp.where(finite, m, 0.0)[:, None], lp)
        new_pk.append(row)
        log_pc = log_pc + m
    log_ev = _lse(log_pc, axis=-1)
    ok = (~bad) & jnp.isfinite(log_ev) & jnp.asarray(valid, bool)
    new_pc = jnp.where(ok, log_pc - jnp.where(ok, log_ev, 0.0), belief.log_pc)
    new_pk = tuple(jnp.where(ok, r, lp) for r, lp in zip(new_pk, belief.log_pk))
    log_ev = jnp.where(bad | ~jnp.asarray(valid, bool), jnp.nan, log_ev)
    return Belief(new_pc, new_pk), UpdateInfo(ok, log_ev)


def update(belief: Belief, logliks: tuple[Float[ArrayLike, "C _L"], ...]) -> Belief:
    """Bayes rule in log space (eq. 3.1); see :func:`update_with_info`.

    Degenerate input (NaN/+inf log-likelihoods, or zero evidence) leaves the
    belief unchanged; use :func:`update_with_info` to see that flag.
    """
    return update_with_info(belief, logliks)[0]


def _sticky(lp, rho, stay):
    """log[rho * P(k) + (1 - rho) / L] where ``stay``, log(1/L) elsewhere."""
    n_levels = lp.shape[-1]
    rho = jnp.asarray(rho, lp.dtype)
    log_u = -math.log(n_levels)
    mixed = jnp.logaddexp(jnp.log(rho) + lp, jnp.log1p(-rho) + log_u)
    return jnp.where(stay, mixed, jnp.full_like(lp, log_u))


def transition(
    belief: Belief,
    moved: Bool[ArrayLike, " n"] | tuple[bool, ...],
    kind: str = "uniform",
    rho: float | Float[ArrayLike, ""] = 0.9,
) -> Belief:
    """Predict the next prior with a per-camera level transition (eq. 3.7-3.9).

    Object and pose never change (eq. 3.8), so only the level rows move:
    ``P_i'(k'|c) = sum_k T_i(k'|k) P_i(k|c)``.

    Kinds (``kind`` is a static Python string):
      * ``"uniform"`` (thesis eq. 3.9, P_alpha = 1/L): a camera that moved gets
        uniform levels; a camera that did not move keeps its levels.
      * ``"sticky"``: a camera that did not move keeps its level with
        probability ``rho``, else draws it uniformly,
        ``T(k'|k) = rho delta_kk' + (1 - rho)/L``; a camera that moved gets
        uniform levels.

    Args:
        belief: the posterior of the last step.
        moved: ``[n_cameras]`` booleans (may be traced).
        kind: ``"uniform"`` or ``"sticky"``.
        rho: stay probability in [0, 1] for ``"sticky"`` (may be traced).
    """
    n = len(belief.log_pk)
    moved = jnp.asarray(moved, bool)
    if moved.shape != (n,):
        raise ValueError(f"transition: `moved` must have shape ({n},), got {moved.shape}")
    out = []
    for i, lp in enumerate(belief.log_pk):
        if kind == "uniform":
            u = jnp.full_like(lp, -math.log(lp.shape[-1]))
            out.append(jnp.where(moved[i], u, lp))
        elif kind == "sticky":
            out.append(_sticky(lp, rho, ~moved[i]))
        else:
            raise ValueError(f"transition: kind must be 'uniform' or 'sticky', got {kind!r}")
    return Belief(belief.log_pc, tuple(out))


def transition_per_position(
    belief: Belief,
    current: tuple[int, ...] | ArrayLike,
    positions: tuple[int, ...],
    kind: str = "uniform",
    rho: float | Float[ArrayLike, ""] = 0.9,
) -> PredictedBelief:
    """The predicted prior for every candidate position of every camera.

    Whether camera i moves depends only on its own next position ``v_i``
    (``v_i != current[i]``), so the predicted level distribution of camera i
    is a ``[V_i, C, L_i]`` array and the prediction still factorises
    (:class:`PredictedBelief`, what every planner scores).  Row ``v`` of
    camera i is :func:`transition`'s with ``moved[i] = (v != current[i])``.
    """
    n = len(belief.log_pk)
    if len(positions) != n:
        raise ValueError(f"transition_per_position: {len(positions)} position counts for {n} cameras")
    out = []
    for i, lp in enumerate(belief.log_pk):
        stay = (jnp.arange(positions[i]) == jnp.asarray(current)[i])[:, None, None]
        if kind == "uniform":
            u = jnp.full_like(lp, -math.log(lp.shape[-1]))
            out.append(jnp.where(stay, lp[None], u[None]))
        elif kind == "sticky":
            out.append(_sticky(lp[None], rho, stay))
        else:
            raise ValueError(f"transition_per_position: kind must be 'uniform' or 'sticky', got {kind!r}")
    return PredictedBelief(belief.log_pc, tuple(out))


def at_every_position(belief: Belief, positions: tuple[int, ...]) -> PredictedBelief:
    """The belief as it is, at every candidate position: ``P_i[v](k | c) = P_i(k | c)``
    for every v (the prediction of no level transition), e.g. to score the
    state's own prior (``jaxrecog plan`` without images) or a belief in a test.
    A broadcast: the values are the belief's."""
    n = len(belief.log_pk)
    if len(positions) != n:
        raise ValueError(f"at_every_position: {len(positions)} position counts for {n} cameras")
    return PredictedBelief(belief.log_pc, tuple(
        jnp.broadcast_to(jnp.asarray(lp)[None], (int(v),) + tuple(jnp.shape(lp))) for lp, v in zip(belief.log_pk, positions)))


def check_predicted(belief, tables) -> None:
    """``belief`` is the :class:`~.belief.PredictedBelief` that the per-camera
    ``tables`` (axes ``[V_i, C, L_i, ...]``, e.g. ``MITables.ld_self``) score:
    the same cameras, C and level rows ``[V_i, C, L_i]``, no NaN where its
    values are concrete; a ``TypeError`` / ``ValueError`` naming what differs
    otherwise.  Shared by every planner kernel."""
    if not isinstance(belief, PredictedBelief):
        raise TypeError(f"a planner kernel scores a PredictedBelief (transition_per_position, or "
                        f"at_every_position for a belief as it is), got {type(belief).__name__}")
    n, c = len(tables), tables[0].shape[1]
    if len(belief.log_pk) != n:
        raise ValueError(f"belief over {len(belief.log_pk)} cameras, tables for {n}")
    if jnp.shape(belief.log_pc) != (c,):
        raise ValueError(f"belief.log_pc has shape {jnp.shape(belief.log_pc)}, tables have C = {c}")
    for i, (lp, t) in enumerate(zip(belief.log_pk, tables)):
        want = (t.shape[0], c, t.shape[2])
        if jnp.shape(lp) != want:
            raise ValueError(f"belief.log_pk[{i}] has shape {jnp.shape(lp)}, the tables' camera {i} wants "
                             f"[V, C, L] = {want}")
    _check_values(belief)


def _check_values(belief) -> None:
    """A belief with concrete values holds no NaN (a ``ValueError`` naming the
    array otherwise).  Traced values (under ``jit``) cannot be checked here;
    the kernels keep their scores free of NaN instead."""
    for name, x in [("log_pc", belief.log_pc)] + [(f"log_pk[{i}]", x) for i, x in enumerate(belief.log_pk)]:
        if isinstance(x, jax.core.Tracer):  # under jit: checked by the caller's NaN-free outputs
            continue
        if bool(jnp.any(jnp.isnan(jnp.asarray(x)))):
            raise ValueError(f"belief.{name} contains NaN (a belief must be log-probabilities, -inf allowed)")


def class_marginal(belief: Belief) -> Float[Array, " C"]:
    """P(c), probabilities ``[C]``."""
    return jnp.exp(belief.log_pc)


def object_marginal(belief: Belief, n_objects: int, n_poses: int) -> Float[Array, " M"]:
    """P(object) ``[M]``, summing P(c) over poses (c = object * n_poses + pose)."""
    return jnp.sum(_object_pose(belief, n_objects, n_poses), axis=1)


def pose_marginal(belief: Belief, n_objects: int, n_poses: int) -> Float[Array, " N"]:
    """P(pose) ``[N]``, summing P(c) over objects."""
    return jnp.sum(_object_pose(belief, n_objects, n_poses), axis=0)


def object_pose_marginal(belief: Belief, n_objects: int, n_poses: int) -> Float[Array, "M N"]:
    """P(object, pose) ``[M, N]`` (the reshaped class marginal)."""
    return _object_pose(belief, n_objects, n_poses)


def _object_pose(belief, n_objects, n_poses):
    c = belief.log_pc.shape[0]
    if n_objects * n_poses != c:
        raise ValueError(f"marginal: n_objects * n_poses = {n_objects * n_poses} != C = {c}")
    return jnp.exp(belief.log_pc).reshape(n_objects, n_poses)


def level_marginal(belief: Belief, camera: int) -> Float[Array, " L"]:
    """P(k_camera) ``[L]`` = sum_c P(c) P_i(k|c)."""
    return jnp.exp(_lse(belief.log_pc[:, None] + belief.log_pk[camera], axis=0))


def log_joint(belief: Belief) -> Float[Array, "C *L"]:
    """The full joint log P(c, k_0, k_1, ...) ``[C, L_0, L_1, ...]`` (for tests)."""
    out = belief.log_pc
    for i, lp in enumerate(belief.log_pk):
        out = out[..., None] + lp.reshape((lp.shape[0],) + (1,) * i + (lp.shape[1],))
    return out


def joint(belief: Belief) -> Float[Array, "C *L"]:
    """The full joint P(c, k_0, k_1, ...) ``[C, L_0, L_1, ...]`` (probabilities)."""
    return jnp.exp(log_joint(belief))


def entropy(belief: Belief, target: str = "state") -> Float[Array, ""]:
    """H(s) = H(c) + sum_i H(k_i | c) (``target="state"``) or H(c) (``"class"``), nats."""
    pc = jnp.exp(belief.log_pc)
    h = -jnp.sum(jnp.where(pc > 0, pc * belief.log_pc, 0.0))
    if target == "class":
        return h
    for lp in belief.log_pk:
        p = jnp.exp(lp)
        h = h - jnp.sum(pc * jnp.sum(jnp.where(p > 0, p * lp, 0.0), axis=-1))
    return h
