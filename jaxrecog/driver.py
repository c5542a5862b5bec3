"""The trial driver: rig -> images -> features -> belief -> planner -> rig.

One loop serves the campaigns (:func:`jaxrecog.campaign.run_campaign`), the
``jaxrecog recognize`` command, the demo's trace and the Gymnasium
environment.  It talks to rigs only through the :class:`~jaxrecog.hardware.Rig`
protocol, by way of a rig pool (:mod:`jaxrecog.hardware.rigs.rig_pool`) that takes
one step's captures at once, in this process or in worker processes.

Trials run in ``batch`` lockstep *slots*; the steps of all slots are one
jitted call (:func:`batched_step`).  A slot that finishes its trial takes the
next one at once (the restart happens inside the jitted step, from a
``fresh`` mask), so the batch stays full instead of idling until its slowest
trial is done.  Slot ``b`` captures with rig ``b % n_rigs`` of the pool; a rig is
``reset`` only when it must show another trial's scene, so with one rig per
slot every trial is reset exactly once.

The data path of one step (``docs/architecture.md`` lists it too):

1. host, per active slot: ``rig.reseed((seed, trial, step))``,
   ``rig.move(config)``, ``rig.capture()`` -> ``images[b]`` (uint8) and the
   true occluded fractions;
2. one upload: ``images [B, n, H, W]``, ``configs [B, n]`` (only read for
   fresh slots), ``fresh [B]``, ``trials [B]``, ``steps [B]``;
3. device, one call: restart fresh slots, features, Bayes update, stop test,
   planner scores, next configuration, next prior;
4. one download: the :class:`~jaxrecog.recognizer.Decision` of every slot
   (with its trace only when tracing); the next step's configurations are its
   ``next_config``.

Devices: ``devices=N`` shards the lockstep batch over N devices (a 1-D
:class:`jax.sharding.Mesh` with the axis ``"trials"``): the per-slot states,
images and inputs are split along the batch (``PartitionSpec("trials")``),
the recognizer (model, planner tables) is replicated, and each device runs the
same per-slot ``lax.map`` over its share (``jax.shard_map``), so a trial's
result is the same as on one device.  The batch is rounded up to a multiple of
N (extra lockstep slots, which take trials like the others).

Pipelining: by default (``pipeline=True``) the slots are two groups, each
stepped by its own call: while the device runs one group's step (dispatched
asynchronously), the host captures the other group's images, so rendering
and the recognizer overlap instead of taking turns.  A trial's result does
not depend on its group (see Keys).

Travel: where the recognizer has a :class:`~jaxrecog.motion.MotionCost`, each
result's ``travel_s`` is the seconds its moves took under that motion model
(the initial configuration is free); otherwise NaN.

A usable image set that the model explains under no class (its likelihood
NaN, +inf or zero for every one, ``Decision.degenerate``) stops the run with
an :class:`UnexplainedCaptureError`: such a model would end every trial at
an unchanged belief, wrong, with nothing to say why.

Keys: trial ``t`` step ``n`` uses ``fold_in(fold_in(key, t), n)`` and the
rig's capture noise is reseeded with ``(seed, t, n)``, so a trial's result
does not depend on the batch, the slot or the trials beside it.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any, Callable, Iterable, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.random as jr
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec
from jaxtyping import ArrayLike, Bool, Int, PRNGKeyArray, Shaped

from .hardware.rigs.rig import Capture, CaptureJob, Rig, RigPool, SceneSpec  # the rig interface: all the driver needs
from .features import host_features_batch
from .recognizer import Decision, Recognizer, RecognizerState, StaticParts, host_planes_of
from .results import TrialResult

__all__ = ["TrialSpec", "StepRecord", "run_trials", "batched_step", "trial_mesh", "TRIALS_AXIS",
           "UnexplainedCaptureError"]


class UnexplainedCaptureError(ValueError):
    """A usable image set whose likelihood under the model is NaN, +inf or
    zero for every class (``Decision.degenerate``): the model cannot explain
    it, and every trial would end at its unchanged (uniform) belief, wrong.
    The trials finished before it keep their results."""

#: The mesh axis the lockstep batch is sharded along (:func:`trial_mesh`).
TRIALS_AXIS = "trials"


@dataclasses.dataclass(frozen=True)
class TrialSpec:
    """Everything that defines one trial (reproducible from the campaign seed)."""

    trial: int
    object: int
    pose: int
    initial: tuple[int, ...]
    occluders: Any = None  # rig-specific layout, None = clean scene
    #: degrees the object is turned off its training pose for the whole trial
    #: (:class:`~jaxrecog.hardware.render.synthetic.OffGrid`); None = on the grid
    #: (the rig's ``reset`` is then called without it, as every rig allows)
    yaw_offset: float | None = None


@dataclasses.dataclass(frozen=True)
class StepRecord:
    """What :func:`run_trials` reports to ``on_step`` after each step of a trial.

    Attributes:
        spec: the trial.
        step: 0-based step number.
        config: the configuration the images were taken at.
        capture: the rig's :class:`~jaxrecog.hardware.Capture`.
        decision: this trial's :class:`~jaxrecog.recognizer.Decision` (NumPy
            leaves; ``trace`` filled when the run traces).
    """

    spec: TrialSpec
    step: int
    config: tuple[int, ...]
    capture: Capture
    decision: Decision


def _slot_step(recognizer: Recognizer, trace: bool, start: RecognizerState, state: RecognizerState, fresh, config,
               images, key, trial, step):
    # a new trial (fresh) restarts from ``start``, the uniform state, at its own configuration
    start = start._replace(config=jnp.asarray(config, jnp.int32))
    state = jax.tree.map(lambda a, b: jnp.where(fresh, a, b), start, state)
    k = jr.fold_in(jr.fold_in(key, trial), step)
    # a trial's stopping step needs no next configuration: skip its planner
    # (Recognizer.step still plans when tracing: the trace shows every step's scores)
    return recognizer.step(state, images, k, trace=trace, plan_on_stop=False)


def _map_slots(recognizer: Recognizer, states, fresh, configs, images, key, trials, steps, vectorize: bool, trace: bool):
    # the uniform start state is the same for every slot but its configuration:
    # built once per batch, not in every slot (``Recognizer.init`` at a configuration)
    start = recognizer.init(config=jnp.zeros(jnp.shape(configs)[1:], jnp.int32))

    def one(args):
        state, fresh_b, config, imgs, trial, step = args
        return _slot_step(recognizer, trace, start, state, fresh_b, config, imgs, key, trial, step)

    xs = (states, fresh, configs, images, trials, steps)
    if vectorize:
        return jax.vmap(lambda *a: one(a))(*xs)
    return jax.lax.map(one, xs)


@functools.partial(jax.jit, static_argnames=("static", "vectorize", "trace", "mesh"))
def _batched_step(params, static: StaticParts, states: RecognizerState, fresh, configs, images, key, trials, steps, *,
                  vectorize: bool, trace: bool, mesh: Mesh | None):
    # module level, the recognizer an argument (its arrays ``params``, the
    # rest ``static``, hashable): jit's cache is keyed on its structure and
    # static fields, so every campaign with the same (or an equal-shaped)
    # recognizer reuses one compiled step.  Plain jax.jit, not eqx.filter_jit:
    # that one waits for the result, and the driver's pipeline needs the call
    # to return while the device computes
    if mesh is None:
        recognizer = eqx.combine(params, static.tree)
        return _map_slots(recognizer, states, fresh, configs, images, key, trials, steps, vectorize, trace)
    # sharded: each device maps its own slots; the recognizer's arrays (model,
    # planner tables, λ) and the key are replicated

    def local(params, key, states, fresh, configs, images, trials, steps):
        rec = eqx.combine(params, static.tree)
        return _map_slots(rec, states, fresh, configs, images, key, trials, steps, vectorize, trace)

    shard, rep = PartitionSpec(TRIALS_AXIS), PartitionSpec()
    f = jax.shard_map(local, mesh=mesh, in_specs=(rep, rep, shard, shard, shard, shard, shard, shard),
                      out_specs=shard, check_vma=False)
    return f(params, key, states, fresh, configs, images, trials, steps)


def trial_mesh(devices: int | Sequence[jax.Device] | None) -> Mesh | None:
    """The 1-D mesh (axis :data:`TRIALS_AXIS`) a campaign shards its batch
    over: ``devices`` = a count (the first N of ``jax.devices()``) or the
    devices themselves; ``None`` or 1 = no sharding (one device, the default
    path).  More devices than exist is a ``ValueError`` naming how many do."""
    if devices is None:
        return None
    if isinstance(devices, (int, np.integer)) and not isinstance(devices, bool):
        n = int(devices)
        if n < 1:
            raise ValueError(f"devices must be >= 1, got {n}")
        have = jax.devices()
        if n > len(have):
            raise ValueError(
                f"asked for {n} devices but {len(have)} exist ({len(have)} x {have[0].platform}: "
                f"{', '.join(str(d) for d in have[:4])}{', ...' if len(have) > 4 else ''}); on a CPU-only "
                f"machine XLA_FLAGS=--xla_force_host_platform_device_count={n} (set before jax is imported) "
                f"makes {n} host devices")
        if n == 1:
            return None
        devs = have[:n]
    else:
        devs = list(devices)
        if not devs:
            raise ValueError("devices: an empty list")
        if len(devs) == 1:
            return None
    return Mesh(np.array(devs), (TRIALS_AXIS,))


def batched_step(recognizer: Recognizer, *, vectorize: bool = False, trace: bool = False, mesh: Mesh | None = None):
    """``(states, fresh[B], configs[B, n], images[B, n, H, W], key, trials[B],
    steps[B]) -> (states, decisions)``: one step of ``B`` lockstep slots in one
    jitted call.  Where ``fresh`` is true the slot first restarts from the
    uniform belief at ``configs[b]`` (a new trial); slot ``b`` uses the key
    ``fold_in(fold_in(key, trials[b]), steps[b])``.

    The compiled step is cached per recognizer (structure, static settings and
    array shapes), not per call of this function: a second campaign with the
    same recognizer compiles nothing.

    By default the batch is a ``lax.map`` (a loop inside the compiled
    program), not a ``vmap``: the kernels guard underflow with a ``lax.cond``
    that runs the exact logsumexp only when needed, and ``vmap`` turns that
    cond into a select that always runs both branches.  Measured on 2 cores
    (DB2 model, 16 trials): MI 6.6 ms/trial alone vs 17.9 ms/trial vmapped;
    CRLB 115 ms vs 652 ms.  ``vectorize=True`` gives the ``vmap`` form.

    ``mesh`` (:func:`trial_mesh`): shard the ``B`` slots over its devices
    (``B`` must be a multiple of their number); the result is the same.
    """
    vectorize, trace = bool(vectorize), bool(trace)
    if mesh is not None and len(mesh.devices.flat) == 1:
        mesh = None
    # split the recognizer once, not at every call (and with a mesh, replicate
    # the model and planner tables once)
    params, static = eqx.partition(recognizer, eqx.is_array)
    static = StaticParts(static)
    planes = host_planes_of(recognizer.model)
    if mesh is not None:
        params = jax.device_put(params, NamedSharding(mesh, PartitionSpec()))

    def step(states, fresh: Bool[ArrayLike, " B"], configs: Int[ArrayLike, "B n"], images: Shaped[ArrayLike, "B n H W"],
             key: PRNGKeyArray, trials: Int[ArrayLike, " B"], steps: Int[ArrayLike, " B"]):
        if mesh is not None:
            n = len(mesh.devices.flat)
            if len(fresh) % n:
                raise ValueError(f"batch {len(fresh)} is not a multiple of the mesh's {n} devices")
        images = _host_projected(planes, recognizer.model.image_shape, states, fresh, configs, images)
        if mesh is not None:
            sh = NamedSharding(mesh, PartitionSpec(TRIALS_AXIS))
            states, fresh, configs, images, trials, steps = jax.device_put(
                (states, fresh, configs, images, trials, steps), sh)
        return _batched_step(params, static, states, fresh, configs, images, key, trials, steps,
                             vectorize=vectorize, trace=trace, mesh=mesh)

    return step


def _host_projected(planes, image_shape, states: RecognizerState, fresh, configs, images):
    """The slots' images projected on the host where the model's planes are
    there (:func:`~jaxrecog.features.host_features_batch`, as a single
    :meth:`Recognizer.step` does: the same features, the same decisions),
    else the images: a continuing slot's images were taken at its state's
    configuration, a fresh slot's at ``configs``.  Inputs whose shapes do not
    agree go to the program as they are (it raises)."""
    if planes is None or any(isinstance(x, jax.core.Tracer) for x in (states.config, fresh, configs, images)):
        return images
    fresh, configs, current = np.asarray(fresh), np.asarray(configs), np.asarray(states.config)
    if not (fresh.ndim == 1 and configs.shape == current.shape and len(fresh) == len(configs)):
        return images
    at = np.where(fresh[:, None], configs, current)
    feats = host_features_batch(planes, at, images, image_shape)
    return images if feats is None else feats


def _initial_states(recognizer: Recognizer, batch: int) -> RecognizerState:
    one = recognizer.init(config=(0,) * len(recognizer.positions))
    # broadcast on the host: an eager broadcast compiles a program per shape
    return jax.tree.map(lambda x: jax.device_put(np.broadcast_to(np.asarray(x), (batch, *x.shape))), one)


@dataclasses.dataclass
class _Slot:
    spec: TrialSpec
    config: tuple[int, ...]
    step: int = 0
    invalid: int = 0
    configs: list = dataclasses.field(default_factory=list)
    occluded: list = dataclasses.field(default_factory=list)
    probs: list = dataclasses.field(default_factory=list)


@dataclasses.dataclass
class _Group:
    """Slots ``offset .. offset + n - 1`` of the lockstep batch and their
    device state; ``pending`` is the group's dispatched, not yet downloaded step."""

    offset: int
    slots: list
    states: Any
    images: np.ndarray
    configs: np.ndarray
    fresh: np.ndarray
    trials: np.ndarray
    steps: np.ndarray
    captures: dict = dataclasses.field(default_factory=dict)
    pending: Any = None

    @classmethod
    def empty(cls, recognizer: Recognizer, start: int, stop: int, n_cams: int, h: int, w: int) -> "_Group":
        n = stop - start
        return cls(start, [None] * n, _initial_states(recognizer, n), np.zeros((n, n_cams, h, w), np.uint8),
                   np.zeros((n, n_cams), np.int32), np.ones(n, bool), np.zeros(n, np.int32), np.zeros(n, np.int32))


