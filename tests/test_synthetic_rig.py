"""The synthetic rig: rendered scene, zoom, look-alike pairs, occluders,
the database writer, and the message when pybullet is missing."""

from __future__ import annotations

import csv
import math
import subprocess
import sys

import numpy as np
import pytest

from jaxrecog import load_database
from jaxrecog.hardware import (
    Noise,
    OccluderLayout,
    Rig,
    RigError,
    SyntheticRig,
    contact_sheet,
    lookalike_distances,
    random_occluders,
    render_database,
)
from jaxrecog.hardware.geometry.positions import CameraTable, default_table

pytest.importorskip("pybullet")

PAIRS = ((4, 5), (6, 7))  # thesis objects 5/6 and 7/8


@pytest.fixture(scope="module")
def rig():
    r = SyntheticRig()
    yield r
    r.close()


@pytest.fixture(scope="module")
def clean(rig):
    """Clean images and object masks of every object x pose x position:
    ``uint8/bool [M, N, V, H, W]``, positions of camera 0 first."""
    V = sum(rig.positions)
    imgs = np.zeros((rig.n_objects, rig.n_poses, V) + rig.image_shape, np.uint8)
    masks = np.zeros(imgs.shape, bool)
    for m in range(rig.n_objects):
        for p in range(rig.n_poses):
            rig.reset(m, p)
            k = 0
            for i, n in enumerate(rig.positions):
                for v in range(n):
                    imgs[m, p, k], masks[m, p, k] = rig.render_clean(i, v)
                    k += 1
    return imgs, masks


def _unit(y: np.ndarray) -> np.ndarray:
    y = y.reshape(y.shape[: -2] + (-1,)).astype(np.float64)
    return y / np.linalg.norm(y, axis=-1, keepdims=True)


# ------------------------------------------------------------------ interface


def test_rig_protocol_and_capture(rig):
    assert isinstance(rig, Rig)
    assert rig.positions == (32, 7)
    assert rig.image_shape == (120, 160)
    rig.reset(2, 1)
    rig.move((5, 3))
    cap = rig.capture()
    images = cap.images
    assert len(images) == 2
    for img in images:
        assert img.dtype == np.uint8 and img.shape == (120, 160)
        assert img.std() > 10  # a scene, not a blank frame
    assert cap.occluded == (0.0, 0.0)
    with pytest.raises(TypeError):
        cap[0]  # a Capture is not the old list of images: old callers fail loudly
    # the capture is the render at the table's eye position
    for i, v in enumerate((5, 3)):
        ref, frac = rig.render_at(i, rig.table.views[i][v].eye, noisy=False)
        np.testing.assert_array_equal(ref, images[i])
        assert frac == 0.0


def test_bad_input_raises_clear_errors(rig):
    fresh = SyntheticRig(default_table().single_camera(1))
    fresh.reset(0, 0)
    with pytest.raises(RigError, match="before move"):
        fresh.capture()
    fresh.close()
    fresh = SyntheticRig(default_table().single_camera(1))
    fresh.move((0,))
    with pytest.raises(RigError, match="reset"):
        fresh.capture()
    fresh.close()
    with pytest.raises(RigError, match="2 cameras"):
        rig.move((1, 2, 3))
    with pytest.raises(RigError, match="camera 1 position 7"):
        rig.move((0, 7))
    with pytest.raises(RigError, match="object 8"):
        rig.reset(8, 0)
    with pytest.raises(RigError, match="pose 4"):
        rig.reset(0, 4)
    with pytest.raises(TypeError, match="OccluderLayout"):
        rig.reset(0, 0, occluders=[1, 2])
    rig.reset(0, 0)
    with pytest.raises(RigError, match="inside the object's bounding sphere"):
        rig.render_at(0, (0.0, 0.0, 0.12))
    with pytest.raises(RigError, match="finite"):
        rig.render_at(0, (np.nan, 1.0, 1.0))


