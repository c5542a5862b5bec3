"""The recognizer: one jitted step a control loop can call.

``Recognizer.step(state, images, key) -> (state, Decision)`` does, with fixed
shapes and no Python branching on data:

1. features per camera at its current position, g_i = V_iᵀ(y_i/‖y_i‖ − x̄_i)
   (eq. 4.1-4.11) — on the host with NumPy when the step is called with
   concrete arrays on the CPU (:func:`~jaxrecog.features.host_features`),
   inside the program when traced;
2. Bayes update of the factorised belief with log p(g_i | c, k_i, v_i)
   (eq. 3.1, 4.17-4.19) — an unusable image (zero energy, NaN) leaves the
   belief unchanged and sets ``Decision.valid = False``; so does a usable
   image set whose likelihood is not finite (or zero) under every class,
   which also sets ``Decision.degenerate``: the model cannot explain it (a
   campaign stops there, :func:`jaxrecog.driver.run_trials`);
3. the stop test: the best (object, pose) reaches ``p_threshold`` (thesis
   P_th = 0.95) or ``max_steps`` image sets were taken;
4. the next configuration: the planner scores all configurations under the
   predicted prior (transition per candidate position, eq. 3.7-3.9), minus
   λ · seconds to move there where the recognizer has a
   :class:`~jaxrecog.motion.MotionCost` (not in the thesis; λ = 0 is the
   planner's own choice), and the best not yet visited is chosen (optionally, ``exclude_visited_positions``,
   also none where some camera would return to a position it already used —
   a departure from the thesis, see :class:`Recognizer`);
5. the prior for the next step: the level transition for the cameras that move.

The state carries the *prior* for the images the rig will capture next.
"""

from __future__ import annotations

import weakref
from typing import NamedTuple, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.random as jr
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int, PRNGKeyArray, Real

from . import kernels as K
from .features import HostFeatures, host_features, host_planes, project_at
from .kernels.config_grid import ConfigGrid
from .motion import MotionCost
from .planners import Planner

__all__ = ["Recognizer", "RecognizerState", "Decision", "StepTrace", "excluded_by_positions", "restrict_cameras", "image_features",
           "check_min_views", "host_planes_of", "initial_belief", "update_from_features", "update_from_images", "view_marginal"]


class RecognizerState(NamedTuple):
    """Carried between steps.

    Attributes:
        prior: belief for the images taken at ``config``.
        config: ``[n_cameras]`` current position of each camera.
        steps: image sets taken so far.
        visited: ``[A]`` configurations already used.
        visited_positions: per camera ``[V_i]``, the positions that camera
            already took an image from (read only with
            ``Recognizer.exclude_visited_positions``).
        explained: image sets so far with some capture the model explained
            (:mod:`jaxrecog.kernels.adaptive_scale`; counted toward
            ``min_views`` only with ``Recognizer.adaptive_scale > 1``).
    """

    prior: K.Belief
    config: Int[Array, " n"]
    steps: Int[Array, ""]
    visited: Bool[Array, " A"]
    visited_positions: tuple[Bool[Array, " _V"], ...] = ()
    explained: Int[Array, ""] | None = None


class StepTrace(NamedTuple):
    """What a step computed beyond the decision, returned only when asked
    (``Recognizer.step(..., trace=True)``): plots, the CLI's ``plan`` and
    per-step belief traces read it, a control loop does not.

    Attributes:
        scores: ``[A]`` planner scores of all configurations (higher = better;
            a failed estimate is ``-inf``), minus λ · travel seconds where the
            recognizer has a motion cost (the scores the choice was made on).
        object_probs: ``[M]`` object marginal (summed over poses).
        class_probs: ``[C]`` (object, pose) marginal.
        posterior: the belief after this step's images.
    """

    scores: Float[Array, " A"]
    object_probs: Float[Array, " M"]
    class_probs: Float[Array, " C"]
    posterior: K.Belief


