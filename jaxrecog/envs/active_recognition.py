"""``ActiveRecognitionEnv``: the rig, a trained model and the recognizer's
belief as a Gymnasium environment, built on ap-gym's
``ActiveClassificationEnv`` (TimSchneider42/active-perception-gym) when
``ap_gym`` is installed (the ``gym`` extra), so that ap-gym's wrappers and
baselines take it; without ``ap_gym`` it is a plain ``gymnasium.Env`` with the
same spaces, reward and info (:data:`AP_GYM` says which).

Episode.  ``reset`` places an object in a pose (and, ``case="occluded"``,
cardboard occluders) and takes the first image set at a random initial
configuration.  Each ``step`` receives ``{"action": configuration,
"prediction": ...}``: the prediction is the agent's guess of the class
c = object * n_poses + pose from the images so far; the agent *declares* when
its prediction reaches ``p_threshold`` (thesis P_th = 0.95): the episode
terminates.  Otherwise, after ``max_steps`` image sets it is truncated;
otherwise the cameras move to the configuration and the next image set is
returned.  The number of steps of an episode is its number of views.

Reward (ap-gym): ``r = base_reward - loss`` with ``base_reward = -step_cost``
and the prediction loss normalised so that a blind guess scores 1,
``loss = -log p(target) / log C`` (cross entropy; for an index prediction the
0-1 loss).  ``info["base_reward"]``, ``info["prediction"]["target"]`` and
``info["prediction"]["loss"]`` carry them.

The episode rule: **a prediction that ends the episode stands for the rest of
it.**  An episode has ``max_steps`` prediction steps; declaring at view ``t``
ends it early, and its loss counts once for each step it skips,
``loss * (max_steps - t + 1)`` (``info["prediction"]["steps"]``).  So a
declared wrong guess costs what never answering costs, and with an index
prediction an episode's return is minus the number of steps without the right
answer: guessing blind at once (expected return ``-(1 - 1/C) max_steps``) is
worse than looking first.  (Without the rule, a guess cost as much as one
"not yet" and ended the episode, so PPO learned to guess at once.)

Prediction forms (``prediction=``):

- ``"probabilities"`` (default): ``Box(0, 1, (C,))`` class weights, normalised
  by the env (all zero = uniform).  ap-gym's logits have unbounded ``Box``
  bounds, which ``gymnasium.utils.env_checker.check_env`` warns about; this
  form carries the same information within bounds.
- ``"logits"``: ap-gym's ``Box(-inf, inf, (C,))``, ``p = softmax(logits)``.
- ``"index"``: ``Discrete(C + 1)``; ``i < C`` declares class ``i`` (ends the
  episode), ``C`` means "not yet" (loss 1 for that step).

Observation (``Dict``): ``images`` ``uint8 [n_cameras, H, W]`` (the model's
image shape), ``configuration`` (the current one, in the action's form), and
with ``features=True`` the eigenspace features per camera, with
``belief=True`` the recognizer's class marginal P(c) after these images.

``info``: the true ``object``, ``pose``, ``occluded_fraction`` per camera
(measured by the renderer; empty where the rig does not know it), ``views``, the belief's best
``belief_class`` and ``belief_probability``, ``valid`` (the images could be
used), and with ``scores=("mi", ...)`` each planner's scores of all
configurations under the predicted prior (``info["scores"][name]``, ``[A]``).
"""

from __future__ import annotations

import math
import os
from typing import Any, Sequence

import equinox as eqx
import gymnasium as gym
import jax.numpy as jnp
import jax.random as jr
import numpy as np

from .. import kernels as K
from ..driver import TrialSpec
from ..kernels.config_grid import ConfigGrid
from . import _engine as E
from .rigs import build_rig, load_env_model

try:  # the ap-gym base (extra `gym`); ap_gym 0.7 imports aiohttp and PIL without declaring them
    import ap_gym as _ap
except ImportError as e:  # the env works without it, as a plain gymnasium.Env
    _ap = None
    AP_GYM_MISSING = f"{type(e).__name__}: {e}"
