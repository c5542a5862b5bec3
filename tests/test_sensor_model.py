"""ML Gaussians vs numpy on the same samples; trained model vs its pixel model."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from builders import make_database

from jaxrecog.augment import DB2_LEVELS, AugmentParams, augment_images
from jaxrecog.features import project
from jaxrecog.sensor_model import GaussianAccumulator
from jaxrecog.train import train_model


@pytest.mark.parametrize("full", [False, True])
def test_streamed_ml_fit_matches_numpy(full, rng):
    C, L, K, n = 3, 2, 4, 50
    g = rng.normal(size=(C, L, n, K)) * rng.uniform(0.1, 2, (C, L, 1, K)) + rng.normal(size=(C, L, 1, K)) * 10
    cls = np.broadcast_to(np.arange(C)[:, None, None], (C, L, n)).ravel()
    lev = np.broadcast_to(np.arange(L)[None, :, None], (C, L, n)).ravel()
    flat = g.reshape(-1, K)
    perm = rng.permutation(len(flat))
    acc = GaussianAccumulator(C, L, K, full=full, ref=rng.normal(size=(C, L, K)))
    for chunk in np.array_split(perm, 7):                 # streamed in random batches
        acc.add(flat[chunk], cls[chunk], lev[chunk])
    mu, var, chol = acc.finalize(0.0)
    np.testing.assert_allclose(mu, g.mean(axis=2), rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(var, g.var(axis=2), rtol=1e-9)
    if full:
        for c in range(C):
            for l in range(L):
                cov = np.cov(g[c, l].T, bias=True)
                np.testing.assert_allclose(chol[c, l] @ chol[c, l].T, cov, rtol=1e-8, atol=1e-12)
                assert np.allclose(chol[c, l], np.tril(chol[c, l]))


def test_variance_floor_keeps_degenerate_class_proper():
    g = np.zeros((10, 3))
    g[:, 0] = np.arange(10)
    acc = GaussianAccumulator(1, 1, 3, full=True)
    acc.add(g, np.zeros(10, int), 0)
    mu, var, chol = acc.finalize(1e-3)
    assert np.all(np.diagonal(chol[0, 0]) > 0) and np.all(var >= 1e-3)
    acc = GaussianAccumulator(1, 1, 3)
    acc.add(g, np.zeros(10, int), 0)
    assert np.all(acc.finalize(1e-3)[1] >= 1e-3)


@pytest.fixture(scope="module")
def db():
    return make_database(positions=(3, 3), n_objects=3, n_poses=2, image_shape=(48, 64))


def test_noiseless_training_equals_projected_pixel_samples(db):
    """With no noise the feature-space path must equal projecting the 8-bit images."""
    p = AugmentParams(noise_sigma=0.0, brightness_sigma=0.0, samples_per_image=6)
    m = train_model(db, kind="DB2", n_components=4, augment=p, samples_per_image=6, var_floor=0.0)
    for cam, pos, k in [(0, 1, 3), (1, 2, 0), (1, 0, 5)]:
        aug = augment_images(db.train_images(cam)[pos], level=k, levels=DB2_LEVELS, params=p,
                             camera=cam, position=pos)
        g = np.array([[np.asarray(project(m, cam, pos, a)) for a in per] for per in aug])
        np.testing.assert_allclose(m.cameras[cam].mu[pos, :, k], g.mean(axis=1), atol=2e-6)
        np.testing.assert_allclose(m.cameras[cam].var[pos, :, k], g.var(axis=1), rtol=2e-3, atol=1e-9)


def test_noisy_training_matches_pixel_model_statistically(db):
    """Noise added in feature space vs noise added to pixels: same Gaussians."""
    p = AugmentParams(noise_sigma=12.0, brightness_sigma=10.0, max_shift=0, samples_per_image=400)
    m = train_model(db, kind="DB1", n_components=5, augment=p, samples_per_image=400)
    cam, pos = 0, 2
    aug = augment_images(db.train_images(cam)[pos], level=0, levels=(0.0,), params=p,
                         camera=cam, position=pos)
    g = np.array([[np.asarray(project(m, cam, pos, a)) for a in per] for per in aug])
    mu, var = np.asarray(m.cameras[cam].mu[pos, :, 0]), np.asarray(m.cameras[cam].var[pos, :, 0])
    se = np.sqrt(var / 400)
    assert np.all(np.abs(g.mean(axis=1) - mu) < 5 * se + 2e-5)   # 2e-5: rounding/clipping
    ratio = g.var(axis=1) / var
    assert np.all((ratio > 0.7) & (ratio < 1.4)), ratio


def test_model_shapes_full_and_reproducible(db):
    m1 = train_model(db, kind="DB2", n_components=3, samples_per_image=10, covariance="full", seed=4)
    m2 = train_model(db, kind="DB2", n_components=3, samples_per_image=10, covariance="full", seed=4)
    cam = m1.cameras[1]
    assert cam.mu.shape == (3, 6, 6, 3) and cam.chol.shape == (3, 6, 6, 3, 3)
    assert cam.mean_image.shape == (3, 48 * 64) and cam.basis.shape == (3, 48 * 64, 3)
    assert cam.mu.dtype == np.float32
    np.testing.assert_array_equal(np.asarray(m1.cameras[0].mu), np.asarray(m2.cameras[0].mu))
    m3 = train_model(db, kind="DB2", n_components=3, samples_per_image=10, seed=5)
    assert not np.array_equal(np.asarray(m1.cameras[0].mu), np.asarray(m3.cameras[0].mu))
    assert m3.cameras[0].chol is None
    assert m1.levels == DB2_LEVELS and m1.n_classes == 6


def test_energy_choice_and_progress(db):
    calls = []
    m = train_model(db, kind="DB1", n_components=0.9, samples_per_image=4,
                    progress=lambda d, t: calls.append((d, t)))
    assert calls[-1] == (6, 6) and len(calls) == 6
    lam = np.asarray(m.cameras[0].eigenvalues)
    assert 1 <= m.n_components <= 5 and np.all(np.diff(lam, axis=1) <= 0)


def test_identical_images_get_identical_gaussians_with_shared_draws():
    """Look-alike classes (identical clean images at a position) must not be told
    apart by sampling noise: with common random numbers their Gaussians match
    exactly; with independent draws they do not."""
    import dataclasses

    from jaxrecog import AugmentParams, ImageDatabase, train_model
    from builders import make_database

    db = make_database(positions=(2,), n_objects=4, n_poses=2)
    images = db.images.copy()
    # make object 2 a copy of object 1 at every position
    for r in np.flatnonzero(db.object == 2):
        twin = np.flatnonzero((db.object == 1) & (db.pose == db.pose[r]) & (db.position == db.position[r]))[0]
        images[r] = images[twin]
    twin_db = ImageDatabase.from_arrays(images, db.camera, db.position, db.object, db.pose, db.split)
    for shared in (True, False):
        params = dataclasses.replace(AugmentParams(), shared_draws=shared)
        model = train_model(twin_db, kind="DB2", n_components=4, samples_per_image=20, augment=params)
        cam = model.cameras[0]
        same_mu = np.array_equal(np.asarray(cam.mu[:, 2:4]), np.asarray(cam.mu[:, 4:6]))  # object 1 vs 2
        same_var = np.array_equal(np.asarray(cam.var[:, 2:4]), np.asarray(cam.var[:, 4:6]))
        assert (same_mu and same_var) == shared


def test_noiseless_training_with_capture_transforms_matches_projected_pixel_samples(db):
    """Rotation, scale, blur and local gain reach the trained Gaussians: with no
    noise they are those of the (8-bit) pixel samples of augment_images."""
    p = AugmentParams(noise_sigma=0.0, brightness_sigma=0.0, samples_per_image=8, max_rotation=5.0,
                      max_scale=0.05, blur_sigma=(0.3, 1.2), gain_amplitude=0.15)
    m = train_model(db, kind="DB2", n_components=4, augment=p, samples_per_image=8, var_floor=0.0)
    plain = train_model(db, kind="DB2", n_components=4, samples_per_image=8, var_floor=0.0,
                        augment=dataclasses.replace(p, max_rotation=0.0, max_scale=0.0, blur_sigma=(0.0, 0.0),
                                                    gain_amplitude=0.0))
    for cam, pos, k in [(0, 1, 3), (1, 2, 0)]:
        aug = augment_images(db.train_images(cam)[pos], level=k, levels=DB2_LEVELS, params=p,
                             camera=cam, position=pos)
        g = np.array([[np.asarray(project(m, cam, pos, a)) for a in per] for per in aug])
        var = np.asarray(m.cameras[cam].var[pos, :, k])
        np.testing.assert_allclose(m.cameras[cam].mu[pos, :, k], g.mean(axis=1), atol=1e-3 * np.sqrt(var.max()) + 1e-5)
        np.testing.assert_allclose(var, g.var(axis=1), rtol=0.05, atol=1e-7)
        assert not np.allclose(var, np.asarray(plain.cameras[cam].var[pos, :, k]), rtol=0.05)


def test_capture_pixel_path_agrees_with_the_shift_table_at_level_0(db):
    """A gain of 1e-12 (float32: exactly 1) sends level 0 through the per-sample
    pixel path instead of the table of shifts: the same model up to float32."""
    p = AugmentParams(samples_per_image=6)
    a = train_model(db, kind="DB1", n_components=4, augment=p, samples_per_image=6)
    b = train_model(db, kind="DB1", n_components=4, augment=dataclasses.replace(p, gain_amplitude=1e-12),
                    samples_per_image=6)
    for ca, cb in zip(a.cameras, b.cameras):
        np.testing.assert_allclose(ca.mu, cb.mu, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(ca.var, cb.var, rtol=1e-4, atol=1e-9)


def test_shifted_energies_are_the_float64_sums_of_the_shifted_images(rng):
    """The level-0 table's ``||S_d x||^2`` (running integer sums) is exactly the
    float64 sum of squares of each shifted image, saturated images included."""
    from jaxrecog.augment import ShiftWindows
    from jaxrecog.train_position import _shifted_energies

    images = rng.integers(0, 256, size=(4, 11, 17), dtype=np.uint8)
    images[0] = 255
    s = 3
    win = ShiftWindows(images, s)
    dy, dx = (x.ravel() for x in np.meshgrid(np.arange(-s, s + 1), np.arange(-s, s + 1), indexing="ij"))
    want = np.array([[np.sum(win.view[c, s - a, s - b].astype(np.float64) ** 2) for a, b in zip(dy, dx)]
                     for c in range(4)])
    np.testing.assert_array_equal(_shifted_energies(win, dy, dx), want)
