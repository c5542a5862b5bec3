"""Environments: the rig, a trained model and the recognizer's belief as a
Gymnasium environment (``jaxrecog/ActiveRecognition-v0``), our planners as
its policies, and a pure JAX functional form for fast rollouts on features.

Needs the ``gym`` extra (``gymnasium``) for the Gymnasium parts; the
functional form (:mod:`jaxrecog.envs.functional`) needs only JAX.
Importing this package registers the environment ids with
``gymnasium.register``, so ``gymnasium.make("jaxrecog/ActiveRecognition-v0",
model=..., rig=...)`` works after ``import jaxrecog.envs``;
``jaxrecog/ActiveRecognitionFlat-v0`` is the same env under
:class:`FlatActions` (a ``Discrete`` action, the prediction from the
recognizer's belief, a flat ``Box`` observation) for stable-baselines3 and
CleanRL.  With ``ap_gym`` installed (the ``gym`` extra) the env is an
``ap_gym.ActiveClassificationEnv`` (:data:`AP_GYM`).
"""

from __future__ import annotations

from .functional import FeatureBank, FunctionalEnv, FunctionalState, bank_from_database, bank_from_rig

ENV_ID = "jaxrecog/ActiveRecognition-v0"
FLAT_ENV_ID = "jaxrecog/ActiveRecognitionFlat-v0"

__all__ = [
    "AP_GYM",
    "ENV_ID",
    "FLAT_ENV_ID",
    "ActiveRecognitionEnv",
    "FlatActions",
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

#: the Gymnasium parts, imported on first use: ``import jaxrecog.envs`` stays
#: light (ap_gym, the env's base class, imports datasets, pandas and pyarrow)
_GYM_NAMES = {
    "ActiveRecognitionEnv": "active_recognition",
    "AP_GYM": "active_recognition",
    "FlatActions": "flat",
    "PlannerPolicy": "policy",
    "run_episodes": "rollout",
    "confident_errors": "rollout",
    "env_vs_campaign": "rollout",
    "summary": "rollout",
}

try:
    import gymnasium as _gym
except ImportError:  # the functional form still works; the rest says what to install
    _gym = None
else:
    if ENV_ID not in _gym.registry:
        _gym.register(id=ENV_ID, entry_point="jaxrecog.envs.active_recognition:ActiveRecognitionEnv")
    if FLAT_ENV_ID not in _gym.registry:
        _gym.register(id=FLAT_ENV_ID, entry_point="jaxrecog.envs.flat:make_flat")


def __getattr__(name: str):
    if name in _GYM_NAMES:
        if _gym is None:
            raise ImportError(f"jaxrecog.envs.{name} needs gymnasium: install the extra, pip install 'jaxrecog[gym]'")
        import importlib

        value = getattr(importlib.import_module(f".{_GYM_NAMES[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'jaxrecog.envs' has no attribute {name!r}")
