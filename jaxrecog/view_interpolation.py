"""Views between the training views: neighbouring positions and the images
interpolated between them.

A capture is never exactly at a training view.  Murase & Nayar's parametric
eigenspace (1995) models the appearance between neighbouring views by
interpolating the appearance manifold; here the images between a training
view and each neighbouring position's training view of the same class are
synthesised and become extra components of a view mixture
(``train_model(interpolate=N)``, :mod:`jaxrecog.kernels.view_mixture`): the
segment from the training view to halfway to the next, ``N`` points a side.

Two interpolations (``interpolation=``):

``"linear"``
    ``x(t) = (1 - t) x_a + t x_b``: the straight segment in image space.  Its
    eigenspace projection is the straight segment between the two views'
    projections (before the norm of eq. 4.3); a cross-fade, so an object that
    moved between the views shows twice, faintly.
``"flow"``
    motion-compensated: the dense optical flow ``f_ab`` from ``x_a`` to
    ``x_b`` and ``f_ba`` back (Farnebäck, OpenCV), each view warped part of
    the way and the two blended,
    ``x(t) = (1 - t) x_a(p - t f_ab(p)) + t x_b(p - (1 - t) f_ba(p))``,
    so an edge that moves across the image between the views is drawn once,
    where it is at ``t`` (the standard view-morphing approximation: the
    flow at the target pixel stands for the flow at its source).
"""

from __future__ import annotations

import numpy as np

__all__ = ["INTERPOLATIONS", "view_neighbours", "interpolated_views", "morph"]

INTERPOLATIONS = ("linear", "flow")

#: Farnebäck parameters: pyramid scale, levels, window, iterations, poly_n, poly_sigma (OpenCV's
#: documented typical values for poly_n 5; not tuned on any test view)
_FLOW = (0.5, 3, 9, 3, 5, 1.1)


def view_neighbours(train: np.ndarray) -> list[tuple[int, int]]:
    """The neighbouring positions of each position of one camera, for
    interpolation: ``[(left, right)] * V`` (a position index, or ``-1`` where
    there is none).

    Candidates are the index neighbours ``v - 1`` and ``v + 1`` (the last and
    the first position too: a turntable is a ring).  With ``S[v, v']`` the
    mean over classes of the cosine between a class's training images at
    ``v`` and ``v'``, a candidate pair counts as neighbouring views when it is
    at least as similar as the median other position of each of the two:
    along a path of views the object changes less between neighbours than
    between most other pairs.  (Not "the nearest": many objects look alike
    from opposite sides, so the view 180° away is often nearer than the
    next one on a 30° grid.)  Positions not ordered along a path find no
    neighbours, and their interpolated slots repeat the training view.

    Args:
        train: ``uint8 [V, C, H, W]`` the camera's training images.
    """
    V, C = train.shape[:2]
    if V < 2:
        return [(-1, -1)] * V
    x = train.reshape(V, C, -1).astype(np.float64)
    x /= np.maximum(np.linalg.norm(x, axis=2, keepdims=True), 1e-12)
    S = np.einsum("vcd,wcd->vw", x, x) / C                         # mean cosine of a class's two views
    typical = np.array([np.median(np.delete(S[v], v)) for v in range(V)])

    def adjacent(a: int, b: int) -> bool:
        return bool(a != b and S[a, b] >= max(typical[a], typical[b]))

    right = [adjacent(v, (v + 1) % V) and (v + 1 < V or V > 2) for v in range(V)]
    return [((v - 1) % V if right[(v - 1) % V] else -1, (v + 1) % V if right[v] else -1) for v in range(V)]