def test_any_number_of_cameras():
    t = default_table()
    three = CameraTable(t.workspace, (t.views[0][:3], t.views[1][:2], t.views[0][20:22]))
    with SyntheticRig(three) as r3:
        assert r3.positions == (3, 2, 2)
        r3.reset(3, 2)
        r3.move((2, 1, 1))
        cap = r3.capture()
        imgs = cap.images
        assert len(imgs) == 3 and len(cap.occluded) == 3
        np.testing.assert_array_equal(imgs[2], r3.render_at(2, t.views[0][21].eye, noisy=False)[0])
    with SyntheticRig(t.single_camera(0)) as r1:
        r1.reset(0, 0)
        r1.move((4,))
        assert len(r1.capture().images) == 1


def test_missing_pybullet_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "pybullet", None)  # makes `import pybullet` raise ImportError
    with pytest.raises(ImportError, match=r"jaxrecog\[sim\]"):
        SyntheticRig()
    # and the package itself still imports without pybullet
    code = "import sys; sys.modules['pybullet'] = None; import jaxrecog.hardware as h; print(h.SyntheticRig.__name__)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "SyntheticRig"


# ------------------------------------------------------------------ geometry


def test_zoom_table_follows_the_fill_rule(rig):
    c = np.asarray(rig.table.workspace.object_xyz)
    for i, views in enumerate(rig.table.views):
        for v, view in enumerate(views):
            r = np.linalg.norm(np.asarray(view.eye) - c)
            half_angle = math.asin(rig.radius / r)  # angular radius of the bounding sphere
            assert 2 * half_angle / math.radians(rig.fov[i][v]) == pytest.approx(rig.intrinsics.fill)
    # nearer positions zoom out: camera 1's steeper tilts are nearer
    assert rig.fov[0][0] < rig.fov[0][8] < rig.fov[0][16] < rig.fov[0][24]


def test_every_position_sees_the_object_inside_the_frame(rig, clean):
    _, masks = clean
    H, W = rig.image_shape
    assert masks.any(axis=(-1, -2)).all(), "object missing from some image"
    margin = 3  # room for the capture's pixel offsets
    border = np.zeros((H, W), bool)
    border[:margin], border[-margin:], border[:, :margin], border[:, -margin:] = True, True, True, True
    touching = (masks & border).any(axis=(-1, -2))
    assert not touching.any(), f"object touches the border at (object, pose, position) {np.argwhere(touching)[:5]}"
    # similar size from every position: per object, area varies by less than 2.5x
    area = masks.mean(axis=(-1, -2))  # [M, N, V]
    ratio = area.max(axis=(1, 2)) / area.min(axis=(1, 2))
    assert (ratio < 2.5).all(), ratio
    assert 0.03 < area.min() and area.max() < 0.4


def test_pose_turns_the_object_about_the_vertical(rig, clean):
    """Oracle: pose p+1 (object turned +90°) seen from camera-1 pan theta - 90°
    has the same silhouette as pose p from pan theta (pans are 45° apart)."""
    _, masks = clean
    ious = []
    for p in range(rig.n_poses - 1):
        for j in range(32):
            tilt, pan = divmod(j, 8)
            a, b = masks[:, p, j], masks[:, p + 1, tilt * 8 + (pan - 2) % 8]
            ious.append((a & b).sum((-1, -2)) / (a | b).sum((-1, -2)))
    assert np.min(ious) > 0.97
    # ... while the silhouettes of different poses from one position do differ
    a, b = masks[:, 0, :32], masks[:, 1, :32]
    assert ((a & b).sum((-1, -2)) / (a | b).sum((-1, -2))).min() < 0.9


def test_poses_differ_from_every_view(clean):
    imgs, _ = clean
    y = _unit(imgs)  # [M, N, V, D]
    N = y.shape[1]
    d = [np.linalg.norm(y[:, p] - y[:, q], axis=-1) for p in range(N) for q in range(p + 1, N)]  # [M, V] each
    closest = np.min(d, axis=0)  # nearest other pose, per object and position
    assert closest.min() > 0.05, closest.min()


