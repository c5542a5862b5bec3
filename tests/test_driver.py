"""The one trial driver (jaxrecog.driver), the Rig protocol it talks to, and the
index <-> configuration helpers."""

from __future__ import annotations

import dataclasses
import itertools

import jax
import jax.numpy as jnp
import jax.random as jr
import numpy as np
import pytest
from builders import moving_database

from jaxrecog import Recognizer, TrialSpec, make_planner, plan_trials, run_trials
from jaxrecog.hardware import Capture, Rig, RigError, config_from_index, index_from_config
from jaxrecog.planners import RandomPlanner

import jaxrecog.kernels as K


class StrictRig:
    """Exactly the Rig protocol and nothing else: the driver may use no other
    attribute.  Replays the moving database's test images; reports a made-up
    occluded fraction (0.1 * position) so the record can be checked; logs every call."""

    def __init__(self, db, black_at: set[tuple[int, int]] = frozenset()):
        self._db, self._black = db, set(black_at)
        test = np.flatnonzero(db.split == "test")
        self._rows = {(int(db.camera[r]), int(db.position[r]), int(db.object[r]), int(db.pose[r])): r for r in test}
        self.calls: list[tuple] = []
        self._scene = self._config = None
        self._n = 0

    positions = property(lambda self: (3,))
    image_shape = property(lambda self: tuple(self._db.images.shape[1:3]))

    def reset(self, object, pose, occluders=None):
        self.calls.append(("reset", object, pose))
        self._scene = (object, pose)

    def reseed(self, seed):
        self.calls.append(("reseed", tuple(seed)))
        self._trial, self._step = seed[1], seed[2]

    def move(self, configuration):
        self.calls.append(("move", tuple(configuration)))
        self._config = tuple(configuration)

    def capture(self):
        self.calls.append(("capture",))
        (v,) = self._config
        img = self._db.images[self._rows[(0, v) + self._scene]]
        if (self._trial, self._step) in self._black:
            img = np.zeros_like(img)
        return Capture(img[None], (0.1 * v,))

    def close(self):
        self.calls.append(("close",))


def test_the_strict_rig_is_a_rig():
    assert isinstance(StrictRig(moving_database()), Rig)


def test_driver_uses_only_the_protocol_and_records_what_the_rig_reports(moving_model):
    db, model = moving_model
    rec = Recognizer(model, RandomPlanner(3), p_threshold=0.999)
    specs = plan_trials(2, 3, (3,), 3, seed=1)
    rig = StrictRig(db)
    steps = []
    results = run_trials(rec, rig, specs, key=jr.PRNGKey(0), batch=2, seed=4, on_step=steps.append)
    assert sorted(r.trial for r in results) == [s.trial for s in specs]
    assert {c[0] for c in rig.calls} <= {"reset", "reseed", "move", "capture"}
    for r in results:
        mine = [s for s in steps if s.spec.trial == r.trial]
        assert [s.step for s in mine] == list(range(r.steps))
        assert tuple(s.config for s in mine) == r.configurations
        # the true occluded fractions come with the images, step by step
        assert r.occluded_fraction == tuple((0.1 * c[0],) for c in r.configurations)
        # each next configuration is the previous decision's choice
        for a, b in itertools.pairwise(mine):
            assert tuple(int(v) for v in a.decision.next_config) == b.config
        assert mine[-1].decision.stop and not any(s.decision.stop for s in mine[:-1])
        assert mine[0].config == next(s.initial for s in specs if s.trial == r.trial)
    # every capture was preceded by a reseed with (seed, trial, step) and a move
    for i, c in enumerate(rig.calls):
        if c[0] == "capture":
            assert rig.calls[i - 1][0] == "move" and rig.calls[i - 2][0] == "reseed"
            assert rig.calls[i - 2][1][0] == 4


def test_a_rig_per_slot_sets_up_each_scene_once_and_gives_the_same_results(moving_model):
    db, model = moving_model
    rec = Recognizer(model, RandomPlanner(3), p_threshold=0.999)
    specs = plan_trials(2, 3, (3,), 4, seed=2)  # 8 trials
    shared = StrictRig(db)
    a = run_trials(rec, shared, specs, key=jr.PRNGKey(1), batch=3)
    pool = [StrictRig(db) for _ in range(3)]
    b = run_trials(rec, pool, specs, key=jr.PRNGKey(1), batch=3)
    assert sorted(a, key=lambda r: r.trial) == sorted(b, key=lambda r: r.trial)
    assert sum(c[0] == "reset" for r in pool for c in r.calls) == len(specs)
    captures = sum(c[0] == "capture" for c in shared.calls)
    assert len(specs) <= sum(c[0] == "reset" for c in shared.calls) <= captures


