"""A pure JAX functional form of the recognition environment (gymnax style),
for fast rollouts on eigenspace features where no rendering is needed.

    state, obs = env.reset(key)
    state, obs, reward, done, info = env.step(state, action, key)

Both are pure functions of arrays (``jax.jit`` / ``jax.vmap`` over keys and
states; the env itself is an ``eqx.Module``).  The observation of a step is
drawn from a :class:`FeatureBank`: for every camera, position and class,
``S`` feature vectors of held-out images (:func:`bank_from_database`, the
``test`` split of an image database) or of rendered captures
(:func:`bank_from_rig`).  Each camera's draw is independent given the class,
as the sensor model assumes (eq. 4.17); real captures of one scene are not.

**This form is for policy research.**  The recognition results we report
(:mod:`jaxrecog.campaigns`, :class:`~jaxrecog.envs.ActiveRecognitionEnv`)
come from rendered images of each trial's scene, never from a feature bank.

The dynamics are those of :class:`~jaxrecog.envs.ActiveRecognitionEnv` with
``prediction="probabilities"`` and ``action="flat"``: the belief update is the
recognizer's (eq. 3.1, 4.17-4.19), with the log-likelihoods of every bank
entry computed once from the model when the env is built (memory
``sum_i V_i C S C L_i`` floats: 15 MB for the thesis's sizes at S = 16), the level transition
for the cameras that move (eq. 3.7-3.9); the agent declares when its
normalised prediction reaches ``p_threshold``; reward
``-step_cost - (-log p(target) / log C)``, a declaration's loss counted for
each step it skips (``max_steps - views + 1``, ActiveRecognitionEnv's episode
rule).  When an episode ends
(``done``), ``step`` returns the state and observation of a fresh episode
(gymnax's auto-reset); ``info`` describes the step that ended.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.random as jr
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int, PRNGKeyArray

from .. import kernels as K
from ..driver import TrialSpec
from ..features import project_camera
from ..kernels.config_grid import ConfigGrid
from ..recognizer import image_features
from . import _engine as E

__all__ = ["FeatureBank", "FunctionalState", "FunctionalEnv", "bank_from_database", "bank_from_rig"]

_P_FLOOR = 1e-12


class FeatureBank(eqx.Module):
    """Per camera ``i``, ``features[i]``: ``[V_i, C, S, K_i]`` feature vectors
    of held-out (or rendered) images of class ``c`` at position ``v``."""

    features: tuple[Float[Array, "_V C S _K"], ...]

    @property
    def samples(self) -> int:
        return int(self.features[0].shape[2])


_project = eqx.filter_jit(image_features)
_project_batch = eqx.filter_jit(project_camera)


def _bank(model, cells: list[dict], what: str) -> FeatureBank:
    """Equal-sized cells: the first ``S = min count`` vectors of each."""
    out = []
    for i, cam in enumerate(model.cameras):
        counts = [len(cells[i].get((v, c), ())) for v in range(cam.n_positions) for c in range(model.n_classes)]
        if min(counts) == 0:
            v, c = next((v, c) for v in range(cam.n_positions) for c in range(model.n_classes) if not cells[i].get((v, c)))
            raise ValueError(f"{what}: no usable image of camera {i}, position {v}, class {c} (object "
                             f"{c // model.n_poses}, pose {c % model.n_poses})")
        s = min(counts)
        arr = np.stack([np.stack([np.stack(cells[i][(v, c)][:s]) for c in range(model.n_classes)])
                        for v in range(cam.n_positions)])
        out.append(jnp.asarray(arr, cam.likelihood.dtype))
    return FeatureBank(tuple(out))


def bank_from_database(model, database, split: str = "test") -> FeatureBank:
    """Project every ``split`` image of an :class:`~jaxrecog.ImageDatabase`
    into its position's eigenspace (eq. 4.1-4.11); ``S`` is the smallest
    number of usable images of any (camera, position, class)."""
    from ..counts import check_counts

    rows = np.flatnonzero(np.asarray(database.split) == split)
    check_counts(model, database, other_name=f"database {getattr(database, 'root', None) or '<in memory>'}")
    cells: list[dict] = [{} for _ in model.cameras]
    for i, cam in enumerate(model.cameras):
        mine = rows[np.asarray(database.camera)[rows] == i]
        if mine.size == 0:
            continue
        gs, ok = _project_batch(cam, jnp.asarray(np.asarray(database.position)[mine], jnp.int32),
                                jnp.asarray(np.asarray(database.images)[mine]))
        gs, ok = np.asarray(gs), np.asarray(ok)
        for j, r in enumerate(mine):
            if ok[j]:
                c = int(database.object[r]) * model.n_poses + int(database.pose[r])
                cells[i].setdefault((int(database.position[r]), c), []).append(gs[j])
    return _bank(model, cells, f"the database's '{split}' split")


def bank_from_rig(model, rig, samples: int, *, occluders=None, seed: int = 0) -> FeatureBank:
    """Render ``samples`` captures of every class at every position of every
    camera (cameras move together: capture ``v`` puts camera ``i`` at
    ``min(v, V_i - 1)``).  ``occluders``: a campaign's occluder factory
    (``(rng, configuration) -> layout``), drawn afresh per capture."""
    if samples < 1:
        raise ValueError(f"samples must be >= 1, got {samples}")
    E.check_layout(model, rig)
    positions = tuple(model.positions)
    cells: list[dict] = [{} for _ in model.cameras]
    for c in range(model.n_classes):
        obj, pose = divmod(c, model.n_poses)
        for s in range(samples):
            for v in range(max(positions)):
                config = tuple(min(v, n - 1) for n in positions)
                rng = np.random.default_rng([seed, c, s, v])
                occ = occluders(rng, config) if occluders is not None else None
                E.start(rig, TrialSpec(-1, obj, pose, config, occ))
                images, _ = E.capture(rig, config, (seed, c, s, v))
                gs, ok = _project(model, jnp.asarray(config, jnp.int32), jnp.asarray(images))
                if bool(ok):
                    for i, g in enumerate(gs):
                        if config[i] == v:
                            cells[i].setdefault((v, c), []).append(np.asarray(g))
    return _bank(model, cells, "the rig's captures")


def _loglik_tables(model, bank: FeatureBank, scales: tuple[float, ...] = (1.0,)) -> tuple[Float[Array, "_V C S C _L"], ...]:
    """log p(g | c', k', v) of every bank entry g (camera i, position v, class
    c, sample s) under every class c' and level k' (eq. 4.17-4.22), computed
    once from the model, so a step is a gather and the Bayes update (the
    thesis's offline-table trick, here for the observations).

    ``scales`` (:func:`~jaxrecog.kernels.adaptive_scale.scale_grid`): with
    more than ``(1,)`` each entry's evidence is the recognizer's adaptive one,
    ``log p*(g | c', k', v)`` at the entry's own profile scale s*(g, v)
    (:mod:`jaxrecog.kernels.adaptive_scale`; ``(1,)`` is the plain density):
    s* depends on the capture and the model only, never on the belief, so it
    is tabled too."""
    from ..recognizer import restrict_cameras

    out = []
    for i, f in enumerate(bank.features):
        one = restrict_cameras(model, (i,))

        def at(v, g, one=one):
            return K.adaptive_scale.adaptive_camera_log_likelihoods((g,), v[None], one.likelihoods, scales)[0][0]

        per_sample = jax.vmap(jax.vmap(jax.vmap(at, (None, 0)), (None, 0)), (0, 0))  # over v; c; s
        out.append(jax.jit(per_sample)(jnp.arange(f.shape[0]), f))
    return tuple(out)


class FunctionalState(NamedTuple):
    """The carried state of one episode.

    Attributes:
        target: the true class c = object * n_poses + pose.
        config: ``[n]`` the cameras' current positions.
        belief: the recognizer's belief after the current features.
        features: the current features per camera.
        views: feature sets taken so far in this episode.
    """

    target: Int[Array, ""]
    config: Int[Array, " n"]
    belief: K.Belief
    features: tuple[Float[Array, " _K"], ...]
    views: Int[Array, ""]


class FunctionalEnv(eqx.Module):
    """The functional environment (module doc).

    Attributes:
        model: the sensor model (its Gaussians give the likelihoods).
        bank: where the observations are drawn from.
        p_threshold, max_steps: declare at P_th; truncate after ``max_steps``.
        transition, rho: the level transition (``"uniform"`` or ``"sticky"``).
        step_cost: ``base_reward = -step_cost``.
        adaptive_scale: the recognizer's evidence of a capture no class
            explains (``Recognizer.adaptive_scale``; 1 = off, the thesis's
            plain Bayes update).  Pass the recipe's (the ``robust`` recipe:
            32; ``env.unwrapped.adaptive_scale`` of an
            :class:`~jaxrecog.envs.ActiveRecognitionEnv`) for the belief its
            recognizer holds.  The episode rule (declare at ``p_threshold``)
            has no ``min_views``: the agent decides when to declare.
    """

    model: object
    bank: FeatureBank
    tables: tuple[Float[Array, "_V C S C _L"], ...]
    p_threshold: float = eqx.field(static=True)
    max_steps: int = eqx.field(static=True)
    transition: str = eqx.field(static=True)
    rho: float = eqx.field(static=True)
    step_cost: float = eqx.field(static=True)
    adaptive_scale: float = eqx.field(static=True)

    def __init__(self, model, bank: FeatureBank, *, p_threshold: float = 0.95, max_steps: int = 7,
                 transition: str = "uniform", rho: float = 0.9, step_cost: float = 0.0,
                 adaptive_scale: float = 1.0):
        pos = tuple(int(f.shape[0]) for f in bank.features)
        if pos != tuple(model.positions) or any(int(f.shape[1]) != model.n_classes for f in bank.features):
            raise ValueError(f"feature bank [V, C, S, K] shapes {[tuple(f.shape) for f in bank.features]} do not fit "
                             f"the model's positions {tuple(model.positions)} and {model.n_classes} classes")
        if transition not in ("uniform", "sticky"):
            raise ValueError(f"transition must be 'uniform' or 'sticky', got {transition!r}")
        scales = K.adaptive_scale.scale_grid(adaptive_scale)  # a finite number >= 1, or a clear error
        self.model, self.bank = model, bank
        self.adaptive_scale = float(adaptive_scale)
        self.tables = _loglik_tables(model, bank, scales)
        self.p_threshold, self.max_steps = float(p_threshold), int(max_steps)
        self.transition, self.rho, self.step_cost = transition, float(rho), float(step_cost)

    @property
    def positions(self) -> tuple[int, ...]:
        return tuple(int(p) for p in self.model.positions)

    @property
    def n_configs(self) -> int:
        return math.prod(self.positions)

    def _draw(self, target, config, key):
        """One bank entry per camera: ``(features, log-likelihoods [C, L_i])``."""
        keys = jr.split(key, len(self.bank.features))
        s = [jr.randint(keys[i], (), 0, f.shape[2]) for i, f in enumerate(self.bank.features)]
        feats = tuple(f[config[i], target, s[i]] for i, f in enumerate(self.bank.features))
        return feats, tuple(t[config[i], target, s[i]] for i, t in enumerate(self.tables))

    def _obs(self, state: FunctionalState) -> dict:
        return {
            "features": state.features,
            "configuration": ConfigGrid(self.positions).index(state.config, clip=True),
            "belief": K.class_marginal(state.belief),
            "views": state.views,
        }

    def init(self, target: Int[ArrayLike, ""], config: Int[ArrayLike, " n"], key: PRNGKeyArray) -> tuple[FunctionalState, dict]:
        """An episode of class ``target`` starting at ``config``: the uniform
        prior updated with the first features."""
        target = jnp.asarray(target, jnp.int32)
        config = jnp.asarray(config, jnp.int32)
        feats, logliks = self._draw(target, config, key)
        belief, _ = E.belief_from_logliks(E.uniform_prior(self.model), logliks)
        state = FunctionalState(target, config, belief, feats, jnp.ones((), jnp.int32))
        return state, self._obs(state)

    def reset(self, key: PRNGKeyArray) -> tuple[FunctionalState, dict]:
        """A uniformly random class and initial configuration."""
        k_class, k_config, k_obs = jr.split(key, 3)
        target = jr.randint(k_class, (), 0, self.model.n_classes)
        a = jr.randint(k_config, (), 0, self.n_configs)
        config = jnp.stack(ConfigGrid(self.positions).configuration(a)).astype(jnp.int32)
        return self.init(target, config, k_obs)

    def step(self, state: FunctionalState, action: dict, key: PRNGKeyArray):
        """``action = {"action": flat configuration index, "prediction": [C]
        class weights}`` -> ``(state, obs, reward, done, info)``."""
        n_classes = self.model.n_classes
        w = jnp.clip(jnp.asarray(action["prediction"], state.belief.log_pc.dtype), 0.0, 1.0)
        total = jnp.sum(w)
        p = jnp.where(total > 0, w / jnp.where(total > 0, total, 1.0), 1.0 / n_classes)
        loss = -jnp.log(jnp.maximum(p[state.target], _P_FLOOR)) / (math.log(n_classes) if n_classes > 1 else 1.0)
        declared = jnp.max(p) >= self.p_threshold
        truncated = ~declared & (state.views >= self.max_steps)
        done = declared | truncated

        # one draw and one Bayes update per step: of the next view, or (done)
        # of a fresh episode's first view from the uniform prior (auto-reset)
        k_class, k_config, k_obs = jr.split(key, 3)
        a = jnp.clip(jnp.asarray(action["action"], jnp.int32), 0, self.n_configs - 1)
        fresh = jr.randint(k_config, (), 0, self.n_configs)
        nxt = jnp.stack(ConfigGrid(self.positions).configuration(jnp.where(done, fresh, a))).astype(jnp.int32)
        target = jnp.where(done, jr.randint(k_class, (), 0, n_classes), state.target)
        moved = E.move_prior(state.belief, state.config, nxt, self.transition, self.rho)
        prior = jax.tree.map(lambda u, m: jnp.where(done, u, m), E.uniform_prior(self.model), moved)
        feats, logliks = self._draw(target, nxt, k_obs)
        belief, _ = E.belief_from_logliks(prior, logliks)
        new = FunctionalState(target, nxt, belief, feats, jnp.where(done, 1, state.views + 1))
        base = -jnp.asarray(self.step_cost, loss.dtype)
        # the episode rule of ActiveRecognitionEnv: a declaration stands for the steps it skips
        steps = jnp.where(declared, self.max_steps - state.views + 1, 1)
        loss = loss * steps
        info = {
            "base_reward": base,
            "prediction": {"target": state.target, "loss": loss, "steps": steps},
            "declared": declared,
            "truncated": truncated,
            "views": state.views,
            "correct": jnp.argmax(p) == state.target,
        }
        return new, self._obs(new), base - loss, done, info
