"""The one check of a model's counts against a database's or a rig's.

Wherever a trained model meets the images it is to recognise (``recognize``
on any rig, a database campaign, the environments, a feature bank,
calibration), :func:`check_counts` compares what both sides know of

- the cameras and each camera's positions,
- the objects and the poses per object,
- the image size,

and raises one :class:`CountsMismatchError` whose one line names both sides
and every count that differs, e.g.::

    rig dataset:db does not match model m.npz: 4 poses vs the model's 2

A side that does not know a count (a hardware rig does not know how many
objects it will be shown) is not checked on it.  Without this, a 3 x 2 model
replayed on a 4-pose database answered "correct, P = 1.000" for the wrong
pose.
"""

from __future__ import annotations

from typing import Any, Iterable

__all__ = ["COUNTS", "CountsMismatchError", "counts_of", "check_counts"]

#: what :func:`check_counts` compares, in the order a message lists it
COUNTS = ("positions", "objects", "poses", "image")


class CountsMismatchError(ValueError):
    """A model and a database or rig disagree on their counts (one line)."""


def _maybe_int(x: Any) -> int | None:
    try:
        return int(x)
    except (TypeError, ValueError):
        return None


def counts_of(x: Any) -> dict[str, Any]:
    """What ``x`` (a sensor model, an image database or a rig) knows of
    :data:`COUNTS`: positions per camera (a tuple), objects, poses, the image
    size ``(H, W)``; a count ``x`` does not have is left out."""
    out: dict[str, Any] = {}
    pos = getattr(x, "positions", None)
    if pos is not None:
        out["positions"] = tuple(int(p) for p in pos)
    for key, attr in (("objects", "n_objects"), ("poses", "n_poses")):
        v = _maybe_int(getattr(x, attr, None))
        if v is not None:
            out[key] = v
    shape = getattr(x, "image_shape", None)
    if shape is not None:
        out["image"] = tuple(int(s) for s in shape)
    return out


def _show(key: str, v: Any) -> str:
    if key == "positions":
        return f"positions {v} per camera"
    if key == "image":
        return f"images {v[0]}x{v[1]}"
    return f"{v} {key}"


def _model_side(key: str, v: Any) -> str:
    if key == "positions":
        return str(v)
    if key == "image":
        return f"{v[0]}x{v[1]}"
    return str(v)


def check_counts(model, other, *, model_name: str | None = None, other_name: str | None = None,
                 only: Iterable[str] = COUNTS) -> None:
    """Raise :class:`CountsMismatchError` when ``other`` (an image database or
    a rig) cannot serve ``model``: any of ``only`` (default all of
    :data:`COUNTS`) that both know and that differ, listed in one line."""
    mine, theirs = counts_of(model), counts_of(other)
    diff = [k for k in COUNTS if k in set(only) and k in mine and k in theirs and mine[k] != theirs[k]]
    if not diff:
        return
    who = other_name or type(other).__name__
    model_txt = f"model {model_name}" if model_name else "the model"
    parts = [f"{_show(k, theirs[k])} vs the model's {_model_side(k, mine[k])}" for k in diff]
    raise CountsMismatchError(f"{who} does not match {model_txt}: " + "; ".join(parts))
