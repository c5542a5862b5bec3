"""Adding objects to a trained model: ``train --add NEW_DB --to MODEL``
fits only the new classes, in the model's eigenspaces, by the model's recipe;
the old classes stay bit for bit; bad input is one line and writes nothing."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from builders import make_database
from clirun import run_cli
from jaxrecog import ImageDatabase, write_database
from jaxrecog.calibration import apply_calibration
from jaxrecog.eigenspace import Eigenspace
from jaxrecog.modelfile import load_model, load_model_meta
from jaxrecog.photo_turntable import PhotoSet, build_photo_database, scan_photos
from jaxrecog.train import AddObjectsError, add_objects, train_image_fingerprints, train_model

FAST = ("--kind", "DB1", "--samples", "10", "--components", "2")
SMALL = dict(positions=(2, 2), n_poses=2, image_shape=(16, 20))


def objects(db: ImageDatabase, keep) -> ImageDatabase:
    """The rows of ``db`` of the objects ``keep``, renumbered 0.. in that order."""
    keep = list(keep)
    rows = np.flatnonzero(np.isin(db.object, keep))
    new = np.searchsorted(keep, db.object[rows]) if keep == sorted(keep) else \
        np.array([keep.index(o) for o in db.object[rows]])
    return ImageDatabase.from_arrays(db.images[rows], db.camera[rows], db.position[rows], new, db.pose[rows],
                                     db.split[rows])


@pytest.fixture(scope="module")
def three():
    """Three synthetic objects (2 cameras x 2 positions, 2 poses, 16 x 20 images, 2 test views each)."""
    return make_database(n_objects=3, n_test=2, **SMALL)


def _arrays(lik):
    return {f: np.asarray(getattr(lik, f)) for f in type(lik).field_shapes}


def test_add_equals_training_at_once_in_the_model_eigenspace(three, monkeypatch):
    """Same classes as training all three objects at once; the old classes bit
    for bit the old model's; the new ones what training at once fits in the
    model's eigenspaces (the same shared draws: only the eigenspaces' float32
    rounding and the summation order differ)."""
    kw = dict(kind="DB1", n_components=2, samples_per_image=10)
    old, info = train_model(objects(three, [0, 1]), **kw, return_info=True)
    added, ainfo = add_objects(old, objects(three, [2]), info.params, return_info=True)
    at_once = train_model(three, **kw)
    assert (added.n_objects, added.n_poses, added.positions, added.levels) == \
        (at_once.n_objects, at_once.n_poses, at_once.positions, at_once.levels)
    C_old = old.n_classes
    for a, b, c in zip(old.cameras, added.cameras, at_once.cameras):
        for f in ("mean_image", "basis", "eigenvalues"):
            assert np.asarray(getattr(a, f)).tobytes() == np.asarray(getattr(b, f)).tobytes()
        x, y, z = _arrays(a.likelihood), _arrays(b.likelihood), _arrays(c.likelihood)
        for f in x:
            assert y[f].shape == z[f].shape
            assert y[f][:, :C_old].tobytes() == x[f].tobytes(), f     # the old classes bit for bit
    assert ainfo.params["n_objects"] == 3 and ainfo.params["added"][0]["objects"] == [2, 2]
    assert ainfo.params["train_image_sha256"] == train_image_fingerprints(three)

    # training at once, every position's eigenspace replaced by the model's: the new classes agree
    spaces = iter([Eigenspace(*(np.asarray(x[v], np.float64) for x in (c.mean_image, c.basis, c.eigenvalues)))
                   for c in old.cameras for v in range(c.n_positions)])
    monkeypatch.setattr("jaxrecog.train.position_eigenspace", lambda images: next(spaces))
    same_space = train_model(three, **kw)
    for b, s in zip(added.cameras, same_space.cameras):
        y, z = _arrays(b.likelihood), _arrays(s.likelihood)
        for f in y:
            np.testing.assert_allclose(y[f][:, C_old:], z[f][:, C_old:], rtol=1e-4, atol=1e-7, err_msg=f)



def test_library_errors_name_the_mismatch(three):
    old, info = train_model(objects(three, [0, 1]), kind="DB1", n_components=2, samples_per_image=10,
                            return_info=True)
    with pytest.raises(AddObjectsError, match="object 0 of database <in memory> is already in the model: its train "
                                              "image .* identical to a training image of the model's object 1"):
        add_objects(old, objects(three, [1, 2]), info.params)
    with pytest.raises(AddObjectsError, match="records no training parameter 'kind'"):
        add_objects(old, objects(three, [2]), {})


# ---------------------------------------------------------------- the command


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """A 2-object synthetic database, its thesis-recipe model, and one new object."""
    root = tmp_path_factory.mktemp("add")
    db = make_database(n_objects=3, **SMALL)
    write_database(root / "old", objects(db, [0, 1]))
    write_database(root / "new", objects(db, [2]))
    p = run_cli("train", root / "old", "--out", root / "old.npz", *FAST, "--recipe", "thesis")
    assert p.returncode == 0, p.stderr
    return root


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_cli_add_writes_the_bigger_model(base, tmp_path):
    p = run_cli("train", "--add", base / "new", "--to", base / "old.npz", "--out", tmp_path / "m.npz")
    assert p.returncode == 0, p.stderr
    assert "added 1 object(s) of" in p.stdout and "as objects 2..2 to" in p.stdout
    old, new = load_model(base / "old.npz"), load_model(tmp_path / "m.npz")
    assert (new.n_objects, new.n_classes) == (3, 6)
    for a, b in zip(old.cameras, new.cameras):
        for f, x in _arrays(a.likelihood).items():
            assert _arrays(b.likelihood)[f][:, :old.n_classes].tobytes() == x.tobytes()
    meta, old_meta = load_model_meta(tmp_path / "m.npz"), load_model_meta(base / "old.npz")
    assert meta["recipe"] == old_meta["recipe"] and meta["manifest_sha256"] == old_meta["manifest_sha256"]
    assert meta["training"]["added"][0]["objects"] == [2, 2] and len(meta["training"]["train_image_sha256"]) == 3


@pytest.mark.parametrize("kind,kw,needle", [
    ("image size", dict(image_shape=(20, 16)), "images 20x16 vs the model's 16x20"),
    ("positions", dict(positions=(3, 2)), "positions (3, 2) per camera vs the model's (2, 2)"),
    ("cameras", dict(positions=(2,)), "has 1 camera(s), the model 2"),
    ("poses", dict(n_poses=3), "3 poses vs the model's 2"),
    ("already in", None, "is already in the model: its train image"),
])
def test_cli_bad_new_database_is_one_line_and_the_model_unchanged(base, tmp_path, kind, kw, needle):
    """A NEW_DB the model cannot take: one line, exit 1, and the model file
    (here also --out: replacing the model in place) is untouched."""
    if kw is None:   # the model's own objects again
        new = base / "old"
    else:
        new = tmp_path / "new"
        write_database(new, make_database(**{**SMALL, "n_objects": 1, **kw}))
    model = tmp_path / "m.npz"
    model.write_bytes((base / "old.npz").read_bytes())
    before = _digest(model)
    p = run_cli("train", "--add", new, "--to", model, "--out", model)
    assert p.returncode == 1, (kind, p.stdout, p.stderr)
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("jaxrecog: error: ") and needle in lines[0], (kind, lines)
    assert _digest(model) == before and sorted(x.name for x in tmp_path.iterdir() if x.is_file()) == ["m.npz"]


@pytest.mark.parametrize("argv,needle", [
    (("--to", "M"), "--add NEW_DB and --to MODEL go together"),
    (("--add", "NEW"), "--add NEW_DB and --to MODEL go together"),
    (("DB", "--add", "NEW", "--to", "M"), "DATABASE DB and --add NEW: give one"),
    (("--add", "NEW", "--to", "M", "--kind", "DB1"), "--kind does not apply with --add"),
    (("--add", "NEW", "--to", "M", "--samples", "5"), "--samples does not apply with --add"),
    ((), "give the image database to train on (DATABASE), or --add NEW_DB --to MODEL"),
])
def test_cli_add_usage_errors(tmp_path, argv, needle):
    p = run_cli("train", *argv, "--out", tmp_path / "o.npz")
    assert p.returncode == 2, p.stderr
    err = [x for x in p.stderr.splitlines() if "error:" in x]
    assert len(err) == 1 and needle in err[0], p.stderr
    assert not (tmp_path / "o.npz").exists()


# ---------------------------------------------------------------- real photos, recipe robust


def test_a_calibrated_model_scales_the_new_classes_by_its_factors(three):
    """The new classes of a calibrated model get its variance factors (the
    result is calibrated as the model was); the old ones and the factors stay."""
    old, info = train_model(objects(three, [0, 1]), kind="DB1", n_components=2, samples_per_image=10,
                            return_info=True)
    factors = [np.array([[1.5], [2.0]], np.float32), np.array([[3.0], [1.25]], np.float32)]
    cal = apply_calibration(old, factors)
    plain = add_objects(old, objects(three, [2]), info.params)
    added = add_objects(cal, objects(three, [2]), info.params)
    want = apply_calibration(plain, factors)
    for a, b, w in zip(cal.cameras, added.cameras, want.cameras):
        assert np.asarray(b.calibration).tobytes() == np.asarray(a.calibration).tobytes()
        for f, x in _arrays(b.likelihood).items():
            assert x[:, :old.n_classes].tobytes() == _arrays(a.likelihood)[f].tobytes(), f
            np.testing.assert_allclose(x, _arrays(w.likelihood)[f], rtol=1e-6, err_msg=f)


@pytest.mark.slow
def test_cli_add_to_a_robust_model_on_real_photos_recalibrates(tmp_path):
    """Real photos, the default recipe (flow-interpolated view mixture): the
    add fits the new object's mixtures toward the neighbours the model
    recorded; --calibrate fits factors on its calib views, and the old classes
    become the old model's times those factors, bit for bit."""
    ps = scan_photos()
    build_photo_database(tmp_path / "old", 40, photos=PhotoSet(ps.folder, ps.files[:2], ps.step))
    build_photo_database(tmp_path / "new", 40, photos=PhotoSet(ps.folder, ps.files[2:3], ps.step))
    fast = ("--kind", "DB1", "--samples", "10", "--components", "4")
    p = run_cli("train", tmp_path / "old", "--out", tmp_path / "old.npz", *fast, "--no-calibrate")
    assert p.returncode == 0, p.stderr
    p = run_cli("train", "--add", tmp_path / "new", "--to", tmp_path / "old.npz", "--out", tmp_path / "add.npz",
                "--calibrate")
    assert p.returncode == 0, p.stderr
    assert "as objects 2..2" in p.stdout and "recalibrated, recipe robust" in p.stdout
    old, add = load_model(tmp_path / "old.npz"), load_model(tmp_path / "add.npz")
    meta = load_model_meta(tmp_path / "add.npz")
    assert meta["training"]["interpolate"] == load_model_meta(tmp_path / "old.npz")["training"]["interpolate"]
    assert sum(sum(n) for n in meta["calibration"]["n_images"]) == 9 * 4     # the new object's calib views
    factors = [np.asarray(f, np.float32) for f in meta["calibration"]["factors"]]
    for a, b in zip(apply_calibration(old, factors).cameras, add.cameras):
        np.testing.assert_array_equal(np.asarray(b.calibration), np.asarray(a.calibration))
        for f, x in _arrays(a.likelihood).items():
            y = _arrays(b.likelihood)[f]
            assert np.all(np.isfinite(y)) and y.shape[:2] == (9, 3 * 4)
            assert y[:, :old.n_classes].tobytes() == x.tobytes(), f
    p = run_cli("train", "--add", tmp_path / "new", "--to", tmp_path / "old.npz", "--out", tmp_path / "nc.npz")
    assert p.returncode == 0 and "not recalibrated" in p.stdout, p.stderr    # the model was not calibrated


def test_cli_add_calibrate_needs_a_calib_split(base, tmp_path):
    p = run_cli("train", "--add", base / "new", "--to", base / "old.npz", "--out", tmp_path / "m.npz", "--calibrate")
    assert p.returncode == 2, p.stderr
    err = [x for x in p.stderr.splitlines() if "error:" in x]
    assert len(err) == 1 and "--calibrate needs a 'calib' split" in err[0], p.stderr
    assert not (tmp_path / "m.npz").exists()
