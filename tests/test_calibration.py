"""Calibration: recovery of a known over-confidence, bounded L-BFGS, the prior's
shrinkage, applying factors, the model file (v2 round trip, v1 with a warning),
and the campaign metrics against hand-computed values."""

from __future__ import annotations

import json
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.stats import multivariate_normal

from jaxrecog.calibration import (
    CalibrationError, CalibrationFeatures, CameraFeatures, apply_calibration, calibrate_model,
    calibration_factors, fit_factors, holdout_calibration, mahalanobis_terms, pooled_log_factors, uncalibrated,
)
from jaxrecog.metrics import (
    campaign_metrics, confident_errors, expected_calibration_error, reliability_bins,
)
from jaxrecog.modelfile import (
    ModelFileVersionWarning, load_model, load_model_meta, save_model,
)
from jaxrecog.results import TrialResult
from jaxrecog.kernels import gaussian
from jaxrecog.sensor_model import CameraModel, SensorModel

pytestmark = pytest.mark.usefixtures("strict_dtype_promotion")  # numerics: no implicit promotion

MAX_ITER = 100


def _model(rng, V=3, n_objects=4, n_poses=2, L=1, K=5, full=False, sep=2.0):
    C = n_objects * n_poses
    D = 12
    mu = rng.normal(size=(V, C, L, K)) * sep
    if full:
        A = rng.normal(size=(V, C, L, K, K)) * 0.4
        cov = A @ np.swapaxes(A, -1, -2) + np.eye(K)
        chol = np.linalg.cholesky(cov)
        var = np.diagonal(cov, axis1=-2, axis2=-1).copy()
    else:
        var = np.exp(rng.uniform(-0.5, 0.5, size=(V, C, L, K)))
        chol = None
    f32 = lambda x: None if x is None else jnp.asarray(x, jnp.float32)
    cam = CameraModel(f32(np.zeros((V, D))), f32(np.zeros((V, D, K))), f32(np.ones((V, K))),
                      gaussian(f32(mu), f32(var), f32(chol)))
    levels = tuple(0.05 * k for k in range(L))
    return SensorModel((cam,), n_objects, n_poses, levels, (3, 4), "full" if full else "diag")


def _draw(rng, model, factors, n, level_of=None):
    """``n`` samples per (position, class) from N(mu, factor * Σ) of the model,
    level 0 (or ``level_of(c)``); ``factors[v, k]``."""
    cam = model.cameras[0]
    mu, var = np.asarray(cam.mu, np.float64), np.asarray(cam.var, np.float64)
    V, C, L, K = mu.shape
    pos = np.repeat(np.arange(V), C * n)
    cls = np.tile(np.repeat(np.arange(C), n), V)
    lev = np.zeros_like(cls) if level_of is None else rng.integers(0, L, size=cls.size)
    z = rng.normal(size=(cls.size, K)) * np.sqrt(factors[pos, lev])[:, None]
    if cam.chol is None:
        g = mu[pos, cls, lev] + z * np.sqrt(var[pos, cls, lev])
    else:
        g = mu[pos, cls, lev] + np.einsum("nij,nj->ni", np.asarray(cam.chol, np.float64)[pos, cls, lev], z)
    return CalibrationFeatures((CameraFeatures(g, pos, cls),))


def test_recovers_fourfold_overconfidence_per_position(rng):
    model = _model(rng)
    true = np.array([[4.0], [4.0], [2.0]])
    feats = _draw(rng, model, true, n=150)
    cal, info = calibrate_model(model, feats, max_iter=MAX_ITER)
    s = info.factors[0]
    assert s.shape == (3, 1)
    np.testing.assert_allclose(s, true, rtol=0.10)
    assert np.all(info.converged[0])
    assert np.all(info.iterations[0] <= 25)        # bounded, far below the cap
    assert np.all(info.nll_after[0] < info.nll_before[0])
    np.testing.assert_array_equal(np.asarray(cal.cameras[0].calibration), s)


