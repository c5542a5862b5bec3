"""Augmentation statistics: noise level, brightness, shift range, occluded
fraction per shape and level, reproducibility; the capture transforms
(rotation, scale, blur, local gain) against direct OpenCV / NumPy
computations, identity when off, seeding and validation."""

from __future__ import annotations

import hashlib
import math

import cv2
import numpy as np
import pytest

from jaxrecog.augment import (
    DB2_LEVELS, SHAPES, AugmentParams, augment_images, capture_rng, draw_plan, levels_for, occluder_bank,
    plan_rng,
)

SHAPE = (48, 64)


def test_noise_and_brightness_levels():
    flat = np.full((1, *SHAPE), 128, np.uint8)
    p = AugmentParams(samples_per_image=400, noise_sigma=5.0, brightness_sigma=0.0, max_shift=0)
    y = augment_images(flat, level=0, levels=(0.0,), params=p).astype(float)[0]
    assert abs((y - 128).std() - 5.0) < 0.1          # per-pixel sd (rounding adds 1/12)
    assert abs((y - 128).mean()) < 0.05
    p = AugmentParams(samples_per_image=400, noise_sigma=0.0, brightness_sigma=8.0, max_shift=0)
    y = augment_images(flat, level=0, levels=(0.0,), params=p).astype(float)[0]
    per_sample = (y - 128).reshape(400, -1)
    assert np.all(per_sample.std(axis=1) < 0.5)      # one offset per image
    b = per_sample.mean(axis=1)
    assert abs(b.std() - 8.0) < 8.0 * 4 / np.sqrt(2 * 400) and abs(b.mean()) < 4 * 8 / 20


def test_shift_range_uniform():
    img = np.zeros((1, *SHAPE), np.uint8)
    img[0, 20, 30] = 200
    img[0, 0, 0] = 1  # keep it non-constant after the shift
    p = AugmentParams(samples_per_image=2000, noise_sigma=0, brightness_sigma=0, max_shift=3)
    y = augment_images(img, level=0, levels=(0.0,), params=p)[0]
    pos = np.array([np.unravel_index(np.argmax(s), SHAPE) for s in y]) - np.array([20, 30])
    assert pos.min() == -3 and pos.max() == 3
    counts = np.bincount((pos[:, 0] + 3) * 7 + pos[:, 1] + 3, minlength=49)
    assert counts.min() > 0 and counts.max() < 3 * 2000 / 49


@pytest.mark.parametrize("shape", SHAPES)
def test_occluded_fraction_per_shape_and_level(shape):
    white = np.full((2, *SHAPE), 255, np.uint8)
    p = AugmentParams(samples_per_image=40, noise_sigma=0, brightness_sigma=0, max_shift=2,
                      shapes=(shape,))
    for k, lev in enumerate(DB2_LEVELS):
        y, masks = augment_images(white, level=k, levels=DB2_LEVELS, params=p, seed=k,
                                  return_masks=True)
        black = (y == 0).reshape(-1, SHAPE[0] * SHAPE[1]).mean(axis=1)  # measured on pixels
        assert np.all(np.abs(black - lev) <= 0.01), (shape, lev, black.min(), black.max())
        np.testing.assert_array_equal(y == 0, masks)


def test_bank_shapes_and_levels():
    bank = occluder_bank(DB2_LEVELS, (120, 160), AugmentParams(), seed=3)
    assert bank.templates[0] == ()
    for k, lev in enumerate(DB2_LEVELS[1:], start=1):
        assert sorted(set(bank.shape_of[k])) == sorted(SHAPES)
        for t in bank.templates[k]:
            assert t.shape[0] <= 120 and t.shape[1] <= 160
            assert abs(t.sum() / (120 * 160) - lev) <= 0.005


def test_occluders_vary_in_place():
    white = np.full((1, *SHAPE), 255, np.uint8)
    p = AugmentParams(samples_per_image=200, noise_sigma=0, brightness_sigma=0, max_shift=0)
    _, masks = augment_images(white, level=3, levels=DB2_LEVELS, params=p, return_masks=True)
    cover = masks[0].mean(axis=0)
    assert (cover > 0).mean() > 0.85  # occluders land all over the image
    centroids = np.array([np.argwhere(m).mean(axis=0) for m in masks[0]])
    assert np.ptp(centroids[:, 0]) > SHAPE[0] / 3 and np.ptp(centroids[:, 1]) > SHAPE[1] / 3


def test_reproducible_and_seed_dependent():
    img = np.random.default_rng(0).integers(30, 220, (3, *SHAPE), dtype=np.uint8)
    a = augment_images(img, level=2, levels=DB2_LEVELS, seed=5)
    b = augment_images(img, level=2, levels=DB2_LEVELS, seed=5)
    c = augment_images(img, level=2, levels=DB2_LEVELS, seed=6)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    assert a.shape == (3, 100, *SHAPE)


