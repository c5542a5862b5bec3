"""The Student-t and low-rank likelihoods end to end on a tiny database:
training (through ``train_model`` and ``jaxrecog train --likelihood``), the
model file (version 3, the version-2 files before it, the one-line errors on
bad parameter fields), calibration of the Student-t's nu, and the MI / CRLB
planners on the recognizer step."""

from __future__ import annotations

import json
import warnings

import jax
import jax.numpy as jnp
import jax.random as jr
import numpy as np
import pytest
from builders import odd_images, steps_stay_finite
from scipy.stats import multivariate_t

from jaxrecog import cli
from jaxrecog import kernels as K
from jaxrecog.calibration import CalibrationFeatures, CameraFeatures, calibrate_model
from jaxrecog.database import write_database
from jaxrecog.kernels.student_t import NU_GRID
from jaxrecog.modelfile import FORMAT_VERSION, ModelFileContentError, _content_hash, load_model, load_model_meta, save_model
from jaxrecog.planners import make_planner
from jaxrecog.recognizer import Recognizer
from jaxrecog.train import train_model

_NEW = {"student-t": {}, "gaussian-lowrank": {"rank": 2}}


@pytest.fixture(scope="module")
def models(small_db):
    return {name: train_model(small_db, kind="DB1", n_components=3, samples_per_image=10, likelihood=name,
                              likelihood_options=opts, return_info=True)
            for name, opts in _NEW.items()}


def test_training_fits_each_family(models, small_db):
    t, _ = models["student-t"]
    lik = t.cameras[0].likelihood
    assert isinstance(lik, K.StudentT) and lik.nu.shape == (2, 1)
    assert set(np.asarray(lik.nu).ravel().tolist()) <= set(NU_GRID)          # chosen on held-out samples
    low, info = models["gaussian-lowrank"]
    assert isinstance(low.cameras[1].likelihood, K.LowRankGaussian) and low.cameras[1].likelihood.W.shape == (2, 4, 1, 3, 2)
    assert info.params["likelihood"] == "gaussian-lowrank" and info.params["likelihood_options"] == {"rank": 2}
    # the same means as the thesis's model: only the dispersion differs
    diag = train_model(small_db, kind="DB1", n_components=3, samples_per_image=10)
    np.testing.assert_array_equal(low.cameras[0].likelihood.mu, diag.cameras[0].mu)
    with pytest.raises(ValueError, match="has no option 'rank' .*it takes: nu"):
        train_model(small_db, likelihood="student-t", likelihood_options={"rank": 2})


def test_model_file_round_trip(tmp_path, models):
    for name, (m, info) in models.items():
        p = save_model(tmp_path / f"{name}.npz", m, training=info.params)
        back = load_model(p)
        meta = load_model_meta(p)
        assert meta["format_version"] == FORMAT_VERSION == 4
        assert meta["likelihoods"] == [name, name] and meta["training"]["likelihood_options"] == _NEW[name]
        assert back.likelihood_kinds == (name, name)
        a, b = jax.tree.leaves(m), jax.tree.leaves(back)
        assert len(a) == len(b) and all(np.asarray(x).tobytes() == np.asarray(y).tobytes() for x, y in zip(a, b))


