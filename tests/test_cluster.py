"""Campaigns and renders on Ray (jaxrecog.cluster): the same
trials and results as in one process, the same database files, a killed
worker that loses no trial and repeats none, and one clear line for a
cluster that is not there or runs other versions.

One local Ray instance (2 CPUs, no dashboard) serves the whole file; its
start-up is most of the file's time."""

from __future__ import annotations

import functools
import json
import os
import signal
import sys
import threading
import time
from pathlib import Path

import jax.random as jr
import numpy as np
import pytest

ray = pytest.importorskip("ray")

from jaxrecog import Recognizer, plan_trials  # noqa: E402
from jaxrecog import cli  # noqa: E402
from jaxrecog.campaign import run_campaign  # noqa: E402
from jaxrecog.cluster import ClusterError, check_cluster, connect, ray_error_line, version_problems  # noqa: E402
from jaxrecog.campaigns import Settings, capture_pool, rig_pool  # noqa: E402
from jaxrecog.hardware import Noise  # noqa: E402
from jaxrecog.hardware.rigs.rig_pool import LocalRigs  # noqa: E402
from jaxrecog.scene import occluder_factory  # noqa: E402
from jaxrecog.planners import RandomPlanner  # noqa: E402
from jaxrecog.results import TrialStore  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def local_ray():
    """One local Ray instance for the file, started as ``--cluster ray``
    starts one (its workers inherit this process's environment: the test
    run's XLA flags and compilation cache)."""
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])  # GateRig, in the workers
    # Ray's memory monitor kills workers when the machine (any process on it) is near full: not here
    os.environ.setdefault("RAY_memory_monitor_refresh_ms", "0")
    assert not ray.is_initialized()
    connect("ray", num_cpus=2)  # --cluster ray's own start: no dashboard, Ray's logs kept out of the output
    yield ray
    ray.shutdown()


def _signature(results):
    return sorted((r.trial, r.predicted_object, r.predicted_pose, r.steps, r.configurations, r.exit_prob,
                   r.occluded_fraction) for r in results)


# -- bad input, no cluster needed


