"""Off-grid captures: the trial's yaw offset, per-capture
eye and light jitter on the synthetic rig, and the ``jitter`` cases."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from jaxrecog import campaigns as ex
from jaxrecog.campaign import plan_trials
from jaxrecog.hardware.render.synthetic import OffGrid
from jaxrecog.results import TrialResult, TrialStore

#: small models on the stride-8 table (the session's rendered database)
SMALL = dict(stride=8, trials_per_object=1, batch=4, samples=64, min_per_stratum=2, samples_per_image=20, n_components=8)


def _capture(rig, seed=(0, 3, 1), config=(2, 0)):
    rig.reseed(seed)
    rig.move(config)
    return rig.capture()


def test_yaw_zero_and_no_jitter_reproduce_the_on_grid_captures():
    s = ex.Settings(stride=8)
    with ex.make_rig(s) as plain, ex.make_rig(dataclasses.replace(s, off_grid_deg=0.0, off_grid_eye=0, off_grid_light=0)) as zero:
        assert zero.off_grid is None
        plain.reset(3, 1)
        zero.reset(3, 1, yaw_offset_deg=0.0)
        a, b = _capture(plain), _capture(zero)
        np.testing.assert_array_equal(a.images, b.images)
    # the trial lists of a zero bound are today's (no draw: yaw_offset None)
    assert plan_trials(8, 4, (4, 1), 3, seed=5) == plan_trials(8, 4, (4, 1), 3, seed=5, yaw_deg=0.0)
    # and the run ids of on-grid settings are unchanged by the new fields
    fields = ex.Settings().flat()
    assert fields["off_grid_deg"] is None
    assert ex.case_settings(ex.CASES["i"], ex.Settings()).off_grid_deg == 0.0


def test_run_id_ignores_zero_off_grid(tmp_path):
    model = tmp_path / "m.npz"
    model.write_bytes(b"model bytes")
    base = ex.naming.run_id(ex.Settings(), model)
    assert ex.naming.run_id(ex.Settings(off_grid_deg=0, off_grid_eye=0.0, off_grid_light=0.0), model) == base
    assert ex.naming.run_id(ex.case_settings(ex.CASES["i"], ex.Settings()), model) == base
    assert ex.naming.run_id(ex.case_settings(ex.CASES["jitter"], ex.Settings()), model) != base


def test_yaw_offsets_are_a_function_of_the_trial():
    a = plan_trials(8, 4, (4, 1), 5, seed=0, yaw_deg=20.0)
    b = plan_trials(8, 4, (4, 1), 5, seed=0, yaw_deg=10.0)
    on = plan_trials(8, 4, (4, 1), 5, seed=0)
    # same scene and start as on the grid, the yaw drawn last
    assert [(s.trial, s.object, s.pose, s.initial) for s in a] == [(s.trial, s.object, s.pose, s.initial) for s in on]
    assert all(s.yaw_offset is not None and -20 <= s.yaw_offset <= 20 for s in a)
    assert len({round(s.yaw_offset, 9) for s in a}) == len(a)
    np.testing.assert_allclose([s.yaw_offset for s in a], [2 * s.yaw_offset for s in b])
    # a sub-list of objects gives the same trial its same offset
    sub = plan_trials(8, 4, (4, 1), 5, seed=0, yaw_deg=20.0, objects=[6])
    assert [s.yaw_offset for s in sub] == [s.yaw_offset for s in a if s.object == 6]


def test_jitter_is_seeded_by_the_capture_stream():
    s = ex.case_settings(ex.CASES["jitter"], ex.Settings(stride=8))
    with ex.make_rig(s) as r1, ex.make_rig(s, seed=99) as r2, ex.make_rig(ex.Settings(stride=8)) as plain:
        assert r1.off_grid == OffGrid(*ex.JITTER)
        for r in (r1, r2, plain):
            r.reset(5, 2, yaw_offset_deg=7.5 if r is not plain else 0.0)
        a, b = _capture(r1), _capture(r2)  # rigs of other seeds, reseeded alike: the same image
        np.testing.assert_array_equal(a.images, b.images)
        c = _capture(r1, seed=(0, 3, 2))  # another step: another eye and light
        assert not np.array_equal(a.images, c.images)
        assert not np.array_equal(a.images, _capture(plain).images)
    with ex.make_rig(dataclasses.replace(s, off_grid_eye=0.0, off_grid_light=0.0)) as yaw_only, \
            ex.make_rig(ex.Settings(stride=8)) as plain:
        assert (yaw_only.off_grid.eye_offset, yaw_only.off_grid.light) == (0.0, 0.0)  # a yaw bound alone: no draws
        yaw_only.reset(5, 2, yaw_offset_deg=7.5)
        plain.reset(5, 2)
        assert not np.array_equal(_capture(yaw_only).images, _capture(plain).images)
        yaw_only.reset(5, 2)
        np.testing.assert_array_equal(_capture(yaw_only).images, _capture(plain).images)


@pytest.mark.parametrize("bad", [-1.0, -1e-9, math.nan, math.inf])
def test_bad_off_grid_amounts_are_value_errors(bad):
    for k in ("off_grid_deg", "off_grid_eye", "off_grid_light"):
        with pytest.raises(ValueError, match=k):
            ex.Settings(**{k: bad})
    for k in ("yaw_deg", "eye_offset", "light"):
        with pytest.raises(ValueError, match=k):
            OffGrid(**{k: bad})
    with pytest.raises(ValueError, match="yaw_deg"):
        plan_trials(8, 4, (4, 1), 1, yaw_deg=bad)


def test_bad_yaw_offset_at_reset():
    with ex.make_rig(ex.Settings(stride=8)) as rig:
        for bad in (math.nan, math.inf, -math.inf):
            with pytest.raises(ValueError, match="yaw_offset_deg"):
                rig.reset(0, 0, yaw_offset_deg=bad)


def test_yaw_offset_in_results_and_old_records_load(tmp_path):
    r = TrialResult(trial=1, object=0, pose=2, predicted_object=0, predicted_pose=2, exit_prob=0.97, steps=1,
                    stopped=True, yaw_offset=-12.25)
    store = TrialStore(tmp_path / "t.jsonl")
    store.append(r)
    store.append(dataclasses.replace(r, trial=2, yaw_offset=None))
    back = store.load()
    assert back[1].yaw_offset == -12.25 and back[2].yaw_offset is None
    assert "yaw_offset" not in dataclasses.replace(r, yaw_offset=None).to_json()  # on-grid records as before


def test_jitter_cases_are_registered():
    for name in ("jitter", "jitter-occluded"):
        c = ex.CASES[name]
        assert c.off_grid == ex.JITTER and c.cameras is None
        assert c.planners == ("mi-class", "mi-class-pairwise", "random")
    assert ex.CASES["jitter"].database == "DB1" and not ex.CASES["jitter"].occluded
    assert ex.CASES["jitter-occluded"].database == "DB2" and ex.CASES["jitter-occluded"].occluded
    assert all(ex.CASES[n].off_grid == (0.0, 0.0, 0.0) for n in ("i", "ii", "iii", "single-clean", "single-occluded"))


def test_jitter_case_at_stride_8_same_offsets_for_every_planner(tmp_path, strided_workdir):
    work = strided_workdir(tmp_path / "work")
    settings = ex.Settings(workdir=work, **SMALL)
    report = ex.run_case("jitter", settings, ("mi-class-pairwise", "random"))
    assert report.settings.off_grid_deg == 20.0 and report.settings.off_grid_eye == ex.JITTER[1]
    a, b = (report.results[p] for p in ("mi-class-pairwise", "random"))
    assert len(a) == len(b) == 8
    assert [r.yaw_offset for r in a] == [r.yaw_offset for r in b]
    assert all(r.yaw_offset is not None and abs(r.yaw_offset) <= 20 for r in a)
    assert [(r.object, r.pose, r.configurations[0]) for r in a] == [(r.object, r.pose, r.configurations[0]) for r in b]
    md, js = report.write()
    assert md.name == "case-jitter.md" and "Off-grid" in md.read_text()
    # resumed: the stored trials (with their offsets) are reused as they are
    again = ex.run_case("jitter", settings, ("random",))
    assert [r.yaw_offset for r in again.results["random"]] == [r.yaw_offset for r in b]
