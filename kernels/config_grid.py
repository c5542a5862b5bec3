"""The configuration grid: flat configuration index <-> one position per camera.

A configuration is one position index per camera, ``(v_0, ..., v_{n-1})``,
``0 <= v_i < V_i``.  Its flat index is row-major over ``V_0 x V_1 x ...``
(camera 0 slowest)::

    a = (...(v_0 V_1 + v_1) V_2 + ...) V_{n-1} + v_{n-1}

so the thesis's 32 x 7 grid has ``a = 7 v_0 + v_1``.  A per-configuration
array ``[A]`` is the flattened ``[V_0, ..., V_{n-1}]`` array of the cameras'
positions, and a per-camera array ``[V_i]`` reaches the grid by broadcasting
it along axis ``i``.  :class:`ConfigGrid` is the one place these conventions
are written (planners, recognizer, motion cost, environments, rigs use it).

Everything is integer arithmetic, reshapes and broadcasts, so one method
serves Python ints, NumPy arrays and traced JAX arrays (inside ``jit``); a
grid is a hashable static value.  This module is a leaf: it imports only
the standard library, NumPy and JAX.
"""

from __future__ import annotations

import math
import numbers

import jax.numpy as jnp
import numpy as np

__all__ = ["ConfigGrid", "position_rows"]