def _rewritten(src, dst, change):
    with np.load(src) as z:
        d = {k: z[k] for k in z.files}
    meta = json.loads(bytes(d["meta"]).decode())
    change(d, meta)
    meta["content_sha256"] = _content_hash({k: v for k, v in d.items() if "." in k})
    d["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    np.savez(dst, **d)
    return dst


def test_version_2_files_load_as_they_are(tmp_path, small_db):
    """A file as the version-2 writer left it: same layout, version 2, no
    ``likelihood_options`` in its training metadata; no warning, no error."""
    model, info = train_model(small_db, kind="DB1", n_components=3, samples_per_image=6, covariance="full",
                              return_info=True)
    new = save_model(tmp_path / "new.npz", model, training=info.params)

    def as_v2(d, meta):
        d["format_version"] = np.array(2, np.int64)
        meta["format_version"] = 2
        del meta["training"]["likelihood_options"]
    old = _rewritten(new, tmp_path / "old.npz", as_v2)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        back = load_model(old)
    assert load_model_meta(old)["format_version"] == 2 and back.likelihood_kinds == ("full", "full")
    for a, b in zip(jax.tree.leaves(model), jax.tree.leaves(back)):
        assert np.asarray(a).tobytes() == np.asarray(b).tobytes()


def _set(field, index, value):
    def change(d, meta):
        d[field] = d[field].copy()
        d[field][index] = value
    return change


@pytest.mark.parametrize("name, change, message", [
    ("student-t", _set("camera0.nu", (1, 0), 0.0), "camera0.nu has non-positive degrees of freedom"),
    ("student-t", _set("camera0.nu", (0, 0), -3.0), "camera0.nu has non-positive degrees of freedom"),
    ("student-t", _set("camera1.nu", (1, 0), 1.5), r"camera1.nu has degrees of freedom <= 2"),
    ("student-t", _set("camera0.nu", (0, 0), np.nan), "camera0.nu contains NaN"),
    ("student-t", _set("camera1.scale2", (0, 1, 0, 2), -1.0), "camera1.scale2 has non-positive scales"),
    ("gaussian-lowrank", _set("camera0.psi", (1, 0, 0, 0), 0.0), "camera0.psi has non-positive variances"),
    ("gaussian-lowrank", _set("camera1.W", (0, 0, 0, 0, 1), np.inf), "camera1.W contains NaN or infinite"),
    ("gaussian-lowrank", lambda d, m: d.update({"camera0.W": np.concatenate([d["camera0.W"]] * 2, axis=-1)}),
     "camera0.W has rank 4, larger than K = 3"),
    ("gaussian-lowrank", lambda d, m: d.pop("camera1.psi"), "missing array camera1.psi"),
])
def test_bad_parameter_fields_are_one_line_errors(tmp_path, models, name, change, message):
    good = save_model(tmp_path / "good.npz", models[name][0])
    with pytest.raises(ModelFileContentError, match=message) as e:
        load_model(_rewritten(good, tmp_path / "bad.npz", change))
    assert "\n" not in str(e.value) and str(tmp_path / "bad.npz") in str(e.value)


def test_cli_train_likelihood_option(tmp_path, small_db, capsys):
    db = write_database(tmp_path / "db", small_db)
    base = ["--quiet", "train", str(db), "--kind", "DB1", "--components", "3", "--samples", "6",
            "--recipe", "thesis"]  # the thesis recipe's single-Gaussian families
    cases = [(["--likelihood", "student-t", "--nu", "auto"], "student-t", {"nu": "auto"}),
             (["--likelihood", "student-t", "--nu", "6"], "student-t", {"nu": 6.0}),
             (["--likelihood", "gaussian-lowrank", "--rank", "1"], "gaussian-lowrank", {"rank": 1}),
             (["--covariance", "full"], "full", {}),
             (["--covariance", "full", "--likelihood", "gaussian-full"], "full", {}),
             ([], "diag", {})]
    for i, (extra, kind, options) in enumerate(cases):
        out = tmp_path / f"m{i}.npz"
        assert cli.main(base + ["--out", str(out)] + extra) == 0, extra
        assert load_model(out).likelihood_kinds == (kind, kind)
        assert load_model_meta(out)["training"]["likelihood_options"] == options
    np.testing.assert_array_equal(load_model(tmp_path / "m1.npz").cameras[0].likelihood.nu, 6.0)  # nu as given
    capsys.readouterr()
    for extra, needle in [(["--covariance", "diag", "--likelihood", "student-t"], "contradicts"),
                          (["--likelihood", "student-t", "--rank", "2"], "--rank applies to gaussian-lowrank"),
                          (["--nu", "5"], "--nu applies to student-t"),
                          (["--likelihood", "student-t", "--nu", "1.5"], "expected 'auto' or a number > 2"),
                          (["--likelihood", "nope"], "invalid choice")]:
        assert cli.main(base + ["--out", str(tmp_path / "x.npz")] + extra) == 2, extra
        assert needle in capsys.readouterr().err
    # a rank the eigenspace cannot hold: a runtime error (exit 1), one line, no model written
    assert cli.main(base + ["--out", str(tmp_path / "x.npz"), "--likelihood", "gaussian-lowrank", "--rank", "3"]) == 1
    err = [l for l in capsys.readouterr().err.splitlines() if "error" in l]
    assert len(err) == 1 and "rank must be in 1..K-1" in err[0]
    assert not (tmp_path / "x.npz").exists()


def test_calibration_fits_nu_on_heavy_tailed_views(models, rng):
    """Held-out views whose deviations are t_3 (a few far off): calibration
    moves the Student-t's nu down and lowers the held-out NLL; the report
    carries the offsets, and the calibrated model saves and loads."""
    model, _ = models["student-t"]
    feats = []
    for cam in model.cameras:
        lik = cam.likelihood
        V, C, L, k = lik.mu.shape
        pos, cls = np.repeat(np.arange(V), C * 60), np.tile(np.repeat(np.arange(C), 60), V)
        sd = np.sqrt(np.asarray(jax.vmap(lambda x: x.variance())(lik), np.float64))
        z = multivariate_t(np.zeros(k), np.eye(k) / 3.0, df=3.0).rvs(pos.size, random_state=rng)
        feats.append(CameraFeatures(np.asarray(lik.mu, np.float64)[pos, cls, 0] + 2.0 * sd[pos, cls, 0] * z, pos, cls))
    cal, info = calibrate_model(model, CalibrationFeatures(tuple(feats)))
    for i, cam in enumerate(cal.cameras):
        assert info.shape_names[i] == ("nu",) and info.shape[i].shape == (2, 1, 1)
        before, after = np.asarray(model.cameras[i].likelihood.nu), np.asarray(cam.likelihood.nu)
        assert np.all(after < before) and np.all(after > 2.0)
        assert np.all(info.nll_after[i] < info.nll_before[i])
    assert "nu offsets" in info.summary()
    # the Gaussians' calibration is unchanged: no shape parameters
    low, _ = models["gaussian-lowrank"]
    _, linfo = calibrate_model(low, CalibrationFeatures(tuple(feats)))
    assert linfo.shape[0].shape == (2, 1, 0) and linfo.shape_names[0] == ()


@pytest.mark.parametrize("name", list(_NEW))
@pytest.mark.parametrize("planner", ["mi", "crlb"])
def test_planners_run_with_the_new_likelihoods(models, small_db, name, planner):
    """The recognizer step (MI / CRLB planners read the likelihood through
    ``sample`` / ``log_density`` in ``mi_tables``) on the database's test
    views and on a blank-ish image far from every class: finite scores and a
    finite belief, never NaN."""
    model, _ = models[name]
    key = jr.PRNGKey(0)
    rec = Recognizer(model, make_planner(planner, model, key=key, samples=32), max_steps=5)
    state = rec.init(config=(1, 0))
    rows = [np.flatnonzero((small_db.split == "test") & (small_db.camera == i) & (small_db.position == v)
                           & (small_db.object == 1) & (small_db.pose == 0))[0] for i, v in enumerate((1, 0))]
    views = small_db.images[rows]
    for t, images in enumerate((views, odd_images(views))):
        state, dec = steps_stay_finite(rec, state, [images], jr.fold_in(key, t))
        assert 0.0 <= float(dec.probability) <= 1.0