class Decision(NamedTuple):
    """Per-step output (not carried): what a control loop needs.

    Attributes:
        object, pose: the best (object, pose) after this step's images.
        probability: its posterior probability.
        stop: whether to stop (threshold reached or step limit).
        reached: whether the threshold was reached.
        next_config: ``[n_cameras]`` positions to move to (if not stopping).
            On a stopping step taken with ``plan_on_stop=False`` the planner
            is not run and this is the first configuration not yet used.
        next_index: the flat configuration index of ``next_config``.
        valid: ``False`` if the images could not be used (belief unchanged).
        trace: a :class:`StepTrace` when the step was asked to trace, else ``None``.
        degenerate: the images were usable but the model's likelihood of
            them was NaN, +inf or zero under every class (belief unchanged,
            ``valid`` False): a model that cannot explain the capture (e.g.
            corrupt arrays), not a bad image.
    """

    object: Int[Array, ""]
    pose: Int[Array, ""]
    probability: Float[Array, ""]
    stop: Bool[Array, ""]
    reached: Bool[Array, ""]
    next_config: Int[Array, " n"]
    next_index: Int[Array, ""]
    valid: Bool[Array, ""]
    trace: StepTrace | None = None
    degenerate: Bool[Array, ""] | None = None


def restrict_cameras(model, cameras: Sequence[int]):
    """The same sensor model over a subset of cameras (e.g. ``(0,)`` for the
    single-camera baseline)."""
    cams = tuple(model.cameras[i] for i in cameras)
    return eqx.tree_at(lambda m: m.cameras, model, cams)


def image_features(model, config: Int[ArrayLike, " n"], images: Real[ArrayLike, "n H W"]
                   ) -> tuple[tuple[Float[Array, " _K"], ...], Bool[Array, ""]]:
    """Eigenspace features per camera (eq. 4.1-4.11) and one validity flag.

    Returns ``(gs, ok)``: one ``[K_i]`` vector per camera (each camera has its
    own eigenspaces, so this is a loop over cameras, unrolled under ``jit``)
    and a scalar bool that is ``False`` when some image is black, constant or
    not finite (:func:`~jaxrecog.features.project_at`).
    """
    gs, oks = zip(*(project_at(cam, config[i], images[i]) for i, cam in enumerate(model.cameras)))
    return tuple(gs), jnp.all(jnp.stack(oks))


def excluded_by_positions(seen: Sequence[Bool[Array, " _V"]], positions: tuple[int, ...]) -> Bool[Array, " A"]:
    """``[A]``: configurations in which some camera i is at a position of
    ``seen[i]``; a camera that has used all its positions excludes nothing
    (so the product of the cameras' remaining positions is never empty)."""
    lapsed = [s & ~jnp.all(s) for s in seen]
    return ConfigGrid(positions).combine(jnp.logical_or, lapsed, jnp.zeros(positions, bool))


def initial_belief(model, shared_view: bool = False) -> K.Belief:
    """The uniform belief of section 3.3 over the model's classes and levels;
    with ``shared_view``, over the ``C * M`` extended classes (the mixture
    weights as the prior of the view component, :mod:`jaxrecog.kernels.shared_latent`)."""
    dtype = model.cameras[0].likelihood.dtype
    prior = K.uniform_belief(model.n_objects * model.n_poses, tuple(len(model.levels) for _ in model.cameras),
                             dtype=dtype)
    if shared_view:
        log_pm = K.shared_latent.prior_log_weights(model.likelihoods[0]).astype(dtype)
        prior = K.shared_latent.extend(prior, log_pm)
    return prior


def update_from_images(model, prior: K.Belief, config: Int[ArrayLike, " n"], images: Real[ArrayLike, "n H W"], *,
                       shared_view: bool = False, adaptive_scale: float = 1.0
                       ) -> tuple[K.Belief, tuple[Float[Array, " _K"], ...], Bool[Array, ""], Bool[Array, ""]]:
    """One image set's Bayes update of the belief (eq. 3.1): features
    g_i = V_iᵀ(y_i/‖y_i‖ − x̄_i) (eq. 4.1-4.11), log p(g_i | c, k_i, v_i) per
    camera (eq. 4.17-4.19) — per view component with ``shared_view``
    (:mod:`jaxrecog.kernels.shared_latent`), weakened per capture with
    ``adaptive_scale > 1`` (:mod:`jaxrecog.kernels.adaptive_scale`) — and the
    update of ``prior``.  An unusable image leaves the belief unchanged.

    Returns ``(posterior, features, ok, explained)``: the posterior in the
    prior's own form (over ``C * M`` extended classes with ``shared_view``),
    one ``[K_i]`` feature vector per camera, whether the update was used, and
    whether some capture was explained (always true without the adaptive scale).
    """
    gs, usable = image_features(model, config, jnp.asarray(images))
    return update_from_features(model, prior, config, gs, usable, shared_view=shared_view,
                                adaptive_scale=adaptive_scale)