else:
    AP_GYM_MISSING = ""

#: whether :class:`ActiveRecognitionEnv` subclasses ``ap_gym.ActiveClassificationEnv``
AP_GYM = _ap is not None

__all__ = ["ActiveRecognitionEnv", "ACTION_FORMS", "PREDICTION_FORMS", "AP_GYM"]

ACTION_FORMS = ("flat", "per-camera")
PREDICTION_FORMS = ("probabilities", "logits", "index")
#: the smallest probability a loss is computed from (keeps the reward finite)
_P_FLOOR = 1e-12


@eqx.filter_jit
def _scores(planner, predicted: K.PredictedBelief, key):
    return planner.scores(predicted, key)


def _is_int(v) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))


_RESET_OPTIONS = ("trial", "capture_seed")


def _reset_options(options) -> dict[str, Any]:
    """``reset(options=...)`` checked: ``None`` or a dict with the keys of
    :data:`_RESET_OPTIONS` only, ``trial`` a :class:`TrialSpec`,
    ``capture_seed`` an integer; a one-line ``TypeError``/``ValueError``
    naming the option otherwise."""
    if options is None:
        return {}
    if not isinstance(options, dict):
        raise TypeError(f"reset(options=...) must be a dict with keys 'trial' and/or 'capture_seed' (or None), "
                        f"got {type(options).__name__}")
    unknown = [k for k in options if k not in _RESET_OPTIONS]
    if unknown:
        raise ValueError(f"unknown reset option(s) {', '.join(sorted(map(repr, unknown)))}; "
                         f"known: 'trial', 'capture_seed'")
    if "trial" in options and not isinstance(options["trial"], TrialSpec):
        raise TypeError(f"options['trial'] must be a jaxrecog.campaign.TrialSpec, got {type(options['trial']).__name__}")
    if "capture_seed" in options:
        if not _is_int(options["capture_seed"]):
            raise TypeError(f"options['capture_seed'] must be an integer, got {options['capture_seed']!r}")
        if "trial" not in options:
            raise ValueError("options['capture_seed'] replays a campaign trial's capture noise: give it with "
                             "options['trial']")
    return dict(options)


# -- fork: JAX is multithreaded, and a forked child of a process whose JAX has
# started hangs in its first JAX call (gymnasium.vector.AsyncVectorEnv's
# default start method on Linux).  Such a child fails at once instead.
from jax._src import xla_bridge as _xla_bridge  # noqa: E402

_FORKED_AFTER_JAX = False


def _after_fork_in_child() -> None:
    global _FORKED_AFTER_JAX
    _FORKED_AFTER_JAX = _FORKED_AFTER_JAX or bool(getattr(_xla_bridge, "_backends", None))


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_after_fork_in_child)

FORK_MESSAGE = ("ActiveRecognitionEnv cannot run in a process forked after JAX started (JAX is multithreaded: the "
                "child would hang); start vector-env workers with spawn: gymnasium.vector.AsyncVectorEnv(env_fns, "
                "context='spawn'), or gymnasium.make_vec(..., vectorization_mode='async', "
                "vector_kwargs={'context': 'spawn'})")


def _check_not_forked() -> None:
    if _FORKED_AFTER_JAX:
        raise RuntimeError(FORK_MESSAGE)


