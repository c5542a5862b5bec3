"""Recipes: one named, versioned bundle of training and stop rule,
recorded in the model file and read back by recognize and experiment; flags
override its parts; old model files are 'thesis'; bad input is one line."""

from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest

from clirun import run_cli
from jaxrecog.modelfile import FORMAT_VERSION, load_model, load_model_meta
from jaxrecog.photo_turntable import build_photo_database
from jaxrecog.recipes import RECIPES, ROBUST, THESIS, get_recipe, recipe_from_meta

FAST = ("--kind", "DB1", "--samples", "10", "--components", "4")


@pytest.fixture(scope="module")
def photo_db(tmp_path_factory):
    """Two real objects on a 40-degree grid (9 positions, 4 poses), test views 20 degrees off."""
    root = tmp_path_factory.mktemp("recipes")
    build_photo_database(root / "db", 40, objects=2)
    return root


@pytest.fixture(scope="module")
def robust_model(photo_db):
    out = photo_db / "robust.npz"
    p = run_cli("train", photo_db / "db", "--out", out, *FAST)
    assert p.returncode == 0, p.stderr
    return out


def _one_error(p, needle):
    lines = [l for l in p.stderr.splitlines() if "error:" in l]
    assert len(lines) == 1 and "Traceback" not in p.stderr, p.stderr
    assert needle in lines[0], lines[0]


def test_registry_and_thesis_is_todays_defaults():
    assert list(RECIPES) == ["robust", "thesis"] and get_recipe("thesis") is THESIS
    assert (THESIS.likelihood, THESIS.interpolate, THESIS.calibrate, THESIS.view_jitter) == ("gaussian-diag", 0, False, False)
    assert THESIS.stop_rule() == {"p_threshold": 0.95, "min_views": 1, "exclude_visited": False, "adaptive_scale": 1.0}
    # a robust file of version 2 (before the adaptive scale) loads as it ran: the scale off
    v2 = {k: v for k, v in ROBUST.to_dict().items() if k != "adaptive_scale"} | {"version": 2}
    assert recipe_from_meta({"recipe": v2}).adaptive_scale == 1.0 and ROBUST.adaptive_scale == 32.0
    with pytest.raises(ValueError, match="adaptive_scale must be a number in"):
        ROBUST.replace(adaptive_scale=0.5)
    assert recipe_from_meta({}) is THESIS                       # a file written before recipes
    assert recipe_from_meta({"recipe": ROBUST.to_dict()}) == ROBUST
    with pytest.raises(ValueError, match="unknown recipe 'fast'; choose robust, thesis"):
        get_recipe("fast")
    with pytest.raises(ValueError, match="no part named colour"):
        ROBUST.replace(colour=1)
    with pytest.raises(ValueError, match="calibrate must be true, false or 'auto'"):
        ROBUST.replace(calibrate="sometimes")
    # a robust file of version 5 (before pooled calibration factors) loads as it ran: not pooled
    v5 = {k: v for k, v in ROBUST.to_dict().items() if k != "calib_pool"} | {"version": 5}
    assert recipe_from_meta({"recipe": v5}).calib_pool is False and ROBUST.calib_pool is True
    with pytest.raises(ValueError, match="the model's recipe entry is not readable"):
        recipe_from_meta({"recipe": v5 | {"calib_pool": "yes"}})


def test_recipes_command_lists_them():
    p = run_cli("recipes")
    assert p.returncode == 0
    assert p.stdout.startswith("robust (default), version 6:") and "\nthesis, version 1:" in p.stdout
    assert "  interpolate = 2" in p.stdout and "  min_views = 1" in p.stdout
    assert "  planner = 'mi-class-pairwise-stable'" in p.stdout and "  planner = 'mi-class-pairwise'" in p.stdout
    p = run_cli("recipes", "fast")
    assert p.returncode == 2
    _one_error(p, "unknown recipe 'fast'")