def test_levels_for():
    assert levels_for("DB1") == (0.0,)
    assert levels_for("DB2") == (0.0, 0.05, 0.10, 0.15, 0.20, 0.25)
    with pytest.raises(ValueError, match="DB3"):
        levels_for("DB3")


# -- capture transforms: rotation, scale, blur, local gain ------------------

IMG = np.random.default_rng(0).integers(30, 220, (3, *SHAPE), dtype=np.uint8)
QUIET = dict(noise_sigma=0.0, brightness_sigma=0.0, max_shift=0, samples_per_image=12)


def _capture_plan(params, n_images=3, seed=5, camera=1, position=2, level=0):
    bank = occluder_bank((0.0,), SHAPE, params, seed)
    return draw_plan(plan_rng(seed, camera, position, level), n_images, params, bank, level, SHAPE,
                     capture_rng(seed, camera, position, level))


def _augment(params, seed=5, camera=1, position=2):
    return augment_images(IMG, level=0, levels=(0.0,), params=params, seed=seed, camera=camera, position=position)


def test_capture_off_is_bit_exact_with_the_samples_before_it():
    # sha256 of the samples of the code before the capture transforms (commit 1c1325c), same seeds
    pins = {0: ("2d9057c9319ab13ce543c1766f7e053450b5f5d5ae41d260bfddfb86851c6bf8",
                "dd493585bde88d5307e760b29cdd3a721ad9fa8fa5cb16618c77889c0d6be401"),
            2: ("e5bbb10766c0177d195e8acc37b804377893f3ae82c0d040356ef36ac91351a5",
                "dce31a56870fed2baaa87e0be94091fdc03cd68b645fb9796e3cb6fa4fbdcf9e")}
    zero = AugmentParams(samples_per_image=20, max_rotation=0.0, max_scale=0.0, blur_sigma=(0.0, 0.0),
                         gain_amplitude=0.0, gain_cells=5)
    assert not zero.capture
    for k, (hy, hm) in pins.items():
        y, m = augment_images(IMG, level=k, levels=DB2_LEVELS, seed=5, camera=1, position=2, params=zero,
                              return_masks=True)
        assert hashlib.sha256(y.tobytes()).hexdigest() == hy
        assert hashlib.sha256(m.tobytes()).hexdigest() == hm
    plan = _capture_plan(zero)
    assert plan.rotation is None and plan.gain is None


