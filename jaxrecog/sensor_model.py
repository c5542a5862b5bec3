"""The sensor model (thesis §4.2-4.3): eigenspaces plus one likelihood per camera.

For camera ``i``, position ``v``, class ``c = object * n_poses + pose`` and
occlusion level ``k`` the likelihood is ``p(g | c, k, v)``, a
:class:`~jaxrecog.kernels.Likelihood` of a registered kind (thesis: the
diagonal Gaussian ``N(g; mu[v, c, k], Σ[v, c, k])``, eq. 4.18-4.19, 4.22),
fitted by maximum likelihood (eq. 4.23-4.24) from the projected augmented
samples.  Fitting streams samples through sufficient statistics
(:class:`GaussianAccumulator`), so the samples are never all held; the family
turns the moments into its parameters (``Likelihood.fit``).
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import numpy as np
from jaxtyping import Array, Float

from . import kernels as K
from ._types import Bases, Cholesky, Eigenvalues, MeanImages, Means, Variances

__all__ = ["CameraModel", "SensorModel", "GaussianAccumulator", "model_problems"]

#: How far a basis vector's length may be from 1, and a mean image's norm
#: above 1, before a model counts as one that cannot explain a capture
BASIS_TOLERANCE = 1e-2
#: The largest feature mean a model may have: a capture's features are
#: bounded by 2 (``|Bᵀ (x̂ - x̄)| <= |x̂| + |x̄| <= 2`` for unit-energy ``x̂``)
MAX_FEATURE_MEAN = 10.0


class CameraModel(eqx.Module):
    """Eigenspaces and likelihood of one camera (arrays over its ``V`` positions).

    Attributes:
        mean_image: ``[V, D]`` mean of the unit-energy training images (eq. 4.4).
        basis: ``[V, D, K]`` orthonormal top-K eigenvectors (eq. 4.10).
        eigenvalues: ``[V, K]`` eigenvalues of ``S Sᵀ`` (eq. 4.9).
        likelihood: p(g | c, k, v), a :class:`~jaxrecog.kernels.Likelihood`
            over the ``V`` positions (thesis: the diagonal Gaussian, eq. 4.18-4.24).
        calibration: ``[V, L]`` variance inflation factors ``s`` already
            applied to the likelihood (``Likelihood.scaled``) by
            :func:`jaxrecog.calibration.apply_calibration`, kept so they can be
            reported; ``None`` = uncalibrated (all factors 1).

    A Gaussian from its arrays is ``likelihood=K.gaussian(mu, var[, chol])``;
    ``mu``, ``var`` and ``chol`` read a Gaussian's arrays back (``chol`` is
    ``None`` for a diagonal one).
    """

    mean_image: MeanImages
    basis: Bases
    eigenvalues: Eigenvalues
    likelihood: K.Likelihood
    calibration: Float[Array, "V L"] | None = None

    @property
    def n_positions(self) -> int:
        return int(self.basis.shape[0])

    @property
    def n_components(self) -> int:
        return int(self.basis.shape[2])

    @property
    def mu(self) -> Means:
        """A Gaussian likelihood's means."""
        return self.likelihood.mu

    @property
    def var(self) -> Variances:
        """A Gaussian likelihood's variances (diagonal of the covariance)."""
        return self.likelihood.var

    @property
    def chol(self) -> Cholesky | None:
        """A full-covariance Gaussian's Cholesky factors (``None`` otherwise)."""
        return getattr(self.likelihood, "chol", None)


