"""Recognizer: fixed shapes, no recompiles, any number of cameras, NaN-safe,
and closed loops on a replayed image database."""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.random as jr
import numpy as np
import pytest
from builders import random_sensor_model, moving_database as _moving_database
from compiles import assert_steps_never_recompile, count_compiles

from jaxrecog import ImageDatabase, train_model
from jaxrecog.campaign import plan_trials, run_campaign
from jaxrecog.features import project_camera
from jaxrecog.hardware import DatasetRig
from jaxrecog.planners import FixedPlanner, MIPlanner, RandomPlanner, make_planner
from jaxrecog.recognizer import Recognizer, restrict_cameras


random_model = random_sensor_model


@pytest.mark.parametrize("positions", [(5,), (4, 3), (3, 2, 2)])
@pytest.mark.parametrize("planner", ["mi", "mi-class", "crlb", "random"])
def test_step_shapes_for_any_number_of_cameras(positions, planner, getkey):
    model = random_model(positions)
    rec = Recognizer(model, make_planner(planner, model, key=getkey(), samples=64))
    state = rec.init(getkey())
    images = jr.randint(getkey(), (len(positions), 6, 8), 0, 255).astype(jnp.uint8)
    for _ in range(3):
        state, dec = rec.step(state, images, getkey(), trace=True)
    a = int(np.prod(positions))
    assert dec.trace.scores.shape == (a,)
    assert dec.next_config.shape == (len(positions),)
    assert int(np.ravel_multi_index(tuple(np.asarray(dec.next_config)), positions)) == int(dec.next_index)
    assert dec.trace.class_probs.shape == (6,) and float(jnp.sum(dec.trace.class_probs)) == pytest.approx(1.0, abs=1e-5)
    # without tracing, the decision carries only what a control loop needs
    k = getkey()
    _, slim = rec.step(state, images, k)
    _, full = rec.step(state, images, k, trace=True)
    assert slim.trace is None
    assert int(slim.next_index) == int(full.next_index) and float(slim.probability) == float(full.probability)
    assert bool(dec.valid)
    assert int(state.steps) == 3
    # never revisits while unvisited configurations remain
    assert not bool(state.visited[dec.next_index]) or bool(jnp.all(state.visited))


@pytest.mark.parametrize("name", ["random", "mi", "crlb", "crlb-det", "crlb-eig"])
def test_zero_recompiles_over_50_steps(name, getkey):
    model = random_model()
    # a threshold no other test uses: the first step cannot find the step
    # already compiled by an earlier test, so it must compile exactly once
    rec = Recognizer(model, make_planner(name, model, key=getkey(), samples=32), p_threshold=0.96789)
    state = rec.init(getkey())

    def images():
        return jr.randint(getkey(), (2, 6, 8), 1, 255).astype(jnp.uint8)

    images()  # the image maker's own first compile is not the recognizer's
    with count_compiles() as first:
        state, dec = rec.step(state, images(), getkey(), trace=True)
        jax.block_until_ready(dec)
    assert first["step"] == 1 and bool(dec.valid), dict(first)
    with count_compiles() as later:
        for _ in range(49):
            if bool(dec.stop):
                state = rec.init(getkey())
            state, dec = rec.step(state, images(), getkey(), trace=True)
            assert bool(dec.valid) and 0 <= int(dec.next_index) < 12 and dec.trace.scores.shape == (12,)
    assert sum(later.values()) == 0, dict(later)


def test_bad_images_never_reach_the_belief(getkey):
    model = random_model()
    rec = Recognizer(model, FixedPlanner(12, 5))
    state = rec.init(config=(1, 2))
    for bad in (jnp.zeros((2, 6, 8)), jnp.full((2, 6, 8), jnp.nan)):
        new, dec = rec.step(state, bad, getkey(), trace=True)
        assert not bool(dec.valid)
        for a, b in zip(jax.tree.leaves(new.prior), jax.tree.leaves(state.prior)):
            assert np.array_equal(np.asarray(a), np.asarray(b))
        assert all(bool(jnp.all(jnp.isfinite(x) | (x == -jnp.inf))) for x in jax.tree.leaves(dec.trace.posterior))


def test_stop_rule_and_fixed_planner(getkey):
    model = random_model()
    rec = Recognizer(model, FixedPlanner(12, 7), max_steps=3, revisit=True)
    state = rec.init(config=(0, 0))
    stops = []
    for _ in range(3):
        state, dec = rec.step(state, jr.randint(getkey(), (2, 6, 8), 1, 255).astype(jnp.uint8), getkey())
        stops.append(bool(dec.stop) or float(dec.probability) >= 0.95)
        assert int(dec.next_index) == 7
    assert stops[-1]