def run_trials(
    recognizer: Recognizer,
    rigs: Rig | Sequence[Rig] | RigPool,
    specs: Iterable[TrialSpec],
    *,
    key: PRNGKeyArray,
    batch: int = 16,
    seed: int = 0,
    trace: bool = False,
    on_step: Callable[[StepRecord], None] | None = None,
    on_result: Callable[[TrialResult], None] | None = None,
    devices: int | Sequence[jax.Device] | None = None,
    pipeline: bool = True,
) -> list[TrialResult]:
    """Run every trial of ``specs`` to its stop and return the results in the
    order the trials finish.

    Args:
        recognizer: the recognizer (its model fixes the cameras and positions).
        rigs: one :class:`~jaxrecog.hardware.Rig`, several identical ones,
            or a :class:`~jaxrecog.hardware.rigs.rig_pool.RigPool` (e.g. rendering
            in worker processes; the results are the same)
            (slot ``b`` uses rig ``b % n_rigs``; one per slot means one
            ``reset`` per trial).
        specs: the trials (see :func:`jaxrecog.campaign.plan_trials`).
        key: PRNG key; trial ``t`` step ``n`` uses ``fold_in(fold_in(key, t), n)``.
        batch: lockstep slots (fixed, so the step compiles once per batch size).
        seed: captures are reseeded with ``(seed, trial, step)``.
        trace: keep per-step object probabilities in each result and pass the
            step traces to ``on_step``.
        on_step: called after every step of every trial with a :class:`StepRecord`.
        on_result: called with each :class:`TrialResult` as its trial finishes.
        devices: shard the batch over this many devices (or these devices;
            :func:`trial_mesh`); ``batch`` is rounded up to a multiple of
            their number.  Default: one device.
        pipeline: step the batch as two halves in turn, so that the device
            steps one half while the host captures the other's images (the
            results are the same; off with one slot or several devices).
    """
    from .hardware.geometry.motion import path_travel_s
    from .hardware.rigs.rig_pool import as_rig_pool

    pool = as_rig_pool(rigs)
    positions = tuple(recognizer.positions)
    from .counts import check_counts  # the one model-vs-rig check (positions, image size, ...)

    check_counts(recognizer.model, pool, other_name="rig")
    if batch < 1:
        raise ValueError(f"batch must be >= 1, got {batch}")
    mesh = trial_mesh(devices)
    if mesh is not None:
        n_dev = len(mesh.devices.flat)
        batch = -(-batch // n_dev) * n_dev  # extra slots take trials like the others
    queue = list(specs)
    ids = [s.trial for s in queue]
    if len(set(ids)) != len(ids):
        raise ValueError("trial ids in `specs` must be unique")
    queue.reverse()  # pop() takes the next trial
    n_cams = len(positions)
    h, w = pool.image_shape
    # two groups of slots, stepped in turn, when the batch can be split: the
    # device steps one group while the host captures the other's images
    # (of equal size, so one compiled step serves both: with an odd batch the
    # second group's last slot never takes a trial)
    n_groups = 2 if (pipeline and mesh is None and batch >= 2) else 1
    size = -(-batch // n_groups)
    groups = [_Group.empty(recognizer, g * size, (g + 1) * size, n_cams, h, w) for g in range(n_groups)]
    step = batched_step(recognizer, trace=trace, mesh=mesh)
    times = None if recognizer.motion is None else [np.asarray(t) for t in recognizer.motion.times]
    showing: list[int | None] = [None] * pool.n_rigs  # the trial each rig's scene is set up for
    results: list[TrialResult] = []

    def finish(g: _Group) -> None:
        """Download the group's pending step and move each of its trials on."""
        dec = jax.device_get(g.pending)
        g.pending = None
        g.fresh[:] = False
        for i, sl in enumerate(g.slots):
            if sl is None:
                continue
            mine = jax.tree.map(lambda x: x[i], dec)
            cap = g.captures[i]
            sl.configs.append(sl.config)
            sl.occluded.append(cap.occluded)
            if mine.degenerate is not None and bool(mine.degenerate):
                raise UnexplainedCaptureError(
                    f"trial {sl.spec.trial}, image set {sl.step + 1}: the model cannot explain the capture (its "
                    "likelihood is not finite, or zero, under every class; are the model's arrays damaged?); "
                    "stopped instead of ending every trial at an unchanged belief")
            sl.invalid += int(not mine.valid)
            if trace:
                sl.probs.append(tuple(float(p) for p in mine.trace.object_probs))
            if on_step is not None:
                on_step(StepRecord(sl.spec, sl.step, sl.config, cap, mine))
            sl.step += 1
            if bool(mine.stop):
                res = TrialResult(
                    trial=sl.spec.trial,
                    object=sl.spec.object,
                    pose=sl.spec.pose,
                    predicted_object=int(mine.object),
                    predicted_pose=int(mine.pose),
                    exit_prob=float(mine.probability),
                    steps=sl.step,
                    stopped=bool(mine.reached),
                    invalid_steps=sl.invalid,
                    occluded_fraction=tuple(sl.occluded),
                    configurations=tuple(sl.configs),
                    object_probs=tuple(sl.probs),
                    travel_s=math.nan if times is None else path_travel_s(times, sl.configs),
                    yaw_offset=sl.spec.yaw_offset,
                )
                results.append(res)
                if on_result is not None:
                    on_result(res)
                g.slots[i] = None
            else:
                sl.config = tuple(int(v) for v in mine.next_config)

    def start(g: _Group) -> None:
        """Give the group's free slots new trials, capture its images and
        dispatch its step (asynchronously: it runs while the host goes on)."""
        for i in range(len(g.slots)):
            if g.slots[i] is None and queue and g.offset + i < batch:
                s = queue.pop()
                g.slots[i] = _Slot(s, tuple(int(v) for v in s.initial))
                g.fresh[i] = True
        jobs, active = [], []
        for i, sl in enumerate(g.slots):
            if sl is None:
                continue
            r = (g.offset + i) % pool.n_rigs
            scene = None
            if showing[r] != sl.spec.trial:
                scene = SceneSpec(sl.spec.object, sl.spec.pose, sl.spec.occluders, sl.spec.yaw_offset)
                showing[r] = sl.spec.trial
            jobs.append(CaptureJob(r, scene, (seed, sl.spec.trial, sl.step), sl.config))
            active.append(i)
            g.configs[i] = sl.config
            g.trials[i] = sl.spec.trial
            g.steps[i] = sl.step
        if not jobs:
            return
        g.captures = dict(zip(active, pool.capture_batch(jobs)))
        for i, cap in g.captures.items():
            g.images[i] = cap.images
        g.states, g.pending = step(g.states, g.fresh, g.configs, g.images, key, g.trials, g.steps)
        # the host buffers are not touched again before finish(g) has the step's result

    while True:
        for g in groups:
            if g.pending is not None:
                finish(g)
            start(g)
        if all(g.pending is None for g in groups):
            return results
