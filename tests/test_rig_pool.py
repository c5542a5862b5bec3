"""Rig pools (jaxrecog.hardware.rigs.rig_pool): a step's captures in this process
or in worker processes give the same images, fractions and trial results;
a failing, killed or closed worker is a clear error."""

from __future__ import annotations

import functools

import jax.random as jr
import numpy as np
import pytest

from jaxrecog import Recognizer, plan_trials, run_trials
from jaxrecog.campaigns import Settings, capture_pool, make_rig, rig_pool
from jaxrecog.scene import occluder_factory
from jaxrecog.hardware import DatasetRig, RigError
from jaxrecog.hardware.rigs.rig_pool import CaptureJob, LocalRigs, ProcessRigs, SceneSpec, as_rig_pool
from jaxrecog.planners import RandomPlanner

STRIDED = Settings(stride=8)  # the thesis table at stride 8: 4 x 1 positions


def _jobs(rig, n_rigs: int) -> list[list[CaptureJob]]:
    """Three steps of captures on ``n_rigs`` rigs: new scenes (clean, with
    boards, turned off the grid), then the same scenes at other positions,
    one rig taking two jobs in a step."""
    rng = np.random.default_rng(3)
    boards = occluder_factory(rig)  # a board in front of each camera's first view, and more
    scenes = [SceneSpec(0, 1), SceneSpec(5, 2, boards(rng, (1, 0))), SceneSpec(6, 3, None, 7.5),
              SceneSpec(2, 0, boards(rng, (3, 0)), -4.0)]
    first = [CaptureJob(r, scenes[r], (0, r, 0), (r % 4, 0)) for r in range(n_rigs)]
    second = [CaptureJob(r, None, (0, r, 1), ((r + 1) % 4, 0)) for r in range(n_rigs)]
    third = [CaptureJob(1, None, (0, 1, 2), (3, 0)), CaptureJob(1, SceneSpec(7, 1, boards(rng, (0, 0))), (0, 9, 0), (0, 0)),
             CaptureJob(3, None, (0, 3, 2), (2, 0))]
    return [first, second, third]


def dataclass_replace(settings, **kw):
    import dataclasses

    return dataclasses.replace(settings, **kw)


def test_worker_processes_capture_what_this_process_captures():
    factory = functools.partial(make_rig, STRIDED, None, seed=0, clean_counts={})
    with LocalRigs(rig_pool(dataclass_replace(STRIDED, batch=4))) as local, ProcessRigs(factory, 4, 2) as remote:
        assert remote.positions == local.positions == (4, 1)
        assert remote.image_shape == local.image_shape == (120, 160)
        for step in _jobs(local.rigs[0], 4):
            a, b = local.capture_batch(step), remote.capture_batch(step)
            assert len(a) == len(b) == len(step)
            for x, y in zip(a, b):
                np.testing.assert_array_equal(x.images, y.images)
                assert x.occluded == y.occluded
        # the boards hide part of the object; the clean scene hides nothing
        fr = [c.occluded[0] for c in remote.capture_batch(_jobs(local.rigs[0], 4)[0])]
        assert fr[0] == 0.0 and fr[1] > 0.0 and fr[3] > 0.0


def test_shared_clean_counts_change_no_fraction():
    """The pool's rigs share one cache of unoccluded pixel counts; a rig with
    its own cache reports the same fractions."""
    shared = LocalRigs(rig_pool(dataclass_replace(STRIDED, batch=2)))
    assert shared.rigs[0]._clean_pixels is shared.rigs[1]._clean_pixels
    alone = LocalRigs([make_rig(STRIDED), make_rig(STRIDED)])
    assert alone.rigs[0]._clean_pixels is not alone.rigs[1]._clean_pixels
    for step in _jobs(alone.rigs[0], 2):
        step = [j for j in step if j.rig < 2]
        for a, b in zip(shared.capture_batch(step), alone.capture_batch(step)):
            np.testing.assert_array_equal(a.images, b.images)
            assert a.occluded == b.occluded
    assert len(shared.rigs[0]._clean_pixels) > 0
    # a dict shared by unlike rigs (another image size) keeps their counts apart
    from jaxrecog.hardware import Intrinsics, SyntheticRig

    small = SyntheticRig(shared.rigs[0].table, intrinsics=Intrinsics(height=60, width=80),
                         clean_counts=shared.rigs[0]._clean_pixels)
    alone_small = SyntheticRig(shared.rigs[0].table, intrinsics=Intrinsics(height=60, width=80))
    job = _jobs(small, 2)[0][1]  # the boards' scene, from scratch
    a, b = (LocalRigs([r]).capture_batch([CaptureJob(0, job.scene, job.seed, job.config)])[0] for r in (small, alone_small))
    assert a.occluded == b.occluded and a.occluded[0] > 0


