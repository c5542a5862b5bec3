"""The capture memo (hardware/rigs/capture_memo.py): campaigns of the same
trials share the captures they agree on, and get exactly the captures (and
results) of their pool alone."""

from __future__ import annotations

import jax.random as jr
import numpy as np
import pytest

from jaxrecog import Recognizer, plan_trials, run_trials
from jaxrecog.campaigns import Settings, capture_pool, rig_tag
from jaxrecog.hardware import CaptureMemo, DatasetRig, MemoRigs
from jaxrecog.hardware.rigs.rig import Capture
from jaxrecog.hardware.rigs.rig_pool import CaptureJob, LocalRigs, SceneSpec
from jaxrecog.planners import RandomPlanner


class CountingPool(LocalRigs):
    """A :class:`LocalRigs` that keeps every job it runs."""

    def __init__(self, rigs):
        super().__init__(rigs)
        self.ran: list[CaptureJob] = []

    def capture_batch(self, jobs):
        self.ran.extend(jobs)
        return super().capture_batch(jobs)


def _signature(results):
    return sorted((r.trial, r.predicted_object, r.predicted_pose, r.steps, r.configurations, r.exit_prob)
                  for r in results)


def test_campaigns_through_a_memo_are_the_campaigns_without_it(moving_model):
    """Two campaigns of the same trials (different planner keys: they part
    after the first view): through one memo, each gives the results it gives
    on the pool alone, the second renders only what the first did not see
    (every first capture is a hit), and the pool ran exactly the misses."""
    db, model = moving_model
    rec = Recognizer(model, RandomPlanner(3), p_threshold=0.999)
    specs = plan_trials(2, 3, (3,), 4, seed=1)
    alone = [run_trials(rec, [DatasetRig(db, seed=0) for _ in range(3)], specs, key=jr.PRNGKey(k), batch=3,
                        seed=2) for k in (0, 1)]
    pool = CountingPool([DatasetRig(db, seed=0) for _ in range(3)])
    memo = CaptureMemo()
    with MemoRigs(pool, memo, tag="moving") as rigs:
        first = run_trials(rec, rigs, specs, key=jr.PRNGKey(0), batch=3, seed=2)
        sent_first = len(pool.ran)
        second = run_trials(rec, rigs, specs, key=jr.PRNGKey(1), batch=3, seed=2)
    assert _signature(first) == _signature(alone[0]) and _signature(second) == _signature(alone[1])
    assert _signature(first) != _signature(second)  # the planners' keys do part the campaigns
    captures = sum(r.steps for r in alone[1])
    assert memo.hits >= len(specs) and len(pool.ran) - sent_first == captures - memo.hits
    assert len(pool.ran) == memo.misses == len(memo)


def _capture(db, scene: SceneSpec, seed, config) -> Capture:
    rig = DatasetRig(db, seed=0)
    return LocalRigs([rig]).capture_batch([CaptureJob(0, scene, seed, config)])[0]


def test_a_rig_answered_from_the_memo_gets_its_scene_with_its_next_job(moving_model):
    """Rig 0's change of scene is answered from the memo (rig 1 captured that
    scene, seed and view): rig 0 still shows the old object, so its next job,
    sent without a scene as the driver sends it, carries the new one."""
    db, _ = moving_model
    pool = CountingPool([DatasetRig(db, seed=0) for _ in range(2)])
    rigs = MemoRigs(pool, CaptureMemo(), tag=None)
    a, b = SceneSpec(0, 0), SceneSpec(1, 2)
    rigs.capture_batch([CaptureJob(0, a, (5, 0, 0), (1,)), CaptureJob(1, b, (5, 1, 0), (2,))])
    (hit,) = rigs.capture_batch([CaptureJob(0, b, (5, 1, 0), (2,))])
    assert len(pool.ran) == 2 and np.array_equal(hit.images, _capture(db, b, (5, 1, 0), (2,)).images)
    (nxt,) = rigs.capture_batch([CaptureJob(0, None, (5, 1, 1), (0,))])
    assert pool.ran[-1].scene == b
    assert np.array_equal(nxt.images, _capture(db, b, (5, 1, 1), (0,)).images)
    assert not hit.images.flags.writeable  # one array answers many jobs


def test_a_failed_batch_sends_every_rig_its_scene_again(moving_model):
    db, _ = moving_model

    class Failing(CountingPool):
        fail = True

        def capture_batch(self, jobs):
            if self.fail:
                self.fail = False
                raise RuntimeError("worker lost")
            return super().capture_batch(jobs)

    pool = Failing([DatasetRig(db, seed=0)])
    rigs = MemoRigs(pool, CaptureMemo(), tag=None)
    scene = SceneSpec(1, 1)
    with pytest.raises(RuntimeError, match="worker lost"):
        rigs.capture_batch([CaptureJob(0, scene, (0, 0, 0), (0,))])
    rigs.capture_batch([CaptureJob(0, None, (0, 0, 1), (1,))])
    assert pool.ran[-1].scene == scene