def test_recovers_fourfold_with_full_covariance(rng):
    model = _model(rng, V=2, full=True, sep=2.5)
    feats = _draw(rng, model, np.full((2, 1), 4.0), n=150)
    cal, info = calibrate_model(model, feats)
    np.testing.assert_allclose(info.factors[0], 4.0, rtol=0.10)
    assert np.all(info.converged[0])
    np.testing.assert_allclose(np.asarray(cal.cameras[0].chol),
                               np.asarray(model.cameras[0].chol) * np.sqrt(info.factors[0])[:, None, :, None, None],
                               rtol=1e-6)


def test_per_level_factors(rng):
    model = _model(rng, V=1, L=2, sep=2.5)
    true = np.array([[4.0, 1.5]])
    feats = _draw(rng, model, true, n=400, level_of=True)
    _, info = calibrate_model(model, feats, per_level=True)
    np.testing.assert_allclose(info.factors[0], true, rtol=0.15)
    _, shared = calibrate_model(model, feats, per_level=False)
    assert shared.factors[0][0, 0] == shared.factors[0][0, 1]


def test_factors_below_one_only_when_unbounded(rng):
    model = _model(rng, V=2, sep=0.8)
    feats = _draw(rng, model, np.full((2, 1), 0.5), n=300)
    _, free = calibrate_model(model, feats, min_factor=None)
    np.testing.assert_allclose(free.factors[0], 0.5, rtol=0.10)
    _, bounded = calibrate_model(model, feats)                      # default: inflation only
    np.testing.assert_array_equal(bounded.factors[0], 1.0)
    assert np.all(bounded.nll_after[0] == bounded.nll_before[0])


def test_mahalanobis_terms_match_scipy(rng):
    model = _model(rng, V=1, L=2, K=4, full=True)
    cam = model.cameras[0]
    g = rng.normal(size=(5, 4)) * 2
    for chol in (None, cam.chol[0]):
        q, logdet = mahalanobis_terms(cam.mu[0], cam.var[0], chol, jnp.asarray(g, jnp.float32))
        ll = -0.5 * (np.asarray(q) + np.asarray(logdet)[None])
        mu = np.asarray(cam.mu[0], np.float64)
        for c in range(mu.shape[0]):
            for k in range(2):
                cov = np.diag(np.asarray(cam.var[0, c, k], np.float64)) if chol is None else \
                    (lambda Lc: Lc @ Lc.T)(np.asarray(chol[c, k], np.float64))
                ref = multivariate_normal(mu[c, k], cov).logpdf(g)
                np.testing.assert_allclose(ll[:, c, k], ref, rtol=1e-4, atol=1e-3)


def test_prior_shrinks_few_images_and_empty_positions_stay_one(rng):
    model = _model(rng, V=3)
    full = _draw(rng, model, np.full((3, 1), 4.0), n=100).cameras[0]
    # position 0: all images; position 1: three images; position 2: none
    keep = (full.position == 0) | (np.flatnonzero(full.position == 1)[:3, None] == np.arange(full.position.size)).any(0)
    feats = CameraFeatures(full.g[keep], full.position[keep], full.cls[keep])
    s, it, conv, nll0, nll1, n = fit_factors(model.cameras[0], feats, prior_sd=0.5)
    assert list(n) == [800, 3, 0]
    assert s[2, 0] == 1.0 and nll0[2] == 0.0
    assert 1.0 < s[1, 0] < s[0, 0]          # few images: pulled toward 1
    strong, *_ = fit_factors(model.cameras[0], feats, prior_sd=0.05)
    assert abs(np.log(strong[1, 0])) < abs(np.log(s[1, 0]))


