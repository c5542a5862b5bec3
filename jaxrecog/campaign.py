"""Monte Carlo recognition campaigns (thesis chapter 7 protocol).

For each object, ``trials_per_object`` trials with a random pose, a random
initial configuration and (when the case asks) a fresh random occluder
layout; the trial driver (:func:`jaxrecog.driver.run_trials`) runs them in
lockstep slots, one jitted call per step.  Finished trials are appended to a
:class:`~jaxrecog.results.TrialStore` as they finish, so an interrupted
campaign resumes without losing any.
"""

from __future__ import annotations

from typing import Any, Callable, Iterable, Sequence

import numpy as np

from .driver import StepRecord, TrialSpec, batched_step, run_trials
from .hardware.rigs.rig import Rig, RigPool
from .recognizer import Recognizer
from .results import TrialResult, TrialStore

__all__ = ["TrialSpec", "plan_trials", "run_campaign", "batched_step", "MAX_TRIALS"]

#: The most trials one campaign plans (all objects together): every trial's
#: spec and result stay in memory (a few hundred bytes and ~1 KB each) and the
#: specs are drawn before the first trial runs, so a mistyped count is refused
#: at once instead of filling the memory.  The thesis runs 800 per case.
MAX_TRIALS = 100_000


OccluderFactory = Callable[[np.random.Generator, tuple[int, ...]], Any]


def plan_trials(
    n_objects: int,
    n_poses: int,
    positions: Sequence[int],
    trials_per_object: int,
    *,
    seed: int = 0,
    objects: Iterable[int] | None = None,
    occluders: OccluderFactory | None = None,
    initial: Sequence[int] | None = None,
    yaw_deg: float = 0.0,
) -> list[TrialSpec]:
    """The trial list: trial ``t`` of object ``m`` uses ``default_rng([seed, m, t])``
    for its pose, initial configuration and occluder layout, so campaigns with
    different planners see the same scenes.

    ``yaw_deg > 0`` (off-grid captures, :class:`~jaxrecog.hardware.render.synthetic.OffGrid`):
    each trial's object also gets a yaw offset ``U(-yaw_deg, yaw_deg)``
    degrees (``TrialSpec.yaw_offset``), drawn last from the same generator,
    so pose, start and occluders are those of the on-grid trial and the
    offsets of two bounds are proportional (``-a + 2 a u``, the same ``u``).
    ``yaw_deg = 0`` draws nothing (``yaw_offset`` None).  At most
    :data:`MAX_TRIALS` trials in all (a ``ValueError`` before any is drawn)."""
    if isinstance(yaw_deg, bool) or not isinstance(yaw_deg, (int, float)) or not 0 <= yaw_deg < float("inf"):
        raise ValueError(f"yaw_deg must be a finite number of degrees >= 0, got {yaw_deg!r}")
    objs = list(range(n_objects)) if objects is None else list(objects)
    if isinstance(trials_per_object, bool) or not isinstance(trials_per_object, int) or trials_per_object < 1 \
            or len(objs) * trials_per_object > MAX_TRIALS:
        raise ValueError(f"{len(objs)} objects x {trials_per_object!r} trials per object: a campaign runs 1 to "
                         f"{MAX_TRIALS} trials (jaxrecog.campaign.MAX_TRIALS; each one's spec and result stay in "
                         "memory)")
    specs = []
    for m in objs:
        for t in range(trials_per_object):
            rng = np.random.default_rng([seed, m, t])
            pose = int(rng.integers(n_poses))
            init = tuple(int(v) for v in initial) if initial is not None else tuple(int(rng.integers(v)) for v in positions)
            occ = occluders(rng, init) if occluders is not None else None
            yaw = float(rng.uniform(-yaw_deg, yaw_deg)) if yaw_deg > 0 else None
            specs.append(TrialSpec(m * trials_per_object + t, m, pose, init, occ, yaw))
    return specs


