"""Eigenspace via the Gram matrix against numpy.linalg.svd of the full matrix."""

from __future__ import annotations

import numpy as np
import pytest
from builders import make_database

from jaxrecog.eigenspace import ComponentsError, Eigenspace, choose_n_components, position_eigenspace, unit_energy


def _full_svd(images):
    y = images.reshape(len(images), -1).astype(np.float64)
    xhat = y / np.linalg.norm(y, axis=1, keepdims=True)
    S = (xhat - xhat.mean(axis=0)).T                      # [D, C]
    U, s, _ = np.linalg.svd(S, full_matrices=False)
    return xhat.mean(axis=0), U, s**2


@pytest.mark.parametrize("seed", [0, 1])
def test_matches_full_svd(seed, rng):
    imgs = make_database(positions=(2,), n_objects=4, n_poses=2, seed=seed).train_images(0)[seed]
    imgs = np.clip(imgs.astype(int) + rng.integers(-5, 6, imgs.shape), 0, 255)
    es = position_eigenspace(imgs)
    mean, U, lam = _full_svd(imgs)
    r = es.rank
    assert r == len(imgs) - 1                             # centring removes one dimension
    np.testing.assert_allclose(es.mean, mean, atol=1e-12)
    np.testing.assert_allclose(es.eigenvalues, lam[:r], rtol=1e-9)
    np.testing.assert_allclose(es.basis.T @ es.basis, np.eye(r), atol=1e-10)
    for k in (1, 3, r):                                    # same subspaces, sign-free
        P1 = es.basis[:, :k] @ es.basis[:, :k].T
        P2 = U[:, :k] @ U[:, :k].T
        assert np.abs(P1 - P2).max() < 1e-8
    np.testing.assert_allclose(np.abs(es.basis.T @ U[:, :r]), np.eye(r), atol=1e-8)
    # sign convention: largest-magnitude entry of each vector is positive
    assert np.all(es.basis[np.argmax(np.abs(es.basis), axis=0), np.arange(r)] > 0)


def test_choose_by_count_and_energy():
    spectra = [np.array([5.0, 3.0, 1.0, 1.0]), np.array([9.0, 0.5, 0.4, 0.1])]
    assert choose_n_components(spectra, 3) == 3
    assert choose_n_components(spectra, 0.8) == 2          # 8/10 vs 9/10: max over positions
    assert choose_n_components(spectra, 0.9) == 3
    assert choose_n_components(spectra, 1.0) == 4
    with pytest.raises(ComponentsError, match="rank is 4") as e:
        choose_n_components(spectra, 5)
    assert (e.value.k, e.value.min_rank) == (5, 4)
    # at_most: K is an upper bound, the smallest rank where that is less
    assert choose_n_components(spectra, 5, at_most=True) == 4
    assert choose_n_components(spectra, 20, at_most=True) == 4
    assert choose_n_components(spectra, 3, at_most=True) == 3
    with pytest.raises(ValueError, match="at least 1"):
        choose_n_components(spectra, 0, at_most=True)
    with pytest.raises(ValueError, match="fraction"):
        choose_n_components(spectra, 1.5)


def test_unit_energy_rejects_black():
    imgs = np.ones((3, 4, 4))
    imgs[1] = 0
    with pytest.raises(ValueError, match="training image 1 has zero"):
        unit_energy(imgs)
    np.testing.assert_allclose(np.linalg.norm(unit_energy(np.ones((2, 4, 4)) * 7), axis=1), 1.0)


def test_truncate_forms_only_the_vectors_it_returns(rng):
    """Training keeps K of up to C - 1 vectors: ``truncate(k)`` forms those k
    alone (``O(D C k)``, not the ``O(D C²)`` of all of them), the same vectors
    as the full basis's first k up to round-off; the full basis is formed once
    on first use."""
    imgs = make_database(positions=(1,), n_objects=4, n_poses=3).train_images(0)[0]
    imgs = np.clip(imgs.astype(int) + rng.integers(-5, 6, imgs.shape), 0, 255)
    full = position_eigenspace(imgs).basis
    lazy = position_eigenspace(imgs)
    for k in (1, 4, lazy.rank):
        mean, basis, lam = lazy.truncate(k)
        assert basis.shape == (imgs[0].size, k) and lam.shape == (k,)
        np.testing.assert_allclose(basis, full[:, :k], rtol=0, atol=1e-12)
    assert lazy._basis is None                               # truncate formed no more than it returned
    assert lazy.basis is lazy.basis                          # formed once
    with pytest.raises(ValueError, match="give the basis"):
        Eigenspace(lazy.mean, None, lazy.eigenvalues)