class SensorModel(eqx.Module):
    """The trained model: one :class:`CameraModel` per camera plus static sizes.

    ``SensorModel(cameras, n_objects, n_poses, levels, image_shape[, covariance], stability=None)``:
    the optional last positional argument (the older name of the likelihood
    kind, e.g. ``"diag"``) is checked against the cameras' likelihoods, not
    stored.  ``stability``: the weight of ``mi-class-pairwise-stable``'s
    instability term fitted on held-out captures
    (:func:`jaxrecog.stability_fit.fit_stability`); ``None``: not fitted (the
    planner's default, 1).
    """

    cameras: tuple[CameraModel, ...]
    n_objects: int = eqx.field(static=True)
    n_poses: int = eqx.field(static=True)
    levels: tuple[float, ...] = eqx.field(static=True)
    image_shape: tuple[int, int] = eqx.field(static=True)
    stability: float | None = eqx.field(static=True, default=None)

    def __init__(self, cameras, n_objects, n_poses, levels, image_shape, covariance: str | None = None, *,
                 stability: float | None = None):
        self.cameras = tuple(cameras)
        self.n_objects = n_objects
        self.n_poses = n_poses
        self.levels = levels
        self.image_shape = image_shape
        if stability is not None and (isinstance(stability, bool) or not isinstance(stability, (int, float))
                                      or not 0.0 <= float(stability) < float("inf")):
            raise ValueError(f"SensorModel: stability must be a finite number >= 0 or None, got {stability!r}")
        self.stability = None if stability is None else float(stability)
        for i, cam in enumerate(self.cameras):
            if covariance is not None and cam.likelihood.kind != covariance:
                raise ValueError(f"SensorModel: covariance {covariance!r}, but camera {i} has a "
                                 f"{cam.likelihood.kind!r} likelihood")

    @property
    def n_cameras(self) -> int:
        return len(self.cameras)

    @property
    def positions(self) -> tuple[int, ...]:
        return tuple(c.n_positions for c in self.cameras)

    @property
    def n_classes(self) -> int:
        return self.n_objects * self.n_poses

    @property
    def n_levels(self) -> int:
        return len(self.levels)

    @property
    def n_components(self) -> int:
        return self.cameras[0].n_components

    @property
    def likelihoods(self) -> tuple[K.Likelihood, ...]:
        """One likelihood per camera: what the kernels take."""
        return tuple(c.likelihood for c in self.cameras)

    @property
    def likelihood_kinds(self) -> tuple[str, ...]:
        return tuple(lik.kind for lik in self.likelihoods)

    @property
    def covariance(self) -> str:
        """The cameras' common likelihood kind (``"mixed"`` if they differ); the
        older name, from when the kind was the Gaussian's covariance form."""
        kinds = set(self.likelihood_kinds)
        return kinds.pop() if len(kinds) == 1 else "mixed"

    def camera_stats(self) -> list[dict[str, Any]]:
        """Per camera: ``eigenspaces`` (its positions), ``eigenvalue_sum`` and
        ``feature_sd`` (``(min, max)`` over its positions of the eigenvalues'
        sum, and of the likelihood's feature standard deviations): what
        :meth:`summary` prints (``jaxrecog inspect --json``)."""
        out = []
        for cam in self.cameras:
            energy = np.asarray(cam.eigenvalues).sum(axis=1)
            sd = np.sqrt(np.asarray(jax.vmap(lambda lik: lik.variance())(cam.likelihood)))
            out.append({"eigenspaces": int(cam.n_positions),
                        "eigenvalue_sum": (float(energy.min()), float(energy.max())),
                        "feature_sd": (float(sd.min()), float(sd.max()))})
        return out

    def summary(self) -> str:
        """A few human-readable lines: sizes, levels and feature statistics."""
        H, W = self.image_shape
        # the families name themselves (Likelihood.summary_words); cameras of
        # families that name themselves differently get the generic words
        words = {type(lik).summary_words for lik in self.likelihoods}
        label, plural = words.pop() if len(words) == 1 else K.Likelihood.summary_words
        lines = [
            f"SensorModel: {self.n_cameras} camera(s), positions {self.positions}, "
            f"{self.n_objects} objects x {self.n_poses} poses = {self.n_classes} classes",
            f"  images {H}x{W} (D={H * W}), K={self.n_components} components, "
            f"{self.n_levels} occlusion level(s) {tuple(round(x, 2) for x in self.levels)}, "
            f"{label} {self.covariance}",
        ]
        for i, st in enumerate(self.camera_stats()):
            lines.append(
                f"  camera {i}: {st['eigenspaces']} eigenspaces, eigenvalue sum "
                f"{st['eigenvalue_sum'][0]:.3g}..{st['eigenvalue_sum'][1]:.3g}, feature sd "
                f"{st['feature_sd'][0]:.3g}..{st['feature_sd'][1]:.3g}"
            )
        for i, cam in enumerate(self.cameras):
            if cam.calibration is not None:
                f = np.asarray(cam.calibration)
                lines.append(
                    f"  camera {i} calibration: variance factors {f.min():.3g}..{f.max():.3g} "
                    f"(median {np.median(f):.3g}) over {f.shape[0]} positions x {f.shape[1]} level(s)"
                )
        n_comp = sum(c.n_positions for c in self.cameras) * self.n_classes * self.n_levels
        lines.append(f"  {n_comp} {plural} (positions x classes x levels)")
        return "\n".join(lines)