def _make_loss_fn(form: str, n_classes: int):
    """The ap-gym loss of one step's prediction (``None`` without ap_gym):
    ap-gym's own normalised cross entropy for logits, the same on normalised
    class weights, the 0-1 loss for an index ("not yet" = ``C`` scores 1)."""
    if _ap is None:
        return None
    if form == "logits":
        return _ap.CrossEntropyLossFn(num_classes=n_classes).normalized
    norm = math.log(n_classes) if n_classes > 1 else 1.0

    class _Loss(_ap.LossFn):
        def numpy(self, prediction, target, batch_shape=(), rng=None):
            t = np.asarray(target)
            if form == "index":
                return (np.asarray(prediction) != t).astype(np.float32)
            x = np.asarray(prediction, np.float64)
            s = x.sum(axis=-1, keepdims=True)
            p = np.where(s > 0, x / np.where(s > 0, s, 1.0), 1.0 / n_classes)
            pt = np.take_along_axis(p, t[..., None], axis=-1)[..., 0]
            return (-np.log(np.maximum(pt, _P_FLOOR)) / norm).astype(np.float32)

        def _lower_bound(self):
            return 0.0

        def _blind_guessing_expected_value(self):
            return 1.0

    return _Loss()


def _choice(name: str, value: str, allowed: Sequence[str]) -> str:
    if value not in allowed:
        raise ValueError(f"{name} must be one of {', '.join(map(repr, allowed))}, got {value!r}")
    return value


_Base = _ap.ActiveClassificationEnv if _ap is not None else gym.Env


