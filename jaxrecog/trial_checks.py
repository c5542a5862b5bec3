"""What a trial store's lines must say to be read back as this run's trials
(:class:`~jaxrecog.results.TrialStore`).

A campaign's store opens with a *header*: one JSON object naming what its
trials depend on (the settings, the model's and the data's digests, the
planner) and the limits every record must keep (:func:`store_header`).  A
store read for a run must have that run's header, so a store renamed from
another run (another threshold, another model, a database re-rendered in
place) is refused instead of being reported as this run's results.  Each
record is then checked against the limits (:func:`record_problem`): the
numbers a recognizer can produce (``1 <= steps <= max_steps``, an object and
pose of the model, a stop consistent with the stop rule, ``correct`` true
exactly when the prediction is the true object and pose).  A store is
refused as a whole, with one line naming the file and the line: its trials
are never merged with a run they do not belong to.
"""

from __future__ import annotations

import json
import math
from typing import Any, Mapping

__all__ = ["HEADER_KEY", "STORE_VERSION", "store_header", "is_header", "header_problem", "record_problem"]

#: The key that marks a store's header line, and its value: the version of the store format
HEADER_KEY = "jaxrecog_trials"
STORE_VERSION = 1
#: float32 beliefs against a float64 threshold: a probability may round this far to either side
_PROB_SLACK = 1e-6


def store_header(run: Mapping[str, Any], limits: Mapping[str, Any]) -> dict:
    """A store's header: ``run`` (what the trials depend on: settings,
    digests, planner; compared whole) and ``limits`` (what every record must
    keep: ``max_steps``, ``p_threshold``, ``min_views``, ``n_objects``,
    ``n_poses``, ``positions``, ``trials_per_object``), as JSON reads them back."""
    return json.loads(json.dumps({HEADER_KEY: STORE_VERSION, "run": dict(run), "limits": dict(limits)},
                                 sort_keys=True, default=str))


def is_header(obj: Any) -> bool:
    """Whether a store line's JSON value is a header (not a trial record)."""
    return isinstance(obj, dict) and HEADER_KEY in obj


def _flat(d: Any, prefix: str = "") -> dict[str, Any]:
    """``{"a.b": value}`` of a nested dict, for naming the first difference."""
    if not isinstance(d, dict):
        return {prefix: d}
    out: dict[str, Any] = {}
    for k, v in d.items():
        out.update(_flat(v, f"{prefix}.{k}" if prefix else str(k)))
    return out


def _show(v: Any) -> str:
    text = json.dumps(v)
    return text if len(text) <= 60 else text[:57] + "..."


def header_problem(found: Any, want: Mapping[str, Any]) -> str | None:
    """Why the header ``found`` is not this run's ``want`` (``None``: it is):
    the first differing entry, recorded against this run's."""
    if not is_header(found):
        return "is not a store header"
    if found.get(HEADER_KEY) != STORE_VERSION:
        return f"is a store of format {_show(found.get(HEADER_KEY))}, this jaxrecog reads {STORE_VERSION}"
    have, need = _flat({k: found.get(k) for k in ("run", "limits")}), _flat({k: want[k] for k in ("run", "limits")})
    for k in sorted(set(have) | set(need)):
        if have.get(k, None) != need.get(k, None):
            return (f"records {json.dumps(k)[1:-1][:80]} = {_show(have.get(k))}, this run has "
                    f"{_show(need.get(k))}: the trials of another run")
    return None


def _steps_problem(name: str, value: Any, steps: int) -> str | None:
    if value and len(value) != steps:
        return f"{name} has {len(value)} entries for {steps} steps"
    return None


def record_problem(raw: Mapping[str, Any], rec, limits: Mapping[str, Any] | None) -> str | None:
    """Why the record ``rec`` (a :class:`~jaxrecog.results.TrialResult`, read
    from the JSON object ``raw``) cannot be a trial of a run with these
    ``limits`` (``None``: a store without a header, checked for what holds
    in any run); ``None`` if it can."""
    if "correct" in raw and raw["correct"] is not rec.correct:
        return (f"correct = {_show(raw['correct'])}, but it predicted object {rec.predicted_object} pose "
                f"{rec.predicted_pose} for object {rec.object} pose {rec.pose}")
    if rec.steps < 1:
        return f"steps = {rec.steps}: every trial takes at least one image set"
    if rec.invalid_steps > rec.steps:
        return f"invalid_steps = {rec.invalid_steps} exceeds steps = {rec.steps}"
    for name in ("configurations", "occluded_fraction", "object_probs"):
        problem = _steps_problem(name, getattr(rec, name), rec.steps)
        if problem:
            return problem
    return None if limits is None else _limits_problem(rec, limits)


def _limits_problem(rec, limits: Mapping[str, Any]) -> str | None:
    """:func:`record_problem`'s checks against a run's limits."""
    max_steps, p_th, min_views = limits["max_steps"], limits["p_threshold"], limits["min_views"]
    n_objects, n_poses, positions = limits["n_objects"], limits["n_poses"], limits["positions"]
    per_object = limits["trials_per_object"]
    if rec.steps > max_steps:
        return f"steps = {rec.steps} exceeds max_steps = {max_steps}"
    for name, n in (("object", n_objects), ("predicted_object", n_objects), ("pose", n_poses),
                    ("predicted_pose", n_poses)):
        if getattr(rec, name) >= n:
            return f"{name} = {getattr(rec, name)}, but the model has {n}"
    if not rec.object * per_object <= rec.trial < (rec.object + 1) * per_object:
        return f"trial {rec.trial} is not one of object {rec.object}'s ({per_object} per object)"
    if rec.stopped and not rec.exit_prob >= p_th - _PROB_SLACK:
        return f"stopped on the threshold at exit_prob = {rec.exit_prob:.6g} < p_threshold = {p_th}"
    if rec.stopped and rec.steps < min(min_views, max_steps):
        return f"stopped after {rec.steps} image set(s), before min_views = {min_views}"
    if not rec.stopped and rec.steps != max_steps:
        return f"ended below the threshold after {rec.steps} of max_steps = {max_steps} image sets"
    if not rec.stopped and not rec.exit_prob < p_th + _PROB_SLACK:
        return f"exit_prob = {rec.exit_prob:.6g} reached p_threshold = {p_th} but the record says it did not stop"
    for step, config in enumerate(rec.configurations):
        if len(config) != len(positions) or not all(0 <= c < n for c, n in zip(config, positions)):
            return f"configuration {list(config)} of step {step + 1} is not one of positions {list(positions)}"
    for step, probs in enumerate(rec.object_probs):
        if len(probs) != n_objects:
            return f"object_probs of step {step + 1} has {len(probs)} entries for {n_objects} objects"
    if not (rec.travel_s != rec.travel_s or (math.isfinite(rec.travel_s) and rec.travel_s >= 0)):
        return f"travel_s = {rec.travel_s} is negative"
    return None