def test_campaign_results_do_not_depend_on_the_pool(moving_model):
    """The driver through a process pool: the same trials as in this process,
    also with fewer rigs than slots (rigs shared by slots and reset between
    them) and an odd batch; a pool dropped without close() stops its workers."""
    import gc

    db, model = moving_model
    rec = Recognizer(model, RandomPlanner(3), p_threshold=0.999)
    specs = plan_trials(2, 3, (3,), 3, seed=1)
    key = jr.PRNGKey(0)

    def signature(results):
        return sorted((r.trial, r.predicted_object, r.predicted_pose, r.steps, r.configurations, r.exit_prob)
                      for r in results)

    local = run_trials(rec, [DatasetRig(db, seed=0) for _ in range(4)], specs, key=key, batch=4, seed=2,
                       pipeline=False)
    pool = ProcessRigs(functools.partial(DatasetRig, db, seed=0), 4, 2)
    remote = run_trials(rec, pool, specs, key=key, batch=4, seed=2)
    shared = run_trials(rec, pool, specs, key=key, batch=5, seed=2)  # a pool serves several campaigns
    assert signature(remote) == signature(local) == signature(shared)
    assert len(local) == len(specs)
    procs = list(pool._procs)
    del pool
    gc.collect()
    assert not any(p.is_alive() for p in procs)


def test_worker_errors_are_raised_here_and_a_batch_cut_short_closes_the_pool(moving_model):
    """A worker's exception is raised here and the pool survives it; so does a
    job that cannot be pickled (it fails before anything is sent: the next
    batch gets its own answers); a worker that dies closes the pool and stops
    the other workers."""
    db, _ = moving_model
    pool = ProcessRigs(functools.partial(DatasetRig, db, seed=0), 2, 2)
    procs = list(pool._procs)
    ok = CaptureJob(0, SceneSpec(0, 0), (0,), (1,))
    with pytest.raises(RigError, match=r"configuration \(7,\) is outside the positions \(3,\)"):
        pool.capture_batch([ok, CaptureJob(1, SceneSpec(1, 0), (0,), (7,))])  # rig 1: position 7 of 3
    assert pool.capture_batch([ok])[0].images.shape == (1, 24, 32)  # the pool still works
    with pytest.raises(ValueError, match="rig 2: the pool has rigs 0..1"):
        pool.capture_batch([CaptureJob(2, None, (0,), (0,))])
    first = pool.capture_batch([ok, CaptureJob(1, SceneSpec(1, 2), (0,), (2,))])
    with pytest.raises(Exception, match="pickle"):
        pool.capture_batch([ok, CaptureJob(1, SceneSpec(1, 0, occluders=lambda: None), (0,), (0,))])
    again = pool.capture_batch([ok, CaptureJob(1, SceneSpec(1, 2), (0,), (2,))])
    for a, b in zip(first, again):
        np.testing.assert_array_equal(a.images, b.images)
    procs[1].kill()
    procs[1].join()
    with pytest.raises(RigError, match="rig worker 1"):
        pool.capture_batch([ok, CaptureJob(1, None, (0,), (0,))])
    assert pool.closed and not any(p.is_alive() for p in procs)
    with pytest.raises(RigError, match="closed"):
        pool.capture_batch([ok])


def _no_rig():
    raise RigError("no camera on this bench")


def test_a_factory_that_fails_is_raised_at_first_use(moving_model):
    pool = ProcessRigs(_no_rig, 2, 1)
    with pytest.raises(RigError, match="no camera on this bench"):
        pool.positions
    with pytest.raises(RigError, match="closed"):
        pool.capture_batch([])
    # closed before its first use: says so
    pool = ProcessRigs(functools.partial(DatasetRig, moving_model[0], seed=0), 1, 1)
    pool.close()
    with pytest.raises(RigError, match="closed"):
        pool.positions


def test_bad_pool_arguments(moving_model, unchecked):
    db, _ = moving_model
    for n, w in ((0, 1), (1, 0)):
        with pytest.raises(ValueError, match="must be >= 1"):
            ProcessRigs(functools.partial(DatasetRig, db), n, w)
    with pytest.raises(ValueError, match="at least one rig"):
        LocalRigs([])
    with pytest.raises(ValueError, match="differ"):
        LocalRigs([DatasetRig(db), make_rig(STRIDED, (0,))])
    rig = DatasetRig(db)
    assert as_rig_pool(rig).rigs == [rig]
    pool = LocalRigs([rig])
    assert as_rig_pool(pool) is pool and as_rig_pool([rig, rig]).n_rigs == 2
    for bad in (-1, 1.5, True):
        with unchecked(), pytest.raises(ValueError, match="render_workers"):  # 1.5: the guard, not the checker
            Settings(render_workers=bad)


def test_capture_pool_follows_the_settings():
    with capture_pool(dataclass_replace(STRIDED, batch=3)) as pool:
        assert isinstance(pool, LocalRigs) and pool.n_rigs == 3
    with capture_pool(dataclass_replace(STRIDED, batch=2, render_workers=5), (0,)) as pool:
        assert isinstance(pool, ProcessRigs) and pool.workers == 2 and pool.positions == (4,)
