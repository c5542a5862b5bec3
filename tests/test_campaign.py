"""Campaigns: the batched step compiles once per recognizer (not per campaign),
and an interrupted campaign resumes from its TrialStore running only the
missing trials, with the same results as an uninterrupted run."""

from __future__ import annotations

import collections

import jax.random as jr
import pytest
from compiles import count_compiles

from jaxrecog.campaign import plan_trials, run_campaign
from jaxrecog.hardware import DatasetRig
from jaxrecog.planners import RandomPlanner, make_planner
from jaxrecog.recognizer import Recognizer
from jaxrecog.results import TrialStore


@pytest.mark.parametrize("planner", ["random", "mi", "mi-class-pairwise", "crlb"])
def test_a_second_campaign_with_the_same_recognizer_compiles_nothing(moving_model, planner):
    db, model = moving_model
    rig = DatasetRig(db, split="test")

    def recognizer():
        # a threshold no other test uses: the first campaign cannot find the
        # step already compiled by an earlier test
        p = make_planner(planner, model, key=jr.PRNGKey(0), samples=32)
        return Recognizer(model, p, p_threshold=0.98765)

    rec = recognizer()
    specs = plan_trials(2, 3, rig.positions, 3, seed=4)  # 6 trials: 2 batches of 4
    with count_compiles() as first:
        a = run_campaign(rec, rig, specs, key=jr.PRNGKey(0), batch=4)
    assert first["_batched_step"] == 1, dict(first)
    with count_compiles() as second:
        b = run_campaign(rec, rig, specs, key=jr.PRNGKey(0), batch=4)
    assert sum(second.values()) == 0, dict(second)
    assert a == b
    # an equal recognizer built afresh (new planner tables, same shapes) reuses it too
    fresh = recognizer()
    with count_compiles() as third:
        run_campaign(fresh, rig, specs[:2], key=jr.PRNGKey(1), batch=4)
    assert sum(third.values()) == 0, dict(third)


class _Interrupted(Exception):
    pass


class _SpyRig(DatasetRig):
    """Records which trials it captured for (the campaign reseeds with
    ``(seed, trial, step)`` before each capture)."""

    def __init__(self, *a, **k):
        super().__init__(*a, **k)
        self.trials: collections.Counter[int] = collections.Counter()
        self.resets = 0

    def reset(self, *a, **k):
        self.resets += 1
        super().reset(*a, **k)

    def reseed(self, seed):
        self._trial = seed[1]
        super().reseed(seed)

    def capture(self):
        self.trials[self._trial] += 1
        return super().capture()


def test_an_interrupted_campaign_resumes_with_the_missing_trials_only(moving_model, tmp_path):
    db, model = moving_model
    rec = Recognizer(model, RandomPlanner(3), p_threshold=0.999)
    specs = plan_trials(2, 3, (3,), 4, seed=7)  # 8 trials
    run = dict(key=jr.PRNGKey(2), batch=3, seed=5)

    whole_rig = _SpyRig(db)
    whole = run_campaign(rec, whole_rig, specs, **run)
    assert set(whole_rig.trials) == set(range(8))

    finished = []

    def progress(n):
        finished.append(n)
        if len(finished) == 4:  # in the second batch, after its first finished trial
            raise _Interrupted

    store = TrialStore(tmp_path / "trials.jsonl")
    first_rig = _SpyRig(db)
    with pytest.raises(_Interrupted):
        run_campaign(rec, first_rig, specs, store=store, progress=progress, **run)
    stored = store.load()
    assert len(stored) == 4
    assert set(first_rig.trials) < set(range(8))

    pool = [_SpyRig(db) for _ in range(run["batch"])]  # one rig per lockstep slot
    finished.clear()
    resumed = run_campaign(rec, pool, specs, store=store, progress=finished.append, **run)
    missing = set(range(8)) - set(stored)
    seen = sum((r.trials for r in pool), collections.Counter())
    assert set(seen) == missing  # only the missing trials ran again
    assert len(finished) == len(missing) == 4
    assert seen == collections.Counter({t: whole_rig.trials[t] for t in missing})  # each as many views as before
    assert sum(r.resets for r in pool) == len(missing)  # with a rig per slot, each scene is set up once
    assert whole_rig.resets <= sum(whole_rig.trials.values())  # one shared rig: at most once per capture
    assert resumed == whole
    assert len(store.load()) == 8
    # a third run finds every trial stored and runs none
    rig = _SpyRig(db)
    assert run_campaign(rec, rig, specs, store=store, **run) == whole
    assert rig.resets == 0
