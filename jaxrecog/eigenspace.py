"""One eigenspace per camera position (thesis §4.1, eq. 4.1-4.12).

The training images of one position (one per class, ``C`` of them) are scaled
to unit energy, ``x̂_i = y_i / ||y_i||`` (eq. 4.1-4.2), mean-adjusted,
``x_i = x̂_i - x̄`` (eq. 4.3-4.4), and arranged as ``S = [x_1 ... x_C]``
(``D x C``, eq. 4.5).  Instead of the ``D x D`` matrix ``Q = S Sᵀ`` (eq. 4.6) we
diagonalise the small Gram matrix ``T = Sᵀ S`` (``C x C``, eq. 4.7):
``T v'_i = λ'_i v'_i`` gives ``λ_i = λ'_i`` (eq. 4.9) and the unit eigenvector
``v_i = λ'_i^{-1/2} S v'_i`` of ``Q`` (eq. 4.10).  Eigenvalues are those of
``S Sᵀ`` (not divided by ``C``).  Each basis vector's sign is fixed so that its
entry of largest magnitude is positive.
"""

from __future__ import annotations

import numpy as np

__all__ = ["unit_energy", "Eigenspace", "position_eigenspace", "choose_n_components", "ComponentsError"]

# eigenvalues below this fraction of the largest count as zero (rank deficiency)
RANK_TOL = 1e-10


def unit_energy(images: np.ndarray) -> np.ndarray:
    """Eq. 4.1-4.2: ``x̂ = y / ||y||`` per row of ``images [N, D]`` (float64).

    Raises:
        ValueError: naming the row of an image with zero energy.
    """
    y = np.asarray(images, dtype=np.float64).reshape(len(images), -1)
    norm = np.linalg.norm(y, axis=1)
    bad = np.flatnonzero(~(norm > 0) | ~np.isfinite(norm))
    if bad.size:
        raise ValueError(f"training image {int(bad[0])} has zero or non-finite energy")
    return y / norm[:, None]