def model_problems(model: "SensorModel") -> list[str]:
    """What makes ``model`` unable to explain any capture, one line each
    (``[]``: none), checked where a model comes from a file
    (:func:`jaxrecog.modelfile.load_model`): a file can hold finite arrays
    (and a valid checksum) with which every capture's features overflow or
    lie far from every class, and every trial would end at a uniform belief.

    Per camera and position: the basis vectors of unit length (eq. 4.10,
    within ``BASIS_TOLERANCE``), the mean image no longer than 1 (the mean of
    unit-energy images, eq. 4.4), the feature means within
    ``MAX_FEATURE_MEAN`` (features are bounded by 2) and the feature
    variances finite and positive."""
    out = []
    with np.errstate(all="ignore"):
        for i, cam in enumerate(model.cameras):
            # each basis vector's length (no matrix product: a BLAS call on a busy machine took seconds)
            norms = np.sqrt(np.einsum("vdk,vdk->vk", np.asarray(cam.basis), np.asarray(cam.basis)))
            off = np.abs(norms.astype(np.float64) - 1.0)
            if not np.all(off <= BASIS_TOLERANCE):
                v, k = np.unravel_index(np.argmax(np.where(np.isnan(off), np.inf, off)), off.shape)
                out.append(f"camera{i}.basis at position {v} is not orthonormal (vector {k} has length "
                           f"{float(norms[v, k]):.3g}, not 1): no capture's features would be comparable with "
                           "the classes'")
            norms = np.linalg.norm(np.asarray(cam.mean_image, np.float64), axis=-1)
            if not np.all(norms <= 1.0 + BASIS_TOLERANCE):
                out.append(f"camera{i}.mean_image has norm {float(np.nanmax(norms)):.3g} > 1 (a mean of "
                           "unit-energy images)")
            mu = getattr(cam.likelihood, "mu", None)
            if mu is not None and not np.all(np.abs(np.asarray(mu)) <= MAX_FEATURE_MEAN):
                out.append(f"camera{i}.mu reaches {float(np.nanmax(np.abs(np.asarray(mu)))):.3g} (a capture's "
                           f"features are at most 2, means beyond {MAX_FEATURE_MEAN:g} explain none)")
            var = np.asarray(jax.vmap(lambda lik: lik.variance())(cam.likelihood), np.float64)
            if not np.all(np.isfinite(var) & (var > 0)):
                out.append(f"camera{i}: feature variances must be finite and > 0 (smallest {float(np.min(var)):.3g},"
                           f" largest {float(np.max(var)):.3g})")
    return out