class ActiveRecognitionEnv(_Base):
    """Active multi-camera recognition of an object on the turn-table (module doc).

    With ``ap_gym`` installed it is an ``ap_gym.ActiveClassificationEnv``:
    ``action_space`` is an ``ap_gym.ActivePerceptionActionSpace``,
    ``prediction_target_space`` ``Discrete(C)``, ``loss_fn`` the per-step loss
    (ap-gym's normalised cross entropy for ``prediction="logits"``), and
    ``_step`` the ap-gym hook.  ``step`` is the env's own: ap-gym 0.7's
    ``ActivePerceptionEnv.step`` replaces ``_step``'s info with only
    ``base_reward`` and ``prediction`` (the true object, pose, belief and
    scores would be lost) and has no place for the episode rule above.

    Args:
        model: a :class:`~jaxrecog.SensorModel`, a model file, or ``None``
            (synthetic rigs: the case's model from
            :func:`jaxrecog.campaigns.prepare` with ``settings``).
        rig: ``"synthetic"``, ``"dataset:FOLDER"``, ``"hardware-sim"`` or a
            ``Rig`` object (:mod:`jaxrecog.envs.rigs`).
        case: ``"clean"`` or ``"occluded"`` (cardboard occluders per episode,
            placed as in the thesis campaigns).
        settings: :class:`jaxrecog.campaigns.Settings`: the synthetic rig's
            table (``stride``), capture noise and work folder, the defaults
            of ``p_threshold``, ``max_steps``, ``transition``, the planners'
            Monte Carlo sizes (``samples``, ``min_per_stratum``, tables
            seeded by ``seed``), and the recognizer's options: the belief
            keeps the view component (``shared_view``) and weakens the
            evidence of unexplained captures (``adaptive_scale``) as the
            recognizer's step does; the policies' recognizers
            (:meth:`make_recognizer`) also take ``min_views`` and
            ``exclude_visited_positions``.
        cameras: a subset of the cameras (e.g. ``(0,)``: single camera).
        action: ``"flat"`` (``Discrete(A)``, row-major index) or
            ``"per-camera"`` (``MultiDiscrete(V_1, ..., V_n)``).
        prediction: ``"probabilities"``, ``"logits"`` or ``"index"``.
        features, belief: add the features / the class belief to the observation.
        scores: planner names (:func:`jaxrecog.planners.make_planner`) whose
            scores of all configurations go into ``info["scores"]``.
        step_cost: the cost of one step (one image set); ``base_reward = -step_cost``.
        p_threshold, max_steps, transition, rho: the stop rule and the level
            transition (defaults from ``settings``; ``rho`` for ``"sticky"``).
        render_mode: ``None`` or ``"rgb_array"`` (the cameras' current images
            side by side).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 2}

    def __init__(
        self,
        model: Any = None,
        rig: Any = "synthetic",
        *,
        case: str = "clean",
        settings=None,
        cameras: Sequence[int] | None = None,
        action: str = "flat",
        prediction: str = "probabilities",
        features: bool = False,
        belief: bool = False,
        scores: Sequence[str] = (),
        step_cost: float = 0.0,
        p_threshold: float | None = None,
        max_steps: int | None = None,
        transition: str | None = None,
        rho: float = 0.9,
        render_mode: str | None = None,
    ):
        from ..campaigns import Settings

        _check_not_forked()
        self.settings = settings if settings is not None else Settings()
        cams = None if cameras is None else tuple(int(c) for c in cameras)
        self.action_form = _choice("action", action, ACTION_FORMS)
        self.prediction_form = _choice("prediction", prediction, PREDICTION_FORMS)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        self.p_threshold = float(self.settings.p_threshold if p_threshold is None else p_threshold)
        self.max_steps = int(self.settings.max_steps if max_steps is None else max_steps)
        self.transition = self.settings.transition if transition is None else transition
        _choice("transition", self.transition, ("uniform", "sticky"))
        self.rho = float(rho)
        if not 0.0 < self.p_threshold <= 1.0 or self.max_steps < 1:
            raise ValueError(f"need 0 < p_threshold <= 1 and max_steps >= 1, got {self.p_threshold}, {self.max_steps}")
        if not math.isfinite(step_cost):
            raise ValueError(f"step_cost must be finite, got {step_cost}")
        self.step_cost = float(step_cost)

        self.model = load_env_model(model, rig, case, self.settings, cams)
        self.shared_view = bool(self.settings.shared_view)
        self.adaptive_scale = float(self.settings.adaptive_scale)
        self.make_recognizer("random")  # the recognizer's checks of these options and the model, before any rig
        self.rig, self._occluders = build_rig(rig, case, self.settings, cams)
        E.check_layout(self.model, self.rig)
        self.case = case
        self.positions = tuple(int(p) for p in self.model.positions)
        self.n_configs = int(np.prod(self.positions))
        self.n_classes = int(self.model.n_classes)
        self._planners = {n: self.make_planner(n) for n in scores}

        cfg_space = gym.spaces.Discrete(self.n_configs) if action == "flat" else gym.spaces.MultiDiscrete(self.positions)
        C = self.n_classes
        logit_space = _ap.LogitSpace if _ap is not None else gym.spaces.Box
        pred_space = {
            "probabilities": gym.spaces.Box(0.0, 1.0, (C,), np.float32),
            "logits": logit_space(-np.inf, np.inf, (C,), np.float32),
            "index": gym.spaces.Discrete(C + 1),
        }[prediction]
        if _ap is not None:
            _ap.ActiveClassificationEnv.__init__(self, C, cfg_space)
            self.action_space = _ap.ActivePerceptionActionSpace(cfg_space, pred_space)
        else:
            self.action_space = gym.spaces.Dict({"action": cfg_space, "prediction": pred_space})
        self.prediction_target_space = gym.spaces.Discrete(C)
        self.loss_fn = _make_loss_fn(prediction, C)
        H, W = self.model.image_shape
        obs = {
            "images": gym.spaces.Box(0, 255, (len(self.positions), H, W), np.uint8),
            "configuration": cfg_space,
        }
        if features:
            obs["features"] = gym.spaces.Tuple(
                [gym.spaces.Box(-E.FEATURE_BOUND, E.FEATURE_BOUND, (c.n_components,), np.float32) for c in self.model.cameras])
        if belief:
            obs["belief"] = gym.spaces.Box(0.0, 1.0, (C,), np.float32)
        self.observation_space = gym.spaces.Dict(obs)
        self._scene: TrialSpec | None = None
        self._done = True

    @property
    def configuration(self) -> tuple[int, ...]:
        """The cameras' current positions."""
        return tuple(int(v) for v in self._config)

    @property
    def class_belief(self) -> np.ndarray:
        """The recognizer's class marginal P(c) after the images so far, ``float32 [C]``."""
        if self._scene is None:
            raise gym.error.ResetNeeded("call reset() before reading the belief")
        return self._class_probs()

    @property
    def views(self) -> int:
        """Image sets taken in the current episode (1 right after ``reset``)."""
        return int(getattr(self, "_views", 0))

    # -- construction helpers -------------------------------------------------

    def make_recognizer(self, planner: str):
        """The recognizer of ``planner`` over the env's model, as a campaign
        with the env's settings builds it (:func:`jaxrecog.recognizer_factory.make_recognizer`):
        the planner's tables (:meth:`make_planner`), the env's stop rule
        (``p_threshold``, ``max_steps``) and transition, and the settings'
        ``min_views``, ``exclude_visited_positions``, ``adaptive_scale`` and
        ``shared_view``."""
        from ..recognizer_factory import make_recognizer

        recipe = self.settings.recipe.replace(p_threshold=self.p_threshold)
        return make_recognizer(self.model, self.make_planner(planner), recipe=recipe, max_steps=self.max_steps,
                               transition=self.transition, rho=self.rho, shared_view=self.shared_view)

    def make_planner(self, name: str):
        """The planner ``name`` over the env's model, built as the campaigns
        build it (tables from ``PRNGKey(settings.seed)``, ``settings.samples``,
        ``settings.min_per_stratum``)."""
        from ..planners import make_planner

        s = self.settings
        return make_planner(name, self.model, key=jr.PRNGKey(s.seed), samples=s.samples, min_per_stratum=s.min_per_stratum)

    # -- the episode ----------------------------------------------------------

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """A new scene and its first image set.

        ``options={"trial": TrialSpec, "capture_seed": s}`` replays a campaign
        trial (:func:`jaxrecog.campaign.plan_trials`): its object, pose,
        initial configuration and occluders, and the capture noise of
        :func:`~jaxrecog.campaign.run_campaign` run with ``seed=s`` (the
        driver's ``(seed, trial, step)``).
        Otherwise the scene is drawn from the env's generator."""
        _check_not_forked()
        options = _reset_options(options)  # before anything changes: a bad option loses nothing
        if "trial" in options:
            self._check_scene(options["trial"])
        super().reset(seed=seed)
        self._done = True  # stays so until the first image set is in
        if "trial" in options:
            scene = options["trial"]
            noise = (int(options.get("capture_seed", self.settings.seed)), scene.trial)
        else:
            rng = self.np_random
            obj, pose = int(rng.integers(self.model.n_objects)), int(rng.integers(self.model.n_poses))
            initial = tuple(int(rng.integers(v)) for v in self.positions)
            occ = self._occluders(rng, initial) if self._occluders is not None else None
            scene = TrialSpec(-1, obj, pose, initial, occ)
            noise = (int(rng.integers(2**62)),)
        self._scene, self._noise = scene, noise
        self._views = 0
        E.start(self.rig, scene)
        self._take_images(np.asarray(scene.initial, np.int32), E.uniform_prior(self.model, self.shared_view))
        self._done = False
        return self._obs(), self._info()

    def _check_scene(self, s: TrialSpec) -> None:
        for name in ("trial", "object", "pose"):
            if not _is_int(getattr(s, name)):
                raise TypeError(f"options['trial'].{name} must be an integer, got {getattr(s, name)!r}")
        if not isinstance(s.initial, (tuple, list, np.ndarray)) or not all(_is_int(v) for v in s.initial):
            raise TypeError(f"options['trial'].initial must be a tuple of integers (one position per camera), "
                            f"got {s.initial!r}")
        if s.yaw_offset is not None and not (isinstance(s.yaw_offset, (int, float, np.floating, np.integer))
                                             and not isinstance(s.yaw_offset, bool) and math.isfinite(s.yaw_offset)):
            raise TypeError(f"options['trial'].yaw_offset must be a finite number of degrees or None, got {s.yaw_offset!r}")
        if not (0 <= s.object < self.model.n_objects and 0 <= s.pose < self.model.n_poses):
            raise ValueError(f"trial {s.trial}: object {s.object} / pose {s.pose} outside the model's "
                             f"{self.model.n_objects} x {self.model.n_poses}")
        if len(s.initial) != len(self.positions) or any(not 0 <= v < n for v, n in zip(s.initial, self.positions)):
            raise ValueError(f"trial {s.trial}: initial configuration {s.initial} outside the positions {self.positions}")

    def _take_images(self, config: np.ndarray, prior: K.Belief) -> None:
        """Capture at ``config`` and update the belief from ``prior`` (the
        episode changes only once both succeeded: a rig error loses nothing)."""
        images, occluded = E.capture(self.rig, config, self._noise + (self._views,))
        posterior, feats, ok = E.observe(self.model, prior, jnp.asarray(config), images, shared_view=self.shared_view,
                                         adaptive_scale=self.adaptive_scale)
        self._config, self._images, self._occluded = config, images, occluded
        self._posterior, self._features, self._valid = posterior, feats, bool(ok)
        self._views += 1

    def step(self, action):
        if self._scene is None:
            raise gym.error.ResetNeeded("call reset() before step()")
        if self._done:
            raise gym.error.ResetNeeded("the episode has ended (terminated or truncated); call reset() before step()")
        self._parse_configuration(action)  # both parts checked before anything changes
        probs, declared = self._parse_prediction(action)
        views = self._views
        obs, base, terminated, truncated, info, target = self._step(action["action"], action["prediction"])
        if self.prediction_form == "index":
            loss = 0.0 if int(action["prediction"]) == target else 1.0
        else:
            loss = -math.log(max(float(probs[target]), _P_FLOOR)) / (math.log(self.n_classes) if self.n_classes > 1 else 1.0)
        # the episode rule (module doc): a declaration stands for the steps it skips
        steps = self.max_steps - views + 1 if declared else 1
        # "metrics": ap-gym's log wrappers read them (its losses here report none)
        info["prediction"] = {"target": target, "loss": float(loss * steps), "steps": steps, "metrics": {}}
        return obs, float(base - loss * steps), terminated, truncated, info

    def _step(self, action, prediction):
        """ap-gym's hook: one transition, ``(obs, base_reward, terminated,
        truncated, info, prediction_target)``, without the prediction's loss."""
        full = {"action": action, "prediction": prediction}
        config = self._parse_configuration(full)
        _, declared = self._parse_prediction(full)
        target = self._target
        terminated = bool(declared)
        truncated = not terminated and self._views >= self.max_steps
        if not (terminated or truncated):
            prior = E.move_prior(self._posterior, jnp.asarray(self._config), jnp.asarray(config), self.transition, self.rho)
            self._take_images(config, prior)
        self._done = terminated or truncated
        base = 0.0 - self.step_cost
        info = self._info()
        info["base_reward"] = base
        return self._obs(), base, terminated, truncated, info, target

    # -- input checks (nothing changes before they pass) ----------------------

    def _parse_configuration(self, action) -> np.ndarray:
        if not isinstance(action, dict) or set(action) != {"action", "prediction"}:
            got = sorted(action) if isinstance(action, dict) else type(action).__name__
            raise gym.error.InvalidAction(f"an action is a dict with keys 'action' and 'prediction', got {got}")
        a = action["action"]
        space = self.action_space["action"]
        if self.action_form == "flat":
            if np.ndim(a) != 0 or not np.issubdtype(np.asarray(a).dtype, np.integer) or not 0 <= int(a) < self.n_configs:
                raise gym.error.InvalidAction(f"action['action'] = {a!r} is outside {space} (a configuration index)")
            return np.asarray(ConfigGrid(self.positions).configuration(int(a)), np.int32)
        arr = np.asarray(a)
        if arr.shape != (len(self.positions),) or not np.issubdtype(arr.dtype, np.integer) or not space.contains(arr.astype(space.dtype)):
            raise gym.error.InvalidAction(f"action['action'] = {a!r} is outside {space} (one position per camera)")
        return arr.astype(np.int32)

    def _parse_prediction(self, action) -> tuple[np.ndarray | None, bool]:
        """``(class probabilities or None, declared)``."""
        p = action["prediction"]
        C = self.n_classes
        if self.prediction_form == "index":
            if np.ndim(p) != 0 or not np.issubdtype(np.asarray(p).dtype, np.integer) or not 0 <= int(p) <= C:
                raise gym.error.InvalidAction(f"action['prediction'] = {p!r} is outside Discrete({C + 1}) "
                                              f"(a class index, or {C} for 'not yet')")
            return None, int(p) < C
        x = np.asarray(p, np.float64)
        if x.shape != (C,):
            raise gym.error.InvalidAction(f"action['prediction'] must have shape ({C},) (one entry per class), got {x.shape}")
        if self.prediction_form == "logits":
            if np.any(np.isnan(x)) or np.any(x == np.inf):
                raise gym.error.InvalidAction("action['prediction'] logits must not be NaN or +inf")
            probs = np.exp(x - x.max()) if np.isfinite(x.max()) else np.full(C, 1.0)
        else:
            if not np.all(np.isfinite(x)):
                raise gym.error.InvalidAction("action['prediction'] must lie in [0, 1] (class weights), got NaN or inf")
            if np.any(x < 0) or np.any(x > 1):
                raise gym.error.InvalidAction(f"action['prediction'] must lie in [0, 1] (class weights), "
                                              f"got values in [{x.min()}, {x.max()}]")
            probs = x if x.sum() > 0 else np.full(C, 1.0)
        probs = probs / probs.sum()
        return probs, bool(probs.max() >= self.p_threshold)

    # -- what the agent and the logs see --------------------------------------

    @property
    def _target(self) -> int:
        return int(self._scene.object * self.model.n_poses + self._scene.pose)

    def _configuration_obs(self):
        if self.action_form == "flat":
            return np.int64(ConfigGrid(self.positions).index(tuple(int(v) for v in self._config)))
        return self._config.astype(np.int64)

    def _class_probs(self) -> np.ndarray:
        belief = E.class_belief(self.model, self._posterior, self.shared_view)
        return np.clip(np.asarray(K.class_marginal(belief), np.float32), 0.0, 1.0)

    def _obs(self) -> dict:
        obs = {"images": self._images.copy(), "configuration": self._configuration_obs()}
        if "features" in self.observation_space.spaces:
            obs["features"] = tuple(np.clip(np.asarray(g, np.float32), -E.FEATURE_BOUND, E.FEATURE_BOUND) for g in self._features)
        if "belief" in self.observation_space.spaces:
            obs["belief"] = self._class_probs()
        return obs

    def _info(self) -> dict:
        pc = self._class_probs()
        best = int(np.argmax(pc))
        info = {
            "object": int(self._scene.object),
            "pose": int(self._scene.pose),
            "occluded_fraction": self._occluded.copy(),
            "views": int(self._views),
            "belief_class": best,
            "belief_probability": float(pc[best]),
            "valid": self._valid,
            "prediction": {"target": self._target},
        }
        if self._planners:
            predicted = E.class_belief(self.model, K.transition_per_position(
                self._posterior, jnp.asarray(self._config), self.positions, kind=self.transition, rho=self.rho),
                self.shared_view)
            key = jr.fold_in(jr.PRNGKey(self.settings.seed), self._views)
            info["scores"] = {n: np.asarray(_scores(p, predicted, key)) for n, p in self._planners.items()}
        return info

    def render(self):
        """The current images, cameras side by side, as ``uint8 [H, n W, 3]``
        (``render_mode="rgb_array"``; ``None`` otherwise)."""
        if self.render_mode != "rgb_array" or self._scene is None:
            return None
        row = np.concatenate(list(self._images), axis=1)
        return np.repeat(row[:, :, None], 3, axis=2)

    def close(self):
        close = getattr(self.rig, "close", None)
        if close is not None and not getattr(self, "_closed", False):
            close()
        self._closed = True
        super().close()