def update_from_features(model, prior: K.Belief, config: Int[ArrayLike, " n"], gs: Sequence[Float[ArrayLike, " _K"]],
                         usable: Bool[ArrayLike, ""], *, shared_view: bool = False, adaptive_scale: float = 1.0
                         ) -> tuple[K.Belief, tuple[Float[Array, " _K"], ...], Bool[Array, ""], Bool[Array, ""]]:
    """:func:`update_from_images` from the image set's features ``gs`` (one
    ``[K_i]`` per camera) and their validity ``usable``, as
    :func:`image_features` or :func:`~jaxrecog.features.host_features` give them."""
    gs = tuple(jnp.asarray(g) for g in gs)
    explained = jnp.ones((), bool)
    if shared_view:
        logliks = K.shared_latent.component_log_likelihoods(gs, config, model.likelihoods)
    elif adaptive_scale > 1.0:
        logliks, explained = K.adaptive_scale.adaptive_camera_log_likelihoods(
            gs, config, model.likelihoods, K.adaptive_scale.scale_grid(adaptive_scale))
    else:
        logliks = K.camera_log_likelihoods(gs, config, model.likelihoods)
    posterior, info = K.update_with_info(prior, logliks, valid=usable)
    return posterior, gs, info.ok, explained


def view_marginal(model, belief: K.Belief | K.PredictedBelief, shared_view: bool = False
                  ) -> K.Belief | K.PredictedBelief:
    """The belief over (class, levels): with ``shared_view`` the marginal of
    one over the ``C * M`` extended classes, of the same form (a
    :class:`~jaxrecog.kernels.PredictedBelief` from
    :func:`~jaxrecog.kernels.transition_per_position` stays one), else
    ``belief`` itself."""
    if not shared_view:
        return belief
    return K.shared_latent.marginal(belief, K.shared_latent.shared_components(model.likelihoods))


def check_min_views(min_views: int, max_steps: int) -> int:
    """``min_views`` as given, or a ``ValueError``: an integer in ``[1, max_steps]``."""
    if isinstance(min_views, bool) or not isinstance(min_views, int) or not 1 <= min_views <= max_steps:
        raise ValueError(f"min_views must be an integer in [1, max_steps = {max_steps}], got {min_views!r}")
    return min_views