class GaussianAccumulator:
    """Streaming sufficient statistics of ``[C, L]`` Gaussians in ``K`` dims.

    Samples are added in batches; each is stored relative to a per-(class,
    level) reference point ``ref`` (e.g. the clean image's features) to avoid
    cancellation, in float64: count ``n``, ``Σ(g - ref)`` and ``Σ(g - ref)²``
    (diag) or ``Σ(g - ref)(g - ref)ᵀ`` (full).
    """

    def __init__(self, n_classes: int, n_levels: int, k: int, *, full: bool = False,
                 ref: np.ndarray | None = None):
        self.full = full
        self.ref = np.zeros((n_classes, n_levels, k)) if ref is None else \
            np.asarray(ref, np.float64).reshape(n_classes, n_levels, k)
        self.n = np.zeros((n_classes, n_levels))
        self.s1 = np.zeros((n_classes, n_levels, k))
        self.s2 = np.zeros((n_classes, n_levels, k, k) if full else (n_classes, n_levels, k))

    def add(self, g: np.ndarray, classes: np.ndarray, level: int | np.ndarray) -> None:
        """Add samples ``g [B, K]`` of classes ``[B]`` at level(s) ``level``."""
        g = np.asarray(g, np.float64)
        classes = np.asarray(classes)
        lev = np.broadcast_to(np.asarray(level), classes.shape)
        if g.shape[0] == 0:
            return
        # group by (class, level): sort, then sum contiguous segments
        key = classes * self.n.shape[1] + lev
        order = np.argsort(key, kind="stable")
        key, g, classes, lev = key[order], g[order], classes[order], lev[order]
        starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
        d = g - self.ref[classes, lev]
        c, l = classes[starts], lev[starts]
        self.n[c, l] += np.diff(np.r_[starts, len(key)])
        self.s1[c, l] += np.add.reduceat(d, starts, axis=0)
        sq = d[:, :, None] * d[:, None, :] if self.full else d * d
        self.s2[c, l] += np.add.reduceat(sq, starts, axis=0)

    def moments(self, *, allow_empty: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """ML moments (divisor ``n``): means ``[C, L, K]`` and variances ``[C, L, K]``
        (diag) or symmetrised covariances ``[C, L, K, K]`` (full).  With
        ``allow_empty`` a (class, level) without samples gets NaN moments."""
        empty = self.n == 0 if allow_empty else np.zeros(self.n.shape, bool)
        if np.any((self.n < 2) & ~empty):
            raise ValueError("every (class, level) needs at least two samples")
        n = np.where(empty, np.nan, self.n)[..., None]
        m = self.s1 / n
        mu = self.ref + m
        if not self.full:
            return mu, self.s2 / n - m * m
        cov = self.s2 / n[..., None] - m[..., :, None] * m[..., None, :]
        return mu, 0.5 * (cov + np.swapaxes(cov, -1, -2))

    def fit(self, family: type[K.Likelihood], var_floor: float | np.ndarray = 0.0, **options) -> K.Likelihood:
        """One position's likelihood of ``family`` (eq. 4.23-4.24) from the moments;
        ``var_floor`` (scalar or per class/level ``[C, L]``) keeps every component proper;
        ``options`` go to ``family.fit`` (its ``fit_options``, and ``holdout``)."""
        want = "full" if self.full else "diag"
        if family.second_moments != want:
            raise ValueError(f"the {family.kind!r} likelihood needs {family.second_moments!r} second moments, "
                             f"this accumulator holds {want!r}")
        floor = np.broadcast_to(np.asarray(var_floor, np.float64), self.n.shape)
        return family.fit(*self.moments(), floor, **options)

    def finalize(self, var_floor: float | np.ndarray = 0.0):
        """ML Gaussians (eq. 4.23-4.24): ``(mu, var, chol)`` of :meth:`fit` with the
        diagonal (``chol = None``) or full Gaussian: diagonal ``var = max(var_ML,
        floor)``; full ``Σ = Σ_ML + floor·I``, ``chol = cholesky(Σ)``, ``var = diag(Σ)``.
        """
        lik = self.fit(K.FullGaussian if self.full else K.DiagonalGaussian, var_floor)
        return lik.mu, lik.var, getattr(lik, "chol", None)