def _refill_rounds(lengths, batch):
    """Oracle: lockstep rounds when a finished slot takes the next trial at the next round."""
    queue, slots, rounds = list(lengths), [0] * batch, 0
    while queue or any(slots):
        slots = [s if s else (queue.pop(0) if queue else 0) for s in slots]
        rounds += 1
        slots = [max(s - 1, 0) for s in slots]
    return rounds


def test_slots_refill_so_the_batch_stays_busy(moving_model, monkeypatch):
    """A finished slot takes the next trial at once, so B = 2 slots need the
    refill schedule's rounds, fewer than chunks of 2 run to their longest."""
    import jaxrecog.driver as D

    db, model = moving_model
    rounds = []
    real = D.batched_step

    def counting(*a, **k):
        step = real(*a, **k)
        return lambda *args: (rounds.append(1), step(*args))[1]

    monkeypatch.setattr(D, "batched_step", counting)
    rec = Recognizer(model, RandomPlanner(3), p_threshold=0.6, max_steps=3)
    specs = plan_trials(2, 3, (3,), 4, seed=3)
    results = {r.trial: r for r in run_trials(rec, StrictRig(db), specs, key=jr.PRNGKey(2), batch=2, pipeline=False)}
    lengths = [results[s.trial].steps for s in specs]
    chunked = sum(max(lengths[i:i + 2]) for i in range(0, len(lengths), 2))
    assert len(set(lengths)) > 1, lengths  # unequal trials, or the test shows nothing
    assert len(rounds) == _refill_rounds(lengths, 2) < chunked


def test_a_pipelined_batch_steps_its_halves_in_turn_and_gives_the_same_trials(moving_model, monkeypatch):
    """pipeline=True (the default) steps the two halves of the slots as two
    calls in turn; the trials are the same as one call over the whole batch."""
    import jaxrecog.driver as D

    db, model = moving_model
    calls = []
    real = D.batched_step

    def logging(*a, **k):
        step = real(*a, **k)

        def run(*args):
            calls.append(len(args[1]))  # fresh[B]: the slots of this call
            return step(*args)

        return run

    monkeypatch.setattr(D, "batched_step", logging)
    rec = Recognizer(model, RandomPlanner(3), p_threshold=0.6, max_steps=3)
    specs = plan_trials(2, 3, (3,), 5, seed=3)
    rigs = [StrictRig(db) for _ in range(5)]
    whole = run_trials(rec, rigs, specs, key=jr.PRNGKey(2), batch=5, seed=1, pipeline=False)
    assert set(calls) == {5}
    calls.clear()
    halves = run_trials(rec, rigs, specs, key=jr.PRNGKey(2), batch=5, seed=1)
    assert set(calls) == {3}  # two halves of 3, one slot idle: one compiled step
    assert sum(c[0] == "reset" for r in rigs for c in r.calls) == 2 * len(specs)  # a rig per slot: one reset per trial and run

    def signature(results):
        return sorted((r.trial, r.predicted_object, r.predicted_pose, r.steps, r.configurations, r.occluded_fraction,
                       r.exit_prob) for r in results)

    assert signature(halves) == signature(whole) and len(whole) == len(specs)
    # two slots: halves of one (a one-trip loop XLA may compile apart) against one call of two
    calls.clear()
    pairs = run_trials(rec, rigs[:2], specs, key=jr.PRNGKey(2), batch=2, seed=1)
    assert set(calls) == {1}
    assert signature(pairs) == signature(run_trials(rec, rigs[:2], specs, key=jr.PRNGKey(2), batch=2, seed=1,
                                                    pipeline=False)) == signature(whole)


def test_an_unusable_image_is_counted_and_leaves_the_belief_alone(moving_model):
    db, model = moving_model
    rec = Recognizer(model, make_planner("mi", model, key=jr.PRNGKey(0), samples=8, min_per_stratum=1), p_threshold=0.999)
    spec = TrialSpec(0, 1, 2, (0,))
    seen = []
    (r,) = run_trials(rec, StrictRig(db, black_at={(0, 0)}), [spec], key=jr.PRNGKey(0), batch=1, trace=True,
                      on_step=seen.append)
    assert r.invalid_steps == 1 and not seen[0].decision.valid and all(s.decision.valid for s in seen[1:])
    # the belief after the black image is still the uniform prior
    probs = np.asarray(seen[0].decision.trace.object_probs)
    np.testing.assert_allclose(probs, np.full(2, 0.5), atol=1e-6)
    for s in seen:
        for leaf in jax.tree.leaves(s.decision.trace.posterior):
            assert not np.any(np.isnan(np.asarray(leaf)))


