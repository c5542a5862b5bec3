"""Sharded campaigns: the lockstep batch split over devices
gives the same TrialResults as one device; too many devices is a clear error.

The two-device run needs ``XLA_FLAGS=--xla_force_host_platform_device_count=2``
before jax is imported, so it runs in a subprocess."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from jaxrecog.driver import trial_mesh

TESTS = Path(__file__).resolve().parent

SCRIPT = textwrap.dedent("""
    import dataclasses, sys
    sys.path.insert(0, {tests!r})
    import jax, jax.numpy as jnp, jax.random as jr, numpy as np
    assert len(jax.devices()) == 2, jax.devices()
    from builders import moving_database
    from jaxrecog import Recognizer, make_planner, plan_trials, run_trials, train_model
    from jaxrecog.driver import batched_step, trial_mesh, _initial_states
    from jaxrecog.hardware import DatasetRig
    from jaxrecog.motion import MotionCost

    db = moving_database()
    model = train_model(db, kind="DB1", n_components=2, samples_per_image=10)
    t = np.array([[0, 1, 2], [1, 0, 4], [2, 4, 0]], float)
    specs = plan_trials(2, 3, (3,), 5, seed=1)  # 10 trials: slots are reused
    for name in ("mi", "random"):
        rec = Recognizer(model, make_planner(name, model, key=jr.PRNGKey(0), samples=64), p_threshold=0.999,
                         motion=MotionCost((t,), 0.2))
        runs = {{}}
        for devices, batch in ((1, 4), (2, 4), (2, 3)):
            res = run_trials(rec, DatasetRig(db, seed=0), specs, key=jr.PRNGKey(2), batch=batch, seed=3,
                             devices=devices, trace=True)
            runs[devices, batch] = sorted(res, key=lambda r: r.trial)
        one = runs[1, 4]
        assert len(one) == len(specs)
        for k, v in runs.items():
            assert v == one, (name, k)
        print(name, "identical", [r.steps for r in one])

    # the states really live on both devices, the model on each
    mesh = trial_mesh(2)
    step = batched_step(rec, mesh=mesh)
    states = _initial_states(rec, 4)
    b = 4
    imgs = np.zeros((b, 1) + tuple(model.image_shape), np.uint8) + 7
    out, dec = step(states, np.ones(b, bool), np.zeros((b, 1), np.int32), imgs, jr.PRNGKey(0),
                    np.arange(b, dtype=np.int32), np.zeros(b, np.int32))
    assert len(out.config.sharding.device_set) == 2, out.config.sharding
    assert out.config.sharding.spec[0] == "trials", out.config.sharding
    try:
        step(states, np.ones(3, bool), np.zeros((3, 1), np.int32), imgs[:3], jr.PRNGKey(0),
             np.arange(3, dtype=np.int32), np.zeros(3, np.int32))
    except ValueError as e:
        assert "multiple" in str(e), e
    else:
        raise AssertionError("a batch of 3 on 2 devices must be refused by batched_step")
    print("OK")
""")


@pytest.mark.slow
def test_two_devices_give_the_same_trials_as_one(tmp_path):
    env = dict(os.environ, JAX_PLATFORMS="cpu",
               XLA_FLAGS=" ".join([os.environ.get("XLA_FLAGS", ""), "--xla_force_host_platform_device_count=2"]).strip())
    script = tmp_path / "sharded.py"
    script.write_text(SCRIPT.format(tests=str(TESTS)))
    p = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=600, env=env)
    assert p.returncode == 0 and "OK" in p.stdout, p.stdout + p.stderr
    assert p.stdout.count("identical") == 2


def test_more_devices_than_exist_is_a_clear_error():
    import jax

    n = len(jax.devices())
    with pytest.raises(ValueError, match=rf"asked for {n + 1} devices but {n} exist"):
        trial_mesh(n + 1)
    with pytest.raises(ValueError, match=">= 1"):
        trial_mesh(0)
    assert trial_mesh(1) is None and trial_mesh(None) is None