def test_train_records_the_resolved_recipe_and_inspect_shows_it(photo_db, robust_model):
    meta = load_model_meta(robust_model)
    assert meta["format_version"] == FORMAT_VERSION == 4
    r = recipe_from_meta(meta)
    # 'auto' resolved against the database: it has a calib split and no jitter rows
    assert (r.name, r.likelihood, r.interpolate, r.calibrate, r.view_jitter) == ("robust", "view-mixture-lowrank", 2, True, False)
    assert meta["calibrated"] and meta["training"]["interpolate"]["points_per_side"] == 2
    assert r.calib_pool is True and meta["calibration"]["settings"]["pool"] is True
    assert load_model(robust_model).cameras[0].likelihood.mu.shape[3] == 5   # 1 training view + 2 x 2 blends
    # stability 'auto': fitted on the calib split, the number recorded in the recipe and the model
    fit = meta["training"]["stability_fit"]
    assert r.stability == fit["weight"] == load_model(robust_model).stability and fit["weight"] in (0.0, 1.0)
    assert fit["n"] == 2 * 4 * 9 and 0 <= fit["n_unexplained"] <= fit["n"]
    p = run_cli("inspect", robust_model)
    assert "recipe: robust (version 6): likelihood = 'view-mixture-lowrank'" in p.stdout
    assert ("interpolated views: 2 per side of each training position, towards its neighbouring views "
            "(camera 0 18 of 18 sides have one)") in p.stdout and "a side without a neighbour" not in p.stdout
    # the thesis recipe: today's defaults; a flag overrides one part and the file records it
    out = photo_db / "thesis.npz"
    p = run_cli("train", photo_db / "db", "--out", out, *FAST, "--recipe", "thesis", "--min-views", "3")
    assert p.returncode == 0, p.stderr
    r = recipe_from_meta(load_model_meta(out))
    assert r == THESIS.replace(min_views=3)
    assert not load_model_meta(out)["calibrated"] and load_model_meta(out)["training"]["likelihood"] == "diag"
    # the planner part: recorded, and what a dataset campaign compares with random by default
    from jaxrecog.campaigns import dataset_planners

    assert dataset_planners(robust_model) == ("mi-class-pairwise-stable", "random")
    assert dataset_planners(out) == ("mi-class-pairwise", "random")
    out2 = photo_db / "thesis-random.npz"
    p = run_cli("train", photo_db / "db", "--out", out2, *FAST, "--recipe", "thesis", "--planner", "random")
    assert p.returncode == 0 and dataset_planners(out2) == ("random",)


def test_train_stability_option_and_a_database_without_calib_split(photo_db, tmp_path, capsys):
    out = tmp_path / "w.npz"
    p = run_cli("train", photo_db / "db", "--out", out, *FAST, "--stability", "0.5")
    assert p.returncode == 0, p.stderr
    assert recipe_from_meta(load_model_meta(out)).stability == 0.5 == load_model(out).stability
    assert "stability_fit" not in load_model_meta(out)["training"]
    for bad in ("-1", "often", "inf"):
        p = run_cli("train", photo_db / "db", "--out", tmp_path / "x.npz", *FAST, "--stability", bad)
        assert p.returncode == 2 and "--stability: expected a" in p.stderr and not (tmp_path / "x.npz").exists()
    # 'auto' without a calib split: not fitted, the planner's default 1, said in one line
    from types import SimpleNamespace

    from jaxrecog.cli.train import _resolve_stability

    params = {}
    recipe, model = _resolve_stability(ROBUST, load_model(out), SimpleNamespace(split=np.array(["train", "test"])), params)
    assert recipe.stability == 1.0 == model.stability and params == {}
    out = capsys.readouterr().out
    assert "has no 'calib' split, so the planner's stability term keeps its default weight 1" in out
    assert "add held-out 'calib' captures and retrain" in out  # what to do about it


def test_calib_pool_option_is_recorded_and_contradicting_no_calibrate_is_one_line(photo_db, tmp_path):
    out = tmp_path / "own.npz"
    p = run_cli("train", photo_db / "db", "--out", out, *FAST, "--no-calib-pool")
    assert p.returncode == 0, p.stderr
    meta = load_model_meta(out)
    assert recipe_from_meta(meta).calib_pool is False and meta["calibration"]["settings"]["pool"] is False
    p = run_cli("train", photo_db / "db", "--out", tmp_path / "x.npz", *FAST, "--calib-pool", "--no-calibrate")
    assert p.returncode == 2 and not (tmp_path / "x.npz").exists()
    _one_error(p, "--calib-pool pools calibration factors, and recipe robust is not calibrated here")


def test_old_model_files_load_as_thesis(photo_db, robust_model, tmp_path):
    """A version-3 file (before recipes): loads unchanged, reports recipe thesis."""
    old = tmp_path / "old.npz"
    with np.load(robust_model) as d:
        arrays = dict(d)
    meta = json.loads(bytes(arrays["meta"]).decode())
    del meta["recipe"]
    meta["format_version"] = 3
    arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    arrays["format_version"] = np.array(3, np.int64)
    np.savez(old, **arrays)
    assert load_model(old).n_objects == 2
    assert recipe_from_meta(load_model_meta(old)) is THESIS
    p = run_cli("inspect", old)
    assert "recipe: thesis (version 1), a file written before recipes" in p.stdout


