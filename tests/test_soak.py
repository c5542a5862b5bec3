"""Soak: a long run of the recognizer with bad images mixed
in, and a campaign killed with SIGKILL and resumed.

1. 10,000 recognizer steps (50 lockstep slots through
   :func:`jaxrecog.campaign.batched_step`; a slot whose trial stops starts a
   new one, inside the step, from the ``fresh`` mask)
   on a small two-camera DB2 model with the MI planner; 5 % of the images are
   bad: all black or NaN (they enter the jitted step, which flags them in
   ``Decision.valid`` and leaves the belief unchanged), or of the wrong size.
   A wrong-size image cannot enter a step of fixed shape: it is rejected at
   the host boundary (:func:`jaxrecog.features.check_image` raises
   :class:`~jaxrecog.features.ImageError`) and a black frame takes its slot,
   so the step reports that view as invalid.  Checked: no NaN in any belief,
   every bad view flagged and its belief unchanged, no compile after the
   warm-up, resident memory grows at most 5 % after the warm-up.
2. A campaign in a subprocess, killed with SIGKILL at random points (some
   mid-write) and resumed 3 times from its TrialStore (twice in subprocesses
   killed again, the last time here), ends with exactly the results of an
   uninterrupted run.

The figures (steps/s, memory before/after, NaN count) are printed (``-s``).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import jax.random as jr
import numpy as np
import pytest
from builders import make_database, moving_database
from compiles import count_compiles

from jaxrecog import train_model
from jaxrecog.campaign import batched_step
from jaxrecog.features import ImageError, check_image
from jaxrecog.modelfile import save_model
from jaxrecog.planners import make_planner
from jaxrecog.recognizer import Recognizer
from jaxrecog.results import TrialStore
from soak_campaign import TRIALS_PER_OBJECT, campaign

pytestmark = pytest.mark.slow

BATCH, WARMUP_CALLS, CALLS = 50, 10, 200  # 50 x 200 = 10,000 steps after the warm-up
BAD_FRACTION = 0.05


def _rss_bytes() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def _leaves_nan(tree) -> int:
    return sum(int(np.isnan(np.asarray(x)).sum()) for x in jax.tree.leaves(tree))


def test_ten_thousand_steps_with_bad_images(capsys, optimized_xla):
    db = make_database(positions=(4, 3), n_objects=3, n_poses=2, image_shape=(24, 32), n_test=1)
    model = train_model(db, kind="DB2", n_components=4, samples_per_image=8)
    rec = Recognizer(model, make_planner("mi", model, key=jr.PRNGKey(0), samples=16))
    step = batched_step(rec, trace=True)  # the trace carries the posterior checked below
    shape, n_cams, C = model.image_shape, len(rec.positions), model.n_objects * model.n_poses
    # per camera the test image of every (position, class): [V, C, H, W]
    tables = []
    for i, V in enumerate(rec.positions):
        t = np.zeros((V, C) + shape, np.float32)
        for r in np.flatnonzero((db.split == "test") & (db.camera == i)):
            t[db.position[r], db.class_index[r]] = db.images[r]
        tables.append(t)

    rng = np.random.default_rng(0)
    draw_config = lambda: np.stack([rng.integers(V, size=BATCH) for V in rec.positions], axis=1)  # noqa: E731
    states = jax.tree.map(lambda x: jnp.stack([x] * BATCH), rec.init(config=(0,) * n_cams))
    fresh = np.ones(BATCH, bool)                      # every slot starts a trial
    cfg, cls = draw_config(), rng.integers(C, size=BATCH)
    trials, steps = np.arange(BATCH), np.zeros(BATCH, np.int64)
    key = jr.PRNGKey(1)
    figures = dict(bad=0, black=0, nan=0, wrong_size=0, flagged=0, nan_in_beliefs=0, restarts=0)

    def one_call():
        nonlocal states, fresh, cfg, cls, trials, steps
        images = np.stack([tables[i][cfg[:, i], cls] for i in range(n_cams)], axis=1)
        images += rng.normal(0.0, 2.0, images.shape).astype(np.float32)
        np.clip(images, 0.0, 255.0, out=images)
        bad = rng.random((BATCH, n_cams)) < BAD_FRACTION
        for b, i in zip(*np.nonzero(bad)):
            kind = ("black", "nan", "wrong_size")[int(rng.integers(3))]
            figures[kind] += 1
            if kind == "black":
                images[b, i] = 0.0
            elif kind == "nan":
                images[b, i].flat[rng.integers(images[b, i].size, size=5)] = np.nan
            else:  # the host boundary: a frame of another size never reaches the step
                frame = np.full((shape[0] + 1, shape[1] - 2), 100.0, np.float32)
                with pytest.raises(ImageError, match="shape"):
                    check_image(frame, shape, name=f"camera {i}")
                images[b, i] = 0.0  # its slot carries a black frame: flagged invalid in the step
        figures["bad"] += int(bad.sum())
        prior = jax.tree.map(np.asarray, states.prior)
        states, dec = step(states, fresh, cfg, images, key, trials, steps)
        valid, stop = np.asarray(dec.valid), np.asarray(dec.stop)
        any_bad = bad.any(axis=1)
        assert not valid[any_bad].any(), "a bad image was used"
        assert valid[~any_bad].all(), "a good image set was rejected"
        figures["flagged"] += int((~valid).sum())
        post = jax.tree.map(np.asarray, dec.trace.posterior)
        kept = any_bad & ~fresh  # (a fresh slot's prior is the uniform belief, set inside the step)
        for p, q in zip(jax.tree.leaves(post), jax.tree.leaves(prior)):
            np.testing.assert_allclose(p[kept], q[kept], atol=1e-6)  # belief unchanged
        figures["nan_in_beliefs"] += _leaves_nan(states.prior) + _leaves_nan(post)
        # the next call: stopped slots start a new trial (a new scene and start), the others move on
        figures["restarts"] += int(stop.sum())
        fresh, steps = stop, np.where(stop, 0, steps + 1)
        trials = np.where(stop, trials + BATCH, trials)
        cls = np.where(stop, rng.integers(C, size=BATCH), cls)
        cfg = np.where(stop[:, None], draw_config(), np.asarray(dec.next_config))

    for _ in range(WARMUP_CALLS):
        one_call()
    rss_before = _rss_bytes()
    t0 = time.perf_counter()
    with count_compiles() as compiles:
        for _ in range(CALLS):
            one_call()
    seconds = time.perf_counter() - t0
    rss_after = _rss_bytes()
    steps = BATCH * CALLS
    with capsys.disabled():
        print(f"\nsoak: {steps} steps in {seconds:.2f} s ({steps / seconds:.0f} steps/s, host loop included); "
              f"RSS {rss_before / 2**20:.1f} -> {rss_after / 2**20:.1f} MiB; {figures}")
    assert sum(compiles.values()) == 0, dict(compiles)
    assert figures["nan_in_beliefs"] == 0
    assert figures["bad"] > 0.03 * steps * n_cams and min(figures["black"], figures["nan"], figures["wrong_size"]) > 0
    assert figures["restarts"] > BATCH  # trials finished and started again throughout
    assert rss_after <= 1.05 * rss_before, (rss_before, rss_after)


def _lines(path) -> int:
    try:
        with open(path, "rb") as f:
            return f.read().count(b"\n")
    except FileNotFoundError:
        return 0


def test_a_campaign_killed_three_times_resumes_to_the_uninterrupted_result(tmp_path):
    db = moving_database()
    model_path = save_model(tmp_path / "model.npz", train_model(db, kind="DB1", n_components=2, samples_per_image=10))
    whole = campaign(model_path)
    n_trials = len(whole)
    assert n_trials == 2 * TRIALS_PER_OBJECT
    # one compilation cache for the killed runs: a restarted campaign does not recompile
    env = dict(os.environ, JAX_PLATFORMS="cpu", JAX_COMPILATION_CACHE_DIR=str(tmp_path / "jax-cache"),
               JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0", JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES="0")
    store = tmp_path / "killed.jsonl"

    rng = np.random.default_rng()  # random kill points; a failure prints them
    targets = sorted(rng.choice(np.arange(2, n_trials - 8), size=3, replace=False).tolist())
    for target in targets:
        proc = subprocess.Popen([sys.executable, str(Path(__file__).with_name("soak_campaign.py")), str(model_path),
                                 str(store)],
                                env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
        deadline = time.monotonic() + 300
        while _lines(store) < target and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.001)
        time.sleep(rng.uniform(0.0, 0.01))  # between two appends, or in the middle of one
        proc.send_signal(signal.SIGKILL)
        out, _ = proc.communicate(timeout=60)
        assert proc.returncode == -signal.SIGKILL, (targets, out.decode())  # killed, not finished
        assert _lines(store) < n_trials, targets
    killed = TrialStore(store).load()
    assert len(killed) >= targets[-1], targets
    resumed = campaign(model_path, store)  # the third resume, here
    assert resumed == whole, targets
    assert TrialStore(store).load() == {r.trial: r for r in whole} and _lines(store) == n_trials  # none lost or repeated
