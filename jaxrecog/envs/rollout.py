"""Episodes of :class:`~jaxrecog.envs.ActiveRecognitionEnv` as campaign trials.

:func:`run_episodes` replays campaign trials (:func:`jaxrecog.campaign.plan_trials`)
through the env with a policy and records each as a
:class:`~jaxrecog.results.TrialResult`, so the env's numbers go through the
same tables (:func:`jaxrecog.results.summarize`) as
:func:`~jaxrecog.campaign.run_campaign`'s.
"""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from ..driver import TrialSpec
from ..results import TrialResult

__all__ = ["run_episodes", "confident_errors", "summary", "env_vs_campaign"]


def _probabilities(env, prediction) -> np.ndarray:
    """The class distribution an agent's prediction stands for."""
    C = env.n_classes
    if env.prediction_form == "index":
        p = np.full(C, 1.0 / C)
        if int(prediction) < C:
            p = np.eye(C)[int(prediction)]
        return p
    x = np.asarray(prediction, np.float64)
    if env.prediction_form == "logits":
        x = np.exp(x - x.max())
    return x / x.sum() if x.sum() > 0 else np.full(C, 1.0 / C)


def run_episodes(env, policy: Callable, specs: Sequence[TrialSpec], *, capture_seed: int = 0) -> list[TrialResult]:
    """One episode per trial spec (``reset(options={"trial": spec, "capture_seed":
    capture_seed})``, ``policy.reset(trial=spec.trial)`` when it has one).

    A trial's answer is the argmax of the agent's last prediction, its exit
    probability that prediction's largest probability, ``stopped`` whether the
    episode terminated (the agent declared) rather than truncated, and
    ``steps`` its number of views."""
    env = env.unwrapped
    out = []
    for spec in specs:
        obs, info = env.reset(options={"trial": spec, "capture_seed": capture_seed})
        if hasattr(policy, "reset"):
            policy.reset(trial=spec.trial)
        cfgs = [env.configuration]
        occl = [tuple(float(x) for x in info["occluded_fraction"])]
        invalid = int(not info["valid"])
        while True:
            action = policy(obs)
            obs, _, terminated, truncated, info = env.step(action)
            if terminated or truncated:
                break
            cfgs.append(env.configuration)
            occl.append(tuple(float(x) for x in info["occluded_fraction"]))
            invalid += int(not info["valid"])
        p = _probabilities(env, action["prediction"])
        best = int(np.argmax(p))
        n_poses = env.model.n_poses
        out.append(TrialResult(
            trial=spec.trial, object=spec.object, pose=spec.pose,
            predicted_object=best // n_poses, predicted_pose=best % n_poses,
            exit_prob=float(p[best]), steps=int(info["views"]), stopped=bool(terminated),
            invalid_steps=invalid, occluded_fraction=tuple(occl), configurations=tuple(cfgs),
        ))
    return out


def confident_errors(results: Sequence[TrialResult]) -> int:
    """Trials that stopped at p >= P_th on the wrong answer (docs/design.md §7)."""
    return sum(1 for r in results if r.stopped and not r.correct)


def summary(results: Sequence[TrialResult], n_objects: int) -> dict:
    """The average row of the thesis table (:func:`jaxrecog.results.summarize`)
    plus the confident errors (a count) and the rate's 95 % Wilson interval (``rate_ci``, percent)."""
    from ..results import summarize

    avg = summarize(results, n_objects)[-1]
    return {"trials": avg.trials, "rate": avg.rate, "rate_ci": list(avg.rate_ci), "exit_prob": avg.exit_prob,
            "views": avg.views,
            "confident_errors": confident_errors(results)}


def env_vs_campaign(env, planner: str, specs: Sequence[TrialSpec], *, batch: int = 16) -> dict:
    """``planner`` through the env (:class:`~jaxrecog.envs.PlannerPolicy`) and
    through :func:`~jaxrecog.campaign.run_campaign` with the same recognizer,
    rig, trials, keys and capture seeds (``env.settings.seed``), with wall times.

    Returns ``{"env": results, "campaign": results, "env_s", "campaign_s",
    "same": fraction of trials with the same answer, views and path}``."""
    import time

    import jax.random as jr

    from ..campaign import run_campaign
    from .policy import PlannerPolicy

    env = env.unwrapped
    seed = env.settings.seed
    policy = PlannerPolicy(planner, env)
    t0 = time.perf_counter()
    via_env = run_episodes(env, policy, specs, capture_seed=seed)
    env_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    # the policy's own recognizer on the env's rig (the campaign resets and
    # reseeds the rig before every capture, as the env does)
    campaign = run_campaign(policy.recognizer, env.rig, specs, key=jr.PRNGKey(seed + 1), batch=batch, seed=seed)
    campaign_s = time.perf_counter() - t0
    path = lambda r: (r.predicted_object, r.predicted_pose, r.steps, r.stopped, r.configurations)  # noqa: E731
    same = float(np.mean([path(a) == path(b) for a, b in zip(via_env, campaign)])) if specs else 1.0
    return {"env": via_env, "campaign": campaign, "env_s": env_s, "campaign_s": campaign_s, "same": same}
