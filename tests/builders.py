"""Small generators of synthetic image databases, for the tests and the
benchmarks (test support: not installed with the package, so OpenCV drawing
stays out of the product).

Each object is a distinct flat shape drawn with OpenCV (polygon with its own
number of corners, gray level and stripe texture, plus an off-centre marker so
the poses differ); the pose rotates it by ``360 * pose / n_poses`` degrees;
the camera position changes the view (offset, scale, foreshortening and the
background gradient).  Intensities stay inside ``[30, 225]`` so that the
augmentation noise rarely clips.  This stands in for the rendered rig until it
lands; it is *not* a physical scene.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from jaxrecog import ImageDatabase, write_database

__all__ = ["render_view", "make_database", "write_synthetic_database", "moving_database", "random_sensor_model",
           "steps_stay_finite", "odd_images"]


def render_view(
    camera: int,
    position: int,
    object: int,
    pose: int,
    *,
    n_poses: int = 4,
    n_positions: int = 8,
    image_shape: tuple[int, int] = (120, 160),
) -> np.ndarray:
    """One clean synthetic view, ``uint8 [H, W]``."""
    H, W = image_shape
    t = (position + 0.5) / max(n_positions, 1)  # 0..1 along the camera's path
    # background: a gentle gradient whose direction depends on camera/position
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    ang = 2 * math.pi * t + camera
    bg = 70 + 25 * ((xx / W) * math.cos(ang) + (yy / H) * math.sin(ang))
    img = bg.copy()
    # object geometry
    n_corners = 3 + object % 5
    radius = min(H, W) * (0.26 + 0.04 * ((object // 5) % 2)) * (0.85 + 0.3 * t)
    squash = 0.6 + 0.4 * abs(math.cos(math.pi * t + 0.7 * camera))  # foreshortening
    cx = W / 2 + W * 0.12 * math.sin(2 * math.pi * t + camera)
    cy = H / 2 + H * 0.08 * math.cos(2 * math.pi * t)
    rot = 2 * math.pi * pose / n_poses + 2 * math.pi * t * 0.25
    k = np.arange(n_corners)
    phase = 0.3 * object
    px = radius * np.cos(2 * math.pi * k / n_corners + phase)
    py = radius * np.sin(2 * math.pi * k / n_corners + phase) * (1.0 - 0.25 * (object % 3) / 2)

    def place(x, y):
        xr = x * math.cos(rot) - y * math.sin(rot)
        yr = x * math.sin(rot) + y * math.cos(rot)
        return np.stack([cx + xr, cy + yr * squash], axis=-1)

    poly = np.round(place(px, py) * 16).astype(np.int32)
    body = np.zeros((H, W), np.uint8)
    cv2.fillPoly(body, [poly], 1, lineType=cv2.LINE_8, shift=4)
    stripes = 0.5 + 0.5 * np.sin((xx * math.cos(rot + object) + yy * math.sin(rot + object))
                                 * (0.35 + 0.1 * object))
    level = 140 + 55 * ((object * 37) % 7) / 6.0
    img = np.where(body > 0, level - 35 * stripes, img)
    # off-centre marker: makes poses distinguishable
    mk = place(np.array([0.55 * radius]), np.array([0.1 * radius]))[0]
    cv2.circle(img, (int(mk[0]), int(mk[1])), max(2, int(radius * 0.18)), 35.0, -1)
    return np.clip(np.round(img), 30, 225).astype(np.uint8)


def make_database(
    positions: Sequence[int] = (3, 3),
    n_objects: int = 3,
    n_poses: int = 2,
    image_shape: tuple[int, int] = (48, 64),
    n_test: int = 0,
    seed: int = 0,
    *,
    n_calib: int = 0,
    view_offset: float = 0.0,
    n_jitter: int = 0,
    jitter_offset: float = 0.25,
) -> ImageDatabase:
    """An in-memory synthetic database: one ``train`` image per
    (camera, position, object, pose), plus ``n_test`` ``test`` and ``n_calib``
    ``calib`` images of each: shifted by up to 2 pixels, gray noise sd 3 and,
    with ``view_offset`` > 0, taken *between* the positions (at
    ``v + U(-view_offset, view_offset)``, labelled with the nearest ``v``:
    views the augmentation does not model); and ``n_jitter`` clean ``jitter``
    images of each, rendered at ``v + d`` for the alternating offsets ``d`` of
    ``hardware.render.render_db.alternating_offsets(n_jitter, jitter_offset)``
    (positions; the same offsets at every view, in the same order, as the
    rendered databases' view jitter)."""
    from jaxrecog.hardware.render.render_db import alternating_offsets

    rng = np.random.default_rng(seed)
    jitter = alternating_offsets(n_jitter, jitter_offset) if n_jitter else ()
    imgs, cam, pos, obj, pose, split = [], [], [], [], [], []
    for i, n_pos in enumerate(positions):
        for v in range(n_pos):
            for m in range(n_objects):
                for p in range(n_poses):
                    kw = dict(n_poses=n_poses, n_positions=n_pos, image_shape=image_shape)
                    clean = render_view(i, v, m, p, **kw)
                    variants = [("train", clean)]
                    variants += [("jitter", render_view(i, v + d, m, p, **kw)) for d in jitter]
                    for s, count in (("test", n_test), ("calib", n_calib)):
                        for _ in range(count):
                            near = render_view(i, v + rng.uniform(-view_offset, view_offset), m, p, **kw) \
                                if view_offset else clean
                            dy, dx = rng.integers(-2, 3, size=2)
                            shifted = np.roll(near, (dy, dx), axis=(0, 1)).astype(np.float64)
                            noisy = shifted + rng.normal(0.0, 3.0, size=clean.shape)
                            variants.append((s, np.clip(np.round(noisy), 0, 255).astype(np.uint8)))
                    for s, im in variants:
                        imgs.append(im)
                        cam.append(i)
                        pos.append(v)
                        obj.append(m)
                        pose.append(p)
                        split.append(s)
    return ImageDatabase.from_arrays(np.stack(imgs), cam, pos, obj, pose, split)


def write_synthetic_database(folder: str | os.PathLike, **kwargs) -> Path:
    """Generate a database with :func:`make_database` and write it to ``folder``."""
    return write_database(folder, make_database(**kwargs))


def moving_database() -> ImageDatabase:
    """A database whose objects can only be told apart by moving: one camera,
    3 positions, 2 objects x 3 poses, ``24 x 32`` images, one ``train`` (clean)
    and one ``test`` (noise sd 4) image per view.  At positions 0 and 1 the
    two objects look identical (only the pose shows); only position 2 shows
    which object it is — the recognizer must move there.  Deterministic."""
    rng = np.random.default_rng(0)
    h, w = 24, 32

    def smooth(lo, hi):  # a low-frequency pattern: survives the training's pixel shifts
        return cv2.resize(rng.uniform(lo, hi, (3, 4)), (w, h), interpolation=cv2.INTER_CUBIC)

    base = np.array([[smooth(90, 160) for _ in range(3)] for _ in range(3)])  # [position, pose]
    marks = np.array([smooth(0, 255) for _ in range(2)])  # per object, seen at position 2 only
    imgs, cam, pos, obj, pose, split = [], [], [], [], [], []
    for v in range(3):
        for m in range(2):
            for p in range(3):
                clean = base[v, p].copy()
                if v == 2:
                    clean[:, : w // 2] = marks[m, :, : w // 2]
                for s, noise in (("train", 0.0), ("test", 4.0)):
                    img = np.clip(clean + rng.normal(0, noise, clean.shape), 0, 255).astype(np.uint8)
                    imgs.append(img)
                    cam.append(0)
                    pos.append(v)
                    obj.append(m)
                    pose.append(p)
                    split.append(s)
    return ImageDatabase.from_arrays(np.stack(imgs), cam, pos, obj, pose, split)


def random_sensor_model(positions=(4, 3), n_objects=3, n_poses=2, levels=(0.0, 0.1), k=3, hw=(6, 8), seed=0):
    """A random diagonal-Gaussian :class:`~jaxrecog.sensor_model.SensorModel`
    (orthonormal bases, means ~ N(0, 0.3^2), variances in [0.01, 0.05]) for the
    recognizer and planner tests that need a model but no images."""
    import jax.numpy as jnp

    from jaxrecog.kernels import gaussian
    from jaxrecog.sensor_model import CameraModel, SensorModel

    rng = np.random.default_rng(seed)
    d = hw[0] * hw[1]
    cams = []
    for v in positions:
        basis = np.linalg.qr(rng.normal(size=(v, d, k)))[0].astype(np.float32)
        cams.append(CameraModel(
            mean_image=jnp.asarray(rng.normal(0, 0.01, (v, d)), jnp.float32),
            basis=jnp.asarray(basis),
            eigenvalues=jnp.ones((v, k), jnp.float32),
            likelihood=gaussian(jnp.asarray(rng.normal(0, 0.3, (v, n_objects * n_poses, len(levels), k)), jnp.float32),
                                jnp.asarray(rng.uniform(0.01, 0.05, (v, n_objects * n_poses, len(levels), k)), jnp.float32)),
        ))
    return SensorModel(tuple(cams), n_objects, n_poses, tuple(levels), hw, "diag")


def steps_stay_finite(rec, state, image_sets, key):
    """Run ``rec.step`` on each ``[n_cameras, H, W]`` image set of ``image_sets``
    (traced), asserting every image set is usable and every planner score and
    belief entry is finite; returns the last ``(state, decision)``."""
    import jax
    import jax.numpy as jnp
    import jax.random as jr

    dec = None
    for t, images in enumerate(image_sets):
        state, dec = rec.step(state, jnp.asarray(images), jr.fold_in(key, t), trace=True)
        assert bool(dec.valid)
        assert np.all(np.isfinite(np.asarray(dec.trace.scores)))
        for leaf in jax.tree.leaves(dec.trace.posterior):
            assert np.all(np.isfinite(np.asarray(leaf)))
    return state, dec


def odd_images(like: np.ndarray) -> np.ndarray:
    """A nearly constant dark image set with one bright band: unlike any training view."""
    odd = np.full_like(like, 3)
    odd[:, :4] = 250
    return odd


def env_and_recognizer_beliefs(env, recognizer, seed: int = 3, steps: int = 2):
    """``(env beliefs, recognizer beliefs)``, each ``[steps, C]``: an episode
    of ``env`` (reset with ``seed``) and ``recognizer`` stepped on the same
    images, the env moved where the recognizer's step says (a blind prediction,
    so the env never ends the episode)."""
    import jax.random as jr

    obs, _ = env.reset(seed=seed)
    state = recognizer.init(config=env.configuration)
    got, want = [], []
    for t in range(steps):
        state, dec = recognizer.step(state, obs["images"], jr.PRNGKey(t), trace=True)
        got.append(env.class_belief)
        want.append(np.asarray(dec.trace.class_probs))
        if t + 1 < steps:
            blind = np.full(env.n_classes, 1.0 / env.n_classes, np.float32)
            obs, *_ = env.step({"action": np.int64(dec.next_index), "prediction": blind})
    return np.array(got), np.array(want)


def recorded_steps(path) -> dict[tuple[str, str], list[int]]:
    """The steps (on the ``step`` timeline) at which a rerun recording holds
    an entry, per (entity path, component): read back with rerun's own
    reader (``rerun.chunk.RrdReader``); static entries are left out."""
    from rerun.chunk import RrdReader

    found: dict[tuple[str, str], list[int]] = {}
    for chunk in RrdReader(path).stream().to_chunks():
        if chunk.is_static or "step" not in chunk.timeline_names:
            continue
        batch = chunk.to_record_batch()
        steps = batch.column("step").to_pylist()
        for name in batch.schema.names:
            if ":" in name:  # Archetype:component (the rest are row ids and timelines)
                found.setdefault((chunk.entity_path, name), []).extend(steps)
    return {k: sorted(v) for k, v in found.items()}