@pytest.mark.parametrize("argv, needle", [
    (("--likelihood", "student-t"), "--likelihood student-t contradicts recipe robust's interpolate = 2"),
    (("--recipe", "thesis", "--interpolate", "2"), "--interpolate 2 needs a mixture likelihood"),
    (("--recipe", "thesis", "--likelihood", "view-mixture"), "--likelihood view-mixture needs mixture components"),
    (("--view-jitter",), "--view-jitter (recipe robust) needs a 'jitter' split"),
    (("--likelihood", "view-mixture", "--rank", "2"), "--rank applies to gaussian-lowrank, view-mixture-lowrank"),
])
def test_train_contradictions_are_one_line_and_write_nothing(photo_db, tmp_path, argv, needle):
    out = tmp_path / "m.npz"
    p = run_cli("train", photo_db / "db", "--out", out, *FAST, *argv)
    assert p.returncode == 2
    _one_error(p, needle)
    assert not out.exists()


def test_unknown_recipe_is_a_usage_error(photo_db, tmp_path):
    p = run_cli("train", photo_db / "db", "--out", tmp_path / "m.npz", "--recipe", "fast")
    assert p.returncode == 2 and "invalid choice: 'fast' (choose from 'robust', 'thesis')" in p.stderr


def test_recognize_and_experiment_take_the_stop_rule_from_the_model(photo_db, robust_model, tmp_path):
    db = photo_db / "db"
    p = run_cli("recognize", robust_model, "--rig", f"dataset:{db}", "--object", "1", "--pose", "2", "--samples", "16")
    assert p.returncode == 0, p.stderr
    assert "recipe robust: at least 2 explained views from new positions (adaptive scale up to 32)" in p.stdout
    assert "planner mi-class-pairwise-stable" in p.stdout       # the recipe's planner
    steps = [l for l in p.stdout.splitlines() if l.strip()[:1].isdigit()]
    assert len(steps) >= 2                      # robust never stops on one view
    p = run_cli("recognize", robust_model, "--rig", f"dataset:{db}", "--object", "1", "--pose", "2", "--samples", "16",
                "--min-views", "1", "--no-exclude-visited", "--adaptive-scale", "1")
    assert p.returncode == 0 and "recipe robust" not in p.stdout
    out = tmp_path / "exp"
    p = run_cli("experiment", "--rig", f"dataset:{db}", "--model", robust_model, "--trials", "2", "--out", out,
                "--planners", "random")
    assert p.returncode == 0, p.stderr
    s = json.loads((out / "case_dataset.json").read_text())
    assert (s["settings"]["min_views"], s["settings"]["exclude_visited_positions"], s["settings"]["adaptive_scale"]) \
        == (2, True, 32.0)
    assert s["tables"]["random"][-1]["views"] >= 2.0
    p = run_cli("experiment", "--rig", f"dataset:{db}", "--model", robust_model, "--trials", "2", "--out", out,
                "--planners", "random", "--min-views", "1", "--threshold", "0.9")
    s = json.loads((out / "case_dataset.json").read_text())["settings"]
    assert (s["min_views"], s["exclude_visited_positions"], s["p_threshold"]) == (1, True, 0.9)


def test_plan_weighs_the_images_as_recognize_does(photo_db, robust_model, tmp_path):
    """``plan --images`` holds the belief the recognizer of ``recognize`` holds
    after those images: the model's recipe's adaptive scale, or --adaptive-scale."""
    import cv2
    import jax.random as jr

    from jaxrecog.recognizer_factory import make_recognizer

    db = photo_db / "db"
    rows = [r.split(",") for r in (db / "manifest.csv").read_text().splitlines()[1:]]
    path, position = next((r[0], int(r[2])) for r in rows if r[5] == "test" and r[3] == "1")
    img = cv2.imread(str(db / path), cv2.IMREAD_GRAYSCALE).astype(np.float32)
    odd = np.clip(0.6 * img + 90.0, 0, 255).astype(np.uint8)  # washed out: no class explains it at scale 1
    cv2.imwrite(str(tmp_path / "odd.png"), odd)
    model = load_model(robust_model)
    recipe = recipe_from_meta(load_model_meta(robust_model))
    assert recipe.adaptive_scale > 1
    got = {}
    for flags, scale in (((), recipe.adaptive_scale), (("--adaptive-scale", "1"), 1.0)):
        p = run_cli("plan", robust_model, "--planner", "random", "--images", tmp_path / "odd.png",
                    "--at", str(position), "--json", *flags)
        assert p.returncode == 0, p.stderr
        doc = json.loads(p.stdout)
        assert doc["adaptive_scale"] == scale
        rec = make_recognizer(model, "random", recipe=recipe.replace(adaptive_scale=scale))
        _, dec = rec.step(rec.init(config=(position,)), np.asarray(odd, np.float32)[None], jr.PRNGKey(0))
        assert (doc["images"]["object"], doc["images"]["pose"]) == (int(dec.object), int(dec.pose))
        np.testing.assert_allclose(doc["images"]["probability"], float(dec.probability), rtol=1e-5)
        got[scale] = doc["images"]["probability"]
    assert got[recipe.adaptive_scale] < got[1.0]  # weakened evidence: a less certain belief