def separated_model(llr=5.0):
    """One camera, 3 positions, 2 objects x 1 pose, one level, and ``images[v, m]``
    whose features are exactly the class means: the clean image of either
    object gives a log-likelihood ratio of ``llr`` for it at every position."""
    model = random_model((3,), n_objects=2, n_poses=1, levels=(0.0,))
    images = np.random.default_rng(1).integers(1, 255, (3, 2, 6, 8)).astype(np.uint8)
    cam = model.cameras[0]
    g = np.stack([np.asarray(project_camera(cam, jnp.full((2,), v), jnp.asarray(images[v]))[0]) for v in range(3)])
    d2 = ((g[:, 0] - g[:, 1]) ** 2).sum(-1)  # [V]
    var = np.broadcast_to((d2 / (2 * llr))[:, None, None, None], (3, 2, 1, g.shape[-1]))
    cam = eqx.tree_at(lambda c: (c.likelihood.mu, c.likelihood.var), cam, (jnp.asarray(g[:, :, None, :]), jnp.asarray(var, jnp.float32)))
    return eqx.tree_at(lambda m: m.cameras, model, (cam,)), images


def test_stop_rule_threshold_and_step_limit(getkey):
    model, images = separated_model(llr=5.0)
    p1 = 1 / (1 + np.exp(-5.0))  # 0.9933: above the thesis threshold, below 0.9999

    def first_step(**settings):
        rec = Recognizer(model, RandomPlanner(3), **settings)
        state = rec.init(config=(1,))
        return rec, rec.step(state, images[1, 1][None], getkey())

    # thesis settings: one clean image of a well-separated object is enough
    _, (state, dec) = first_step(max_steps=7)
    assert int(state.steps) == 1 and int(dec.object) == 1
    assert float(dec.probability) == pytest.approx(p1, rel=1e-5)
    assert bool(dec.reached) and bool(dec.stop)
    # a threshold very close to 1: not reached at step 1, and no stop before the limit
    rec, (state, dec) = first_step(max_steps=7, p_threshold=0.9999)
    assert not bool(dec.reached) and not bool(dec.stop)
    # a second clean image doubles the evidence (llr 10: p = 0.99995) and reaches it
    state, dec = rec.step(state, images[int(dec.next_config[0]), 1][None], getkey())
    assert int(state.steps) == 2 and bool(dec.reached) and bool(dec.stop)
    # the step limit alone stops, without reaching the threshold
    _, (state, dec) = first_step(max_steps=1, p_threshold=0.9999)
    assert bool(dec.stop) and not bool(dec.reached)


def test_min_views_confirms_a_decision_before_stopping(getkey):
    """``min_views=2``: the threshold reached at step 1 does not stop; step 2
    stops once it is reached again; the step limit still stops; out-of-range
    values are one-line errors."""
    model, images = separated_model(llr=5.0)
    rec = Recognizer(model, RandomPlanner(3), min_views=2)
    state = rec.init(config=(1,))
    state, dec = rec.step(state, images[1, 1][None], getkey())
    assert bool(dec.reached) and not bool(dec.stop)  # p = 0.9933 >= 0.95, one view only
    state, dec = rec.step(state, images[int(dec.next_config[0]), 1][None], getkey())
    assert int(state.steps) == 2 and bool(dec.reached) and bool(dec.stop)
    # min_views = max_steps: the limit stops whatever the belief
    rec = Recognizer(model, RandomPlanner(3), min_views=2, max_steps=2, p_threshold=0.9999999)
    state = rec.init(config=(1,))
    for want in (False, True):
        state, dec = rec.step(state, images[int(state.config[0]), 1][None], getkey())
        assert bool(dec.stop) == want and not bool(dec.reached)
    for bad in (0, 8, True):
        with pytest.raises(ValueError, match="min_views must be an integer in"):
            Recognizer(model, RandomPlanner(3), min_views=bad)


def test_the_recognizer_reads_the_planners_revisits_attribute(getkey):
    """Not a branch on the planner's class: any planner with ``revisits``
    keeps its argmax even when visited, any other is moved off it."""
    model = random_model()

    class Favourite(RandomPlanner):  # always prefers configuration 0
        def scores(self, prior, key):
            return jax.nn.one_hot(0, self.n_configs)

    class Stubborn(Favourite):
        revisits: ClassVar[bool] = True

    images = jr.randint(getkey(), (2, 6, 8), 1, 255).astype(jnp.uint8)
    chosen = {}
    for planner in (Favourite(12), Stubborn(12)):
        rec = Recognizer(model, planner)
        state, dec = rec.step(rec.init(config=(0, 0)), images, getkey())
        chosen[type(planner).__name__] = int(dec.next_index)
    assert chosen == {"Favourite": 1, "Stubborn": 0}
    assert FixedPlanner.revisits and not RandomPlanner.revisits