def test_lookalike_pairs_differ_only_where_the_sticker_shows(rig, clean):
    imgs, _ = clean
    y = _unit(imgs)
    labels = [f"{i}:{v}" for i, n in enumerate(rig.positions) for v in range(n)]
    print("\nlook-alike distances ||y_a/|y_a| - y_b/|y_b|||, nonzero entries (camera:position)")
    for a, b in PAIRS:
        d = np.linalg.norm(y[a] - y[b], axis=-1)  # [N, V]
        np.testing.assert_allclose(d, lookalike_distances(rig, a, b), atol=1e-12)
        for p in range(rig.n_poses):
            hits = np.flatnonzero(d[p] > 1e-3)
            print(f"  objects {a}/{b} pose {p}: " + ", ".join(f"{labels[k]}={d[p, k]:.3f}" for k in hits))
            differ = d[p] > 0.05
            close = d[p] < 1e-3
            assert 1 <= differ.sum() <= 5, (a, b, p, d[p])
            assert (differ | close).all(), f"in-between distances {d[p][~(differ | close)]}"
        # the difference is the sticker, not noise: other objects are far apart everywhere
        other = np.linalg.norm(y[a] - y[(b + 1) % rig.n_objects], axis=-1)
        assert other.min() > 0.05


# ------------------------------------------------------------------ occluders


def test_random_occluders_are_seeded_and_between_camera_and_object():
    table = default_table()
    a = random_occluders(np.random.default_rng(7), table, radius=0.15)
    b = random_occluders(np.random.default_rng(7), table, radius=0.15)
    c = random_occluders(np.random.default_rng(8), table, radius=0.15)
    assert a == b and a != c and hash(a) == hash(b)
    assert len(a) == table.n_cameras
    o = np.asarray(table.workspace.object_xyz)
    for layout in (a, c, random_occluders(np.random.default_rng(9), table, radius=0.15, boards_per_camera=3)):
        for board in layout.boards:
            i, v = board.aimed_at
            e = np.asarray(table.views[i][v].eye)
            u = (e - o) / np.linalg.norm(e - o)
            depth = float(np.dot(np.asarray(board.centre) - o, u))
            assert 0.15 < depth < np.linalg.norm(e - o)  # outside the object's sphere, before the eye
            # the board's thin axis (rotated y) faces the camera
            x, y, z, w = board.quaternion
            normal = np.array([2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)])
            assert abs(np.dot(normal, u)) == pytest.approx(1.0)
    with pytest.raises(TypeError, match="Generator"):
        random_occluders(np.random.RandomState(0), table)
    with pytest.raises(ValueError, match="camera 5"):
        random_occluders(np.random.default_rng(0), table, cameras=[5])


def test_occluded_fraction_is_measured_from_the_masks(rig):
    """Oracle: Capture.occluded = 1 - |object mask with boards| / |object mask without|."""
    layout = random_occluders(np.random.default_rng(3), rig.table, radius=rig.radius, boards_per_camera=2)
    checked = 0
    for m in (1, 4):
        rig.reset(m, 2, layout)
        for board in layout.boards:
            cfg = [0] * rig.table.n_cameras
            cfg[board.aimed_at[0]] = board.aimed_at[1]
            rig.move(cfg)
            cap = rig.capture()
            i, v = board.aimed_at
            img_occ, mask_occ = rig.render_clean(i, v)
            rig.reset(m, 2)
            img_clean, mask_clean = rig.render_clean(i, v)
            rig.reset(m, 2, layout)
            assert not (mask_occ & ~mask_clean).any()  # boards only hide object pixels
            expect = 1.0 - mask_occ.sum() / mask_clean.sum()
            assert cap.occluded[i] == pytest.approx(expect, abs=1e-12)
            checked += expect > 0
            if expect > 0:
                assert (img_occ != img_clean).any()
            _, frac = rig.render_at(i, rig.table.views[i][v].eye)
            assert frac == pytest.approx(expect, abs=1e-12)
    assert checked >= 2
    rig.reset(0, 0)


