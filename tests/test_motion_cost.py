"""Motion-cost-aware planning: the travel-time tables
against a hand computation, the rig file's [motion] speeds, λ = 0 is the plain
planner, a large λ picks the nearest configuration, λ < 0 is an error, a new λ
recompiles nothing, and campaigns record the travel time per trial."""

from __future__ import annotations

import dataclasses
import json
import math

import jax
import jax.numpy as jnp
import jax.random as jr
import numpy as np
from builders import random_sensor_model
import pytest
from compiles import count_compiles

from jaxrecog.hardware import RigConfig
from jaxrecog.hardware.geometry.kinematics import Workspace
from jaxrecog.hardware.geometry.motion import (MotionSpeeds, camera_travel_times, configuration_travel_times,
                                      path_travel_s)
from jaxrecog.hardware.geometry.positions import CameraTable, default_table
from jaxrecog.motion import MotionCost, check_weight, rig_travel_times, with_motion_cost
from jaxrecog.planners import make_planner
from jaxrecog.recognizer import Recognizer
from jaxrecog.results import TrialResult, summarize, table_markdown


random_model = random_sensor_model


def small_table() -> CameraTable:
    """Camera 1 at (pan 0, tilt 45) and (pan 90, tilt 45); camera 2 at pan 0 and 45 deg."""
    r = math.radians
    return CameraTable.from_angles(Workspace(), [(r(0), r(45)), (r(90), r(45))], [r(0), r(45)])


def test_travel_table_against_a_hand_computation():
    # camera 1: dz = 0.7 - 0.1 = 0.6, tilt 45 -> horizontal distance 0.6: eyes
    # (0, 0.6) and (0.6, 0): the gantry moves 0.6 m on x and on y at once
    # -> 0.6 / 0.25 = 2.4 s.  The PTU (mount pan_zero -22.5): azimuths to the
    # object 180 and -90 deg -> PTU pans wrap(202.5) = -157.5 and -67.5:
    # 90 deg, 0.3 s at 300 deg/s; both tilts -45 deg.
    # camera 2: y = 0.75 tan(pan) = 0 and 0.75 m -> 3.0 s on the track; its PTU
    # (pan_zero -90, sign -1) turns 45 deg and tilts by
    # atan(0.15 / 0.75) - atan(0.15 / (0.75 sqrt 2)) = 3.26 deg.
    t1, t2 = camera_travel_times(small_table())
    np.testing.assert_allclose(t1, [[0, 2.4], [2.4, 0]], atol=1e-9)
    np.testing.assert_allclose(t2, [[0, 3.0], [3.0, 0]], atol=1e-9)
    # slow pan-tilt units: the PTU sets the time (90 deg and 45 deg at 10 deg/s)
    s1, s2 = camera_travel_times(small_table(), MotionSpeeds(ptu_deg_s=10.0))
    assert s1[0, 1] == pytest.approx(9.0) and s2[0, 1] == pytest.approx(4.5)
    # a slow track alone: camera 2's 0.75 m at 0.05 m/s
    _, s2 = camera_travel_times(small_table(), MotionSpeeds(track_m_s=0.05))
    assert s2[1, 0] == pytest.approx(15.0)
    # configurations (row-major, camera 1 first): the cameras move in parallel
    full = configuration_travel_times((t1, t2))
    np.testing.assert_allclose(full, [[0, 3.0, 2.4, 3.0],
                                      [3.0, 0, 3.0, 2.4],
                                      [2.4, 3.0, 0, 3.0],
                                      [3.0, 2.4, 3.0, 0]], atol=1e-9)
    assert path_travel_s((t1, t2), [(0, 0), (1, 0), (1, 1), (1, 1)]) == pytest.approx(2.4 + 3.0)


def test_thesis_table_travel_times_are_symmetric_and_bounded():
    t1, t2 = camera_travel_times(default_table())
    assert t1.shape == (32, 32) and t2.shape == (7, 7)
    for t in (t1, t2):
        np.testing.assert_allclose(t, t.T)
        assert np.all(np.diag(t) == 0) and np.all(t[~np.eye(len(t), dtype=bool)] > 0)
    # camera 2 end to end: 2 * 0.75 tan(60 deg) m of track at 0.25 m/s
    assert t2[0, 6] == pytest.approx(2 * 0.75 * math.tan(math.radians(60)) / 0.25)


