"""Type checks of settings from their annotations.

A settings file (an experiment TOML) gives any TOML type for any field; the
run-time type checker is off for users.  :func:`check_field_types` gives
the one-line ``TypeError``-free answer: a :class:`ValueError` ``"FIELD must
be WHAT, got VALUE"`` for the first field whose value does not fit its
annotation, before any value is used (a list for ``samples`` failed deep in
a campaign with ``'<=' not supported between instances of 'int' and
'list'``).  Annotations it does not know are not checked.
"""

from __future__ import annotations

import math
import os
from typing import Any, Callable, Mapping

import numpy as np

from .problems import one_line

__all__ = ["check_field_types", "check_settings"]


def _int(v) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))


def _number(v) -> bool:
    return (isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))
            and math.isfinite(v))


def _seq(n: int, *checks: Callable[[Any], bool]) -> Callable[[Any], bool]:
    def ok(v) -> bool:
        return isinstance(v, (tuple, list)) and len(v) == n and all(c(x) for c, x in zip(checks, v))
    return ok


def _options(v) -> bool:
    if isinstance(v, dict):
        return all(isinstance(k, str) for k in v)
    return isinstance(v, (tuple, list)) and all(
        isinstance(p, (tuple, list)) and len(p) == 2 and isinstance(p[0], str) for p in v)


#: annotation (as written) -> (check, what it must be)
_RULES: dict[str, tuple[Callable[[Any], bool], str]] = {
    "int": (_int, "an integer"),
    "float": (_number, "a finite number"),
    "float | None": (lambda v: v is None or _number(v), "a finite number (or left out)"),
    "int | None": (lambda v: v is None or _int(v), "an integer (or left out)"),
    "bool": (lambda v: isinstance(v, (bool, np.bool_)), "true or false"),
    "str": (lambda v: isinstance(v, str), "a string"),
    "str | None": (lambda v: v is None or isinstance(v, str), "a string (or left out)"),
    "Path | str": (lambda v: isinstance(v, (str, os.PathLike)), "a folder name"),
    "tuple[float, float, int]": (_seq(3, _number, _number, _int), "three numbers (the last an integer)"),
    "tuple[float, float] | list[float]": (_seq(2, _number, _number), "two numbers"),
    "tuple[float, float] | list[float] | float": (lambda v: _number(v) or _seq(2, _number, _number)(v),
                                                  "a number or two numbers"),
    "tuple[tuple[str, object], ...] | dict[str, object]": (_options, "a table of named options"),
}


def check_field_types(values: Mapping[str, Any], types: Mapping[str, str]) -> None:
    """Raise ``ValueError("FIELD must be WHAT, got VALUE")`` for the first
    setting of ``values`` (in ``types``' order) whose value does not fit its
    annotation ``types[name]`` (as written; one not in :data:`_RULES` is not checked)."""
    for name, annotation in types.items():
        rule = _RULES.get(annotation)
        if rule is None:
            continue
        check, what = rule
        v = values[name]
        if not check(v):
            raise ValueError(f"{name} must be {what}, got {one_line(repr(v), 80)}")


#: integer fields of :class:`jaxrecog.campaigns.Settings` and their smallest value
_AT_LEAST = {"samples": 1, "batch": 1, "n_components": 1, "min_per_stratum": 1, "max_steps": 1}


def check_settings(values: Mapping[str, Any], types: Mapping[str, str]) -> None:
    """:func:`check_field_types`, then the ranges of the
    :class:`~jaxrecog.campaigns.Settings` fields not checked elsewhere
    (counts >= 1, the seed, ``p_threshold``, ``transition``, ``capture_noise``;
    a field left ``None`` is not checked here).  ``values``: the settings by
    their flat names; ``types``: each one's annotation."""
    check_field_types(values, types)
    for name, lo in _AT_LEAST.items():
        v = values.get(name)
        if v is not None and v < lo:
            raise ValueError(f"{name} must be an integer >= {lo}, got {v!r}")
    seed = values.get("seed")
    if seed is not None and not 0 <= seed < 2**63:
        raise ValueError(f"seed must be an integer in 0..2**63-1, got {seed!r}")
    p = values.get("p_threshold")
    if p is not None and not 0.0 < p <= 1.0:
        raise ValueError(f"p_threshold must be a probability in (0, 1], got {p!r}")
    t = values.get("transition")
    if t is not None and t not in ("uniform", "sticky"):
        raise ValueError(f"transition must be 'uniform' or 'sticky', got {one_line(repr(t), 80)}")
    noise = values.get("capture_noise")
    if noise is not None and min(noise) < 0:
        raise ValueError(f"capture_noise (brightness, pixel sigma, max shift) must be >= 0, got {tuple(noise)!r}")