def test_occluded_fractions_span_0_to_30_percent(rig):
    rng = np.random.default_rng(2024)
    aimed, swept = [], []
    for trial in range(32):
        layout = random_occluders(rng, rig.table, radius=rig.radius)
        assert isinstance(layout, OccluderLayout)
        rig.reset(trial % rig.n_objects, trial % rig.n_poses, layout)
        for board in layout.boards:
            cfg = [0] * rig.table.n_cameras
            cfg[board.aimed_at[0]] = board.aimed_at[1]
            rig.move(cfg)
            aimed.append(rig.capture().occluded[board.aimed_at[0]])
        if trial < 3:  # every position for a few layouts
            for v in range(max(rig.positions)):
                rig.move([min(v, n - 1) for n in rig.positions])
                swept.extend(rig.capture().occluded)
    aimed, swept = np.array(aimed), np.array(swept)
    allf = np.concatenate([aimed, swept])
    assert ((allf >= 0) & (allf <= 1)).all()
    nonzero = allf[allf > 0.005]
    assert np.quantile(nonzero, 0.95) <= 0.3 and nonzero.max() <= 0.45, np.sort(nonzero)[-5:]
    # the range is spanned: small, medium and large occlusions all occur where boards are aimed
    assert (aimed[(aimed > 0)] < 0.05).any()
    assert ((aimed >= 0.1) & (aimed <= 0.3)).mean() >= 0.3
    assert (aimed >= 0.2).any()
    # from most other positions the boards hide nothing
    assert (swept == 0).mean() > 0.6
    rig.reset(0, 0)


# ------------------------------------------------------------------ noise


def test_noise_is_seeded_and_shifts_are_whole_pixels():
    table = default_table()
    kw = dict(noise=Noise(brightness=0.1, pixel=3.0, max_shift=2))
    r1, r2, r3 = SyntheticRig(table, seed=5, **kw), SyntheticRig(table, seed=5, **kw), SyntheticRig(table, seed=6, **kw)
    for r in (r1, r2, r3):
        r.reset(3, 1)
        r.move((12, 2))
    a, b, c = r1.capture().images, r2.capture().images, r3.capture().images
    for x, y, z in zip(a, b, c):
        np.testing.assert_array_equal(x, y)
        assert (x != z).any()
    # a shift of (dx, dy) moves the whole render by whole pixels (principal-point offset)
    scene, eye = r1.scene, table.views[0][12].eye
    fov = r1.fov[0][12]
    img0, seg0 = scene.render(eye, fov, r1.intrinsics)
    img1, seg1 = scene.render(eye, fov, r1.intrinsics, shift=(2, -1))
    inner0, inner1 = seg0[1:, : -2], seg1[:-1, 2:]  # pixel (r, c) -> (r - 1, c + 2)
    assert (inner0 == inner1).mean() > 0.995
    assert np.abs(img0[1:, :-2].astype(int) - img1[:-1, 2:]).mean() < 1.0
    for r in (r1, r2, r3):
        r.close()


# ------------------------------------------------------------------ database


def _check_manifest(folder, rig_positions, n_objects, n_poses, splits):
    with open(folder / "manifest.csv", newline="") as fh:
        reader = csv.reader(fh)
        header = next(reader)
        rows = list(reader)
    assert header == ["path", "camera", "position", "object", "pose", "split"]
    keys = {}
    for row in rows:
        path, i, v, m, p, split = row[0], *map(int, row[1:5]), row[5]
        assert split in splits and 0 <= i < len(rig_positions) and 0 <= v < rig_positions[i]
        assert 0 <= m < n_objects and 0 <= p < n_poses
        assert (folder / path).is_file()
        keys.setdefault(split, []).append((i, v, m, p))
    return rows, keys