def test_the_memo_keeps_the_recently_used_within_its_bytes():
    one = lambda v: Capture(np.full((1, 4, 8), v, np.uint8), (0.0,))  # noqa: E731  32 bytes
    memo = CaptureMemo(max_bytes=64)
    memo.put("a", one(1))
    memo.put("b", one(2))
    assert memo.get("a").images[0, 0, 0] == 1   # "a" used last: "b" goes first
    memo.put("c", one(3))
    assert memo.get("b") is None and memo.get("c") is not None and len(memo) == 2 and memo.nbytes == 64
    assert (memo.hits, memo.misses) == (2, 1)
    empty = CaptureMemo(max_bytes=0)
    empty.put("a", one(1))
    assert len(empty) == 0
    with pytest.raises(ValueError, match="max_bytes"):
        CaptureMemo(max_bytes=-1)


def test_unkeyable_jobs_pass_through(moving_model):
    """A job whose seed cannot key a dict or is ``None`` (fresh entropy), or
    a rig never given a scene, is captured by the pool and not kept; a job
    for a rig the pool does not have is refused even where the memo could
    answer it."""
    db, _ = moving_model
    pool = CountingPool([DatasetRig(db, seed=0)])
    memo = CaptureMemo()
    rigs = MemoRigs(pool, memo, tag=None)
    for seed in ([1, 2], [1, 2], None, None):
        rigs.capture_batch([CaptureJob(0, SceneSpec(0, 1), seed, (0,))])
    assert len(pool.ran) == 4 and len(memo) == 0
    rigs.capture_batch([CaptureJob(0, SceneSpec(0, 1), (1, 2), (0,))])
    with pytest.raises(ValueError, match="rig 1: the pool has rigs 0..0"):
        rigs.capture_batch([CaptureJob(1, SceneSpec(0, 1), (1, 2), (0,))])
    with pytest.raises(TypeError):
        MemoRigs(pool, memo, tag=[1])


def test_a_batch_that_fails_before_the_pool_runs_changes_nothing(moving_model):
    """A job that cannot be keyed fails the batch before anything is sent:
    the scene the batch's earlier job gave is not taken as shown, so the
    rig's next job (sent without a scene, as the driver sends it) carries it."""
    db, _ = moving_model
    pool = CountingPool([DatasetRig(db, seed=0)])
    rigs = MemoRigs(pool, CaptureMemo(), tag=None)
    rigs.capture_batch([CaptureJob(0, SceneSpec(0, 0), (0, 0, 0), (0,))])

    class Unhashable:
        def __hash__(self):
            raise RuntimeError("cannot hash")

    scene = SceneSpec(1, 2)
    with pytest.raises(RuntimeError, match="cannot hash"):
        rigs.capture_batch([CaptureJob(0, scene, (0, 1, 0), (1,)), CaptureJob(0, None, Unhashable(), (1,))])
    assert len(pool.ran) == 1
    rigs.capture_batch([CaptureJob(0, None, (0, 1, 0), (1,))])
    assert pool.ran[-1].scene == scene


def test_capture_pool_keeps_captures_under_the_rig_settings():
    """``capture_pool(..., memo=)`` wraps the pool (on this machine); the tag is what the rig is
    built from, so a case with other capture noise or cameras shares nothing."""
    settings = Settings(stride=8, batch=1, render_workers=0)
    memo = CaptureMemo()
    with capture_pool(settings, (0,), seed=3, memo=memo) as rigs:
        assert isinstance(rigs, MemoRigs) and rigs.tag == rig_tag(settings, (0,), 3)
        assert rigs.positions == (4,)
    other = Settings(stride=8, batch=1, render_workers=0, capture_noise=(0.0, 0.0, 0))
    assert rig_tag(other, (0,), 3) != rig_tag(settings, (0,), 3) != rig_tag(settings, None, 3)
    assert not isinstance(capture_pool(settings, (0,), seed=3), MemoRigs)


def test_no_memo_on_a_cluster(monkeypatch):
    """A cluster's pool runs whole trials in its actors (run_campaign hands
    them over when the pool has ``run_trials``): it is not wrapped."""
    from jaxrecog import ray_rigs

    class Cluster:
        def __init__(self, *args, cluster):
            pass

        def run_trials(self, *args, **kw):
            pass

    monkeypatch.setattr(ray_rigs, "RayRigs", Cluster)
    pool = capture_pool(Settings(stride=8, batch=1, cluster="ray"), (0,), memo=CaptureMemo())
    assert isinstance(pool, Cluster)
