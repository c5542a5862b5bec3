"""Motion-cost-aware planning: score(a) − λ · (seconds to move to a).

A :class:`MotionCost` holds the per-camera travel-time tables of a rig
(:func:`jaxrecog.hardware.geometry.motion.camera_travel_times`: appendix-C kinematics,
PTU / gantry / track speeds) and the weight λ.  The recognizer applies it to
*any* planner's scores in its step (``Recognizer(..., motion=...)``), so every
planner of the registry becomes motion-aware without a change.

λ is in units of the planner's score per second: nats per second for the MI
planners (``mi``, ``mi-class``, the pairwise ones), units of the CRLB
criterion per second for ``crlb*``, and of a uniform(0, 1) draw per second for
``random`` (there any λ > 0 mostly picks the nearest configuration).  λ = 0
gives exactly the planner's own choice.  λ is an array leaf, not a static
setting: a campaign or a sweep that changes it reuses the compiled step.
"""

from __future__ import annotations

from typing import Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from .kernels.config_grid import ConfigGrid

__all__ = ["MotionCost", "check_weight", "rig_travel_times", "with_motion_cost"]


def check_weight(weight) -> float:
    """λ as a float; a ``ValueError`` unless it is a finite number >= 0."""
    try:
        w = float(weight)
    except (TypeError, ValueError):
        raise ValueError(f"motion cost λ must be a number >= 0 (score units per second), got {weight!r}") from None
    if not np.isfinite(w) or w < 0:
        raise ValueError(f"motion cost λ must be finite and >= 0 (score units per second, nats/s for MI), got {weight!r}")
    return w


class MotionCost(eqx.Module):
    """Per-camera travel times and the weight λ.

    Attributes:
        times: per camera ``[V_i, V_i]`` seconds from position ``v`` (row) to
            ``w`` (column).
        weight: λ >= 0, score units per second (a float32 scalar array, so a
            new value does not recompile the step).
    """

    times: tuple[Float[Array, "_V _V"], ...]
    weight: Float[Array, ""]

    def __init__(self, times: Sequence[Float[ArrayLike, "_V _V"]], weight: float = 0.0):
        ts = tuple(jnp.asarray(t, jnp.float32) for t in times)
        for i, t in enumerate(ts):
            if t.ndim != 2 or t.shape[0] != t.shape[1]:
                raise ValueError(f"travel times of camera {i} must be a square [V, V] table, got shape {t.shape}")
        self.times = ts
        self.weight = jnp.asarray(check_weight(weight), jnp.float32)

    @property
    def positions(self) -> tuple[int, ...]:
        return tuple(int(t.shape[0]) for t in self.times)

    def seconds(self, config: Int[Array, " n"]) -> Float[Array, " A"]:
        """``[A]``: seconds from ``config`` to every configuration, the
        slowest camera's time (they move in parallel)."""
        rows = [t[config[i]] for i, t in enumerate(self.times)]  # [V_i] from each camera's position
        return ConfigGrid(self.positions).combine(jnp.maximum, rows, jnp.zeros(self.positions, jnp.float32))

    def apply(self, scores: Float[Array, " A"], config: Int[Array, " n"]) -> Float[Array, " A"]:
        """``scores − λ · seconds(config)`` in the scores' dtype (non-finite
        scores stay as they are: −inf − x = −inf, NaN stays NaN)."""
        pen = self.weight.astype(scores.dtype) * self.seconds(config).astype(scores.dtype)
        return scores - pen

    def path_seconds(self, configurations: Sequence[Sequence[int]]) -> float:
        """Seconds to visit ``configurations`` in order (host side; the first costs nothing)."""
        from .hardware.geometry.motion import path_travel_s

        return path_travel_s([np.asarray(t) for t in self.times], configurations)


def with_motion_cost(recognizer, weight: float):
    """The recognizer with λ set to ``weight`` (same travel tables: the
    compiled step is reused).  It must already have a :class:`MotionCost`."""
    if recognizer.motion is None:
        raise ValueError("the recognizer has no travel-time tables (Recognizer(..., motion=MotionCost(...)))")
    w = jnp.asarray(check_weight(weight), jnp.float32)
    return eqx.tree_at(lambda r: r.motion.weight, recognizer, w)


def rig_travel_times(rig) -> tuple[np.ndarray, ...] | None:
    """Per-camera travel times of a rig that knows its geometry: a
    :class:`~jaxrecog.hardware.HardwareRig` (its rig file's table, mounts and
    ``[motion]`` speeds) or a synthetic rig (its table, the default mounts and
    speeds); ``None`` for a rig without one (a replayed database)."""
    from .hardware.geometry.motion import camera_travel_times

    config = getattr(rig, "config", None)
    if config is not None and hasattr(config, "travel_times"):
        return config.travel_times()
    table = getattr(rig, "table", None)
    if table is not None and hasattr(table, "views"):
        return camera_travel_times(table)
    return None