def run_campaign(
    recognizer: Recognizer,
    rig: Rig | Sequence[Rig] | RigPool,
    specs: Sequence[TrialSpec],
    *,
    key,
    batch: int = 16,
    seed: int = 0,
    store: TrialStore | None = None,
    progress: Callable[[int], None] | None = None,
    trace: bool = False,
    devices: int | None = None,
    on_step: Callable[[StepRecord], None] | None = None,
) -> list[TrialResult]:
    """Run the trials (skipping those already in ``store``) and return every
    result, old and new, ordered by trial number.  A stored trial of another
    object, pose, initial configuration or yaw offset than its spec is a
    ``ValueError`` naming the store: it holds another run's trials.

    Args:
        recognizer: the recognizer (its model fixes the cameras).
        rig: a :class:`~jaxrecog.hardware.Rig` with the same positions, or
            several identical ones (one per lockstep slot: each trial's scene
            is then set up once; see :func:`jaxrecog.driver.run_trials`), or
            a :class:`~jaxrecog.hardware.rigs.rig_pool.RigPool` (e.g. rendering in
            worker processes: :func:`jaxrecog.campaigns.capture_pool`).
        specs: from :func:`plan_trials`.
        key: PRNG key; trial ``t`` step ``n`` uses ``fold_in(fold_in(key, t), n)``.
        batch: trials run in lockstep (fixed, so the step compiles once).
        seed: the rig's capture noise is reseeded with ``(seed, trial, step)``
            before every capture, so a trial's images do not depend on the
            batch it ran in.
        store: where finished trials are appended (and read back on resume).
        progress: called with the number of trials finished at each finish
            (one, or on a cluster the several that came back together).
        trace: keep per-step object probabilities in each result.
        devices: shard the lockstep batch over this many devices
            (:func:`jaxrecog.driver.trial_mesh`; the results are the same as on one).
        on_step: an observer of every step of the trials run here (e.g. the
            live view, :class:`jaxrecog.liveview.RerunRecorder`); the steps
            come traced.  Not with a pool that runs whole trials itself (a cluster).
    """
    ids = [s.trial for s in specs]
    if len(set(ids)) != len(ids):
        raise ValueError("trial ids in `specs` must be unique")
    done: dict[int, TrialResult] = store.load() if store is not None else {}
    by_id = {s.trial: s for s in specs}
    for t, r in done.items():
        s = by_id.get(t)
        # a stored trial is reused only if it is the same scene and start; one that is not says the store
        # is another run's: refused whole (rerunning the trial would record it twice)
        if s is not None and (r.object, r.pose, r.configurations[:1], r.yaw_offset) != (s.object, s.pose, (s.initial,), s.yaw_offset):
            raise ValueError(f"{store.path}: trial {t} is object {r.object} pose {r.pose} from "
                             f"{list(r.configurations[0]) if r.configurations else '?'}, but this run's trial {t} "
                             f"is object {s.object} pose {s.pose} from {list(s.initial)}: the trials of another run; "
                             "move the file away to start afresh")
    todo = [s for s in specs if s.trial not in done]

    def finished(results: Sequence[TrialResult]) -> None:
        for res in results:
            done[res.trial] = res
        if store is not None:
            store.extend(results)  # one fsync for the group
        if progress is not None:
            progress(len(results))

    kw = dict(key=key, batch=batch, seed=seed, trace=trace or on_step is not None, devices=devices)
    if hasattr(rig, "run_trials") and on_step is not None:
        raise ValueError("a step observer (the live view) needs the trials run here, not on a cluster")
    if hasattr(rig, "run_trials"):  # a pool that runs whole trials itself (a cluster: jaxrecog.ray_rigs)
        rig.run_trials(recognizer, todo, on_results=finished, **kw)  # results in groups, as they come
    else:
        run_trials(recognizer, rig, todo, on_result=lambda res: finished([res]), on_step=on_step, **kw)
    return [done[k] for k in sorted(done) if k in by_id]