def test_restrict_cameras_gives_single_camera_model():
    model = random_model((4, 3))
    single = restrict_cameras(model, (0,))
    assert single.positions == (4,)
    rec = Recognizer(single, RandomPlanner(4))
    assert rec.n_configs == 4


@pytest.mark.slow
def test_dataset_rig_campaign_must_move_to_tell_objects_apart():
    db = _moving_database()
    model = train_model(db, kind="DB1", n_components=2, samples_per_image=30)
    rig = DatasetRig(db, split="test")
    assert rig.positions == (3,)
    rec = Recognizer(model, MIPlanner.from_model(model, key=jr.PRNGKey(0), samples=64, target="class"))
    specs = plan_trials(2, 3, rig.positions, 6, seed=3, initial=(0,))
    results = run_campaign(rec, rig, specs, key=jr.PRNGKey(1), batch=4)
    assert len(results) == 12
    assert sum(r.correct for r in results) >= 11
    # from position 0 the objects are indistinguishable, so every trial moved
    assert all(r.steps >= 2 for r in results)
    # and MI sends it straight to the one informative position
    assert all(r.configurations[1] == (2,) for r in results)


def test_fixed_planner_never_moves_and_nan_scores_do_not_pick_visited(getkey):
    model = random_model()
    rec = Recognizer(model, FixedPlanner(12, 5))
    state = rec.init(config=(1, 2))
    for _ in range(4):
        state, dec = rec.step(state, jr.randint(getkey(), (2, 6, 8), 1, 255).astype(jnp.uint8), getkey())
        assert int(dec.next_index) == 5

    class NanPlanner(RandomPlanner):
        def scores(self, prior, key):
            return jnp.full((self.n_configs,), jnp.nan)

    rec = Recognizer(model, NanPlanner(12))
    state = rec.init(config=(0, 0))
    seen = {0}
    for _ in range(5):
        state, dec = rec.step(state, jr.randint(getkey(), (2, 6, 8), 1, 255).astype(jnp.uint8), getkey())
        assert int(dec.next_index) not in seen  # never back to a visited configuration
        seen.add(int(dec.next_index))


def test_resume_refuses_a_stored_trial_whose_scene_changed(tmp_path, moving_model):
    """A stored trial of another scene says the store is another run's: refused
    whole, naming the file (rerunning the trial recorded it twice)."""
    from jaxrecog.campaign import TrialSpec
    from jaxrecog.results import TrialResult, TrialStore

    db, model = moving_model
    rig = DatasetRig(db, split="test")
    rec = Recognizer(model, RandomPlanner(3))
    store = TrialStore(tmp_path / "t.jsonl")
    store.append(TrialResult(0, 0, 0, 0, 0, 1.0, 1, True, ((0.0,),), ((1,),)))  # a stale record of another scene
    spec = TrialSpec(0, 1, 2, (0,))
    with pytest.raises(ValueError, match=rf"^{store.path}: trial 0 is object 0 pose 0 from \[1\], but this run's "
                                         r"trial 0 is object 1 pose 2 from \[0\]"):
        run_campaign(rec, rig, [spec], key=jr.PRNGKey(0), batch=1, store=store)
    assert store.path.read_text().count("\n") == 1   # nothing added
    with pytest.raises(ValueError, match="unique"):
        run_campaign(rec, rig, [spec, spec], key=jr.PRNGKey(0), batch=1)


def test_trials_are_reproducible_whatever_the_batch(tmp_path, moving_model):
    """A trial's images depend on (seed, trial, step) only, not on which
    trials ran before or beside it."""
    db, model = moving_model
    # two different test images per view, so the rig's random choice matters
    rng = np.random.default_rng(3)
    test = np.flatnonzero(db.split == "test")
    extra = np.clip(db.images[test].astype(float) + rng.normal(0, 20, db.images[test].shape), 0, 255).astype(np.uint8)
    db = ImageDatabase.from_arrays(
        np.concatenate([db.images, extra]),
        *(np.concatenate([getattr(db, f), getattr(db, f)[test]]) for f in ("camera", "position", "object", "pose", "split")),
    )

    class Spy(DatasetRig):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            self.seen = {}

        def reseed(self, seed):
            self.key = tuple(seed)
            super().reseed(seed)

        def capture(self):
            cap = super().capture()
            self.seen[self.key] = b"".join(im.tobytes() for im in cap.images)
            return cap

    rec = Recognizer(model, RandomPlanner(3), p_threshold=0.999)
    specs = plan_trials(2, 3, (3,), 3, seed=5)
    together, alone, other = Spy(db, seed=1), Spy(db, seed=2), Spy(db, seed=2)
    a = run_campaign(rec, together, specs, key=jr.PRNGKey(0), batch=4, seed=9)
    b = run_campaign(rec, alone, specs[2:3], key=jr.PRNGKey(0), batch=1, seed=9)
    run_campaign(rec, other, specs[2:3], key=jr.PRNGKey(0), batch=1, seed=10)
    assert a[2] == b[0]
    mine = {k: v for k, v in together.seen.items() if k[1] == 2}
    assert mine and mine == alone.seen
    assert list(other.seen.values()) != list(alone.seen.values())  # the seed does matter