def test_rig_file_motion_speeds_and_ptu_speed():
    cfg = RigConfig.from_dict({"kind": "simulated", "motion": {"gantry_m_s": 0.5, "track_m_s": 0.1, "ptu_deg_s": 60}})
    assert cfg.motion == MotionSpeeds(gantry_m_s=0.5, track_m_s=0.1, ptu_deg_s=60.0)
    t1, t2 = cfg.travel_times()
    d1, d2 = camera_travel_times(default_table(), cfg.motion)
    np.testing.assert_allclose(t1, d1)
    np.testing.assert_allclose(t2, d2)
    assert RigConfig.from_dict({"kind": "simulated"}).motion == MotionSpeeds()
    from jaxrecog.hardware import ConfigError

    with pytest.raises(ConfigError, match=r"\[motion\].*unknown"):
        RigConfig.from_dict({"kind": "simulated", "motion": {"speed": 1}})
    with pytest.raises(ConfigError, match="gantry_m_s"):
        RigConfig.from_dict({"kind": "simulated", "motion": {"gantry_m_s": 0}})
    # a PTU run at its own speed is timed at it
    mounts = [{"pan_zero_deg": -22.5, "tilt_zero_deg": -45.0}, {"pan_zero_deg": -90.0, "pan_sign": -1}]
    slow = RigConfig.from_dict({"kind": "simulated", "ptu": [{"speed_deg_s": 1.0, **mounts[0]}, mounts[1]]})
    assert MotionSpeeds.from_config(slow).ptu(0) == 1.0 and MotionSpeeds.from_config(slow).ptu(1) == 300.0
    assert slow.travel_times()[0].max() > 100


def test_negative_or_bad_lambda_is_a_clear_error():
    for bad in (-0.1, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="motion cost"):
            check_weight(bad)
        with pytest.raises(ValueError, match="motion cost"):
            MotionCost((np.zeros((2, 2)),), bad)
    with pytest.raises(ValueError, match="motion cost"):
        check_weight("x")
    from jaxrecog.campaigns import Settings

    with pytest.raises(ValueError, match="motion cost"):
        Settings(motion_cost=-1.0)
    model = random_model((4, 3))
    rec = Recognizer(model, make_planner("random", model, key=jr.PRNGKey(0)),
                     motion=MotionCost((np.zeros((4, 4)), np.zeros((3, 3))), 1.0))
    with pytest.raises(ValueError, match="motion cost"):
        with_motion_cost(rec, -2.0)
    with pytest.raises(ValueError, match="positions"):
        Recognizer(model, rec.planner, motion=MotionCost((np.zeros((3, 3)),), 1.0))


def _tables(positions, seed=0):
    rng = np.random.default_rng(seed)
    out = []
    for v in positions:
        t = rng.uniform(1.0, 10.0, (v, v))
        t = (t + t.T) / 2
        np.fill_diagonal(t, 0.0)
        out.append(t)
    return tuple(out)


def _trajectory(rec, config, images, keys):
    state = rec.init(config=config)
    picks, scores = [], []
    for k in keys:
        state, dec = rec.step(state, images, k, trace=True)
        picks.append(int(dec.next_index))
        scores.append(np.asarray(dec.trace.scores))
    return picks, scores


@pytest.mark.parametrize("planner", ["mi", "random"])
def test_lambda_zero_is_the_plain_planner(planner, getkey):
    model = random_model((4, 3))
    plain = Recognizer(model, make_planner(planner, model, key=getkey(), samples=32), max_steps=20, p_threshold=1.1)
    costed = dataclasses.replace(plain, motion=MotionCost(_tables(model.positions), 0.0))
    images = jr.randint(getkey(), (2, 6, 8), 1, 255).astype(jnp.uint8)
    keys = [getkey() for _ in range(5)]
    a, sa = _trajectory(plain, (1, 2), images, keys)
    b, sb = _trajectory(costed, (1, 2), images, keys)
    assert a == b
    for x, y in zip(sa, sb):
        np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("planner", ["mi", "mi-class", "random"])
def test_a_large_lambda_picks_the_nearest_unvisited_configuration(planner, getkey):
    model = random_model((4, 3))
    tables = _tables(model.positions, seed=3)
    full = configuration_travel_times(tables)
    rec = Recognizer(model, make_planner(planner, model, key=getkey(), samples=32), max_steps=20, p_threshold=1.1,
                     motion=MotionCost(tables, 1e4))
    images = jr.randint(getkey(), (2, 6, 8), 1, 255).astype(jnp.uint8)
    state = rec.init(config=(2, 1))
    visited = set()
    for _ in range(6):
        here = int(np.ravel_multi_index(tuple(np.asarray(state.config)), model.positions))
        visited.add(here)
        state, dec = rec.step(state, images, getkey())
        t = full[here].copy()
        t[list(visited)] = np.inf
        assert full[here, int(dec.next_index)] == pytest.approx(t.min(), abs=1e-5)