@pytest.mark.slow
def test_vmapped_fit_equals_per_position_fit(rng):
    model = _model(rng, V=3)
    feats = _draw(rng, model, np.array([[3.0], [0.7], [5.0]]), n=40).cameras[0]
    s_all = fit_factors(model.cameras[0], feats, min_factor=None)[0]
    for v in range(3):
        cam = model.cameras[0]
        one = CameraModel(cam.mean_image[v:v + 1], cam.basis[v:v + 1], cam.eigenvalues[v:v + 1],
                          gaussian(cam.mu[v:v + 1], cam.var[v:v + 1]))
        sel = feats.position == v
        s_one = fit_factors(one, CameraFeatures(feats.g[sel], feats.position[sel] * 0, feats.cls[sel]),
                            min_factor=None)[0]
        np.testing.assert_allclose(s_one[0], s_all[v], rtol=1e-4)


def test_optimiser_hits_cap_when_tolerance_unreachable(rng):
    model = _model(rng, V=2)
    feats = _draw(rng, model, np.full((2, 1), 4.0), n=50)
    _, info = calibrate_model(model, feats, max_iter=2, tol=1e-30)
    assert np.all(info.iterations[0] == 2) and not np.any(info.converged[0])


def test_apply_compose_and_undo(rng):
    model = _model(rng, V=2, L=2)
    f1 = np.array([[2.0, 3.0], [1.5, 0.5]], np.float32)
    m1 = apply_calibration(model, [f1])
    np.testing.assert_allclose(np.asarray(m1.cameras[0].var),
                               np.asarray(model.cameras[0].var) * f1[:, None, :, None], rtol=1e-6)
    m2 = apply_calibration(m1, [np.array([2.0, 2.0], np.float32)])   # [V] broadcasts over levels
    np.testing.assert_allclose(calibration_factors(m2)[0], f1 * 2, rtol=1e-6)
    back = uncalibrated(m2)
    assert back.cameras[0].calibration is None
    np.testing.assert_allclose(np.asarray(back.cameras[0].var), np.asarray(model.cameras[0].var), rtol=1e-5)
    np.testing.assert_array_equal(calibration_factors(model)[0], np.ones((2, 2)))
    with pytest.raises(ValueError, match="camera 0: factors must be finite and > 0"):
        apply_calibration(model, [np.zeros((2, 2))])
    with pytest.raises(ValueError, match=r"camera 0: factors of shape \(3, 1\)"):
        apply_calibration(model, [np.ones(3)])


def test_bad_calibration_inputs(rng):
    model = _model(rng, V=2)
    g = np.zeros((4, 5))
    with pytest.raises(CalibrationError, match=r"expected \[N, 5\]"):
        calibrate_model(model, CalibrationFeatures((CameraFeatures(np.zeros((4, 3)), np.zeros(4, int), np.zeros(4, int)),)))
    with pytest.raises(CalibrationError, match="NaN"):
        calibrate_model(model, CalibrationFeatures((CameraFeatures(g * np.nan, np.zeros(4, int), np.zeros(4, int)),)))
    with pytest.raises(CalibrationError, match="positions must be in 0..1"):
        calibrate_model(model, CalibrationFeatures((CameraFeatures(g, np.full(4, 2), np.zeros(4, int)),)))
    with pytest.raises(CalibrationError, match="classes must be in 0..7"):
        calibrate_model(model, CalibrationFeatures((CameraFeatures(g, np.zeros(4, int), np.full(4, 8)),)))
    with pytest.raises(CalibrationError, match="2 camera"):
        calibrate_model(model, CalibrationFeatures((CameraFeatures(g, np.zeros(4, int), np.zeros(4, int)),) * 2))
    with pytest.raises(TypeError, match="dict"):
        calibrate_model(model, {})


# ---------------------------------------------------------------- database + model file


@pytest.fixture(scope="module")
def trained():
    from builders import make_database
    from jaxrecog.train import train_model

    db = make_database(positions=(2, 1), n_objects=2, n_poses=2, image_shape=(16, 20), n_test=3)
    model = train_model(db, kind="DB2", n_components=3, samples_per_image=8)
    return db, model


@pytest.fixture(scope="module")
def calibrated(trained):
    db, model = trained
    held = holdout_calibration(db, 0.5, seed=1)
    cal, info = calibrate_model(model, held, per_level=True)
    return held, cal, info


