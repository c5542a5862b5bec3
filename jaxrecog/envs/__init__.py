"""Environments: the rig, a trained model and the recognizer's belief as a
Gymnasium environment (``jaxrecog/ActiveRecognition-v0``), our planners as
its policies, and a pure JAX functional form for fast rollouts on features.

Needs the ``gym`` extra (``gymnasium``) for the Gymnasium parts; the
functional form (:mod:`jaxrecog.envs.functional`) needs only JAX.
Importing this package registers the environment id with
``gymnasium.register``, so ``gymnasium.make("jaxrecog/ActiveRecognition-v0",
model=..., rig=...)`` works after ``import jaxrecog.envs``.
"""

from __future__ import annotations

from .functional import FeatureBank, FunctionalEnv, FunctionalState, bank_from_database, bank_from_rig

ENV_ID = "jaxrecog/ActiveRecognition-v0"

__all__ = [
    "ENV_ID",
    "ActiveRecognitionEnv",
    "FeatureBank",
    "FunctionalEnv",
    "FunctionalState",
    "PlannerPolicy",
    "bank_from_database",
    "bank_from_rig",
    "confident_errors",
    "env_vs_campaign",
    "run_episodes",
    "summary",
]

_GYM_NAMES = {"ActiveRecognitionEnv", "PlannerPolicy", "run_episodes", "confident_errors", "env_vs_campaign", "summary"}

try:
    import gymnasium as _gym
except ImportError:  # the functional form still works; the rest says what to install
    _gym = None
else:
    from .active_recognition import ActiveRecognitionEnv
    from .policy import PlannerPolicy
    from .rollout import confident_errors, env_vs_campaign, run_episodes, summary

    if ENV_ID not in _gym.registry:
        _gym.register(id=ENV_ID, entry_point="jaxrecog.envs.active_recognition:ActiveRecognitionEnv")


def __getattr__(name: str):
    if name in _GYM_NAMES:
        raise ImportError(f"jaxrecog.envs.{name} needs gymnasium: install the extra, pip install 'jaxrecog[gym]'")
    raise AttributeError(f"module 'jaxrecog.envs' has no attribute {name!r}")
