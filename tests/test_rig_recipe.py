"""scripts/rig_recipe.py: a recipe on a synthetic case with every part of it:
held-out captures like the case's (jaxrecog/campaigns/held_out.py), calibration
and the planner's stability weight fitted on them, the case's trials."""

from __future__ import annotations

import json

import pytest
from clirun import run_script

from jaxrecog.campaigns import CASES, Settings
from jaxrecog.campaigns.held_out import like_case


def test_held_out_captures_are_drawn_like_the_case():
    s = Settings(capture_noise=(0.1, 3.0, 2))
    on_grid, jitter = like_case(CASES["iii"], s), like_case(CASES["jitter-occluded"], s)
    assert (on_grid.yaw_deg, on_grid.eye_offset, on_grid.light) == (0.0, 0.0, 0.0)
    assert (jitter.yaw_deg, jitter.eye_offset, jitter.light) == (20.0, 0.04, 0.2)
    assert (on_grid.noise.brightness, on_grid.noise.pixel, on_grid.noise.max_shift) == (0.1, 3.0, 2)
    assert like_case(CASES["jitter"], Settings(off_grid_deg=5.0)).yaw_deg == 5.0   # the settings' override


@pytest.mark.slow
def test_rig_recipe_script_on_a_strided_table(tmp_path, strided_workdir):
    work = strided_workdir(tmp_path / "rig")
    p = run_script("rig_recipe", "--case", "single-clean", "--trials", "1", "--stride", "8", "--view-jitter", "0",
                   "--n-components", "4", "--samples-per-image", "10", "--no-calibrate", "--workdir", work)
    assert p.returncode == 0, p.stderr
    assert "planner stability weight" in p.stdout and "factors" not in p.stdout     # fitted, not calibrated
    assert "recipe robust version 6" in p.stdout and "| mi-class-pairwise-stable | 8 |" in p.stdout
    js = json.loads((work / "results" / "rig-recipe-single-clean-robust-n1-stride8-cal0.json").read_text())
    fit = js["notes"]["stability_fit"]
    # a single-camera case: the fit reads camera 0's held-out captures only (4 positions x 8 objects x 4 poses)
    assert js["stability"] == fit["weight"] in (0.0, 1.0) and fit["n"] == 4 * 8 * 4
    assert js["recipe"]["occluder_gray"] == [0.0, 255.0] and js["recipe"]["calibrate"] is False   # the parts as used
    assert js["recipe"]["stability"] == js["stability"]
    assert (work / "held-out-single-clean-stride8-seed0" / "manifest.csv").exists()
    assert len(list((work / "trials").glob("recipe-single-clean-mi-class-pairwise-stable-robust6-*.jsonl"))) == 1
    q = run_script("rig_recipe", "--case", "iv")
    assert q.returncode == 2 and "'iv'" in q.stderr and "Traceback" not in q.stderr


def test_held_out_captures_of_an_occluded_case_have_boards_in_front(tmp_path, monkeypatch):
    """The occluded case's renderer gets a board for a share ``occluded_fraction`` of
    the views (a layout for that one camera), the clean case none; a folder with a
    manifest is kept."""
    import numpy as np

    import jaxrecog.hardware as hw
    from jaxrecog.campaigns.held_out import render_held_out

    calls = []
    monkeypatch.setattr(hw, "render_database", lambda folder, table, **kw: calls.append((folder, table, kw)))
    s = Settings(stride=16)
    for frac in (1.0, 0.0):
        render_held_out(tmp_path / f"f{frac}", s, CASES["iii"], like_case(CASES["iii"], s), occluded_fraction=frac, seed=3)
    render_held_out(tmp_path / "clean", s, CASES["i"], like_case(CASES["i"], s))
    (full, table, kw), (empty, _, kw0), (_, _, clean) = calls
    assert tuple(len(v) for v in table.views) == (2, 1) and kw["seed"] == 3 and kw["train"] is False
    assert kw["calib_per_view"] == 1 and clean["calib_occluders"] is False
    rng = np.random.default_rng(0)
    layouts = [kw["calib_occluders"](rng, cam, v) for cam, v in ((0, 0), (0, 1), (1, 0))]
    assert all(lay is not None and len(lay.boards) >= 1 for lay in layouts)
    assert all(kw0["calib_occluders"](rng, 0, 0) is None for _ in range(5))
    (tmp_path / "kept").mkdir()
    (tmp_path / "kept" / "manifest.csv").write_text("")
    assert render_held_out(tmp_path / "kept", s, CASES["iii"], None) == tmp_path / "kept" and len(calls) == 3