class Recognizer(eqx.Module):
    """Sensor model + planner + settings.  ``init`` / ``step`` (see module doc).

    Attributes:
        model: the :class:`~jaxrecog.sensor_model.SensorModel` (its number of
            cameras is the recognizer's).
        planner: any :class:`~jaxrecog.planners.Planner`.
        p_threshold: stop when the best (object, pose) reaches it (P_th).
        max_steps: stop after this many image sets (thesis: 7).
        min_views: never stop on the threshold before this many image sets
            (default 1, the thesis's rule: stop at the first step that reaches
            P_th).  2 asks every decision to be confirmed by a second image
            set from another configuration: *a departure from the thesis*,
            against one-view decisions that an unmodelled capture (an
            occluder read as a look-alike's sticker) drives to p ~ 1.
        transition: ``"uniform"`` (thesis, eq. 3.9) or ``"sticky"``.
        rho: stay probability of the sticky transition.
        revisit: allow choosing a configuration already used (always true
            for a planner whose ``revisits`` class attribute is true, e.g. a
            :class:`~jaxrecog.planners.FixedPlanner`, which never moves).
        exclude_visited_positions: also exclude every configuration in which
            some camera returns to a position it already took an image from
            (default off).  *A departure from the thesis*, which excludes only
            configurations already used, so one camera may stay on its view
            while the other moves: that second capture counts as independent
            evidence (eq. 4.17) although a shift- or occlusion-driven error of
            the same view is systematic.  Per camera the exclusion lapses once
            all its positions are used (e.g. camera 2 after 7 views), so some
            configuration always remains; configurations already used stay
            excluded as before.  Ignored where revisits are allowed.
        shared_view: for a view-mixture model, keep the mixture component
            (the object's turn off the training pose) in the state, one for
            every camera and step, instead of marginalising it per capture
            (:mod:`jaxrecog.kernels.shared_latent`; default off).  *Not in the
            thesis*: the belief is over ``(c, m, k_i)``; everything outside
            the step (decisions, planner, trace) sees its marginal over ``m``
            (:meth:`belief`).  A ``ValueError`` for a model without view
            components.
        adaptive_scale: the largest per-capture variance factor of the
            adaptive scale (:mod:`jaxrecog.kernels.adaptive_scale`; default 1,
            off: the thesis's evidence).  Above 1, each capture's evidence is
            weakened by the factor ``s*`` under which its best class explains
            it best, and only image sets with some capture explained
            (``s* <= √2``) count toward ``min_views``: a trial whose captures
            all fall between the training views looks again instead of
            stopping sure and wrong.  *Not in the thesis.*
    """

    model: object
    planner: Planner
    p_threshold: float = eqx.field(static=True, default=0.95)
    max_steps: int = eqx.field(static=True, default=7)
    min_views: int = eqx.field(static=True, default=1)
    transition: str = eqx.field(static=True, default="uniform")
    rho: float = eqx.field(static=True, default=0.9)
    revisit: bool = eqx.field(static=True, default=False)
    exclude_visited_positions: bool = eqx.field(static=True, default=False)
    motion: MotionCost | None = None
    shared_view: bool = eqx.field(static=True, default=False)
    adaptive_scale: float = eqx.field(static=True, default=1.0)

    def __check_init__(self):
        check_min_views(self.min_views, self.max_steps)
        K.adaptive_scale.scale_grid(self.adaptive_scale)   # a ValueError for a bad value
        if self.adaptive_scale > 1.0 and self.shared_view:
            raise ValueError("adaptive_scale and shared_view cannot be combined (the shared view component "
                             "keeps per-component evidence; the adaptive scale rescales per capture)")
        if self.motion is not None and tuple(self.motion.positions) != tuple(self.positions):
            raise ValueError(f"motion cost tables have positions {self.motion.positions}, the model {tuple(self.positions)}")
        if self.shared_view:
            K.shared_latent.shared_components(self.model.likelihoods)
            for i, lik in enumerate(self.model.likelihoods):
                if isinstance(lik.log_w, jax.core.Tracer):   # inside a transform: checked where it was built
                    continue
                w = np.asarray(lik.log_w)
                if not np.allclose(w, w[:1, :, :1, :], atol=1e-5):
                    raise ValueError(f"shared_view: camera {i}'s mixture weights differ between positions or "
                                     f"levels; a shared view component needs one prior over components per class")

    @property
    def n_view_components(self) -> int:
        """``M`` of the shared view component (1 without ``shared_view``)."""
        return K.shared_latent.shared_components(self.model.likelihoods) if self.shared_view else 1

    def belief(self, prior: K.Belief | K.PredictedBelief) -> K.Belief | K.PredictedBelief:
        """The belief over (class, levels) of a state's ``prior`` (with
        ``shared_view``, its marginal over the view component; else itself),
        of the same form (a :class:`~jaxrecog.kernels.PredictedBelief` stays one)."""
        return view_marginal(self.model, prior, self.shared_view)

    @property
    def positions(self) -> tuple[int, ...]:
        return self.model.positions

    @property
    def n_configs(self) -> int:
        return int(np.prod(self.positions))

    def init(self, key: PRNGKeyArray | None = None, config: Sequence[int] | Int[ArrayLike, " n"] | None = None) -> RecognizerState:
        """Uniform belief (section 3.3) at ``config`` (default: a random
        configuration drawn from ``key``, or all zeros without a key)."""
        positions = self.positions
        if config is None:
            if key is None:
                config = (0,) * len(positions)
            else:
                a = jr.randint(key, (), 0, self.n_configs)
                config = jnp.stack(ConfigGrid(positions).configuration(a)).astype(jnp.int32)
        config = jnp.asarray(config, jnp.int32)
        if config.shape != (len(positions),):
            raise ValueError(f"config must give one position per camera ({len(positions)}), got shape {config.shape}")
        prior = initial_belief(self.model, self.shared_view)
        # zeros made on the host: an eager jnp.zeros compiles a program per shape
        zeros = lambda shape, dtype: jax.device_put(np.zeros(shape, dtype))  # noqa: E731
        return RecognizerState(prior, config, zeros((), np.int32), zeros((self.n_configs,), bool),
                               tuple(zeros((v,), bool) for v in positions), zeros((), np.int32))

    def step(self, state: RecognizerState, images: Real[ArrayLike, "n H W"] | HostFeatures, key: PRNGKeyArray, *,
             trace: bool = False, plan_on_stop: bool = True) -> tuple[RecognizerState, Decision]:
        """One image set in, the belief updated, the next configuration out.

        ``trace=True`` (static: one compile per value) adds the
        :class:`StepTrace` (scores, marginals, posterior) to the decision.
        ``plan_on_stop=False`` (static) skips the planner on a step that stops,
        unless ``trace`` asks for the scores (a ``lax.cond``: under ``jit`` or ``lax.map`` only the taken branch
        runs; under ``vmap`` both do).  The campaigns' driver uses it: every
        trial's last step is one of its ~2 steps, and the planner is most of
        a step's time.  The belief, the decision and every non-stopping step
        are unchanged; only a stopping step's ``next_config`` is then the first
        unused configuration instead of the planned one (a caller that goes on
        after ``stop``, e.g. the Gymnasium policy, keeps the default).

        One jitted program per (recognizer structure, static settings, shapes):
        a plain ``jax.jit`` over the recognizer's arrays, split from its static
        part once per recognizer (:func:`_split`), so a call costs one dispatch
        and returns before the device is done (``eqx.filter_jit`` re-split the
        recognizer and waited for the result at every call).

        Called with concrete arrays on the CPU, the images are projected on the
        host (:func:`~jaxrecog.features.host_features`: XLA's CPU projection
        is half of a single-trial step) and the program starts from their
        features; traced (inside a transform: the campaigns' batched step) or
        on another device, the program projects them itself.  The two agree to
        float32 rounding.  ``images`` may also be the
        :class:`~jaxrecog.features.HostFeatures` of the image set (the
        campaigns' driver projects its slots so)."""
        params, static, planes = _split(self)
        feats = None
        if planes is not None and not isinstance(images, HostFeatures):
            feats = host_features(planes, state.config, images, self.model.image_shape)
        return _jit_step(params, static, state, images if feats is None else feats, key, bool(trace),
                         bool(plan_on_stop))

    def _step(self, state: RecognizerState, images, key, trace: bool, plan_on_stop: bool
              ) -> tuple[RecognizerState, Decision]:
        """The body of :meth:`step` (traced inside its program)."""
        model = self.model
        positions = self.positions
        # the state's own belief (over (c, m, k) with shared_view), and its
        # marginal over (c, k), which everything after the update reads
        if isinstance(images, HostFeatures):  # projected on the host (:meth:`step`)
            gs, usable = images
        else:
            gs, usable = image_features(model, state.config, jnp.asarray(images))
        state_posterior, _, ok, explained = update_from_features(
            model, state.prior, state.config, gs, usable, shared_view=self.shared_view,
            adaptive_scale=self.adaptive_scale)
        degenerate = jnp.asarray(usable, bool) & ~ok   # usable images the model explains under no class
        posterior = self.belief(state_posterior)

        pc = jnp.minimum(K.class_marginal(posterior), 1.0)   # exp of a float32 log-probability may round above 1
        best = jnp.argmax(pc)
        prob = pc[best]
        steps = state.steps + 1
        n_explained = (jnp.zeros((), jnp.int32) if state.explained is None else state.explained) \
            + (explained & ok).astype(jnp.int32)
        reached = prob >= self.p_threshold
        # with the adaptive scale only explained image sets count toward min_views
        views = n_explained if self.adaptive_scale > 1.0 else steps
        stop = (reached & (views >= self.min_views)) | (steps >= self.max_steps)

        here = ConfigGrid(positions).index(state.config)
        visited = state.visited.at[here].set(True)
        seen = state.visited_positions or tuple(jnp.zeros((v,), bool) for v in positions)
        seen = tuple(s.at[state.config[i]].set(True) for i, s in enumerate(seen))
        state_predicted = K.transition_per_position(state_posterior, state.config, positions, kind=self.transition, rho=self.rho)
        predicted = self.belief(state_predicted)
        # a planner that looks past this prior predicts with the recognizer's transition
        planner = self.planner.with_transition(self.transition, self.rho)

        def plan(_):
            out = planner.scores(predicted, key)
            return out if self.motion is None else self.motion.apply(out, state.config)

        if plan_on_stop or trace:
            scores = plan(None)
        else:
            shape = jax.eval_shape(plan, None)
            scores = jax.lax.cond(stop, lambda _: jnp.zeros(shape.shape, shape.dtype), plan, None)
        # a non-finite score (a failed estimate) ranks below every finite one,
        # but above a configuration excluded as visited
        usable = jnp.where(jnp.isfinite(scores), scores, jnp.finfo(scores.dtype).min)
        if self.revisit or self.planner.revisits:
            scores_for_choice = usable
        else:
            excluded = visited
            if self.exclude_visited_positions:
                excluded = excluded | excluded_by_positions(seen, positions)
            masked = jnp.where(excluded, -jnp.inf, usable)
            # with the per-camera lapse, everything is excluded only once every
            # configuration was used (an unused position of any camera leaves
            # configurations never used): then revisit, as before
            scores_for_choice = jnp.where(jnp.all(excluded), usable, masked)
        nxt = jnp.argmax(scores_for_choice)
        next_config = jnp.stack(ConfigGrid(positions).configuration(nxt)).astype(jnp.int32)

        # the prior for the next images: the predicted prior at the chosen positions
        next_prior = state_predicted.at(next_config)
        new_state = RecognizerState(next_prior, next_config, steps, visited, seen, n_explained)
        step_trace = None
        if trace:
            step_trace = StepTrace(
                scores=jnp.where(jnp.isnan(scores), -jnp.inf, scores),
                object_probs=K.object_marginal(posterior, model.n_objects, model.n_poses),
                class_probs=pc,
                posterior=posterior,
            )
        decision = Decision(
            object=(best // model.n_poses).astype(jnp.int32),
            pose=(best % model.n_poses).astype(jnp.int32),
            probability=prob,
            stop=stop,
            reached=reached,
            next_config=next_config,
            next_index=nxt.astype(jnp.int32),
            valid=ok,
            trace=step_trace,
            degenerate=degenerate,
        )
        return new_state, decision


class StaticParts:
    """A recognizer's non-array part as a static jit argument: hashed and
    compared by its tree structure and leaves (a leaf is equal to itself even
    where ``==`` says otherwise, e.g. a NaN setting), so an equal recognizer
    built afresh finds the compiled step."""

    def __init__(self, tree):
        self.tree = tree
        self._leaves, self._treedef = jax.tree.flatten(tree)
        self._hash = hash((self._treedef, tuple(self._leaves)))

    def __hash__(self) -> int:
        return self._hash

    def __eq__(self, other) -> bool:
        if not isinstance(other, StaticParts):
            return NotImplemented
        return (self._treedef == other._treedef and len(self._leaves) == len(other._leaves)
                and all(a is b or bool(a == b) for a, b in zip(self._leaves, other._leaves)))


#: id(recognizer) -> (weak reference, arrays, static part, host planes): the
#: split of a recognizer, made once (~80 us a split on the 2-core CPU, against
#: a ~1 ms step)
_SPLITS: dict[int, tuple] = {}


def host_planes_of(model) -> tuple[tuple[np.ndarray, np.ndarray], ...] | None:
    """Per camera its :func:`~jaxrecog.features.host_planes` where the
    model's bases live on the CPU, else ``None``."""
    arrays = [a for cam in model.cameras for a in (cam.mean_image, cam.basis)]
    if not all(isinstance(a, jax.Array) and all(d.platform == "cpu" for d in a.devices()) for a in arrays):
        return None
    return tuple(host_planes(cam) for cam in model.cameras)


def _split(rec: Recognizer) -> tuple[object, StaticParts, tuple | None]:
    """``(arrays, static part, host planes)`` of a recognizer, cached per live
    object (modules are immutable); not cached while its leaves are tracers (a
    recognizer rebuilt inside a transform, e.g. the driver's batched step)."""
    hit = _SPLITS.get(id(rec))
    if hit is not None and hit[0]() is rec:
        return hit[1], hit[2], hit[3]
    params, static = eqx.partition(rec, eqx.is_array)
    static = StaticParts(static)
    if any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(params)):
        return params, static, None
    planes = host_planes_of(rec.model)
    key = id(rec)
    _SPLITS[key] = (weakref.ref(rec, lambda _, key=key: _SPLITS.pop(key, None)), params, static, planes)
    return params, static, planes


def _step_program(params, static: StaticParts, state: RecognizerState, images, key, trace: bool, plan_on_stop: bool):
    return eqx.combine(params, static.tree)._step(state, images, key, trace, plan_on_stop)


_step_program.__name__ = _step_program.__qualname__ = "step"  # the compile logs' name (tests/compiles.py)
_jit_step = jax.jit(_step_program, static_argnums=(1, 5, 6))