def flow_pair(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The dense optical flows ``a -> b`` and ``b -> a`` (Farnebäck), ``float32 [H, W, 2]`` each."""
    import cv2  # imported on first use: `import jaxrecog` does not load OpenCV
    return (cv2.calcOpticalFlowFarneback(a, b, None, *_FLOW, 0),
            cv2.calcOpticalFlowFarneback(b, a, None, *_FLOW, 0))


def morph(a: np.ndarray, b: np.ndarray, ts, interpolation: str = "linear", flows=None) -> np.ndarray:
    """The images ``t`` of the way from ``a`` to ``b`` (module doc), ``uint8 [len(ts), H, W]``.

    Args:
        a, b: ``uint8 [H, W]`` the two views.
        ts: fractions in [0, 1].
        interpolation: ``"linear"`` or ``"flow"``.
        flows: ``"flow"`` only: :func:`flow_pair` ``(a, b)`` when already
            computed (the way back from ``b`` to ``a`` uses the same two).
    """
    import cv2  # imported on first use: `import jaxrecog` does not load OpenCV
    if interpolation not in INTERPOLATIONS:
        raise ValueError(f"interpolation must be one of {', '.join(INTERPOLATIONS)}, got {interpolation!r}")
    fa, fb = a.astype(np.float64), b.astype(np.float64)
    out = []
    if interpolation == "flow":
        f_ab, f_ba = flow_pair(a, b) if flows is None else flows
        H, W = a.shape
        y, x = np.mgrid[:H, :W].astype(np.float32)
    for t in ts:
        t = float(t)
        if interpolation == "flow":
            wa = cv2.remap(a, x - t * f_ab[..., 0], y - t * f_ab[..., 1], cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_REPLICATE).astype(np.float64)
            wb = cv2.remap(b, x - (1 - t) * f_ba[..., 0], y - (1 - t) * f_ba[..., 1], cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_REPLICATE).astype(np.float64)
            out.append((1.0 - t) * wa + t * wb)
        else:
            out.append((1.0 - t) * fa + t * fb)
    return np.clip(np.rint(np.stack(out)), 0, 255).astype(np.uint8)


def interpolated_views(train: np.ndarray, neighbours: list[tuple[int, int]], n: int,
                       interpolation: str = "linear") -> list[tuple[np.ndarray, np.ndarray]]:
    """Images between each training view and its neighbours, as jitter
    images: per position ``v``, ``(uint8 [C * 2n, H, W], class int [C * 2n])``.

    For class ``c`` and side ``s`` (left, right) with neighbour ``v_s`` the
    images are :func:`morph` of ``x[v, c]`` toward ``x[v_s, c]`` at
    ``t_j = j / (2 n)``, ``j = 1..n``: from the training view to halfway to
    the next (a view ``t`` of the way is modelled by the component at ``t``).
    With ``"linear"`` the eigenspace projection of a blend is the blend of the
    projections (before the norm of eq. 4.3).  A side without a neighbour
    repeats the other side (or the training view itself), so every position
    has ``2 n`` of them per class and the mixture one ``M``.

    Args:
        train: ``uint8 [V, C, H, W]`` one camera's training images.
        neighbours: :func:`view_neighbours` of ``train``.
        n: points per side (>= 1).
        interpolation: ``"linear"`` or ``"flow"`` (module doc).
    """
    V, C = train.shape[:2]
    ts = np.arange(1, n + 1) / (2.0 * n)
    out = []
    flows: dict[tuple[int, int, int], tuple[np.ndarray, np.ndarray]] = {}   # (v, s, c) -> flow_pair

    def pair(v: int, s: int, c: int):
        if interpolation != "flow":
            return None
        if (s, v, c) in flows:                 # the way back: the same two flows, swapped (each used twice)
            f_sv, f_vs = flows.pop((s, v, c))
            return f_vs, f_sv
        flows[(v, s, c)] = flow_pair(train[v, c], train[s, c])
        return flows[(v, s, c)]

    for v in range(V):
        left, right = neighbours[v]
        sides = [s for s in (left, right) if s >= 0] or [v]
        sides = (sides * 2)[:2]
        imgs, cls = [], []
        for c in range(C):
            for s in sides:
                imgs.append(morph(train[v, c], train[s, c], ts, interpolation, flows=pair(v, s, c)) if s != v
                            else np.repeat(train[v, c][None], n, axis=0))
                cls += [c] * n
        out.append((np.concatenate(imgs), np.asarray(cls, np.int64)))
    return out