@pytest.mark.slow
def test_calibrate_from_database(trained, calibrated):
    db, model = trained
    held, cal, info = calibrated
    with pytest.raises(CalibrationError, match="no 'calib' rows"):
        calibrate_model(model, db)
    with pytest.raises(CalibrationError, match="train split cannot be held out"):
        holdout_calibration(db, 0.5, source="train")
    assert len(held.rows("calib")) == round(0.5 * len(db.rows("test")))
    assert len(held.rows("test")) + len(held.rows("calib")) == len(db.rows("test"))
    assert sum(int(n.sum()) for n in info.n_images) == len(held.rows("calib"))
    for i in range(2):
        assert info.factors[i].shape == (model.positions[i], model.n_levels)
        assert np.all(info.nll_after[i] <= info.nll_before[i] + 1e-6)
    json.dumps(info.to_dict())
    assert "calibration: variance factors" in cal.summary()


def test_calibrated_model_file_round_trips_bit_exact(tmp_path, trained, calibrated):
    db, model = trained
    _, cal, info = calibrated
    path = save_model(tmp_path / "cal.npz", cal, calibration=info.to_dict())
    back = load_model(path)
    for a, b in zip(cal.cameras, back.cameras):
        for f in ("mean_image", "basis", "eigenvalues", "mu", "var", "calibration"):
            x, y = np.asarray(getattr(a, f)), np.asarray(getattr(b, f))
            assert x.dtype == y.dtype == np.float32
            assert x.tobytes() == y.tobytes(), f
    meta = load_model_meta(path)
    assert meta["calibrated"] is True and meta["calibration"]["settings"]["prior_sd"] == 1.0
    # an uncalibrated model round-trips with calibration None
    save_model(tmp_path / "plain.npz", model)
    assert all(c.calibration is None for c in load_model(tmp_path / "plain.npz").cameras)