def test_render_database_writes_the_manifest_format(tmp_path):
    import cv2

    t = default_table()
    small = CameraTable(t.workspace, (t.views[0][::11], t.views[1][::3]))  # 3 + 3 positions
    with SyntheticRig(small) as rig:
        manifest = render_database(tmp_path, rig=rig, test_per_view=2, test_occluders=True, seed=1)
        assert manifest == tmp_path / "manifest.csv"
        rows, keys = _check_manifest(tmp_path, rig.positions, 8, 4, {"train", "test"})
        assert len(keys["train"]) == 6 * 32 == len(set(keys["train"]))
        assert len(keys["test"]) == 2 * 6 * 32
        # a train image is the clean render, read back bit-exact
        rig.reset(5, 3)
        path = next(r[0] for r in rows if r[1:] == ["1", "2", "5", "3", "train"])
        img = cv2.imread(str(tmp_path / path), cv2.IMREAD_UNCHANGED)
        assert img.dtype == np.uint8 and img.shape == (120, 160)
        np.testing.assert_array_equal(img, rig.render_clean(1, 2)[0])
    # the foundation loader accepts the folder as it is written
    db = load_database(tmp_path)
    assert db.n_rows == len(rows) == 3 * 6 * 32
    assert db.n_cameras == 2 and db.positions == rig.positions == (3, 3)
    assert db.n_objects == 8 and db.n_poses == 4 and db.n_classes == 32
    assert db.image_shape == (120, 160) and db.images.dtype == np.uint8
    assert db.rows("train").size == 6 * 32 and db.rows("test").size == 2 * 6 * 32
    assert db.train_images(1).shape == (3, 32, 120, 160)
    j = db.paths.index(path)
    np.testing.assert_array_equal(db.images[j], img)


@pytest.mark.slow
def test_render_full_training_database(tmp_path):
    manifest = render_database(tmp_path)
    _, keys = _check_manifest(tmp_path, (32, 7), 8, 4, {"train"})
    assert len(keys["train"]) == 1248 == len(set(keys["train"]))
    per_position = {}
    for i, v, _, _ in keys["train"]:
        per_position[i, v] = per_position.get((i, v), 0) + 1
    assert len(per_position) == 39 and set(per_position.values()) == {32}
    assert manifest.stat().st_size > 0
    db = load_database(tmp_path)
    assert db.n_rows == 1248 and db.positions == (32, 7)
    assert db.n_classes == 32 and db.image_shape == (120, 160)
    assert db.train_images(0).shape == (32, 32, 120, 160)
    assert db.train_images(1).shape == (7, 32, 120, 160)


def test_contact_sheet_tiles_every_object_and_pose(rig):
    sheet = contact_sheet(rig, [(0, 9), (1, 3)])
    H, W = rig.image_shape
    assert sheet.dtype == np.uint8
    assert sheet.shape[0] >= 8 * H and sheet.shape[1] >= 8 * W
    rig.reset(7, 2)
    np.testing.assert_array_equal(sheet[7 * (H + 2) : 7 * (H + 2) + H, 2 * (W + 2) : 2 * (W + 2) + W], rig.render_clean(0, 9)[0])


def test_pybullet_import_prints_no_build_time_line():
    """pybullet's C code prints its build time on fd 2 at import, into every rig
    command's progress bars: the import is silenced, and fd 2 works afterwards."""
    import subprocess
    import sys

    code = ("import sys\nfrom jaxrecog.hardware.render.scene import require_pybullet\n"
            "p, _ = require_pybullet()\np.disconnect(p.connect(p.DIRECT))\nprint('stderr still here', file=sys.stderr)\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "build time" not in proc.stderr + proc.stdout and "stderr still here" in proc.stderr
