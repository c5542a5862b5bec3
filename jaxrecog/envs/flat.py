"""``FlatActions``: :class:`~jaxrecog.envs.ActiveRecognitionEnv` with a plain
``Discrete``/``MultiDiscrete`` action and a flat ``Box`` observation, for RL
libraries that take neither a ``Dict`` action nor a ``Dict`` observation
(stable-baselines3's ``MlpPolicy``, CleanRL's ``ppo.py``).

The agent chooses only the next camera configuration.  The prediction is
taken from the recognizer's belief: the env's class marginal P(c) after the
images so far, in the env's prediction form (class weights, log-probabilities
as logits, or for an index the argmax once it reaches ``p_threshold`` and
"not yet" before).  So the episode ends as the recognizer stops (P(c) reaches
P_th) or after ``max_steps`` image sets, and the reward is the env's:
``-step_cost`` minus the belief's normalised cross entropy each step, the
last one counted for every step it skips (the env's episode rule).

Registered as ``jaxrecog/ActiveRecognitionFlat-v0`` (:func:`make_flat`): the
keyword arguments of :class:`~jaxrecog.envs.ActiveRecognitionEnv` plus
``observation``.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from .active_recognition import ActiveRecognitionEnv

__all__ = ["FlatActions", "make_flat", "OBSERVATIONS"]

OBSERVATIONS = ("belief", "dict")


class FlatActions(gym.Wrapper):
    """The configuration as the whole action; the prediction from the belief.

    Args:
        env: an :class:`~jaxrecog.envs.ActiveRecognitionEnv` (or a wrapper of one).
        observation: ``"belief"`` (default): ``Box(0, 1, (C + sum V_i + 1,))``
            ``float32``, the class marginal P(c), a one-hot of each camera's
            position and ``views / max_steps``; ``"dict"``: the env's own
            observation (images, configuration, ...) unchanged.
    """

    def __init__(self, env: gym.Env, observation: str = "belief"):
        super().__init__(env)
        if observation not in OBSERVATIONS:
            raise ValueError(f"observation must be one of {', '.join(map(repr, OBSERVATIONS))}, got {observation!r}")
        base = env.unwrapped
        if not isinstance(base, ActiveRecognitionEnv):
            raise TypeError(f"FlatActions wraps an ActiveRecognitionEnv, got {type(base).__name__}")
        self.base = base
        self.observation_form = observation
        self.action_space = base.action_space["action"]
        if observation == "belief":
            n = base.n_classes + sum(base.positions) + 1
            self.observation_space = gym.spaces.Box(0.0, 1.0, (n,), np.float32)

    def prediction(self) -> Any:
        """The recognizer's prediction now, in the env's prediction form."""
        e = self.base
        pc = e.class_belief
        if e.prediction_form == "index":
            best = int(np.argmax(pc))
            return np.int64(best if pc[best] >= e.p_threshold else e.n_classes)
        if e.prediction_form == "logits":
            return np.log(np.maximum(pc, 1e-30)).astype(np.float32)
        return pc.astype(np.float32)

    def _observe(self, obs):
        if self.observation_form == "dict":
            return obs
        e = self.base
        parts = [e.class_belief]
        for v, n in zip(e.configuration, e.positions):
            parts.append(np.eye(n, dtype=np.float32)[v])
        parts.append(np.array([min(e.views / e.max_steps, 1.0)], np.float32))
        return np.clip(np.concatenate(parts).astype(np.float32), 0.0, 1.0)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        return self._observe(obs), info

    def step(self, action):
        if not self.action_space.contains(np.asarray(action, dtype=self.action_space.dtype)) \
                or not np.issubdtype(np.asarray(action).dtype, np.integer):
            raise gym.error.InvalidAction(f"action {action!r} is outside {self.action_space} (a configuration)")
        obs, reward, terminated, truncated, info = self.env.step({"action": action, "prediction": self.prediction()})
        return self._observe(obs), reward, terminated, truncated, info


def make_flat(observation: str = "belief", **kwargs) -> FlatActions:
    """``jaxrecog/ActiveRecognitionFlat-v0``: ``FlatActions(ActiveRecognitionEnv(**kwargs), observation)``."""
    return FlatActions(ActiveRecognitionEnv(**kwargs), observation=observation)
