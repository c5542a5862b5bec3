"""Features at the boundary: bad images raise ImageError naming the image;
the pure batched versions agree with the checked one, under jit, and never NaN."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxrecog.features import ImageError, project, project_batch, project_camera
from jaxrecog.testing import make_database
from jaxrecog.train import train_model


@pytest.fixture(scope="module")
def setup():
    db = make_database(positions=(2, 3), n_objects=2, n_poses=2, image_shape=(24, 32), n_test=1)
    return db, train_model(db, kind="DB1", n_components=3, samples_per_image=4)


def test_project_matches_numpy(setup):
    db, m = setup
    i = int(db.rows("test")[5])
    cam, pos = int(db.camera[i]), int(db.position[i])
    y = db.images[i].astype(np.float64).ravel()
    c = m.cameras[cam]
    ref = np.asarray(c.basis[pos], np.float64).T @ (y / np.linalg.norm(y) - np.asarray(c.mean_image[pos]))
    np.testing.assert_allclose(np.asarray(project(m, cam, pos, db.images[i])), ref, atol=1e-5)


@pytest.mark.parametrize("make,match", [
    (lambda s: np.zeros(s, np.uint8), "all-black image has zero energy"),
    (lambda s: np.full(s, 77, np.uint8), "constant image"),
    (lambda s: np.where(np.eye(*s) > 0, np.nan, 5.0), "1 pixel"),
    (lambda s: np.ones((s[0] + 1, s[1]), np.uint8), "does not match"),
    (lambda s: np.full(s, np.inf), "NaN or infinite"),
])
def test_bad_images_raise_naming_image(setup, make, match):
    _, m = setup
    img = make(m.image_shape)
    if match == "1 pixel":
        img = np.full(m.image_shape, 5.0)
        img[3, 4] = np.nan
    with pytest.raises(ImageError, match=match) as e:
        project(m, 1, 2, img, name="frame_0042.png")
    assert str(e.value).startswith("frame_0042.png:")
    with pytest.raises(ImageError, match=r"camera 1, position 2"):
        project(m, 1, 2, img)


def test_out_of_range(setup):
    _, m = setup
    with pytest.raises(IndexError, match="position 3"):
        project(m, 0, 3, np.ones(m.image_shape))


def test_batched_agree_jit_and_flag_bad(setup):
    db, m = setup
    cam = m.cameras[1]
    rows = db.rows("test")
    rows = rows[db.camera[rows] == 1][:6]
    imgs = db.images[rows].astype(np.float32)
    bad = np.stack([np.zeros(m.image_shape), np.full(m.image_shape, 3.0),
                    np.full(m.image_shape, np.nan)]).astype(np.float32)
    all_imgs = np.concatenate([imgs, bad])
    pos = np.concatenate([db.position[rows], [0, 1, 2]])
    g, valid = jax.jit(project_camera)(cam, jnp.asarray(pos), jnp.asarray(all_imgs))
    g2, valid2 = project_camera(cam, jnp.asarray(pos), jnp.asarray(all_imgs))
    np.testing.assert_allclose(g, g2, atol=1e-6)
    assert valid.tolist() == [True] * 6 + [False] * 3
    assert np.all(np.isfinite(np.asarray(g))) and np.all(np.asarray(g[6:]) == 0)
    for j, r in enumerate(rows):
        np.testing.assert_allclose(g[j], project(m, 1, int(db.position[r]), db.images[r]), atol=1e-5)
    p = int(db.position[rows[0]])
    gb, vb = jax.jit(project_batch)(cam.mean_image[p], cam.basis[p],
                                    jnp.asarray(all_imgs.reshape(9, -1)))
    np.testing.assert_allclose(gb[0], g[0], atol=1e-6)
    assert vb.tolist() == valid.tolist() and np.all(np.isfinite(np.asarray(gb)))
