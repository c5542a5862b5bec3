"""``campaigns.Settings`` selects the likelihood and the capture
augmentation that ``prepare`` trains (the defaults keep the old model file
names, cache keys and run ids), the shared CLI options reach them, and
``train_model(view_jitter=True)`` uses a database's ``jitter`` rows."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from builders import make_database, write_synthetic_database

from jaxrecog import ImageDatabase, cli, load_database, write_database
from jaxrecog import campaigns as ex
from jaxrecog.kernels import DiagonalGaussian, LowRankGaussian, StudentT
from jaxrecog.modelfile import load_model, load_model_meta
from jaxrecog.train import train_model

ROOT = Path(__file__).resolve().parent.parent


class _Stop(Exception):
    pass


# -- Settings: names and keys ------------------------------------------------

def test_default_settings_keep_model_names_cache_keys_and_run_ids(tmp_path):
    s = ex.Settings(workdir=tmp_path)
    assert ex.model_path(s, "DB2") == tmp_path / "model-db2-K20-S100-seed0.npz"
    assert ex.model_path(ex.Settings(workdir=tmp_path, stride=8), "DB1").name == "model-db1-stride8-K20-S100-seed0.npz"
    assert ex.naming.training_params(s, "DB2") == {"kind": "DB2", "K": 20, "samples_per_image": 100, "seed": 0}
    # pinned against the formula before the likelihood / augmentation fields existed
    model = tmp_path / "m.npz"
    model.write_bytes(b"model")
    assert ex.naming.run_id(s, model) == "233947c420"
    assert ex.naming.run_id(ex.Settings(workdir="/x", stride=8, motion_cost=0.5), model) == "46afd2476c"
    # min_views (added later): 1 keeps the digest, another value gets its own trials
    assert ex.naming.run_id(ex.Settings(workdir=tmp_path, min_views=1), model) == "233947c420"
    assert ex.naming.run_id(ex.Settings(workdir=tmp_path, min_views=2), model) != "233947c420"
    with pytest.raises(ValueError, match="min_views"):
        ex.Settings(workdir=tmp_path, min_views=8)
    # the default family under another of its names is the default
    for same in (ex.Settings(workdir=tmp_path, likelihood="diag"), ex.Settings(workdir=tmp_path, likelihood_options={})):
        assert same == s and ex.model_path(same, "DB2") == ex.model_path(s, "DB2")
        assert ex.naming.run_id(same, model) == "233947c420"


def test_non_default_likelihood_or_augmentation_gets_its_own_names(tmp_path):
    model = tmp_path / "m.npz"
    model.write_bytes(b"model")
    base = ex.Settings(workdir=tmp_path)
    variants = [
        ex.Settings(workdir=tmp_path, likelihood="student-t"),
        ex.Settings(workdir=tmp_path, likelihood="student-t", likelihood_options={"nu": 5.0}),
        ex.Settings(workdir=tmp_path, likelihood="gaussian-lowrank"),
        ex.Settings(workdir=tmp_path, likelihood="gaussian-lowrank", likelihood_options=(("rank", 2),)),
        ex.Settings(workdir=tmp_path, max_rotation=3.0),
        ex.Settings(workdir=tmp_path, blur_sigma=1.0),
        ex.Settings(workdir=tmp_path, likelihood="student-t", max_scale=0.03, gain_amplitude=0.05),
        ex.Settings(workdir=tmp_path, occluder_gray=(0, 255)),
    ]
    names = {ex.model_path(s, "DB2") for s in [base, *variants]}
    assert len(names) == len(variants) + 1
    assert ex.model_path(variants[0], "DB2").name.startswith("model-db2-K20-S100-seed0-student-t-")
    assert len({ex.naming.run_id(s, model) for s in [base, *variants]}) == len(variants) + 1
    keys = [ex.naming.training_params(s, "DB2") for s in variants]
    assert all(k != ex.naming.training_params(base, "DB2") for k in keys)
    assert keys[1]["likelihood"] == "student-t" and keys[1]["likelihood_options"] == {"nu": 5.0}
    assert keys[5]["augment"]["blur_sigma"] == [0.0, 1.0]
    # a field added later counts only when set: model files from before it match as they did
    assert "occluder_gray" not in keys[5]["augment"] and keys[7]["augment"]["occluder_gray"] == [0.0, 255.0]
    # hashable, options normalised to sorted pairs
    assert hash(variants[1]) == hash(ex.Settings(workdir=tmp_path, likelihood="student-t",
                                                 likelihood_options=(("nu", 5.0),)))
    with pytest.raises(ValueError, match="no option 'rank'"):
        ex.Settings(likelihood="student-t", likelihood_options={"rank": 2})
    with pytest.raises(ValueError, match="likelihood"):
        ex.Settings(likelihood="cauchy")
    with pytest.raises(ValueError, match="max_scale"):
        ex.Settings(max_scale=1.5)


def _small_workdir(tmp_path) -> ex.Settings:
    """A work folder whose stride-8 database is a tiny builders database (so
    ``prepare`` trains without rendering the rig)."""
    write_synthetic_database(tmp_path / "database-stride8", positions=(2, 1), n_objects=2, n_poses=2,
                             image_shape=(24, 32))
    return ex.Settings(workdir=tmp_path, stride=8, n_components=3, samples_per_image=10)


def test_prepare_trains_the_selected_family_and_caches_it(tmp_path, monkeypatch):
    import dataclasses

    import jaxrecog.campaigns.preparation as train_mod  # where prepare calls train_model

    base = _small_workdir(tmp_path)
    seen = []
    real = train_mod.train_model

    def spy(*a, **kw):
        seen.append(kw)
        return real(*a, **kw)

    monkeypatch.setattr(train_mod, "train_model", spy)
    t = dataclasses.replace(base, likelihood="student-t", likelihood_options={"nu": 6.0})
    p = ex.prepare(t, databases=("DB1",))
    assert p.models["DB1"] == ex.model_path(t, "DB1") and "student-t" in p.models["DB1"].name
    lik = load_model(p.models["DB1"]).cameras[0].likelihood
    assert isinstance(lik, StudentT)
    np.testing.assert_allclose(np.asarray(lik.nu), 6.0)
    assert seen[-1]["likelihood"] == "student-t" and seen[-1]["likelihood_options"] == {"nu": 6.0}
    # cached: the same settings train nothing
    ex.prepare(t, databases=("DB1",))
    assert len(seen) == 1
    # the default family next to it, under the old name
    d = ex.prepare(base, databases=("DB1",))
    assert d.models["DB1"].name == "model-db1-stride8-K3-S10-seed0.npz"
    assert isinstance(load_model(d.models["DB1"]).cameras[0].likelihood, DiagonalGaussian)
    # low rank and the capture augmentation reach train_model and the file's params
    a = dataclasses.replace(base, likelihood="gaussian-lowrank", likelihood_options={"rank": 2},
                            max_rotation=3.0, blur_sigma=(0.0, 1.0))
    q = ex.prepare(a, databases=("DB1",))
    assert isinstance(load_model(q.models["DB1"]).cameras[0].likelihood, LowRankGaussian)
    assert seen[-1]["augment"].max_rotation == 3.0 and seen[-1]["augment"].blur_sigma == (0.0, 1.0)
    params = load_model_meta(q.models["DB1"])["training"]["params"]
    assert params["augment"]["max_rotation"] == 3.0 and params["likelihood_options"] == {"rank": 2}
    n = len(seen)
    ex.prepare(a, databases=("DB1",))  # the nested augment params match the cache key
    assert len(seen) == n


# -- view jitter -------------------------------------------------------------

def _with_jitter(db: ImageDatabase, jitter: list[tuple[int, int, int, int, np.ndarray]]) -> ImageDatabase:
    extra = np.stack([j[4] for j in jitter])
    cols = [np.concatenate([getattr(db, f), [j[k] for j in jitter]])
            for k, f in enumerate(("camera", "position", "object", "pose"))]
    return ImageDatabase.from_arrays(np.concatenate([db.images, extra]), *cols,
                                     np.concatenate([db.split, ["jitter"] * len(jitter)]))


def _train_image(db, camera, position, obj, pose):
    (row,) = np.flatnonzero((db.split == "train") & (db.camera == camera) & (db.position == position)
                            & (db.object == obj) & (db.pose == pose))
    return db.images[row]


def test_view_jitter_adds_the_jitter_images_samples(tmp_path):
    db = make_database(positions=(2,), n_objects=4, n_poses=1, image_shape=(24, 32))
    kw = dict(kind="DB1", n_components=3, samples_per_image=20)
    plain, info0 = train_model(db, return_info=True, **kw)
    assert "view_jitter" not in info0.params
    img = _train_image(db, 0, 0, 1, 0)
    # a jitter image identical to its training image: the same samples twice, the same moments
    same, _ = train_model(_with_jitter(db, [(0, 0, 1, 0, img)]), view_jitter=True, return_info=True, **kw)
    a, b = plain.cameras[0].likelihood, same.cameras[0].likelihood
    np.testing.assert_allclose(np.asarray(b.mu), np.asarray(a.mu), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(np.asarray(b.var), np.asarray(a.var), rtol=1e-4, atol=1e-7)
    # a view seen from a little off the grid (shifted beyond the augmentation's 3 px): class 1 at
    # position 0 moves, every other (position, class) keeps the training image's samples exactly
    moved = np.roll(img, (0, 6), axis=(0, 1))
    jdb = _with_jitter(db, [(0, 0, 1, 0, moved), (0, 0, 1, 0, np.roll(img, (5, 0), axis=(0, 1)))])
    jit, info = train_model(jdb, view_jitter=True, return_info=True, **kw)
    a, b = plain.cameras[0].likelihood, jit.cameras[0].likelihood
    mu_a, mu_b, var_a, var_b = (np.asarray(x) for x in (a.mu, b.mu, a.var, b.var))
    assert not np.allclose(mu_b[0, 1], mu_a[0, 1], atol=1e-3)
    assert not np.allclose(var_b[0, 1], var_a[0, 1], rtol=0.05)
    keep = np.ones(mu_a.shape[:2], bool)
    keep[0, 1] = False
    np.testing.assert_array_equal(mu_b[keep], mu_a[keep])
    np.testing.assert_array_equal(var_b[keep], var_a[keep])
    assert info.params["view_jitter"] == {"mode": "added", "images": 2, "views": 1, "positions": 1}
    # without the flag the jitter rows are ignored
    off = train_model(jdb, **kw)
    np.testing.assert_array_equal(np.asarray(off.cameras[0].likelihood.mu), mu_a)
    # a family with held-out samples (student-t, nu auto) trains with jitter too
    t = train_model(jdb, view_jitter=True, likelihood="student-t", **kw)
    assert isinstance(t.cameras[0].likelihood, StudentT)
    # the split survives a folder round trip
    write_database(tmp_path / "jdb", jdb)
    back = load_database(tmp_path / "jdb")
    assert int((back.split == "jitter").sum()) == 2


def test_view_jitter_without_jitter_rows_is_an_error():
    db = make_database(positions=(2,), n_objects=4, n_poses=1, image_shape=(24, 32))
    with pytest.raises(ValueError, match="no 'jitter' rows"):
        train_model(db, kind="DB1", n_components=3, samples_per_image=10, view_jitter=True)


# -- CLI ---------------------------------------------------------------------

def test_train_cli_flags_reach_train_model(tmp_path, monkeypatch, capsys):
    import jaxrecog.cli.train as cli_train

    db = make_database(positions=(2,), n_objects=4, n_poses=1, image_shape=(24, 32))
    folder = tmp_path / "db"
    write_database(folder, _with_jitter(db, [(0, 1, 2, 0, np.roll(_train_image(db, 0, 1, 2, 0), 5, axis=1))]))
    seen = {}
    real = cli_train.train_model

    def spy(*a, **kw):
        seen.update(kw)
        return real(*a, **kw)

    monkeypatch.setattr(cli_train, "train_model", spy)
    out = tmp_path / "m.npz"
    argv = ["--quiet", "train", str(folder), "--out", str(out), "--recipe", "thesis", "--kind", "DB1", "--components",
            "3", "--samples", "10", "--likelihood", "student-t", "--nu", "5", "--view-jitter", "--rotation", "3", "--scale", "0.03",
            "--blur", "1", "--gain", "0.05"]
    assert cli.main(argv) == 0
    assert seen["likelihood"] == "student-t" and seen["likelihood_options"] == {"nu": 5.0}
    assert seen["view_jitter"] is True
    aug = seen["augment"]
    assert (aug.max_rotation, aug.max_scale, aug.blur_sigma, aug.gain_amplitude) == (3.0, 0.03, (0.0, 1.0), 0.05)
    capsys.readouterr()
    assert cli.main(["inspect", str(out)]) == 0
    assert "view jitter: 1 jitter image(s) of 1 view(s), added" in capsys.readouterr().out
    # --view-jitter on a database without jitter rows: one clear usage error before training, exit 2
    plain = tmp_path / "plain"
    write_database(plain, db)
    capsys.readouterr()
    assert cli.main(["--quiet", "train", str(plain), "--out", str(tmp_path / "p.npz"), "--kind", "DB1",
                     "--components", "3", "--samples", "10", "--view-jitter"]) == 2
    assert "--view-jitter (recipe robust) needs a 'jitter' split" in capsys.readouterr().err
    assert not (tmp_path / "p.npz").exists()
    assert cli.main(["train", str(plain), "--out", str(tmp_path / "x.npz"), "--likelihood", "view-mixture", "--rank", "2"]) == 2  # --rank is the low-rank families'


def test_experiment_cli_flags_reach_settings(tmp_path, monkeypatch, capsys):
    seen = {}

    def run_case(name, settings, planners=None, **kw):
        seen["settings"] = settings
        raise _Stop

    monkeypatch.setattr(ex, "run_case", run_case)
    argv = ["--quiet", "experiment", "i", "--out", str(tmp_path), "--likelihood", "gaussian-lowrank", "--rank", "2",
            "--rotation", "3", "--blur", "0.5,1", "--gain", "0.05", "--gain-cells", "4", "--occluder-gray", "20,200"]
    assert cli.main(argv) == 1  # the stub stops the campaign
    s = seen["settings"]
    assert s.occluder_gray == (20.0, 200.0)
    assert (s.likelihood, s.likelihood_options) == ("gaussian-lowrank", (("rank", 2),))
    assert (s.max_rotation, s.max_scale, s.blur_sigma, s.gain_amplitude, s.gain_cells) == (3.0, 0.0, (0.5, 1.0),
                                                                                           0.05, 4)
    # an experiment file's likelihood and options, --nu over them
    toml = tmp_path / "e.toml"
    toml.write_text('case = "iii"\n[settings]\nlikelihood = "student-t"\nlikelihood_options = {nu = 4.0}\n'
                    'blur_sigma = [0.0, 2.0]\n')
    assert cli.main(["--quiet", "experiment", str(toml), "--out", str(tmp_path)]) == 1
    assert seen["settings"].likelihood_options == (("nu", 4.0),) and seen["settings"].blur_sigma == (0.0, 2.0)
    assert cli.main(["--quiet", "experiment", str(toml), "--out", str(tmp_path), "--nu", "auto"]) == 1
    assert seen["settings"].likelihood_options == (("nu", "auto"),)
    # defaults: the thesis's training
    assert cli.main(["--quiet", "experiment", "i", "--out", str(tmp_path)]) == 1
    assert seen["settings"] == ex.Settings(workdir=tmp_path / "work")
    capsys.readouterr()
    # an option of another family, or training flags with a given model: usage errors
    assert cli.main(["experiment", "i", "--out", str(tmp_path), "--nu", "5"]) == 2
    assert cli.main(["experiment", "--rig", f"dataset:{tmp_path}", "--model", "m.npz", "--out", str(tmp_path),
                     "--rotation", "2"]) == 2


def test_reproduce_thesis_flags_reach_settings(monkeypatch):
    spec = importlib.util.spec_from_file_location("reproduce_thesis", ROOT / "scripts" / "reproduce_thesis.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    seen = {}

    def prepare(settings, **kw):
        seen["settings"] = settings
        raise _Stop

    monkeypatch.setattr(mod, "prepare", prepare)
    with pytest.raises(_Stop):
        mod.main(["--case", "iii", "--likelihood", "student-t", "--nu", "auto", "--rotation", "3", "--scale",
                  "0.03", "--blur", "1", "--gain", "0.05", "--workdir", "w"])
    s = seen["settings"]
    assert (s.likelihood, s.likelihood_options, s.max_rotation, s.max_scale, s.blur_sigma, s.gain_amplitude) == (
        "student-t", (("nu", "auto"),), 3.0, 0.03, (0.0, 1.0), 0.05)
    with pytest.raises(_Stop):
        mod.main(["--case", "i", "--workdir", "w"])
    # the defaults but where the captures render (not part of any cache key or run id)
    assert seen["settings"] == ex.Settings(workdir="w", render_workers=mod.DEFAULT_RENDER_WORKERS)
    with pytest.raises(_Stop):
        mod.main(["--case", "i", "--workdir", "w", "--render-workers", "0", "--max-shift", "2"])
    assert seen["settings"] == ex.Settings(workdir="w", max_shift=2)
    assert ex.model_path(seen["settings"], "DB2") != ex.model_path(ex.Settings(workdir="w"), "DB2")
    with pytest.raises(SystemExit):
        mod.main(["--case", "i", "--likelihood", "student-t", "--rank", "2"])


def test_interpolation_is_its_own_cache_key_and_linear_keeps_the_old_one(tmp_path):
    """Settings.interpolation: a flow-interpolated model has its own training
    key; a linear one keeps the key it had before the field existed; a bad
    value is one line naming it."""
    import pytest

    from jaxrecog import campaigns as ex

    base = dict(workdir=tmp_path, likelihood="view-mixture", interpolate=2)
    linear = ex.naming.training_params(ex.Settings(**base), "DB1")
    flow = ex.naming.training_params(ex.Settings(**base, interpolation="flow"), "DB1")
    assert linear["interpolate"] == {"points_per_side": 2}
    assert flow["interpolate"] == {"points_per_side": 2, "interpolation": "flow"}
    # a model file records both parts: the linear key matches a linear file, the flow key only a flow file
    lin_file = {**linear, "interpolate": {"points_per_side": 2, "interpolation": "linear"}}
    assert ex.naming.params_match(lin_file, linear) and not ex.naming.params_match(lin_file, flow)
    with pytest.raises(ValueError, match="interpolation must be 'linear' or 'flow', got 'cubic'"):
        ex.Settings(**base, interpolation="cubic")
