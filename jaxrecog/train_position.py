"""Training one camera position: its likelihood from streamed augmented
samples (:func:`fit_position`), and a camera's likelihood from its positions'
fits (:func:`stack_positions`).  :func:`jaxrecog.train.train_model` and
:func:`jaxrecog.train.add_objects` call them per position.

Speed: the projection is linear, so the expensive part per sample is one row
of a matmul of the (shifted, occluded) clean image ``z = m ⊙ S_d x`` with
``[V | 1]`` (features and pixel sum at once), done in float32 for a whole
batch.  The brightness offset ``b`` and the pixel noise ``n`` of the
augmentation model ``y = z + b·1 + n`` (:mod:`jaxrecog.augment`) are added in
feature space *exactly in distribution*: with ``u = z + b·1``,
``ρ = ||u - V Vᵀ u||`` and independent ``α ~ N(0, σ² I_K)``, ``β ~ N(0, σ²)``,
``γ ~ σ² χ²(D - K - 1)`` (the coordinates of ``n`` along ``V``, along the
residual of ``u`` and the squared rest)::

    Vᵀ y   = Vᵀ u + α
    ||y||² = ||u||² + 2 (Vᵀu · α + ρ β) + ||α||² + β² + γ
    g      = Vᵀ y / ||y|| - Vᵀ x̄                      (eq. 4.1-4.11)

This is the unclipped, unrounded pixel model; the 8-bit images of
:func:`~jaxrecog.augment.augment_images` differ only where ``y`` leaves
``[0, 255]`` and by rounding (variance 1/12 gray level²).  Level-0 samples
take ``Vᵀ z`` from a table of all ``(2s+1)²`` shifts of each image, unless
the capture transforms (rotation, scale, blur, local gain; off by default) are
on: then every sample's ``z`` is computed in pixel space, as at the occluded
levels.
"""

from __future__ import annotations

import jax
import numpy as np

from .augment import SamplePlan, ShiftWindows, apply_geometry, capture_rng, draw_plan, plan_rng
from .kernels import Likelihood
from .sensor_model import GaussianAccumulator

__all__ = ["fit_position", "stack_positions", "stack_arrays"]


def stack_positions(liks: list[Likelihood]) -> Likelihood:
    """One camera's likelihood from its per-position fits: the stored fields
    stacked (float32), and whatever the family derives from them computed on
    the stack, exactly as the model file's load does (``from_arrays``)."""
    names = type(liks[0]).field_shapes
    return type(liks[0]).from_arrays({f: stack_arrays(*(getattr(lik, f) for lik in liks)) for f in names})


def stack_arrays(*per_position):
    """``[V, ...]`` float32 JAX array of per-position float64 arrays (put on
    the device as it is: ``jnp.asarray`` of a NumPy array compiles a program
    per shape)."""
    return jax.device_put(np.stack(per_position).astype(np.float32))