def test_driver_rejects_a_rig_of_another_layout_and_duplicate_trials(moving_model):
    db, model = moving_model
    rec = Recognizer(model, RandomPlanner(3))

    class Other(StrictRig):
        positions = property(lambda self: (4,))

    with pytest.raises(ValueError, match=r"^rig does not match the model: positions \(4,\) per camera vs the model's \(3,\)$"):
        run_trials(rec, Other(db), [TrialSpec(0, 0, 0, (0,))], key=jr.PRNGKey(0))
    with pytest.raises(ValueError, match="unique"):
        run_trials(rec, StrictRig(db), [TrialSpec(0, 0, 0, (0,))] * 2, key=jr.PRNGKey(0))
    with pytest.raises(ValueError, match="at least one rig"):
        run_trials(rec, [], [TrialSpec(0, 0, 0, (0,))], key=jr.PRNGKey(0))


# ---------------------------------------------------------------- Capture


def test_capture_checks_its_parts():
    img = np.zeros((2, 4, 5), np.uint8)
    assert Capture(img, (0.0, 0.5)).occluded == (0.0, 0.5)
    assert Capture.of([img[0], img[1]]).occluded == ()
    with pytest.raises(RigError, match="2 image.* 1 occluded"):
        Capture(img, (0.0,))
    with pytest.raises(RigError, match="one 2-D image per camera"):
        Capture(img[0], ())


# ---------------------------------------------------------------- index <-> configuration


@pytest.mark.parametrize("positions", [(32, 7), (5,), (3, 2, 4)])
def test_index_helpers_agree_with_numpy_and_under_jit(positions):
    total = int(np.prod(positions))
    for a in range(total):
        cfg = config_from_index(a, positions)
        assert cfg == tuple(int(v) for v in np.unravel_index(a, positions))
        assert index_from_config(cfg, positions) == a == np.ravel_multi_index(cfg, positions)
        assert index_from_config(tuple(np.int64(v) for v in cfg), positions) == a
    to_cfg = jax.jit(lambda a: jnp.stack(config_from_index(a, positions)))
    to_idx = jax.jit(lambda c: index_from_config(c, positions))
    a = jnp.arange(total)
    cfgs = jax.vmap(to_cfg)(a)
    np.testing.assert_array_equal(cfgs, np.stack(np.unravel_index(np.arange(total), positions), axis=1))
    np.testing.assert_array_equal(jax.vmap(to_idx)(cfgs), np.arange(total))


def test_index_helpers_range_check_concrete_values():
    with pytest.raises(ValueError, match="outside 0..223"):
        config_from_index(224, (32, 7))
    with pytest.raises(ValueError, match=r"\(3, 7\) does not fit the positions \(32, 7\)"):
        index_from_config((3, 7), (32, 7))
    with pytest.raises(ValueError, match="does not fit"):
        index_from_config((1,), (32, 7))


def test_update_with_a_false_valid_mask_changes_nothing():
    b = K.uniform_belief(4, (2, 3))
    ll = (jnp.arange(8.0).reshape(4, 2), jnp.zeros((4, 3)))
    out, info = K.update_with_info(b, ll, valid=jnp.asarray(False))
    assert not bool(info.ok)
    for x, y in zip(jax.tree.leaves(out), jax.tree.leaves(b)):
        np.testing.assert_array_equal(x, y)
    moved, info = K.update_with_info(b, ll, valid=True)
    assert bool(info.ok) and not np.allclose(moved.log_pc, b.log_pc)


class _CountingPlanner(RandomPlanner):
    """RandomPlanner that counts its runs on the host (``jax.debug.callback``
    fires only where the planner's branch actually runs)."""

    def scores(self, prior, key):
        out = super().scores(prior, key)
        jax.debug.callback(_PLANNED.append, out[0], ordered=False)
        return out


_PLANNED: list = []


