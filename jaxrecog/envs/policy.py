"""Our planners as policies of :class:`~jaxrecog.envs.ActiveRecognitionEnv`.

A :class:`PlannerPolicy` acts from the env's own observation (the images and
the current configuration) through the same recognizer a campaign runs (the
planner's tables seeded by ``settings.seed`` as in
:mod:`jaxrecog.campaigns`, the env's stop rule and transition:
:meth:`~jaxrecog.envs.ActiveRecognitionEnv.make_recognizer`).  Each step it updates
its belief from the images (eq. 3.1), predicts the class marginal P(c) — the
env ends the episode when that reaches P_th, as the recognizer stops — and
moves to the planner's best not yet visited configuration.  Run with the
keys of :func:`~jaxrecog.campaign.run_campaign` (``reset(trial=t)``), an
episode replaying a campaign trial takes the campaign's decisions.
"""

from __future__ import annotations

from typing import Any

import jax.random as jr
import numpy as np

from .. import kernels as K
from ..kernels.config_grid import ConfigGrid

__all__ = ["PlannerPolicy"]


class PlannerPolicy:
    """``policy(obs) -> action`` for one env (one episode at a time; a new
    episode of the env starts a new one of the policy).

    Args:
        name: a planner of :func:`jaxrecog.planners.make_planner` (``mi``,
            ``mi-class``, ``crlb``, ``random``, ...).
        env: the :class:`~jaxrecog.envs.ActiveRecognitionEnv` (or a wrapper of
            it) whose model, settings and action forms the policy uses.
    """

    def __init__(self, name: str, env):
        self.env = env.unwrapped
        self.name = name
        e = self.env
        self.recognizer = e.make_recognizer(name)
        s = e.settings
        self._base = jr.PRNGKey(s.seed + 1)  # run_campaign's key in the campaigns
        self._episodes = 0
        self.reset()

    def reset(self, *, trial: int | None = None, key=None) -> None:
        """Start a new episode: its keys are ``fold_in(key, step)`` with
        ``key = fold_in(PRNGKey(settings.seed + 1), trial)`` as in a campaign
        (default ``trial``: the number of episodes started so far)."""
        if key is None:
            key = jr.fold_in(self._base, self._episodes if trial is None else int(trial))
        self._key = key
        self._episodes += 1
        self._state = None
        self._n = 0
        self.last_decision = None

    def _config(self, obs) -> np.ndarray:
        c = np.asarray(obs["configuration"])
        if c.ndim == 0:
            c = np.asarray(ConfigGrid(self.env.positions).configuration(int(c)))
        return c.astype(np.int32)

    def __call__(self, obs: dict) -> dict[str, Any]:
        if self._n > 0 and self.env.views == 1:
            self.reset()  # the env was reset since the last call: a new episode
        config = self._config(obs)
        if self._state is None:
            self._state = self.recognizer.init(config=tuple(int(v) for v in config))
        elif not np.array_equal(np.asarray(self._state.config), config):
            raise ValueError(f"the observation is at configuration {tuple(config)}, but the policy moved to "
                             f"{tuple(np.asarray(self._state.config))}: the env did not take the policy's action")
        self._state, dec = self.recognizer.step(self._state, obs["images"], jr.fold_in(self._key, self._n))
        self._n += 1
        self.last_decision = dec
        # the class marginal after these images: the next prior's (the level
        # transition leaves P(c) as it is, eq. 3.8)
        pc = np.clip(np.asarray(K.class_marginal(self.recognizer.belief(self._state.prior)), np.float64), 0.0, 1.0)
        form = self.env.prediction_form
        if form == "index":
            pred: Any = np.int64(np.argmax(pc)) if bool(dec.stop) else np.int64(self.env.n_classes)
        elif form == "logits":
            pred = np.log(np.maximum(pc, 1e-30)).astype(np.float32)
        else:
            pred = pc.astype(np.float32)
        if self.env.action_form == "flat":
            act: Any = np.int64(dec.next_index)
        else:
            act = np.asarray(dec.next_config, np.int64)
        return {"action": act, "prediction": pred}