def test_version_1_file_loads_uncalibrated_with_warning(tmp_path, trained):
    _, model = trained
    path = save_model(tmp_path / "new.npz", model)
    with np.load(path) as z:
        d = {k: z[k] for k in z.files}
    meta = json.loads(bytes(d["meta"]).decode())
    meta["format_version"] = 1
    del meta["calibrated"], meta["calibration"]
    d["format_version"] = np.array(1, np.int64)
    d["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    old = tmp_path / "old.npz"
    np.savez(old, **d)
    with pytest.warns(ModelFileVersionWarning, match="format version 1"):
        back = load_model(old)
    assert all(c.calibration is None for c in back.cameras)
    np.testing.assert_array_equal(np.asarray(back.cameras[0].var), np.asarray(model.cameras[0].var))
    # and without pytest.warns the warning is an error (pytest's filterwarnings = error)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ModelFileVersionWarning):
            load_model(old)


# ---------------------------------------------------------------- metrics


def _trial(i, p, correct, stopped=True, steps=1):
    return TrialResult(trial=i, object=0, pose=0, predicted_object=0 if correct else 1,
                       predicted_pose=0, exit_prob=p, steps=steps, stopped=stopped)


def test_ece_and_reliability_hand_computed():
    rs = [_trial(0, 0.99, True), _trial(1, 0.97, False), _trial(2, 0.95, True),
          _trial(3, 0.55, True), _trial(4, 0.45, False), _trial(5, 0.0, False)]
    bins = reliability_bins(rs, n_bins=10)
    # 0.0 -> first bin; 0.45 -> (0.4, 0.5]; 0.55 -> (0.5, 0.6]; 0.95, 0.97, 0.99 -> (0.9, 1]
    assert [(round(b.lo, 1), b.count) for b in bins] == [(0.0, 1), (0.4, 1), (0.5, 1), (0.9, 3)]
    top = bins[-1]
    assert top.confidence == pytest.approx((0.99 + 0.97 + 0.95) / 3)
    assert top.accuracy == pytest.approx(2 / 3)
    ece = (1 * 0.0 + 1 * 0.45 + 1 * 0.45 + 3 * abs(2 / 3 - 0.97)) / 6
    assert expected_calibration_error(rs, 10) == pytest.approx(ece)
    # 0.95 sits on an edge with 20 bins: it belongs to (0.90, 0.95]
    assert [b.count for b in reliability_bins(rs, 20) if b.lo >= 0.9] == [1, 2]


def test_confident_errors_hand_computed():
    rs = [_trial(0, 0.99, True), _trial(1, 0.97, False), _trial(2, 0.95, False),
          _trial(3, 0.96, False, stopped=False, steps=7), _trial(4, 0.60, False, stopped=False, steps=7)]
    ce = confident_errors(rs, 0.95)
    assert (ce.trials, ce.stopped, ce.wrong) == (5, 3, 2)
    assert ce.rate == pytest.approx(2 / 3) and ce.rate_of_all == pytest.approx(2 / 5)
    m = campaign_metrics(rs, 0.95)
    assert m["recognition_rate"] == pytest.approx(20.0)
    assert m["mean_views"] == pytest.approx((1 + 1 + 1 + 7 + 7) / 5)
    assert m["confident_error_rate"] == pytest.approx(200 / 3)
    assert m["confident_error_pct_of_trials"] == pytest.approx(40.0)
    assert confident_errors([_trial(0, 0.5, False, stopped=False)]).rate == 0.0
    with pytest.raises(ValueError, match="trial 7: exit probability nan"):
        expected_calibration_error([_trial(7, float("nan"), True)])
    with pytest.raises(ValueError, match="no trial results"):
        confident_errors([])


def test_reliability_plot_writes_png(tmp_path):
    from jaxrecog.calibration_plots import reliability_plot

    r = np.random.default_rng(0)
    p = r.uniform(0.3, 1.0, 200)
    a = [_trial(i, float(x), bool(r.random() < x ** 3)) for i, x in enumerate(p)]
    b = [_trial(i, float(x), bool(r.random() < x)) for i, x in enumerate(p)]
    path = reliability_plot({"uncalibrated": a, "calibrated": b}, tmp_path / "rel.png")
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000


# ---------------------------------------------------------------- synthetic calib split


def test_synthetic_calib_split_is_perturbed_near_the_training_view(tmp_path):
    pytest.importorskip("pybullet")
    from jaxrecog.database import load_database
    from jaxrecog.hardware import SyntheticRig, render_database
    from jaxrecog.hardware.geometry.positions import CameraTable, default_table
    from jaxrecog.hardware.render.scene import default_objects
    from jaxrecog.hardware.render.synthetic import Noise, Perturb

    t = default_table()
    small = CameraTable(t.workspace, (t.views[0][::16], t.views[1][::4]))      # 2 + 2 positions
    unit = lambda y: y.astype(np.float64).ravel() / np.linalg.norm(y.astype(np.float64))
    with SyntheticRig(small, objects=default_objects()[:2], n_poses=2, seed=3) as rig:
        rig.reset(1, 0)
        clean = rig.render_clean(0, 1)[0]
        other_pose = (rig.reset(1, 1), rig.render_clean(0, 1)[0])[1]
        rig.reset(1, 0)
        quiet = Perturb(noise=Noise())
        a = rig.render_perturbed(0, 1, quiet, np.random.default_rng(7))[0]
        b = rig.render_perturbed(0, 1, quiet, np.random.default_rng(7))[0]
        np.testing.assert_array_equal(a, b)                                    # seeded
        np.testing.assert_array_equal(rig.render_clean(0, 1)[0], clean)        # scene restored
        d_pert = np.linalg.norm(unit(a) - unit(clean))
        assert 0 < d_pert < 0.5 * np.linalg.norm(unit(other_pose) - unit(clean))
        with pytest.raises(ValueError, match="perturbations must be >= 0"):
            Perturb(yaw_deg=-1)
        render_database(tmp_path, rig=rig, calib_per_view=1, seed=2)
    db = load_database(tmp_path)
    assert len(db.rows("train")) == 4 * 4 and len(db.rows("calib")) == 4 * 4
    calib = db.images[db.rows("calib")]
    train = db.images[db.rows("train")]
    assert not any(np.array_equal(c, tr) for c, tr in zip(calib, train))


def test_features_are_each_image_projected_alone_and_bad_images_are_named(trained):
    """``features_from_database`` checks and normalises all the rows of a
    position at once: the same numbers, bit for bit, as projecting each image
    alone (the per-image loop it replaces), and the first bad image named."""
    from jaxrecog.calibration import features_from_database
    from jaxrecog.database import ImageDatabase
    from jaxrecog.features import ImageError

    db, model = trained
    held = holdout_calibration(db, 0.5, seed=1)
    feats = features_from_database(model, held)
    for i, (f, cam) in enumerate(zip(feats.cameras, model.cameras)):
        rows = held.rows("calib")
        rows = rows[held.camera[rows] == i]
        mean, basis = (np.asarray(x, np.float64) for x in (cam.mean_image, cam.basis))
        want = [(y / np.linalg.norm(y) - mean[v]) @ basis[v]
                for y, v in ((held.images[r].astype(np.float64).ravel(), held.position[r]) for r in rows)]
        assert f.g.tobytes() == np.asarray(want).tobytes()
        assert f.cls.tolist() == held.class_index[rows].tolist()
    images = held.images.copy()
    rows = held.rows("calib")
    rows = rows[held.camera[rows] == 0]
    images[rows[1]] = 0          # all black: the first bad row
    images[rows[2]] = 7          # constant
    bad = ImageDatabase.from_arrays(images, held.camera, held.position, held.object, held.pose, held.split,
                                    paths=[f"img{j}.png" for j in range(len(images))])
    with pytest.raises(ImageError, match=f"^img{rows[1]}.png: all-black"):
        features_from_database(model, bad)


@pytest.mark.parametrize("full", [False, True])
def test_scaling_terms_in_chunks_equal_the_vmap_over_positions(rng, full):
    """The calibration terms are made a few features at a time (memory): bit
    for bit the one ``vmap`` over positions, and the terms without a feature
    axis (``log|2πΣ|``) once."""
    from jaxrecog.calibration import _scaling_terms

    lik = _model(rng, V=3, L=2, full=full).cameras[0].likelihood
    g = jnp.asarray(rng.normal(size=(3, 16, 5)) * 2.0, jnp.float32)
    want = jax.vmap(lambda lik_v, g_v: lik_v.scaling_terms(g_v))(lik, g)
    per_feature = 3 * lik.n_classes * 2 * 5
    got = _scaling_terms(lik, g, budget=4 * per_feature)             # chunks of 4 features
    assert jax.tree_util.tree_structure(got) == jax.tree_util.tree_structure(want)
    for a, b in zip(jax.tree_util.tree_leaves(want), jax.tree_util.tree_leaves(got)):
        assert a.shape == b.shape and np.asarray(a).tobytes() == np.asarray(b).tobytes()


def _random_effects_reference(theta, e2):
    """DerSimonian-Laird by the textbook's steps, one group, every position with images."""
    w = [1.0 / x for x in e2]
    fixed = sum(wi * t for wi, t in zip(w, theta)) / sum(w)
    q = sum(wi * (t - fixed) ** 2 for wi, t in zip(w, theta))
    tau2 = max(0.0, (q - (len(theta) - 1)) / (sum(w) - sum(wi * wi for wi in w) / sum(w)))
    ws = [1.0 / (x + tau2) for x in e2]
    mean = sum(wi * t for wi, t in zip(ws, theta)) / sum(ws)
    return [mean + tau2 / (tau2 + x) * (t - mean) for t, x in zip(theta, e2)], mean


def test_pooled_log_factors_against_the_textbook_steps():
    theta = np.array([[0.2], [1.5], [0.4], [2.6]])
    curv = np.array([[40.0], [8.0], [25.0], [2.0]])
    got = pooled_log_factors(theta, curv, np.array([5, 5, 5, 5]))
    want, mean = _random_effects_reference(theta[:, 0], 1.0 / curv[:, 0])
    np.testing.assert_allclose(got[:, 0], want, rtol=1e-12)
    # the spread is real here (tau2 > 0): each keeps part of its own value, the
    # least certain (position 3) the smallest part
    kept = (got[:, 0] - mean) / (theta[:, 0] - mean)
    assert np.all((kept > 0) & (kept < 1)) and np.argmin(kept) == 3
    # no spread beyond the sampling noise: all take the pooled value; a position
    # without images takes it too; fewer than two with images: unchanged
    a = np.asarray
    same = pooled_log_factors(a([[1.0], [1.1], [0.9], [5.0]]), np.ones((4, 1)), a([3, 3, 3, 0]))
    np.testing.assert_allclose(same[:, 0], np.mean([1.0, 1.1, 0.9]), rtol=1e-12)
    np.testing.assert_array_equal(pooled_log_factors(a([[0.3], [2.0]]), a([[4.0], [4.0]]), a([7, 0])), [[0.3], [2.0]])
    # a position whose images carry no information takes the pooled value; a
    # diverged one stays non-finite (the fit's check raises)
    some = pooled_log_factors(a([[1.0], [1.2], [3.0], [np.nan]]), a([[5.0], [5.0], [np.nan], [5.0]]), a([4, 4, 4, 4]))
    assert some[2, 0] == pytest.approx(1.1) and np.isnan(some[3, 0])


def test_pooled_calibration_is_nearer_a_shared_factor_and_fills_empty_positions(rng):
    model = _model(rng, V=6, sep=1.5)
    full = _draw(rng, model, np.full((6, 1), 4.0), n=3).cameras[0]   # 24 images a position
    keep = full.position != 5                                           # position 5: none
    feats = CalibrationFeatures((CameraFeatures(full.g[keep], full.position[keep], full.cls[keep]),))
    _, own = calibrate_model(model, feats)
    _, pooled = calibrate_model(model, feats, pool=True)
    err = lambda s: np.sqrt(np.mean(np.log(s[:5, 0] / 4.0) ** 2))      # noqa: E731
    assert err(pooled.factors[0]) < err(own.factors[0])
    assert own.factors[0][5, 0] == 1.0 and pooled.factors[0][5, 0] > 2.0
    assert pooled.settings["pool"] is True and own.settings["pool"] is False
    # the NLL it reports is that of the factors it applied: a model scaled by them
    # starts there (its NLL at s = 1)
    _, again = calibrate_model(apply_calibration(model, pooled.factors), feats, max_iter=1)
    np.testing.assert_allclose(again.nll_before[0][:5], pooled.nll_after[0][:5], rtol=1e-4)
    # one factor per level: pooled per level, finite
    two = _model(rng, V=4, L=2)
    _, levels = calibrate_model(two, _draw(rng, two, np.full((4, 2), 3.0), n=20, level_of=True), per_level=True,
                                pool=True)
    assert levels.factors[0].shape == (4, 2) and np.all(np.isfinite(levels.factors[0]))


def test_pooling_keeps_well_fitting_positions_near_one_beside_a_badly_fitting_one(rng):
    """Four positions whose held-out views fit as trained (factor 1) and one
    that needs 8: the pool does not lend the bad one's inflation to the others
    (their posterior variances under the fit's prior count them as near 1), and
    the bad one keeps most of its own."""
    model = _model(rng, V=5, sep=2.5)
    feats = _draw(rng, model, np.array([[1.0], [1.0], [1.0], [1.0], [8.0]]), n=4)
    _, own = calibrate_model(model, feats)
    _, pooled = calibrate_model(model, feats, pool=True)
    s_own, s_pool = own.factors[0][:, 0], pooled.factors[0][:, 0]
    assert s_own[4] > 4.0 and np.all(s_own[:4] < 2.0)
    assert np.all(s_pool[:4] < 1.15 * s_own[:4] + 0.15)          # not pulled toward the pool's mean
    assert s_pool[4] > 0.8 * s_own[4]