class ConfigGrid:
    """The row-major grid of configurations of cameras with ``positions``
    ``(V_0, ..., V_{n-1})`` positions each (any row-major grid of sizes, e.g.
    the strata ``(C, L_0, L_1, ...)`` of a lookahead).

    Attributes:
        positions: ``(V_0, ..., V_{n-1})``, Python ints >= 1.
    """

    __slots__ = ("positions",)

    def __init__(self, positions):
        sizes = tuple(int(n) for n in positions)
        if not sizes or any(n < 1 for n in sizes):
            raise ValueError(f"a configuration grid needs one size >= 1 per camera, got {tuple(positions)}")
        object.__setattr__(self, "positions", sizes)

    def __setattr__(self, name, value):
        raise AttributeError("a ConfigGrid is immutable")

    def __eq__(self, other):
        return isinstance(other, ConfigGrid) and other.positions == self.positions

    def __hash__(self):
        return hash((ConfigGrid, self.positions))

    def __repr__(self):
        return f"ConfigGrid({self.positions})"

    @property
    def n_cameras(self) -> int:
        """``n``, the number of cameras (grid axes)."""
        return len(self.positions)

    @property
    def size(self) -> int:
        """``A = V_0 V_1 ... V_{n-1}``, the number of configurations."""
        return math.prod(self.positions)

    def _check(self, configuration) -> None:
        cfg = tuple(int(v) for v in configuration)
        if len(cfg) != len(self.positions) or any(not 0 <= v < n for v, n in zip(cfg, self.positions)):
            raise ValueError(f"configuration {cfg} does not fit the positions {self.positions}")

    def index(self, configuration, clip: bool = False):
        """Per-camera positions -> flat configuration index (row-major, camera 0 slowest).

        Python ints and NumPy integers are range-checked (``ValueError``) and
        give an ``int``; an array ``[n]`` (or a tuple of arrays, one per
        camera, of one shape) gives the index array (traced under ``jit``; no
        check).  ``clip``: clamp each position into ``0 .. V_i - 1`` first
        (``jnp.ravel_multi_index(..., mode="clip")``), for a traced configuration.
        """
        concrete = all(isinstance(v, numbers.Integral) for v in configuration)
        if concrete:
            self._check(configuration)
        elif clip:
            configuration = [jnp.clip(configuration[i], 0, n - 1) for i, n in enumerate(self.positions)]
        a = 0
        for i, n in enumerate(self.positions):
            a = a * n + configuration[i]
        return int(a) if concrete else a

    def configuration(self, a):
        """Flat configuration index -> per-camera positions (row-major), the
        inverse of :meth:`index`.

        An ``int`` gives a tuple of ints (``ValueError`` outside ``0 .. A-1``);
        an integer array (NumPy, JAX, traced) gives a tuple of arrays of its
        shape, one per camera (no check)."""
        concrete = isinstance(a, numbers.Integral)
        if concrete:
            if not 0 <= int(a) < self.size:
                raise ValueError(f"configuration index {int(a)} is outside 0..{self.size - 1}")
            a = int(a)
        out = []
        for n in reversed(self.positions):
            out.append(a % n)
            a = a // n
        out.reverse()
        return tuple(int(v) for v in out) if concrete else tuple(out)

    def configurations(self) -> np.ndarray:
        """``int64 [A, n]``: every configuration, in flat-index order."""
        return np.stack(self.configuration(np.arange(self.size, dtype=np.int64)), axis=1)

    def expand(self, x, camera: int, axis: int = -1):
        """``x`` with its axis ``axis`` (camera ``camera``'s positions, or any
        per-camera size) put at grid slot ``camera``: shape ``x.shape[:axis] +
        (1,) * camera + (x.shape[axis],) + (1,) * (n - 1 - camera) +
        x.shape[axis + 1:]``, which broadcasts against the grid's
        ``[..., V_0, ..., V_{n-1}, ...]`` (no data moves: a reshape)."""
        n = self.n_cameras
        if not 0 <= camera < n:
            raise ValueError(f"camera {camera} is not one of the grid's {n}")
        axis = axis % x.ndim
        shape = x.shape[:axis] + (1,) * camera + (x.shape[axis],) + (1,) * (n - 1 - camera) + x.shape[axis + 1:]
        return x.reshape(shape)

    def combine(self, op, values, out):
        """``[..., A]``: ``out`` combined with every camera's ``values[i]``
        (``[..., V_i]``, leading axes broadcast) at that camera's position,
        camera 0 first: ``out = op(out, values[i][..., a_i])`` for i = 0, 1, ...

        ``out``: the start value, broadcastable to ``[..., V_0, ..., V_{n-1}]``
        (e.g. ``zeros(positions)``); ``op``: a binary elementwise function
        (``jnp.maximum``, ``operator.or_``, ...)."""
        if len(values) != self.n_cameras:
            raise ValueError(f"{len(values)} per-camera arrays for a grid of {self.n_cameras} cameras")
        for i, v in enumerate(values):
            if v.shape[-1] != self.positions[i]:
                raise ValueError(f"camera {i}'s array has {v.shape[-1]} positions, the grid {self.positions[i]}")
            out = op(out, self.expand(v, i))
        return self.flatten(out)

    def flatten(self, x):
        """``[..., V_0, ..., V_{n-1}] -> [..., A]`` (the grid's trailing axes, row-major)."""
        n = self.n_cameras
        if tuple(x.shape[x.ndim - n:]) != self.positions:
            raise ValueError(f"an array of shape {x.shape} does not end in the grid {self.positions}")
        return x.reshape(x.shape[:x.ndim - n] + (self.size,))

    def unflatten(self, x):
        """``[..., A] -> [..., V_0, ..., V_{n-1}]``, the inverse of :meth:`flatten`."""
        if x.shape[-1] != self.size:
            raise ValueError(f"an array of shape {x.shape} has no trailing axis of A = {self.size} configurations")
        return x.reshape(x.shape[:-1] + self.positions)


def position_rows(t, front: tuple[int, ...] = (1,)):
    """A camera's per-position table as rows of its (position, level) grid:
    ``t`` ``[V, C, L, ...]`` -> ``[*front axes, V * L, other axes]``, row
    ``x = v L + k`` (the row-major :class:`ConfigGrid` ``(V, L)``).

    ``front``: the axes of ``t`` (not 0 or 2) put first, in that order (the
    classes ``C = 1``, and e.g. the replicates ``J``); the remaining axes
    follow the rows in their order.  A transpose and a reshape (exact)."""
    front = tuple(int(a) for a in front)
    if 0 in front or 2 in front or len(set(front)) != len(front):
        raise ValueError(f"position_rows: front axes {front} must be distinct and leave axes 0 and 2")
    rest = tuple(a for a in range(3, t.ndim) if a not in front)
    order = front + (0, 2) + rest
    v, l = t.shape[0], t.shape[2]
    return jnp.transpose(t, order).reshape(tuple(t.shape[a] for a in front) + (v * l,) + tuple(t.shape[a] for a in rest))