def test_capture_draws_leave_the_other_draws_alone_and_are_independent_of_each_other():
    base = AugmentParams(samples_per_image=20)
    on = AugmentParams(samples_per_image=20, max_rotation=5.0, max_scale=0.1, blur_sigma=(0.5, 1.5),
                       gain_amplitude=0.2)
    a, b = _capture_plan(base), _capture_plan(on)
    for f in ("image", "dy", "dx", "template", "y0", "x0", "brightness"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
    rot_only = _capture_plan(AugmentParams(samples_per_image=20, max_rotation=5.0))
    np.testing.assert_array_equal(rot_only.rotation, b.rotation)  # blur / gain on or off: same angles
    assert np.all(rot_only.scale == 0) and np.all(rot_only.blur == 0) and np.all(rot_only.gain == 0)
    assert np.all(np.abs(b.rotation) <= 5.0) and np.ptp(b.rotation[:20]) > 5.0
    assert np.all(np.abs(b.scale) <= 0.1)
    assert np.all((b.blur >= 0.5) & (b.blur <= 1.5))
    assert b.gain.shape == (60, 3, 3) and np.all(np.abs(b.gain) <= 0.2)
    # shared draws: sample j of every image has the same transform
    np.testing.assert_array_equal(b.rotation[:20], b.rotation[20:40])
    np.testing.assert_array_equal(b.gain[:20], b.gain[40:])


def test_capture_seeded_and_order_independent():
    p = AugmentParams(**QUIET, max_rotation=4.0, max_scale=0.05, blur_sigma=(0.0, 1.0), gain_amplitude=0.1)
    first = {(c, v): _augment(p, camera=c, position=v) for c in (0, 1) for v in (0, 3)}
    again = {(c, v): _augment(p, camera=c, position=v) for c in (1, 0) for v in (3, 0)}  # other order
    for key in first:
        np.testing.assert_array_equal(first[key], again[key])
    assert not np.array_equal(first[0, 0], first[0, 3])
    assert not np.array_equal(first[0, 0], _augment(p, seed=6, camera=0, position=0))


def _rotation_matrix(angle_deg, scale, H, W):
    """Rotation by ``angle`` (counter-clockwise on screen) and scaling about the image centre, built by hand."""
    t = math.radians(angle_deg)
    a, b = scale * math.cos(t), scale * math.sin(t)
    cx, cy = (W - 1) / 2.0, (H - 1) / 2.0
    return np.array([[a, b, (1 - a) * cx - b * cy], [-b, a, b * cx + (1 - a) * cy]])


def test_rotation_and_scale_against_direct_warp():
    p = AugmentParams(**QUIET, max_rotation=6.0, max_scale=0.08)
    y = _augment(p).reshape(-1, *SHAPE)
    plan = _capture_plan(p)
    H, W = SHAPE
    for b in range(len(plan)):
        M = _rotation_matrix(plan.rotation[b], 1.0 + plan.scale[b], H, W)
        ref = cv2.warpAffine(IMG[plan.image[b]].astype(np.float32), M, (W, H), flags=cv2.INTER_LINEAR,
                             borderMode=cv2.BORDER_REPLICATE)
        np.testing.assert_array_equal(y[b], np.clip(np.round(ref), 0, 255).astype(np.uint8))
    # and the centre pixel stays put, a pixel off-centre moves along the rotation
    dot = np.zeros((1, 41, 41), np.uint8)
    dot[0, 20, 30] = 255
    q = AugmentParams(**QUIET, max_rotation=30.0)
    out = augment_images(dot, level=0, levels=(0.0,), params=q).astype(float)[0]
    angles = _capture_plan(q, n_images=1, seed=0, camera=0, position=0).rotation
    for s, ang in zip(out, angles):
        yy, xx = np.unravel_index(np.argmax(s), s.shape)
        t = math.radians(ang)  # positive angle: counter-clockwise with y down
        assert abs(xx - (20 + 10 * math.cos(t))) <= 1 and abs(yy - (20 - 10 * math.sin(t))) <= 1


def _gauss_blur_numpy(img, sigma):
    r = int(math.ceil(4 * sigma))
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    k /= k.sum()
    pad = np.pad(img.astype(np.float64), r, mode="edge")
    rows = sum(k[i] * pad[:, i: i + img.shape[1]] for i in range(2 * r + 1))[r:-r]
    return sum(k[i] * rows_i for i, rows_i in enumerate(
        np.pad(rows, ((r, r), (0, 0)), mode="edge")[i: i + img.shape[0]] for i in range(2 * r + 1)))


def test_blur_against_numpy_gaussian():
    p = AugmentParams(**QUIET, blur_sigma=(0.6, 1.8))
    y = _augment(p).reshape(-1, *SHAPE).astype(float)
    plan = _capture_plan(p)
    for b in range(len(plan)):
        ref = _gauss_blur_numpy(IMG[plan.image[b]], plan.blur[b])
        assert np.abs(y[b] - ref).max() <= 1.0  # OpenCV's kernel truncation + 8-bit rounding
        exact = cv2.GaussianBlur(IMG[plan.image[b]].astype(np.float32), (0, 0), plan.blur[b],
                                 borderType=cv2.BORDER_REPLICATE)
        np.testing.assert_array_equal(y[b], np.clip(np.round(exact), 0, 255))


def _bilinear_upsample_numpy(grid, H, W):
    """cv2.resize INTER_LINEAR (pixel centres aligned, edges clamped), in NumPy."""
    gh, gw = grid.shape
    sy = np.clip((np.arange(H) + 0.5) * gh / H - 0.5, 0, gh - 1)
    sx = np.clip((np.arange(W) + 0.5) * gw / W - 0.5, 0, gw - 1)
    y0, x0 = np.minimum(sy.astype(int), gh - 2), np.minimum(sx.astype(int), gw - 2)
    fy, fx = (sy - y0)[:, None], (sx - x0)[None, :]
    g = grid.astype(np.float64)
    return ((1 - fy) * (1 - fx) * g[y0][:, x0] + (1 - fy) * fx * g[y0][:, x0 + 1]
            + fy * (1 - fx) * g[y0 + 1][:, x0] + fy * fx * g[y0 + 1][:, x0 + 1])


def test_local_gain_against_numpy_bilinear_field():
    p = AugmentParams(**QUIET, gain_amplitude=0.25, gain_cells=4)
    y = _augment(p).reshape(-1, *SHAPE).astype(float)
    plan = _capture_plan(p)
    assert plan.gain.shape[1:] == (4, 4)
    for b in range(len(plan)):
        field = _bilinear_upsample_numpy(plan.gain[b], *SHAPE)
        assert np.abs(field).max() <= 0.25
        assert np.abs(np.diff(field, axis=1)).max() < 0.5 / (SHAPE[1] / 4) + 1e-9  # smooth
        ref = np.clip(IMG[plan.image[b]] * (1.0 + field), 0, 255)
        assert np.abs(y[b] - ref).max() <= 0.5 + 1e-3  # 8-bit rounding only


def test_capture_then_occluder_keeps_the_occluder_black():
    white = np.full((2, *SHAPE), 255, np.uint8)
    p = AugmentParams(samples_per_image=10, noise_sigma=0, brightness_sigma=0, max_shift=1,
                      max_rotation=5.0, blur_sigma=(0.5, 1.0), gain_amplitude=0.1)
    y, masks = augment_images(white, level=2, levels=DB2_LEVELS, params=p, return_masks=True)
    assert np.all(y[masks] == 0) and masks.any()


@pytest.mark.parametrize("kw,needle", [
    ({"max_rotation": -1.0}, "max_rotation"),
    ({"max_rotation": 200.0}, "max_rotation"),
    ({"max_scale": -0.1}, "max_scale"),
    ({"max_scale": 1.0}, "max_scale"),
    ({"gain_amplitude": -0.1}, "gain_amplitude"),
    ({"gain_amplitude": float("nan")}, "gain_amplitude"),
    ({"blur_sigma": (-1.0, 1.0)}, "blur_sigma"),
    ({"blur_sigma": (2.0, 1.0)}, "blur_sigma"),
    ({"gain_cells": 1}, "gain_cells"),
    ({"occluder_gray": (10.0, 5.0)}, "occluder_gray"),
    ({"occluder_gray": (0.0, 300.0)}, "occluder_gray"),
    ({"occluder_gray": (float("nan"), 5.0)}, "occluder_gray"),
])
def test_capture_parameter_validation(kw, needle):
    with pytest.raises(ValueError, match=needle):
        AugmentParams(**kw)


def test_draw_plan_needs_the_capture_generator():
    p = AugmentParams(max_rotation=1.0)
    bank = occluder_bank((0.0,), SHAPE, p, 0)
    with pytest.raises(ValueError, match="capture generator"):
        draw_plan(plan_rng(0, 0, 0, 0), 1, p, bank, 0, SHAPE)


# -- gray occluders ------------------------------------------------------------

@pytest.mark.parametrize("capture", [False, True])
def test_gray_occluders_paint_the_occluder_with_its_drawn_level(capture):
    """``occluder_gray = (lo, hi)``: every occluded pixel of sample b is its own
    v_b (rounded in the uint8 form; exactly v_b in the float form of the capture
    transforms), v_b spread over [lo, hi]; the pixels outside are untouched."""
    white = np.full((2, *SHAPE), 255, np.uint8)
    extra = dict(max_rotation=5.0) if capture else {}
    p = AugmentParams(samples_per_image=40, noise_sigma=0, brightness_sigma=0, max_shift=1,
                      occluder_gray=(60.0, 200.0), **extra)
    y, masks = augment_images(white, level=3, levels=DB2_LEVELS, params=p, return_masks=True, seed=4)
    y, masks = y.reshape(-1, *SHAPE), masks.reshape(-1, *SHAPE)          # one row per sample
    values = []
    for b in range(len(y)):
        occ = y[b][masks[b]]
        assert occ.size and np.ptp(occ) <= (1 if capture else 0)       # one level per sample
        values.append(float(np.median(occ)))
        if not capture:
            assert np.all(y[b][~masks[b]] == 255)
    values = np.array(values)
    assert values.min() >= 60 - 1 and values.max() <= 200 + 1 and np.ptp(values) > 70


def test_gray_occluders_leave_every_other_draw_alone():
    """Switching gray occluders on changes no shift, occluder, brightness or
    capture draw (it draws last from the capture generator), and off it is
    the black occluder, no extra field."""
    for extra in ({}, {"max_rotation": 3.0, "blur_sigma": (0.0, 1.0)}):
        base = AugmentParams(**extra)
        gray = AugmentParams(occluder_gray=(0.0, 255.0), **extra)
        bank = occluder_bank(DB2_LEVELS, SHAPE, base, 1)
        a = draw_plan(plan_rng(1, 0, 3, 2), 4, base, bank, 2, SHAPE, capture_rng(1, 0, 3, 2))
        b = draw_plan(plan_rng(1, 0, 3, 2), 4, gray, bank, 2, SHAPE, capture_rng(1, 0, 3, 2))
        assert a.occluder_value is None and b.occluder_value.shape == (len(b),)
        for f in ("image", "dy", "dx", "template", "y0", "x0", "brightness", "rotation", "scale", "blur", "gain"):
            va, vb = getattr(a, f), getattr(b, f)
            assert (va is None and vb is None) or np.array_equal(va, vb), f
    with pytest.raises(ValueError, match="capture generator"):
        draw_plan(plan_rng(0, 0, 0, 0), 1, gray, bank, 1, SHAPE)