def fit_position(images, mean, basis, lam, levels, params, bank, seed, camera, position, *,
                  family, var_floor, batch_size, options=None, holdout=0.0, labels=None, n_classes=None):
    """The ``family`` likelihood (``[C, L]`` components) of one camera position
    from streamed samples (``holdout > 0``: every ``round(1 / holdout)``-th
    sample of each (class, level) goes to ``fit``'s ``holdout`` instead).
    ``images`` ``[N, H, W]`` are the base images, of classes ``labels``
    (``None``: image ``c`` is class ``c``; view jitter appends more)."""
    N, H, W = images.shape
    C = N if n_classes is None else n_classes
    labels = np.arange(N) if labels is None else np.asarray(labels, np.int64)
    train_flat = images[:C]
    D, K = basis.shape
    s = params.max_shift
    sigma = float(params.noise_sigma)
    vaug = np.concatenate([basis, np.ones((D, 1))], axis=1).astype(np.float32)   # [D, K+1]
    vt1 = basis.sum(axis=0)                                                        # Vᵀ1 [K]
    vt_mean = mean @ basis                                                         # Vᵀx̄ [K]
    flat = train_flat.reshape(C, D).astype(np.float64)
    g_clean = (flat / np.linalg.norm(flat, axis=1, keepdims=True) - mean) @ basis  # [C, K]
    comp, M = _view_components(labels, C, camera, position) if family.view_components else (np.zeros(N, np.int64), 1)
    acc = GaussianAccumulator(C * M, len(levels), K, full=family.second_moments == "full",
                              ref=np.broadcast_to(np.repeat(g_clean, M, axis=0)[:, None, :], (C * M, len(levels), K)))

    win = ShiftWindows(images, s)
    # level 0: a table of Vᵀz, Σz, ||z||² over every shift of every image
    side = 2 * s + 1
    dy, dx = np.meshgrid(np.arange(-s, s + 1), np.arange(-s, s + 1), indexing="ij")
    z = side * side
    table_p = np.empty((N, z, K + 1), np.float64)
    for c0 in range(0, N, _TABLE_IMAGES):   # a few images' shifts per product (fewer, larger BLAS calls)
        cs = np.arange(c0, min(N, c0 + _TABLE_IMAGES))
        b = len(cs) * z
        plan = SamplePlan(np.repeat(cs, z), np.tile(dy.ravel(), len(cs)), np.tile(dx.ravel(), len(cs)),
                          np.full(b, -1), np.zeros(b, np.int64), np.zeros(b, np.int64), np.zeros(b))
        w = apply_geometry(win, plan, bank, 0, s).reshape(b, D).astype(np.float32)
        table_p[cs] = (w @ vaug).reshape(len(cs), z, K + 1)
    table_q = _shifted_energies(win, dy.ravel(), dx.ravel())

    buf = np.empty((batch_size, D), np.float32)
    period = max(2, round(1.0 / holdout)) if holdout > 0 else 0
    held: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    for k in range(len(levels)):
        seen = np.zeros(C, np.int64)  # samples of each class so far at this level
        rng = plan_rng(seed, camera, position, k)
        # a mixture may take its occluded jitter components from the training view's (view_mixture.py)
        n_img = N if not family.view_components or family.jitter_sampled(k, **(options or {})) else C
        plan = draw_plan(rng, n_img, params, bank, k, (H, W), capture_rng(seed, camera, position, k))
        B = len(plan)
        m = params.samples_per_image if params.shared_draws else B
        alpha = rng.standard_normal((m, K)) * sigma
        beta = rng.standard_normal(m) * sigma
        gamma = rng.chisquare(D - K - 1, size=m) * sigma**2 if sigma > 0 else np.zeros(m)
        if params.shared_draws:  # same noise draw j for every class (AugmentParams.shared_draws)
            alpha, beta, gamma = np.tile(alpha, (n_img, 1)), np.tile(beta, n_img), np.tile(gamma, n_img)
        for start in range(0, B, batch_size):
            sl = slice(start, min(start + batch_size, B))
            p = plan.take(sl)
            if bank.templates[k] or params.capture:
                w = buf[: len(p)]  # reused float32 buffer: no page faults per batch
                np.copyto(w, apply_geometry(win, p, bank, k, s).reshape(len(p), D),
                          casting="unsafe")
                pz = (w @ vaug).astype(np.float64)
                qz = np.einsum("bd,bd->b", w, w).astype(np.float64)
            else:
                idx = (p.dy + s) * side + (p.dx + s)
                pz = table_p[p.image, idx]
                qz = table_q[p.image, idx]
            g = _noisy_features(pz, qz, p.brightness, alpha[sl], beta[sl], gamma[sl],
                                vt1, vt_mean, D)
            cls_, sub = labels[p.image], comp[p.image]   # class, and component within it (0 but for a mixture)
            if period:
                first = np.eye(C, dtype=np.int64)[cls_]      # [b, C] one-hot
                rank = seen[cls_] + np.cumsum(first, axis=0)[np.arange(len(p)), cls_] - 1
                seen += first.sum(axis=0)
                out = rank % period == period - 1
                held.append((g[out], cls_[out], np.full(int(out.sum()), k)))
                g, cls_, sub = g[~out], cls_[~out], sub[~out]
            acc.add(g, cls_ * M + sub, k)
    floor = var_floor * lam.sum() / (K * C)
    if period:
        options = {**(options or {}), "holdout": tuple(np.concatenate(x) for x in zip(*held))}
    if family.view_components:  # moments per (class, component) -> [C, L, M, K]
        mean, second = acc.moments(allow_empty=True)   # NaN where fit derives a component
        per = lambda x: np.swapaxes(x.reshape((C, M) + x.shape[1:]), 1, 2)  # noqa: E731
        return family.fit(per(mean), per(second), np.full((C, len(levels)), floor), **(options or {}))
    return acc.fit(family, floor, **(options or {}))