def test_campaign_steps_skip_the_planner_on_stopping_steps_and_give_the_same_trials(moving_model):
    """The driver runs the planner only on steps that do not stop (a trial's
    last step needs no next configuration), with the same trials as a step
    that always plans; a stopping step's next configuration is then the first
    unused one."""
    db, model = moving_model
    rec = Recognizer(model, _CountingPlanner(3), p_threshold=0.6, max_steps=3)
    specs = plan_trials(2, 3, (3,), 2, seed=5)
    _PLANNED.clear()
    records = []  # one slot: no idle slot steps beside the trials
    results = run_trials(rec, StrictRig(db), specs, key=jr.PRNGKey(3), batch=1, on_step=records.append)
    jax.effects_barrier()
    steps = sum(r.steps for r in results)
    assert len(_PLANNED) == steps - len(results) < steps  # one fewer planner run per trial
    for s in records:
        if s.decision.stop:  # the first configuration not yet used
            used = [index_from_config(r.config, (3,)) for r in records if r.spec.trial == s.spec.trial]
            assert int(s.decision.next_index) == min(set(range(3)) - set(used) or {0})
    # the same trials when every step plans (a traced run plans on every step)
    _PLANNED.clear()
    traced = run_trials(rec, StrictRig(db), specs, key=jr.PRNGKey(3), batch=1, trace=True)
    jax.effects_barrier()
    assert len(_PLANNED) == steps
    assert all(r.object_probs for r in traced)  # (what a trace adds; nothing else may differ)
    untraced = [dataclasses.replace(r, object_probs=()) for r in traced]
    assert sorted(results, key=lambda r: r.trial) == sorted(untraced, key=lambda r: r.trial)


def test_a_campaign_step_crosses_between_configuration_and_flat_index_twice(monkeypatch):
    """The target: in one campaign step the configuration crosses
    between its tuple and its flat index at most twice (docs/architecture.md,
    "The data path of one campaign step"): inside the compiled step, the
    current configuration's index (the visited set) and the chosen index's
    configuration; the host passes configurations as they are."""
    from builders import make_database

    from jaxrecog import train_model
    from jaxrecog.driver import batched_step
    from jaxrecog.hardware import DatasetRig
    from jaxrecog.kernels.config_grid import ConfigGrid

    db = make_database(positions=(3, 2), n_objects=2, n_poses=2, image_shape=(16, 20), n_test=1)
    model = train_model(db, kind="DB1", n_components=2, samples_per_image=4)
    rec = Recognizer(model, RandomPlanner(6), p_threshold=0.999, max_steps=4)
    calls = []
    for name in ("index", "configuration"):
        def counted(self, x, *args, _orig=getattr(ConfigGrid, name), _name=name, **kw):
            calls.append((_name, any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(x))))
            return _orig(self, x, *args, **kw)

        monkeypatch.setattr(ConfigGrid, name, counted)
    # one step program, traced once: the crossings every step executes
    states = jax.tree.map(lambda x: jnp.stack([x] * 2), rec.init(config=(0, 0)))
    args = (states, jnp.ones(2, bool), jnp.zeros((2, 2), jnp.int32), jnp.zeros((2, 2, 16, 20), jnp.uint8),
            jr.PRNGKey(0), jnp.arange(2), jnp.zeros(2, jnp.int32))
    jax.make_jaxpr(batched_step(rec))(*args)
    assert calls == [("index", True), ("configuration", True)]
    # a campaign of such steps: the host never converts
    calls.clear()
    specs = [TrialSpec(t, t % 2, t % 2, (t % 3, t % 2)) for t in range(6)]
    results = run_trials(rec, DatasetRig(db), specs, key=jr.PRNGKey(1), batch=2)
    assert len(results) == 6 and sum(r.steps for r in results) > 6
    assert [c for c in calls if not c[1]] == []


def test_a_model_that_explains_no_capture_stops_the_run_instead_of_ending_wrong(moving_model):
    """A model whose basis is 1e30 (finite arrays) made every image set's
    likelihood NaN under every class: each trial ran to max_steps at the
    uniform belief, WRONG, with no word.  Now the step says ``degenerate``
    (the belief unchanged, no NaN in it) and the driver stops with one line."""
    import equinox as eqx

    from jaxrecog.driver import UnexplainedCaptureError

    db, model = moving_model
    broken = eqx.tree_at(lambda m: m.cameras[0].basis, model, model.cameras[0].basis * 1e30)
    rec = Recognizer(broken, RandomPlanner(3), p_threshold=0.9)
    state, dec = rec.step(rec.init(config=(0,)), db.images[db.split == "test"][:1], jr.PRNGKey(0), trace=True)
    assert bool(dec.degenerate) and not bool(dec.valid)
    assert all(np.all(np.isfinite(np.asarray(x))) for x in jax.tree.leaves(dec.trace.posterior))
    np.testing.assert_allclose(np.asarray(dec.trace.object_probs), np.full(2, 0.5), atol=1e-6)
    done = []
    with pytest.raises(UnexplainedCaptureError, match=r"^trial 0, image set 1: the model cannot explain the capture"):
        run_trials(rec, StrictRig(db), [TrialSpec(0, 1, 2, (0,))], key=jr.PRNGKey(0), batch=1, on_result=done.append)
    assert done == []