@pytest.mark.parametrize("planner", ["mi-pairwise", "mi-class-pairwise"])
def test_pairwise_planners_run_and_do_not_recompile(planner, getkey):
    model = random_model()
    rec = Recognizer(model, make_planner(planner, model, key=getkey()), p_threshold=0.96788)
    assert_steps_never_recompile(rec, getkey, n_configs=12)


@pytest.mark.parametrize("planner", ["mi", "random"])
def test_exclude_visited_positions(planner, getkey):
    """With the option, no camera returns to a position it used while it has an
    unused one (camera 1 has 3 positions: after 3 views it lapses); never a NaN,
    no recompiles across steps."""
    model = random_model((4, 3))
    rec = Recognizer(model, make_planner(planner, model, key=getkey(), samples=32), max_steps=50, p_threshold=1.1,
                     exclude_visited_positions=True)
    state = rec.init(config=(0, 0))
    used = [{0}, {0}]
    images = jr.randint(getkey(), (2, 6, 8), 1, 255).astype(jnp.uint8)
    state, dec = rec.step(state, images, getkey())
    with count_compiles() as later:
        for step in range(11):
            nxt = tuple(int(x) for x in np.asarray(dec.next_config))  # host-side: no eager ops in the counter
            for i, v in enumerate(nxt):
                if len(used[i]) < model.positions[i]:
                    assert v not in used[i], (step, nxt, used)
                used[i].add(v)
            visited = np.asarray(state.visited)
            assert not visited[int(dec.next_index)] or visited.all()
            state, dec = rec.step(state, images, getkey())
    assert sum(later.values()) == 0, dict(later)
    # off (the default): the same planner may keep a camera where it was
    assert not Recognizer(model, rec.planner).exclude_visited_positions


def test_excluded_by_positions_lapses_per_camera():
    from jaxrecog.recognizer import excluded_by_positions

    seen = (jnp.array([True, False, False]), jnp.array([True, True]))  # camera 1 used both its positions
    ex = np.asarray(excluded_by_positions(seen, (3, 2))).reshape(3, 2)
    np.testing.assert_array_equal(ex, [[True, True], [False, False], [False, False]])


def test_host_projection_step_equals_the_traced_step(getkey):
    """Called with concrete arrays on the CPU the step projects on the host;
    traced (as in the campaigns' batched step) it projects inside the program:
    the same decisions and, to float32 rounding, the same beliefs, over a
    closed loop with an unusable image set in it; a model whose bases are not
    on the CPU as JAX arrays is projected in the program."""
    from jaxrecog import recognizer as R

    model = random_model((4, 3))
    rec = Recognizer(model, make_planner("mi-class-pairwise", model, key=getkey()), max_steps=7, p_threshold=0.999)
    assert R._split(rec)[2] is not None
    traced = jax.jit(lambda s, i, k: rec.step(s, i, k, trace=True))
    a = b = rec.init(config=(1, 2))
    for t in range(4):
        images = np.asarray(jr.randint(getkey(), (2, 6, 8), 0, 255)).astype(np.uint8)
        if t == 2:
            images[1] = 0  # black: the belief stays, valid is False on both paths
        k = getkey()
        a, da = rec.step(a, images, k, trace=True)
        b, db = traced(b, images, k)
        for f in ("object", "pose", "stop", "next_index", "valid"):
            assert int(getattr(da, f)) == int(getattr(db, f)), (t, f)
        assert bool(da.valid) == (t != 2)
        np.testing.assert_allclose(np.asarray(da.trace.class_probs), np.asarray(db.trace.class_probs), rtol=1e-4, atol=1e-6)
        np.testing.assert_allclose(np.asarray(da.trace.scores), np.asarray(db.trace.scores), rtol=1e-4, atol=1e-5)
        a, b = a, b._replace(prior=a.prior)  # the same prior on: rounding does not accumulate into a choice
    off_cpu = eqx.tree_at(lambda m: m.cameras[0].basis, model, np.asarray(model.cameras[0].basis))
    assert R.host_planes_of(off_cpu) is None