def test_recipe_part_occluder_gray(photo_db, tmp_path):
    assert ROBUST.occluder_gray == (0.0, 255.0) and THESIS.occluder_gray == (0.0, 0.0)
    assert "occluder_gray = [0.0, 255.0]" in ROBUST.describe()
    v4 = {k: v for k, v in ROBUST.to_dict().items() if k not in ("occluder_gray", "stability")} | {"version": 4}
    assert recipe_from_meta({"recipe": v4}).occluder_gray == (0.0, 0.0)       # as it ran: black
    assert recipe_from_meta({"recipe": json.loads(json.dumps(ROBUST.to_dict()))}) == ROBUST
    for bad in ((10.0, 5.0), (0.0, 300.0), (-1.0, 0.0)):
        with pytest.raises(ValueError, match="occluder_gray must be two gray levels"):
            ROBUST.replace(occluder_gray=bad)
    # the flag overrides the part and the file records it; DB2 trains with it
    out = tmp_path / "g.npz"
    p = run_cli("train", photo_db / "db", "--out", out, "--kind", "DB2", "--samples", "4", "--components", "3",
                "--recipe", "thesis", "--occluder-gray", "40,60")
    assert p.returncode == 0, p.stderr
    meta = load_model_meta(out)
    assert recipe_from_meta(meta).occluder_gray == (40.0, 60.0)
    assert tuple(meta["training"]["augment"]["occluder_gray"]) == (40.0, 60.0)


def test_a_recipe_newer_than_this_code_is_one_line_not_dropped_parts():
    """A model whose recipe is a later version than this code knows, or has a
    part it does not know, is refused naming the known versions (before, the
    part was dropped and the model ran as another recipe)."""
    v7 = ROBUST.to_dict() | {"version": 7, "colour_boost": 2.0}
    with pytest.raises(ValueError, match=r"recipe robust version 7 is newer than this jaxrecog knows "
                                         r"\(known recipe versions: robust 1-6, thesis 1\)"):
        recipe_from_meta({"recipe": v7})
    with pytest.raises(ValueError, match="recipe robust version 6 has part.s. this jaxrecog does not know: "
                                         "colour_boost .known recipe versions: robust 1-6, thesis 1"):
        recipe_from_meta({"recipe": ROBUST.to_dict() | {"colour_boost": 2.0}})
    with pytest.raises(ValueError, match="recipe thesis version 2 is newer"):
        recipe_from_meta({"recipe": THESIS.to_dict() | {"version": 2}})
    with pytest.raises(ValueError, match="version 'seven' is not an integer"):
        recipe_from_meta({"recipe": THESIS.to_dict() | {"version": "seven"}})
    assert recipe_from_meta({"recipe": ROBUST.to_dict() | {"version": 3}}).version == 3   # older: as it ran


def test_a_two_image_database_says_what_to_train_instead(tmp_path):
    """The default recipe's low-rank covariance needs K >= 2; two training
    images per position give K = 1: one line naming what works, before any
    sampling, with or without --components 1 (the rank used to fail inside the
    fit as 'rank must be in 1..K-1 = 1..0, got None')."""
    from builders import write_synthetic_database

    from clirun import one_error_line

    db = write_synthetic_database(tmp_path / "db", positions=(1,), n_objects=2, n_poses=1, image_shape=(30, 40))
    for extra in ((), ("--components", "1")):
        p = run_cli("train", db, "--out", tmp_path / "m.npz", "--samples", "4", *extra)
        assert p.returncode == 1
        one_error_line(p, "K >= 2", "K = 1", "--recipe thesis", "--likelihood view-mixture")
        assert "1..0" not in p.stderr and not (tmp_path / "m.npz").exists()
    # what it names works
    assert run_cli("train", db, "--out", tmp_path / "m.npz", "--samples", "4", "--recipe", "thesis", "--kind", "DB1").returncode == 0


def test_inspect_says_what_missing_view_neighbours_mean():
    """Sides without a neighbouring view: said in words with what to do, not as bare lists."""
    from jaxrecog.cli._common import interpolation_lines

    lines = interpolation_lines({"points_per_side": 2, "neighbours": [[(-1, 1), (0, 2), (1, 3), (2, -1)], [(-1, -1)]]})
    assert lines[0].endswith("(camera 0 6 of 8, camera 1 0 of 2 sides have one)")
    assert "no views between the positions" in lines[1] and "add positions in between" in lines[1]
    assert len(interpolation_lines({"points_per_side": 1, "neighbours": [[(1, 1), (0, 0)]]})) == 1
