"""Features at the boundary: bad images raise ImageError naming the image;
the pure batched versions agree with the checked one, under jit, and never NaN."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from builders import make_database

from jaxrecog.features import ImageError, project, project_batch, project_camera
from jaxrecog.train import train_model

pytestmark = pytest.mark.usefixtures("strict_dtype_promotion")  # numerics: no implicit promotion


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
    (lambda s: np.full(s, 1e39), "overflow float32"),
    (lambda s: np.where(np.eye(*s) > 0, -1.0, 5.0), "negative"),
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


@pytest.mark.parametrize("scale", [1e30, 1e-30, 1e6])
def test_project_is_scale_invariant_without_overflow(setup, scale):
    """Pixels whose squares overflow (1e30) or underflow (1e-30) in float32
    still give the finite features of the unscaled image (eq. 4.2 is scale
    invariant), on the checked and on the batched path."""
    db, m = setup
    i = int(db.rows("test")[5])
    cam, pos = int(db.camera[i]), int(db.position[i])
    ref = np.asarray(project(m, cam, pos, db.images[i]))
    img = db.images[i].astype(np.float64) * scale
    g = np.asarray(project(m, cam, pos, img))
    assert np.all(np.isfinite(g))
    np.testing.assert_allclose(g, ref, atol=1e-5)
    gb, vb = project_camera(m.cameras[cam], jnp.asarray([pos]),
                            jnp.asarray(img[None].astype(np.float32)))
    assert vb.tolist() == [True]
    np.testing.assert_allclose(np.asarray(gb[0]), ref, atol=1e-5)


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


def test_batched_marks_overflow_and_negative_invalid(setup):
    """In-graph rows that overflow float32 (1e39 -> inf after the cast), hold a
    negative pixel, or whose energy overflows float32 (1e30 per pixel) never
    give NaN/inf: the first two are invalid with ``g = 0``, the last is valid
    with the features of the unscaled image."""
    db, m = setup
    cam = m.cameras[1]
    rows = db.rows("test")
    rows = rows[db.camera[rows] == 1][:3]
    imgs = db.images[rows].astype(np.float64)
    with np.errstate(over="ignore"):                     # the cast a float32 graph sees
        huge = np.full(m.image_shape, 1e39).astype(np.float32)
    negative = imgs[0].copy()
    negative[3, 4] = -1.0
    batch = np.stack([imgs[0], huge, negative, imgs[1] * 1e30, imgs[2]]).astype(np.float32)
    pos = np.asarray([int(db.position[rows[0]]), 0, int(db.position[rows[0]]),
                      int(db.position[rows[1]]), int(db.position[rows[2]])])
    for fn in (project_camera, jax.jit(project_camera)):
        g, valid = fn(cam, jnp.asarray(pos), jnp.asarray(batch))
        g = np.asarray(g)
        assert valid.tolist() == [True, False, False, True, True]
        assert np.all(np.isfinite(g)) and np.all(g[1:3] == 0)
        np.testing.assert_allclose(g[3], project(m, 1, int(pos[3]), db.images[rows[1]]), atol=1e-5)
    p = int(pos[0])
    gb, vb = jax.jit(project_batch)(cam.mean_image[p], cam.basis[p],
                                    jnp.asarray(batch.reshape(5, -1)))
    assert vb.tolist() == [True, False, False, True, True]
    assert np.all(np.isfinite(np.asarray(gb))) and np.all(np.asarray(gb[1:3]) == 0)


def _image_sets(db):
    """Image sets of the two cameras (positions 1 and 2), good and bad, in
    each dtype a camera or a file gives."""
    i0 = int(db.rows("test")[0])
    good = np.stack([db.images[i0], db.images[int(db.rows("test")[-1])]])
    odd = good.astype(np.float32)
    black, const, nan, neg, big, inf = (odd.copy() for _ in range(6))
    black[1] = 0
    const[0] = 7
    nan[1, 3, 4] = np.nan
    neg[0, 0, 0] = -1
    big[0] *= np.float32(1e30)  # its energy overflows float32 without the peak scaling
    inf[1, 2, 2] = np.inf
    wide = good.astype(np.int32) * 10**6 + 7  # checked and scaled after the cast to float32
    over, under = (good.astype(np.float64) * f for f in (1e37, 1e-47))  # float32: inf; 0 (all black)
    return {"uint8": good, "float32": odd, "float64": good.astype(np.float64), "uint16": good.astype(np.uint16) * 200,
            "int32": wide, "black": black, "constant": const, "nan": nan, "negative": neg, "huge": big, "inf": inf,
            "float64-overflow": over, "float64-underflow": under}


def test_host_features_equal_the_compiled_projection(setup):
    """The single-trial step's host projection (NumPy) gives what project_at
    gives inside a program: the same validity, the same g to float32 rounding,
    g = 0 for an unusable image set."""
    from jaxrecog.features import host_features, host_planes, project_at

    db, m = setup
    planes = [host_planes(c) for c in m.cameras]
    config = np.array([1, 2])
    compiled = jax.jit(lambda imgs, cfg: [project_at(c, cfg[i], imgs[i]) for i, c in enumerate(m.cameras)])
    for name, imgs in _image_sets(db).items():
        got = host_features(planes, config, imgs, m.image_shape)
        with np.errstate(over="ignore"):  # float64 beyond float32: inf, as the cast in the program gives
            want = compiled(jnp.asarray(imgs, jnp.float32) if imgs.dtype == np.float64 else jnp.asarray(imgs),
                            jnp.asarray(config))
        assert bool(got.ok) == all(bool(ok) for _, ok in want), name
        assert bool(got.ok) == (name in ("uint8", "float32", "float64", "uint16", "int32", "huge")), name
        for g, (w, ok) in zip(got.gs, want):
            assert g.dtype == np.float32 and np.all(np.isfinite(g))
            if bool(got.ok):
                np.testing.assert_allclose(g, np.asarray(w), rtol=1e-4, atol=2e-6, err_msg=name)
            elif not bool(ok):
                assert not np.any(g), name


def test_host_features_leave_traced_or_odd_input_to_the_program(setup):
    from jaxrecog.features import host_features, host_planes

    db, m = setup
    planes = [host_planes(c) for c in m.cameras]
    imgs = _image_sets(db)["uint8"]
    assert host_features(planes, np.array([0, 0]), imgs, m.image_shape) is not None
    assert host_features(planes, np.array([0, 0]), imgs[:1], m.image_shape) is None        # one camera short
    assert host_features(planes, np.array([0, 0]), imgs[:, :-1], m.image_shape) is None    # wrong size
    assert host_features(planes, np.array([0, 0]), imgs > 9, m.image_shape) is None        # not a gray image
    seen = []
    jax.jit(lambda i: seen.append(host_features(planes, np.array([0, 0]), i, m.image_shape)) or i)(imgs)
    assert seen == [None]


def test_host_features_of_a_batch_are_those_of_each_image_set(setup):
    """The driver's batch: slots at different positions, good and bad image
    sets mixed, give bit for bit what each set gives alone (however a batch is
    split, a slot's value is its own); positions a camera does not have go to
    the program (None)."""
    from jaxrecog.features import host_features, host_features_batch, host_planes

    db, m = setup
    planes = [host_planes(c) for c in m.cameras]
    sets = _image_sets(db)
    names = ["uint8", "black", "uint8", "nan", "uint8"]
    imgs = np.stack([sets[n].astype(np.float32) for n in names])
    configs = np.array([[0, 2], [1, 1], [1, 0], [0, 0], [1, 2]])
    batch = host_features_batch(planes, configs, imgs, m.image_shape)
    assert batch.ok.tolist() == [True, False, True, False, True]
    for b, (cfg, img) in enumerate(zip(configs, imgs)):
        one = host_features(planes, cfg, img, m.image_shape)
        assert bool(one.ok) == bool(batch.ok[b])
        for g, gb in zip(one.gs, batch.gs):
            np.testing.assert_array_equal(gb[b], g)
    assert host_features_batch(planes, configs + [[0, 1]], imgs, m.image_shape) is None   # camera 1 has 3
    # 64-bit integers whose energy overflows float32: scaled by the peak, the image's own features
    # (the program cannot take them: JAX keeps 32-bit integers)
    big = host_features(planes, configs[0], sets["uint8"].astype(np.int64) * 10**16, m.image_shape)
    ref = host_features(planes, configs[0], sets["uint8"], m.image_shape)
    assert bool(big.ok)
    for g, r in zip(big.gs, ref.gs):
        np.testing.assert_allclose(g, r, rtol=1e-4, atol=1e-6)
    assert host_features(planes, np.array([-1, 0]), imgs[0], m.image_shape) is None