_TABLE_IMAGES = 8   # images per product of the level-0 shift table


def _shifted_energies(win: ShiftWindows, dy: np.ndarray, dx: np.ndarray) -> np.ndarray:
    """``||S_d x_c||^2`` for every image ``c`` of ``win`` and shift ``d = (dy[j], dx[j])``,
    float64 ``[N, len(dy)]``: window sums of the squared edge-padded images, in
    integers (exact: the same numbers as summing the shifted images' squares in
    float64), from running sums along each row (int32: a row of ``W + 2s``
    squares of 8-bit values stays below 2^31), then down the columns of the few
    window starts (int64)."""
    s = win.max_shift
    H, W = win.view.shape[-2:]
    y0, x0 = s - dy, s - dx                       # the window of shift d starts at (s - dy, s - dx)
    sq = win.padded.astype(np.int32) ** 2                                         # [N, H+2s, W+2s]
    along = np.zeros(sq.shape[:2] + (sq.shape[2] + 1,), np.int32)
    np.cumsum(sq, axis=2, out=along[:, :, 1:])
    starts = np.unique(x0)
    rows = (along[:, :, starts + W] - along[:, :, starts]).astype(np.int64)      # [N, H+2s, |starts|]
    down = np.zeros((rows.shape[0], rows.shape[1] + 1, rows.shape[2]), np.int64)
    np.cumsum(rows, axis=1, out=down[:, 1:])
    col = np.searchsorted(starts, x0)
    return (down[:, y0 + H, col] - down[:, y0, col]).astype(np.float64)


def _view_components(labels, n_classes, camera, position):
    """Component of each base image for a ``view_components`` family: 0 for the
    training image of its class, then 1, 2, ... for that class's jitter images
    in database order; and ``M``.  Every class of the view needs the same
    number of jitter images (else a ``ValueError``)."""
    labels = np.asarray(labels, np.int64)
    comp = np.zeros(len(labels), np.int64)
    counts = np.zeros(n_classes, np.int64)
    for j in range(n_classes, len(labels)):
        counts[labels[j]] += 1
        comp[j] = counts[labels[j]]
    if counts.min() != counts.max():
        raise ValueError(f"view-mixture: camera {camera} position {position} has {counts.min()}..{counts.max()} "
                         f"jitter images per class; every class of a view needs the same number")
    return comp, int(counts[0]) + 1


def _noisy_features(pz, qz, b, alpha, beta, gamma, vt1, vt_mean, D):
    """Features of ``y = z + b·1 + n`` from ``[Vᵀz | Σz]``, ``||z||²`` and the noise
    coordinates (module docstring), float64 ``[B, K]``."""
    K = vt1.shape[0]
    vtu = pz[:, :K] + b[:, None] * vt1[None, :]
    uu = qz + 2.0 * b * pz[:, K] + b * b * D
    rho = np.sqrt(np.maximum(uu - np.einsum("bk,bk->b", vtu, vtu), 0.0))
    vty = vtu + alpha
    yy = uu + 2.0 * (np.einsum("bk,bk->b", vtu, alpha) + rho * beta) \
        + np.einsum("bk,bk->b", alpha, alpha) + beta * beta + gamma
    if np.any(~(yy > 0)):
        raise FloatingPointError("an augmented sample has zero energy")
    return vty / np.sqrt(yy)[:, None] - vt_mean[None, :]