def test_a_new_lambda_compiles_nothing(getkey):
    model = random_model((4, 3))
    rec = Recognizer(model, make_planner("mi", model, key=getkey(), samples=32), p_threshold=0.96123,
                     motion=MotionCost(_tables(model.positions), 0.0))
    images = jr.randint(getkey(), (2, 6, 8), 1, 255).astype(jnp.uint8)
    state = rec.init(config=(0, 0))
    state1, dec = rec.step(state, images, getkey(), trace=True)
    jax.block_until_ready(dec)
    weights = [0.5, 3.0, 1e3, 0.0]
    recs = [with_motion_cost(rec, w) for w in weights]  # eager ops outside the counter
    keys = [getkey() for _ in weights]
    picks = []
    with count_compiles() as later:
        for r, k in zip(recs, keys):
            _, d = r.step(state1, images, k, trace=True)
            picks.append(int(d.next_index))
    assert sum(later.values()) == 0, dict(later)
    assert float(recs[1].motion.weight) == 3.0 and len(set(picks)) >= 1


def test_results_record_travel_and_old_stores_still_load(tmp_path):
    from jaxrecog.results import TrialStore

    old = {"trial": 0, "object": 0, "pose": 0, "predicted_object": 0, "predicted_pose": 0, "exit_prob": 0.9,
           "steps": 2, "stopped": False, "configurations": [[0, 0], [1, 0]]}
    path = tmp_path / "old.jsonl"
    path.write_text(json.dumps(old) + "\n")
    (r,) = TrialStore(path).load().values()
    assert math.isnan(r.travel_s)
    new = dataclasses.replace(r, trial=1, travel_s=2.5)
    store = TrialStore(path)
    store.append(new)
    got = store.load()
    assert got[1].travel_s == 2.5 and math.isnan(got[0].travel_s)
    assert '"travel_s":null' in dataclasses.replace(r, trial=2).to_json()  # strict JSON for unknown
    rows = summarize([new], 1)
    assert rows[-1].travel_s == 2.5 and "Mean travel (s)" in table_markdown(rows) and "2.50" in table_markdown(rows)
    assert "travel" not in table_markdown(summarize([r], 1))  # nothing recorded: the column stays out


def test_campaign_on_a_rig_with_a_geometry_records_travel(moving_model):
    """The driver adds up the moves of each trial under the recognizer's tables."""
    from jaxrecog.campaign import plan_trials, run_campaign
    from jaxrecog.hardware import DatasetRig

    db, model = moving_model
    assert rig_travel_times(DatasetRig(db, seed=0)) is None  # a replayed database has no geometry
    t = np.array([[0, 1, 2], [1, 0, 4], [2, 4, 0]], float)
    rec = Recognizer(model, make_planner("random", model, key=jr.PRNGKey(0)), p_threshold=0.999,
                     motion=MotionCost((t,), 0.0))
    res = run_campaign(rec, DatasetRig(db, seed=0), plan_trials(2, 3, (3,), 2, seed=1), key=jr.PRNGKey(0), batch=2)
    for r in res:
        want = sum(t[a[0], b[0]] for a, b in zip(r.configurations, r.configurations[1:]))
        assert r.travel_s == pytest.approx(want)
    plain = Recognizer(model, rec.planner, p_threshold=0.999)
    res0 = run_campaign(plain, DatasetRig(db, seed=0), plan_trials(2, 3, (3,), 2, seed=1), key=jr.PRNGKey(0), batch=2)
    assert all(math.isnan(r.travel_s) for r in res0)
    # λ = 0: the same trials as without the tables
    assert [dataclasses.replace(r, travel_s=0.0) for r in res] == [dataclasses.replace(r, travel_s=0.0) for r in res0]


def test_synthetic_rig_travel_times_are_the_tables_ones():
    class FakeSynthetic:
        table = default_table()

    t = rig_travel_times(FakeSynthetic())
    d = camera_travel_times(default_table())
    assert len(t) == 2 and all(np.array_equal(a, b) for a, b in zip(t, d))


@pytest.mark.slow
def test_sweep_script_writes_json_and_plot(strided_workdir, tmp_path):
    from clirun import run_script

    work = strided_workdir(tmp_path / "work")
    out = tmp_path / "out"
    p = run_script("motion_cost_sweep", "--quick", "--stride", "8", "--trials", "1", "--lambdas", "0", "5", "--batch", "4",
                   "--workdir", work, "--out", out)
    assert p.returncode == 0, p.stderr
    summary = json.loads((out / "motion_cost_sweep.json").read_text())
    assert [r["lambda"] for r in summary["rows"]] == [0.0, 5.0] and summary["positions"] == [4, 1]
    assert all(r["trials"] == 8 and r["travel_s"] >= 0 for r in summary["rows"])
    assert (out / "motion_cost_sweep.png").stat().st_size > 1000
    bad = run_script("motion_cost_sweep", "--lambdas", "-1", "--out", out)
    assert bad.returncode == 2 and "motion cost" in bad.stderr
