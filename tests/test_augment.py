"""Augmentation statistics: noise level, brightness, shift range, occluded
fraction per shape and level, reproducibility."""

from __future__ import annotations

import numpy as np
import pytest

from jaxrecog.augment import (
    DB2_LEVELS, SHAPES, AugmentParams, augment_images, levels_for, occluder_bank,
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
