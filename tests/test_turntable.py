"""The turntable set of many objects: random_urdfs objects,
the off-grid test / calib / jitter views, ``render --turntable`` and the
campaign helpers."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from jaxrecog import load_database
from jaxrecog.hardware.render.random_objects import (
    N_RANDOM,
    RESTING_ROTATIONS,
    parse_objects,
    random_objects,
    rested,
)
from jaxrecog.hardware.render.scene import Intrinsics, default_objects, object_radius
from jaxrecog.hardware.render.turntable import render_turntable, turntable_angles, turntable_rig

pytest.importorskip("pybullet")

SMALL = Intrinsics(height=30, width=40)


@pytest.fixture(scope="module")
def three():
    return random_objects(3)


def test_random_objects_are_deterministic_gray_meshes_of_the_thesis_radius(three):
    again = random_objects(3)
    assert again == three
    assert random_objects(5)[:3] == three  # a larger n extends the selection
    assert random_objects(3, seed=1) != three
    assert len({o.name for o in random_objects(200)}) == 200  # no folder twice
    radius = object_radius(default_objects())
    for obj in three:
        (part,) = obj.parts
        assert part.shape == "mesh" and part.mesh.startswith("random_urdfs/") and part.mesh.endswith(".obj")
        assert part.rgba == three[0].parts[0].rgba  # one gray for all: shape is the only cue
        posed = [rested(obj, r) for r in RESTING_ROTATIONS]
        reach = object_radius(posed)
        assert reach <= radius + 1e-9 and reach >= 0.999 * radius  # fills the thesis radius, in every pose


@pytest.mark.parametrize("n", [0, -1, N_RANDOM + 1])
def test_random_objects_rejects_counts_outside_the_folders(n):
    with pytest.raises(ValueError, match="1..1000"):
        random_objects(n)


@pytest.mark.parametrize("text, message", [("random:0", "1..1000"), ("random:abc", "integer"),
                                           ("random:1001", "1..1000"), ("abc", "random:N"), ("0", "positive")])
def test_parse_objects_errors(text, message):
    with pytest.raises(ValueError, match=message):
        parse_objects(text)


def test_parse_objects():
    assert parse_objects("random:50") == ("random", 50)
    assert parse_objects("8") == ("thesis", 8)


def test_every_object_in_every_pose_renders_in_frame(three):
    rig = turntable_rig(three, [[0.0, 120.0, 240.0]], poses=4, intrinsics=SMALL)
    try:
        assert rig.n_objects == 12 and rig.n_poses == 1
        images = {}
        for m in range(3):
            for p in range(4):
                rig.reset(m * 4 + p, 0)
                for v in range(3):
                    img, mask = rig.render_clean(0, v)
                    assert mask.sum() > 20, (m, p, v)
                    # in frame: the object touches no image border
                    assert not (mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any())
                    images[m, p, v] = img
        assert not np.array_equal(images[0, 0, 0], images[0, 1, 0])  # poses are different resting orientations
        assert not np.array_equal(images[0, 0, 0], images[1, 0, 0])
    finally:
        rig.close()


def test_off_grid_views_are_labelled_with_the_nearest_training_view():
    step, n = 20.0, 18
    f = turntable_angles(n, step, test_per_view=2, calib_per_view=2, jitter_per_view=4)
    grid = np.arange(n) * step

    def ring(a, b):
        return abs((a - b + 180.0) % 360.0 - 180.0)

    for v in range(n):
        assert f["train"](v, 0) == grid[v]
        for j in range(2):
            a = f["test"](v, j)
            assert ring(a, grid[v]) == pytest.approx(10.0)  # halfway: off the grid
            assert min(ring(a, g) for g in grid) == pytest.approx(ring(a, grid[v]))  # v is a nearest view
            assert a > grid[v]  # always +10: the lower of the two nearest views is the label
            c = f["calib"](v, j)
            assert ring(c, grid[v]) == pytest.approx(5.0)
            assert sorted(ring(c, g) for g in grid)[1] > 5.0  # v is the one nearest view
        offs = sorted(f["jitter"](v, j) - grid[v] for j in range(4))
        assert offs == pytest.approx([-5.0, -2.5, 2.5, 5.0])
    assert {f["calib"](v, 0) - grid[v] for v in range(n)} == {5.0, -5.0}
    with pytest.raises(ValueError, match="off the grid"):
        turntable_angles(n, step, jitter_per_view=1, jitter_offset=20.0)
    on_grid = turntable_angles(n, step, test_per_view=1, test_offset=0.0)  # the control: test on the grid
    assert on_grid["test"](3, 0) == on_grid["train"](3, 0)


def test_render_turntable_writes_every_split(tmp_path, three):
    manifest = render_turntable(tmp_path / "db", three[:2], cameras=2, step_deg=120, poses=2, test_per_view=1,
                                calib_per_view=1, jitter_per_view=2, occluders=True, intrinsics=SMALL)
    db = load_database(manifest.parent)
    assert tuple(db.positions) == (3, 3) and (db.n_objects, db.n_poses) == (2, 2)
    split = np.asarray(db.split)
    n_views = 2 * 3 * 2 * 2
    assert {s: int((split == s).sum()) for s in ("train", "test", "calib", "jitter")} == \
        {"train": n_views, "test": n_views, "calib": n_views, "jitter": 2 * n_views}
    key = list(zip(db.camera, db.position, db.object, db.pose))
    train = {k: db.images[i] for i, k in enumerate(key) if split[i] == "train"}
    for i, k in enumerate(key):
        if split[i] != "train":
            assert not np.array_equal(db.images[i], train[k]), (split[i], k)  # off the grid: another image


def _cli(capsys, *args):
    from jaxrecog.cli import main

    try:
        rc = main([str(a) for a in args])
    except SystemExit as e:  # argparse errors
        rc = e.code
    out = capsys.readouterr()
    return rc, out.out, out.err


def test_render_turntable_cli(tmp_path, capsys):
    rc, out, err = _cli(capsys, "render", "--out", tmp_path / "db", "--objects", "random:3", "--turntable",
                        "--step", 120, "--poses", 1, "--jitter-per-view", 2, "-q")
    assert rc == 0, err
    assert "images/s" in out
    db = load_database(tmp_path / "db")
    split = np.asarray(db.split)
    assert tuple(db.positions) == (3,) and (db.n_objects, db.n_poses) == (3, 1)
    assert {s: int((split == s).sum()) for s in ("train", "test", "calib", "jitter")} == \
        {"train": 9, "test": 18, "calib": 9, "jitter": 18}
    layout = json.loads((tmp_path / "db" / "rig.json").read_text())
    assert layout["turntable"] and layout["positions"] == [3] and layout["objects"] == "random:3"
    assert layout["names"] == [o.name for o in random_objects(3)]
    assert layout["offsets_deg"]["test"] == 60


@pytest.mark.parametrize("objects, message", [("random:0", "1..1000"), ("random:abc", "integer"),
                                              ("random:1001", "1..1000"), ("3", "--turntable needs")])
def test_render_turntable_cli_rejects_bad_objects(tmp_path, capsys, objects, message):
    rc, out, err = _cli(capsys, "render", "--out", tmp_path / "db", "--objects", objects, "--turntable", "-q")
    assert rc == 2 and message in err, err
    assert not (tmp_path / "db").exists()


def test_render_turntable_cli_rejects_bad_steps(tmp_path, capsys):
    rc, _, err = _cli(capsys, "render", "--out", tmp_path / "db", "--objects", "random:2", "--turntable",
                      "--step", 7, "-q")
    assert rc == 2 and "divide 360" in err
    rc, _, err = _cli(capsys, "render", "--out", tmp_path / "db", "--objects", "random:2", "--turntable",
                      "--poses", 5, "-q")
    assert rc == 2 and "at most 4" in err


@pytest.mark.slow
def test_turntable_campaign_end_to_end(tmp_path):
    """prepare_turntable renders, trains and calibrates once (cached); run_turntable replays the test split."""
    from jaxrecog.campaigns import Settings, prepare_turntable, run_turntable
    from jaxrecog.modelfile import load_model

    s = Settings(workdir=tmp_path, trials_per_object=2, samples=64, n_components=2, samples_per_image=8, batch=4)
    prep = prepare_turntable(s, 3, 1, False, poses=1, step_deg=120)
    model = load_model(prep.models["turntable"])
    assert model.cameras[0].calibration is not None and tuple(model.positions) == (3,)
    assert model.stability == 1.0           # the thesis recipe's number (nothing fitted)
    mtime = prep.models["turntable"].stat().st_mtime_ns
    report = run_turntable(s, 3, 1, False, planners=["random"], poses=1, step_deg=120)
    assert prep.models["turntable"].stat().st_mtime_ns == mtime  # cached
    assert len(report.results["random"]) == 6
    assert math.isfinite(report.rows["random"][-1].rate)


def test_turntable_takes_the_settings_likelihood_and_view_jitter(tmp_path):
    """Settings.likelihood and Settings.view_jitter reach the turntable's
    training: the jitter split is rendered into its own folder and used, the
    family is the one asked for; jitter as far off as the test views is refused."""
    from jaxrecog import kernels as K
    from jaxrecog.campaigns import Settings, prepare_turntable
    from jaxrecog.modelfile import load_model, load_model_meta

    s = Settings(workdir=tmp_path, n_components=2, samples_per_image=6, likelihood="student-t",
                 likelihood_options={"nu": 5.0}, view_jitter=2, view_jitter_deg=20.0)
    prep = prepare_turntable(s, 3, 1, False, poses=1, step_deg=120)
    assert prep.database.name.endswith("-vj2x20")
    assert isinstance(load_model(prep.models["turntable"]).cameras[0].likelihood, K.StudentT)
    assert load_model_meta(prep.models["turntable"])["training"]["params"]["view_jitter"]["images"] == 2 * 3 * 3
    with pytest.raises(ValueError, match="view_jitter_deg"):
        prepare_turntable(Settings(workdir=tmp_path, view_jitter=2, view_jitter_deg=60.0), 3, 1, False, poses=1,
                          step_deg=120)


def test_turntable_with_the_robust_recipe_fits_the_planner_weight_on_its_calib_split(tmp_path):
    """recipe robust (stability = auto): the calibrated turntable model carries the
    weight fitted on the set's calib split, and the fit is recorded."""
    from jaxrecog.campaigns import Settings, prepare_turntable
    from jaxrecog.modelfile import load_model, load_model_meta
    from jaxrecog.recipes import ROBUST

    s = Settings(recipe=ROBUST, workdir=tmp_path, n_components=2, samples_per_image=6)
    prep = prepare_turntable(s, 3, 1, False, poses=1, step_deg=120)
    meta = load_model_meta(prep.models["turntable"])
    fit = meta["training"]["stability_fit"]
    assert load_model(prep.models["turntable"]).stability == fit["weight"] in (0.0, 1.0)
    assert fit["n"] == 3 * 3 and meta["training"]["params"]["stability"] == "auto"
    assert meta["recipe"]["name"] == "robust" and meta["recipe"]["stability"] == fit["weight"]   # the file says so
    # a numeric weight is the model's, and never reuses the file fitted under 'auto'
    s0 = Settings(recipe=ROBUST.replace(stability=0.25), workdir=tmp_path, n_components=2, samples_per_image=6)
    prep0 = prepare_turntable(s0, 3, 1, False, poses=1, step_deg=120)
    assert load_model(prep0.models["turntable"]).stability == 0.25
    assert "stability_fit" not in load_model_meta(prep0.models["turntable"])["training"]