def test_cluster_specs_and_a_cluster_that_is_not_there(tmp_path, capsys):
    assert check_cluster(None) is None and check_cluster("") is None and check_cluster("ray") == "ray"
    assert check_cluster("ray://head.lab:10001") == "ray://head.lab:10001"
    for bad in ("spark", "ray://head", "ray://:10001", "ray://head:0", "ray://head:port"):
        with pytest.raises(ValueError, match="ray"):
            check_cluster(bad)
    with pytest.raises(ValueError, match="cluster must be 'ray'"):
        Settings(cluster="dask")
    t0 = time.monotonic()
    with pytest.raises(ClusterError, match=r"cannot reach the Ray cluster at ray://127\.0\.0\.1:9: connection refused"):
        connect("ray://127.0.0.1:9")
    with pytest.raises(ClusterError, match="unknown host"):
        connect("ray://no-such-head.invalid:10001")
    # the command: one line, within 10 s, before anything renders or trains
    code = cli.main(["experiment", "i", "--stride", "8", "--quick", "--cluster", "ray://127.0.0.1:9",
                     "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and "cannot reach the Ray cluster at ray://127.0.0.1:9" in err[0], err
    assert time.monotonic() - t0 < 10
    assert not list((tmp_path / "o" / "work").iterdir())  # nothing rendered
    assert cli.main(["render", "--out", str(tmp_path / "r"), "--cluster", "ray:/head:1"]) == 2
    assert "ray://HOST:PORT" in capsys.readouterr().err


def test_a_version_mismatch_is_named():
    from ray._private.utils import check_version_info

    with pytest.raises(RuntimeError) as raised:  # Ray Client's own check, with an older cluster
        check_version_info({"ray_version": "2.9.3", "python_version": "3.10.12"}, "Ray Client",
                           raise_on_mismatch=True, python_version_match_level="minor")
    line = ray_error_line(raised.value, "ray://head:10001")
    assert line.startswith("Ray version mismatch with ray://head:10001: the cluster runs Ray 2.9.3 (Python 3.10.12), "
                           f"this process Ray {ray.__version__}"), line
    assert "\n" not in line
    here = {"Python": "3.11", "Ray": "2.60.0", "JAX": "0.7.0", "jaxrecog": "0.1.0"}
    assert version_problems(here, dict(here), "0") is None
    assert version_problems(here, dict(here, Ray="2.59.0"), "3 (node ab12)") == (
        "Ray version mismatch on the cluster's worker 3 (node ab12): Ray 2.59.0 there, 2.60.0 here "
        "(install the same versions on every node)")
    assert version_problems(here, dict(here, jaxrecog="0.0.9"), "1").startswith("version mismatch")


# -- on the local instance

STRIDED = Settings(stride=8, batch=2, cluster="ray", render_workers=2)  # (4, 1) positions, 2 rigs per worker


class GateRig:
    """The strided synthetic rig, noting every scene it is set up for
    (``resets.log``: pid, trial); the first time it reaches the trial named
    in ``gate`` (when that file exists) it writes its pid to ``gate.pid``
    and waits there to be killed."""

    def __init__(self, folder):
        from jaxrecog.campaigns import make_rig

        self.rig, self.folder, self.fresh = make_rig(STRIDED), Path(folder), False

    def __getattr__(self, name):
        return getattr(self.rig, name)

    def reset(self, *args, **kw):
        self.rig.reset(*args, **kw)
        self.fresh = True

    def reseed(self, value):
        _, trial, _ = value
        if self.fresh:
            self.fresh = False
            with open(self.folder / "resets.log", "a") as f:
                f.write(f"{os.getpid()} {trial}\n")
        gate, marker = self.folder / "gate", self.folder / "gate.pid"
        if gate.exists() and trial == int(gate.read_text()) and not marker.exists():
            marker.write_text(str(os.getpid()))
            time.sleep(60)
        self.rig.reseed(value)


@pytest.fixture(scope="module")
def ray_pool(local_ray, tmp_path_factory):
    """Two Ray workers with two gated synthetic rigs each, for the file's campaigns."""
    from jaxrecog.ray_rigs import RayRigs

    folder = tmp_path_factory.mktemp("gate")
    with RayRigs(functools.partial(GateRig, folder), 2, 2) as pool:
        yield pool, folder


@pytest.fixture(scope="module")
def recognizer():
    from builders import random_sensor_model

    model = random_sensor_model(positions=(4, 1), n_objects=8, n_poses=4, hw=(120, 160))
    return Recognizer(model, RandomPlanner(4), p_threshold=0.999, max_steps=3)


def test_capture_pool_puts_the_rigs_on_the_cluster(monkeypatch):
    from jaxrecog import ray_rigs

    monkeypatch.setattr(ray_rigs, "RayRigs", lambda *args, cluster: (*args, cluster))
    factory, n_rigs, workers, spec = capture_pool(STRIDED, (0,))
    assert (n_rigs, workers, spec) == (2, 2, "ray")
    with factory() as rig:
        assert rig.positions == (4,) and rig.image_shape == (120, 160)


def test_a_campaign_on_ray_is_the_local_campaign(ray_pool, recognizer, tmp_path):
    """Synthetic rig captures (boards in front of the first views) in Ray
    actors: the same trials as in this process, into a resumable store; the
    pool's own captures match too."""
    pool, _ = ray_pool
    local = LocalRigs(rig_pool(STRIDED))
    specs = plan_trials(8, 4, (4, 1), 1, seed=3, objects=[1, 6], occluders=occluder_factory(local.rigs[0]))
    specs += plan_trials(8, 4, (4, 1), 2, seed=3, objects=[2, 5])
    key = jr.PRNGKey(7)
    here = run_campaign(recognizer, local, specs, key=key, batch=2, seed=5)
    store = TrialStore(tmp_path / "trials.jsonl")
    assert (pool.n_rigs, pool.workers, pool.positions, pool.image_shape) == (2, 2, (4, 1), (120, 160))
    pool.trials_per_task = 2  # three batches over two workers
    there = run_campaign(recognizer, pool, specs, key=key, batch=2, seed=5, store=store)
    assert _signature(there) == _signature(here) and len(there) == 6
    assert any(f > 0 for r in there for f in r.occluded_fraction[0])  # the boards were there
    lines = store.path.read_text().splitlines()
    assert len(lines) == 6 and set(store.load()) == {s.trial for s in specs}
    again = run_campaign(recognizer, pool, specs, key=key, batch=2, seed=5, store=store)  # resumed: nothing to run
    assert _signature(again) == _signature(here) and store.path.read_text().splitlines() == lines
    from jaxrecog.hardware.rigs.rig_pool import CaptureJob, SceneSpec

    jobs = [CaptureJob(0, SceneSpec(3, 1, specs[0].occluders), (5, 0, 0), (2, 0)),
            CaptureJob(1, SceneSpec(4, 2, None, 6.0), (5, 1, 0), (1, 0))]
    for a, b in zip(pool.capture_batch(jobs), local.capture_batch(jobs)):
        np.testing.assert_array_equal(a.images, b.images)
        assert a.occluded == b.occluded


def test_a_killed_worker_loses_no_trial_and_repeats_none(ray_pool, recognizer, tmp_path):
    """Worker A's process is killed while it runs its batch's fourth trial
    (its first trials are stored by then): the trials it had not sent back
    run again elsewhere, the ones it had are never run again, and the store
    holds each trial once, with the results of a run in this process."""
    pool, folder = ray_pool
    specs = plan_trials(8, 4, (4, 1), 3, seed=1, objects=[0, 3, 4, 7])  # ids 0..2, 9..11, 12..14, 21..23
    ids = [s.trial for s in specs]
    key = jr.PRNGKey(0)
    here = run_campaign(recognizer, LocalRigs(rig_pool(STRIDED)), specs, key=key, batch=2, seed=2)
    (folder / "resets.log").unlink(missing_ok=True)
    gate = ids[3]  # worker A: batch ids[:6], worker B: ids[6:]
    (folder / "gate").write_text(str(gate))
    store = TrialStore(tmp_path / "trials.jsonl")
    before: dict = {}

    def stored() -> set[int]:
        """The trials in the store's complete lines (read only: ``TrialStore.load``
        would cut a line the campaign is writing)."""
        text = store.path.read_text() if store.path.exists() else ""
        return {json.loads(line)["trial"] for line in text.split("\n")[:-1]}

    def kill_at_the_gate():
        marker = folder / "gate.pid"
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:  # the gate reached, and the worker's first trials stored
            if marker.exists() and len(stored() & set(ids[:6])) >= 2:
                before["stored"] = stored()
                os.kill(int(marker.read_text()), signal.SIGKILL)
                return
            time.sleep(0.02)

    pool.trials_per_task = 6
    killer = threading.Thread(target=kill_at_the_gate)
    killer.start()
    there = run_campaign(recognizer, pool, specs, key=key, batch=2, seed=2, store=store)
    killer.join()
    lost = pool.last_run
    assert "stored" in before, ("the gate was not reached", (folder / "resets.log").read_text(),
                                sorted(store.load()), (folder / "gate.pid").exists(), lost)
    assert lost["workers_lost"] == 1 and gate in lost["sent_again"], lost
    again = set(lost["sent_again"])
    assert again <= set(ids[:6]) and not before["stored"] & again
    assert _signature(there) == _signature(here)
    assert len(store.path.read_text().splitlines()) == len(specs) and sorted(store.load()) == sorted(ids)
    resets = [int(line.split()[1]) for line in (folder / "resets.log").read_text().splitlines()]
    runs = {t: resets.count(t) for t in ids}
    # a trial ran twice only when its worker died under it (the gate, and maybe the one beside it)
    assert runs[gate] == 2 and all(runs[t] == 1 for t in set(ids) - again) and all(runs[t] <= 2 for t in again), runs


def test_rendering_on_ray_writes_the_same_files(local_ray, tmp_path):
    """Both render paths, with random splits (test boards, noise, calib
    perturbations) whose draws run through the whole database in order."""
    from jaxrecog.ray_render import render_database_on, render_turntable_on
    from jaxrecog.campaigns import rig_table
    from jaxrecog.hardware import SyntheticRig, default_objects, render_database
    from jaxrecog.hardware.render.random_objects import random_objects
    from jaxrecog.hardware.render.turntable import render_turntable

    def files(folder):
        return {p.relative_to(folder): p.read_bytes() for p in folder.rglob("*") if p.is_file()}

    factory = functools.partial(SyntheticRig, rig_table(Settings(stride=8)), objects=default_objects()[:2],
                                n_poses=2, seed=4)
    kw = dict(test_per_view=1, test_occluders=True, calib_per_view=1, seed=3, test_noise=Noise(0.05, 2.0, 2))
    with factory() as rig:
        render_database(tmp_path / "a", rig=rig, **kw)
    render_database_on("ray", tmp_path / "b", rig_factory=factory, **kw)
    a, b = files(tmp_path / "a"), files(tmp_path / "b")
    assert len(a) == 1 + 2 * 2 * 5 * 3 and a == b
    objs = random_objects(1, seed=0)
    tk = dict(poses=2, step_deg=120, test_per_view=2, calib_per_view=1, occluders=True, seed=1)
    render_turntable(tmp_path / "c", objs, **tk)
    render_turntable_on("ray", tmp_path / "d", objs, **tk)
    c, d = files(tmp_path / "c"), files(tmp_path / "d")
    assert len(c) == 1 + 2 * 3 * 4 and c == d