class Eigenspace:
    """Full eigen-decomposition of one position (all non-zero components).

    Attributes:
        mean: ``x̄ [D]`` (eq. 4.4).
        basis: ``[D, R]`` orthonormal eigenvectors of ``S Sᵀ`` (eq. 4.10),
            ``R`` = numerical rank (at most ``C - 1``), eigenvalues descending.
        eigenvalues: ``[R]`` (eq. 4.9, 4.12).

    An eigenspace from :func:`position_eigenspace` forms its basis (eq. 4.10)
    only when asked: :attr:`basis` forms all ``R`` vectors (once),
    :meth:`truncate` only the ``k`` it returns.  Forming ``R`` vectors costs
    ``O(D R²)`` (the re-orthonormalising QR), ``k`` of them ``O(D C k)``: a
    model keeps ``K`` of up to ``C - 1``, so training cost stays linear in the
    number of classes ``C`` there.
    """

    def __init__(self, mean: np.ndarray, basis: np.ndarray | None, eigenvalues: np.ndarray, *,
                 images: np.ndarray | None = None, gram_vectors: np.ndarray | None = None):
        if basis is None and (images is None or gram_vectors is None):
            raise ValueError("Eigenspace: give the basis, or the images and the Gram eigenvectors to form it")
        self.mean = mean
        self._basis = basis
        self.eigenvalues = eigenvalues
        self._images, self._gram_vectors = images, gram_vectors   # [C, ...] and [C, R]: what forms the basis

    @property
    def basis(self) -> np.ndarray:
        if self._basis is None:
            self._basis = self._form(self.rank)
            self._images = self._gram_vectors = None
        return self._basis

    @property
    def rank(self) -> int:
        return int(self.eigenvalues.shape[0])

    def truncate(self, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(mean [D], basis [D, k], eigenvalues [k])``."""
        if not 1 <= k <= self.rank:
            raise ValueError(f"n_components={k} but this position's eigenspace has rank {self.rank}")
        basis = self._basis[:, :k] if self._basis is not None else self._form(k)
        return self.mean, basis, self.eigenvalues[:k]

    def _form(self, k: int) -> np.ndarray:
        """The top ``k`` basis vectors ``v_i = λ_i^{-1/2} S v'_i`` (eq. 4.10),
        re-orthonormalised against round-off (they are orthonormal in exact
        arithmetic), each signed so that its largest-magnitude entry is positive."""
        S = (unit_energy(self._images) - self.mean).T   # [D, C]   eq. 4.3, 4.5 (the same numbers as before)
        lam = self.eigenvalues[:k]
        vp = self._gram_vectors if k == self._gram_vectors.shape[1] else self._gram_vectors[:, :k]
        V = (S @ vp) / np.sqrt(lam)                     # [D, k]   eq. 4.10
        V, _ = np.linalg.qr(V)
        idx = np.argmax(np.abs(V), axis=0)
        return V * np.sign(V[idx, np.arange(V.shape[1])])


def position_eigenspace(images: np.ndarray) -> Eigenspace:
    """Eigenspace of the training images ``[C, H, W]`` (or ``[C, D]``) of one
    camera position via the Gram matrix ``Sᵀ S`` (eq. 4.1-4.10), in float64;
    its basis is formed when first used (:class:`Eigenspace`), from ``images``
    kept by reference until then (do not change them in between)."""
    xhat = unit_energy(images)                      # [C, D]   eq. 4.1
    mean = xhat.mean(axis=0)                        # [D]      eq. 4.4
    S = (xhat - mean).T                             # [D, C]   eq. 4.3, 4.5
    T = S.T @ S                                     # [C, C]   eq. 4.7
    del xhat, S
    lam, vp = np.linalg.eigh(T)
    order = np.argsort(lam)[::-1]
    lam, vp = lam[order], vp[:, order]
    keep = lam > RANK_TOL * max(lam[0], np.finfo(np.float64).tiny)
    return Eigenspace(mean, None, lam[keep], images=images, gram_vectors=vp[:, keep])


class ComponentsError(ValueError):
    """K (``n_components``) above the smallest eigenspace rank: ``k`` and ``min_rank``."""

    def __init__(self, k: int, min_rank: int):
        super().__init__(f"n_components={k} but the smallest eigenspace rank is {min_rank} "
                         f"(at most one less than the number of training images per position)")
        self.k, self.min_rank = k, min_rank


def choose_n_components(spectra: list[np.ndarray], n_components: int | float, *, at_most: bool = False) -> int:
    """K shared by all positions.

    ``n_components`` an ``int``: that K (with ``at_most``: at most that K,
    ``min(n_components, smallest rank)``).  A ``float`` in ``(0, 1]``: the
    smallest K such that every position captures at least that fraction of its
    energy, ``sum_{i<=K} λ_i / sum_i λ_i``.  K never exceeds the smallest rank.

    Raises:
        ComponentsError: an int K larger than some position's rank (not with ``at_most``).
        ValueError: a K below 1, or a bad fraction.
    """
    min_rank = min(len(s) for s in spectra)
    if isinstance(n_components, (bool, np.bool_)):
        raise TypeError("n_components must be an int (K) or a float energy fraction")
    if isinstance(n_components, (int, np.integer)):
        k = int(n_components)
        if k < 1:
            raise ValueError(f"n_components={k}: K must be at least 1")
        if k > min_rank:
            if not at_most:
                raise ComponentsError(k, min_rank)
            k = min_rank
        return k
    frac = float(n_components)
    if not 0.0 < frac <= 1.0:
        raise ValueError(f"energy fraction must be in (0, 1], got {frac}")
    k = 1
    for lam in spectra:
        cum = np.cumsum(lam) / lam.sum()
        k = max(k, int(np.searchsorted(cum, frac - 1e-12) + 1))
    return min(k, min_rank)
