"""Real turntable photos as an image database, and the interpolated views
between training views: the mapping of data/turntable-photos/README.md,
that no test photo is fitted or calibrated on, and the interpolated mixture
components against a NumPy reference."""

from __future__ import annotations

import numpy as np
import pytest

from jaxrecog.database import ImageDatabase, load_database
from jaxrecog.photo_turntable import PHOTOS, build_photo_database, scan_photos
from jaxrecog.train import train_model
from jaxrecog.view_interpolation import interpolated_views, morph, view_neighbours
from jaxrecog.augment import AugmentParams


def test_the_shipped_photos_are_ten_objects_every_5_degrees():
    ps = scan_photos()
    assert ps.folder == PHOTOS and ps.n_objects == 10 and ps.step == 5.0
    assert all(len(f) == 72 for f in ps.files)
    assert ps.files[3][7] == "obj4__7.png"


@pytest.mark.parametrize("grid", [20, 30, 40])
def test_photo_database_maps_views_and_keeps_test_photos_apart(tmp_path, grid):
    build_photo_database(tmp_path, grid, objects=2, jitter_per_view=1)
    db = load_database(tmp_path)
    n = 360 // grid
    assert db.positions == (n,) and db.n_objects == 2 and db.n_poses == 4
    angle = {s: {} for s in ("train", "test", "calib", "jitter")}
    for path, v, m, p, s in zip(db.paths, db.position, db.object, db.pose, db.split):
        k = int(path.split("__")[1].split(".")[0])
        angle[s][m, p, v] = k * 5
        assert path.startswith(f"photos/obj{m + 1}__")
    for (m, p, v), a in angle["train"].items():
        assert a == (90 * p + grid * v) % 360
        assert angle["test"][m, p, v] == (a + grid // 2) % 360      # halfway to the next view
        assert abs(((angle["calib"][m, p, v] - a + 180) % 360) - 180) == 5
        assert angle["jitter"][m, p, v] != angle["calib"][m, p, v]
    test = {(m, a) for (m, _, _), a in angle["test"].items()}
    for s in ("calib", "jitter"):
        assert not test & {(m, a) for (m, _, _), a in angle[s].items()}
    # a test view is never a training photo of the position it is replayed at
    assert not {(m, v, a) for (m, _, v), a in angle["test"].items()} & {(m, v, a) for (m, _, v), a in angle["train"].items()}


def test_photo_database_bad_input(tmp_path):
    with pytest.raises(ValueError, match="grid must divide 360"):
        build_photo_database(tmp_path, 25)
    with pytest.raises(ValueError, match="not a multiple"):
        build_photo_database(tmp_path, 20, test_offset=7)
    with pytest.raises(ValueError, match="test photo .* calib photo"):
        build_photo_database(tmp_path, 20, test_offset=5)
    with pytest.raises(ValueError, match="objects must lie"):
        build_photo_database(tmp_path, 20, objects=11)
    with pytest.raises(ValueError, match="no files named"):
        scan_photos(tmp_path)


def _ring(V=12, C=6, H=16, W=16, seed=0):
    """Images of C blobs seen from V angles of a ring: neighbours look alike."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:H, :W]
    out = np.zeros((V, C, H, W), np.uint8)
    for c in range(C):
        cy, cx, r = rng.uniform(5, 11, 2).tolist() + [rng.uniform(2, 4)]
        for v in range(V):
            a = 2 * np.pi * v / V
            y, x = cy + 3 * np.sin(a + c), cx + 3 * np.cos(a + c)
            out[v, c] = np.clip(255 * np.exp(-((yy - y) ** 2 + (xx - x) ** 2) / (2 * r * r)), 0, 255).astype(np.uint8)
    return out


def test_view_neighbours_finds_the_ring_and_not_a_shuffle():
    train = _ring()
    V = train.shape[0]
    assert view_neighbours(train) == [((v - 1) % V, (v + 1) % V) for v in range(V)]
    order = np.random.default_rng(1).permutation(V)
    shuffled = view_neighbours(train[order])
    found = sum(x >= 0 for pair in shuffled for x in pair)
    assert found < V  # most index neighbours of a shuffled ring are not neighbouring views
    assert view_neighbours(train[:1]) == [(-1, -1)]


def test_interpolated_views_are_the_blends_numpy():
    train = _ring(V=6, C=2)
    nb = view_neighbours(train)
    views = interpolated_views(train, nb, 2)
    imgs, cls = views[0]
    assert imgs.shape == (2 * 4, 16, 16) and cls.tolist() == [0, 0, 0, 0, 1, 1, 1, 1]
    left, right = nb[0]
    x = train.astype(np.float64)
    want = [np.rint((1 - t) * x[0, c] + t * x[s, c]) for c in range(2) for s in (left, right) for t in (0.25, 0.5)]
    np.testing.assert_array_equal(imgs, np.stack(want).astype(np.uint8))
    # a position without neighbours repeats its training view
    lone = interpolated_views(train, [(-1, -1)] * 6, 1)[2][0]
    np.testing.assert_array_equal(lone, np.repeat(train[2], 2, axis=0))


def test_interpolated_mixture_components_are_the_projected_blends():
    """Without noise, brightness and shifts every sample of a component is the
    same feature: the mixture's component means are the eigenspace features
    ((x / |x|) - mean) @ basis of the blended images (eq. 4.3), the NumPy
    reference."""
    train = _ring(V=6, C=6)
    V, C, H, W = train.shape
    rows = [(train[v, c], 0, v, c, 0, "train") for v in range(V) for c in range(C)]
    db = ImageDatabase.from_arrays(np.stack([r[0] for r in rows]), *(np.array([r[i] for r in rows]) for i in range(1, 5)),
                                   np.array([r[5] for r in rows]))
    params = AugmentParams(samples_per_image=3, noise_sigma=0.0, brightness_sigma=0.0, max_shift=0)
    model, info = train_model(db, kind="DB1", n_components=4, samples_per_image=3, likelihood="view-mixture",
                              interpolate=1, augment=params, return_info=True)
    assert info.params["interpolate"]["neighbours"][0] == [[(v - 1) % V, (v + 1) % V] for v in range(V)]
    cam = model.cameras[0]
    mu = np.asarray(cam.likelihood.mu)                           # [V, C, L, M, K]
    assert mu.shape == (V, C, 1, 3, 4)  # M = 1 training view + 1 blend per side
    blends = interpolated_views(train, view_neighbours(train), 1)
    for v in range(V):
        mean, basis = np.asarray(cam.mean_image[v], np.float64), np.asarray(cam.basis[v], np.float64)
        for c in range(C):
            imgs = [train[v, c]] + [im for im, k in zip(*blends[v]) if k == c]
            for m, im in enumerate(imgs):
                x = im.reshape(-1).astype(np.float64)
                np.testing.assert_allclose(mu[v, c, 0, m], (x / np.linalg.norm(x) - mean) @ basis, atol=2e-5)


def test_interpolate_needs_a_mixture_family():
    train = _ring(V=4, C=4)
    rows = [(train[v, c], 0, v, c, 0, "train") for v in range(4) for c in range(4)]
    db = ImageDatabase.from_arrays(np.stack([r[0] for r in rows]), *(np.array([r[i] for r in rows]) for i in range(1, 5)),
                                   np.array([r[5] for r in rows]))
    with pytest.raises(ValueError, match="interpolate: the interpolated views are mixture components"):
        train_model(db, kind="DB1", n_components=2, samples_per_image=2, interpolate=1)
    with pytest.raises(ValueError, match="interpolate must be >= 0"):
        train_model(db, kind="DB1", n_components=2, samples_per_image=2, likelihood="view-mixture", interpolate=-1)


def _blob(cx, cy=32.0, size=64, r=6.0):
    yy, xx = np.mgrid[:size, :size]
    return np.clip(255 * np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / (2 * r * r)), 0, 255).astype(np.uint8)


def test_flow_morph_moves_an_edge_where_a_cross_fade_draws_it_twice():
    """A blob moved 8 pixels: the optical-flow morph halfway is one blob 4
    pixels along (near the NumPy-drawn blob there), the linear cross-fade two
    half blobs; at t = 0 and 1 both give the end views."""
    a, b, mid = _blob(28.0), _blob(36.0), _blob(32.0)
    flow = morph(a, b, [0.0, 0.5, 1.0], "flow")
    lin = morph(a, b, [0.0, 0.5, 1.0], "linear")
    np.testing.assert_array_equal(lin[0], a)
    np.testing.assert_array_equal(lin[2], b)
    assert np.abs(flow[0].astype(int) - a).max() <= 2 and np.abs(flow[2].astype(int) - b).max() <= 2
    err = lambda x: np.abs(x.astype(float) - mid).mean()  # noqa: E731
    assert err(flow[1]) < 0.2 * err(lin[1])
    cols = flow[1].astype(float).sum(axis=0)
    assert abs(float((cols * np.arange(64)).sum() / cols.sum()) - 32.0) < 0.5      # its centre moved halfway
    np.testing.assert_allclose(lin[1], np.rint(0.5 * a.astype(float) + 0.5 * b), atol=0)
    with pytest.raises(ValueError, match="interpolation must be one of linear, flow"):
        morph(a, b, [0.5], "cubic")


def test_flow_views_reuse_each_pairs_flows_and_match_morph(monkeypatch):
    """interpolated_views computes each neighbouring pair's two flows once
    (the way back swaps them) and gives exactly what morph computes alone."""
    import jaxrecog.view_interpolation as vi

    rng = np.random.default_rng(3)
    train = np.stack([np.stack([_blob(20.0 + 6 * v + c) for c in range(2)]) for v in range(4)])
    train = np.clip(train.astype(int) + rng.integers(0, 3, train.shape), 0, 255).astype(np.uint8)
    neighbours = [((v - 1) % 4, (v + 1) % 4) for v in range(4)]
    calls = []
    real = vi.flow_pair
    monkeypatch.setattr(vi, "flow_pair", lambda a, b: calls.append(1) or real(a, b))
    views = vi.interpolated_views(train, neighbours, 2, "flow")
    assert len(calls) == 4 * 2                    # 4 ring pairs x 2 classes, not 16
    for v, (imgs, cls) in enumerate(views):
        want = np.concatenate([morph(train[v, c], train[s, c], [0.25, 0.5], "flow")
                               for c in range(2) for s in neighbours[v]])
        np.testing.assert_array_equal(imgs, want)
        np.testing.assert_array_equal(cls, [0, 0, 0, 0, 1, 1, 1, 1])
