"""Per-trial campaign records, a resumable JSON-lines store, and the
thesis-shaped results table (per object: recognition rate, mean exit
probability, mean number of views; plus the average)."""

from __future__ import annotations

import dataclasses
import json
import math
import os
from pathlib import Path
from typing import Any, Iterable, Sequence

from . import trial_checks

__all__ = ["TrialResult", "TrialStore", "ObjectRow", "wilson_interval", "summarize", "table_markdown",
           "table_json", "format_rate"]

#: the confidence of every interval printed with a rate
CONFIDENCE = 0.95


def wilson_interval(successes: int, trials: int, confidence: float = CONFIDENCE) -> tuple[float, float]:
    """The Wilson score interval of a binomial proportion, as fractions in [0, 1].

    With ``p = k/n`` and ``z`` the two-sided normal quantile of ``confidence``
    (1.96 for 95 %): centre ``(p + z²/2n) / (1 + z²/n)``, half-width
    ``z/(1 + z²/n) · sqrt(p(1-p)/n + z²/4n²)``.  Unlike ``p ± z·se`` it stays
    in [0, 1] and is not empty at ``k = 0`` or ``k = n`` (20 of 20 correct:
    [83.9, 100] %).  ``(nan, nan)`` for ``n = 0``.

    Raises:
        ValueError: ``successes`` not in ``0..trials`` or ``confidence`` not in (0, 1).
    """
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    if trials < 0 or not 0 <= successes <= trials:
        raise ValueError(f"successes must be in 0..trials, got {successes} of {trials}")
    if trials == 0:
        return math.nan, math.nan
    from statistics import NormalDist

    z = NormalDist().inv_cdf(0.5 + confidence / 2)
    n, p = float(trials), successes / trials
    denom = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z / denom * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    lo = 0.0 if successes == 0 else max(0.0, centre - half)
    hi = 1.0 if successes == trials else min(1.0, centre + half)
    return lo, hi


def _pct_interval(successes: int, trials: int) -> tuple[float, float]:
    lo, hi = wilson_interval(successes, trials)
    return 100.0 * lo, 100.0 * hi


def format_rate(rate: float, interval: Sequence[float], digits: int = 1) -> str:
    """``"95.0 [86.5, 98.3]"``: a percentage and its 95 % interval (an em dash for NaN)."""
    if rate != rate:
        return "\u2014"
    lo, hi = interval
    if lo != lo:
        return f"{rate:.{digits}f}"
    return f"{rate:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"


@dataclasses.dataclass(frozen=True)
class TrialResult:
    """One recognition trial.  ``steps`` = number of image sets taken."""

    trial: int
    object: int
    pose: int
    predicted_object: int
    predicted_pose: int
    exit_prob: float
    steps: int
    stopped: bool  # reached the threshold (True) or the step limit (False)
    occluded_fraction: tuple[tuple[float, ...], ...] = ()  # per step, per camera
    configurations: tuple[tuple[int, ...], ...] = ()  # per step
    object_probs: tuple[tuple[float, ...], ...] = ()  # per step (optional trace)
    invalid_steps: int = 0  # image sets the recognizer could not use (belief left unchanged)
    #: seconds the trial's moves took under the recognizer's motion model
    #: (:mod:`jaxrecog.hardware.geometry.motion`; the initial configuration is free);
    #: NaN where unknown (no travel-time tables, or a store written before)
    travel_s: float = math.nan
    #: the trial's object yaw offset off the training pose, degrees
    #: (:class:`~jaxrecog.driver.TrialSpec`); None = on the grid (left out of
    #: the JSON record, so on-grid stores are as before)
    yaw_offset: float | None = None

    @property
    def correct(self) -> bool:
        return self.object == self.predicted_object and self.pose == self.predicted_pose

    def to_json(self) -> str:
        d = dataclasses.asdict(self)
        d["correct"] = self.correct
        if d["travel_s"] != d["travel_s"]:
            d["travel_s"] = None  # unknown: null, strict JSON
        if d["yaw_offset"] is None:
            del d["yaw_offset"]
        return json.dumps(d, separators=(",", ":"))

    @classmethod
    def from_dict(cls, d: Any) -> "TrialResult":
        """A record read back (:meth:`to_json`'s fields); every field is
        checked for its type, so a damaged record fails here, naming the field,
        instead of in the table after every remaining trial has run.

        Raises:
            ValueError: not a JSON object, a required field missing, or a
                field of the wrong type or range.
        """
        if not isinstance(d, dict):
            raise ValueError(f"a JSON object expected, got {type(d).__name__}")
        fields = {f.name for f in dataclasses.fields(cls)}
        kw = {k: v for k, v in d.items() if k in fields}
        missing = [f.name for f in dataclasses.fields(cls)
                   if f.default is dataclasses.MISSING and f.name not in kw]
        if missing:
            raise ValueError(f"missing field(s) {', '.join(missing)}")
        if kw.get("travel_s", 0.0) is None:
            del kw["travel_s"]
        for k, v in kw.items():
            problem = _field_problem(k, v)
            if problem:
                raise ValueError(f"{k} = {_short(v)} {problem}")
        for k in ("occluded_fraction", "configurations", "object_probs"):
            if k in kw:
                kw[k] = tuple(tuple(x) for x in kw[k])
        return cls(**kw)


def _short(v) -> str:
    text = json.dumps(v) if not isinstance(v, float) else repr(v)
    return text if len(text) <= 40 else text[:37] + "..."


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_number(v) -> bool:
    return (isinstance(v, (int, float)) and not isinstance(v, bool)) and math.isfinite(v)


def _field_problem(name: str, v) -> str | None:
    """Why ``v`` cannot be field ``name`` of a :class:`TrialResult` (``None``: it can)."""
    if name in ("trial", "object", "pose", "predicted_object", "predicted_pose", "steps", "invalid_steps"):
        return None if _is_int(v) and v >= 0 else "is not a non-negative integer"
    if name == "exit_prob":
        # float32 beliefs may round a sure answer a few ulp above 1
        return None if _is_number(v) and 0.0 <= v <= 1.0 + 1e-4 else "is not a probability (a number in 0..1)"
    if name == "stopped":
        return None if isinstance(v, bool) else "is not true or false"
    if name in ("travel_s", "yaw_offset"):
        return None if v is None or _is_number(v) else "is not a finite number (or null)"
    if name in ("occluded_fraction", "object_probs", "configurations"):
        def number(x) -> bool:  # NaN as the store writes it
            return isinstance(x, (int, float)) and not isinstance(x, bool)

        check = _is_int if name == "configurations" else number
        ok = isinstance(v, list) and all(isinstance(row, list) and all(check(x) for x in row) for row in v)
        return None if ok else f"is not a list of lists of {'integers' if check is _is_int else 'numbers'}"
    return None


class TrialStore:
    """Append-only JSON-lines file of finished trials, so an interrupted
    campaign resumes without losing or repeating a trial.

    Each record (or group of records, :meth:`extend`) is written with one
    ``write`` + ``fsync``; a torn last line (the
    process died mid-write) is ignored on reading and truncated away before the
    next append.

    ``header`` (:func:`jaxrecog.trial_checks.store_header`: what the trials
    depend on and the limits of their values) is written as the first line of
    a new store and must be the first line of an existing one.  Every record
    is checked when read (:func:`jaxrecog.trial_checks.record_problem`:
    against the header's limits where the store has one) and each trial may
    be recorded once: a store that fails is refused whole (a ``ValueError``
    naming the file and line), never merged.
    """

    def __init__(self, path: str | os.PathLike, header: dict | None = None):
        self.path = Path(path)
        self.header = header
        self.path.parent.mkdir(parents=True, exist_ok=True)

    def load(self) -> dict[int, TrialResult]:
        out: dict[int, TrialResult] = {}
        if not self.path.exists():
            return out
        good_bytes = 0
        with open(self.path, "rb") as f:
            lines = f.readlines()
        check = _StoreReader(self.path, self.header)
        for number, raw in enumerate(lines, 1):
            if not raw.endswith(b"\n") and number == len(lines):
                break  # a torn final write: dropped below
            rec = check.line(number, raw)
            if rec is not None:
                out[rec.trial] = rec
            good_bytes += len(raw)
        if good_bytes != self.path.stat().st_size:
            with open(self.path, "r+b") as f:
                f.truncate(good_bytes)
        return out

    def append(self, result: TrialResult) -> None:
        self.extend([result])

    def extend(self, results: Sequence[TrialResult]) -> None:
        """Append ``results`` with one ``write`` + ``fsync`` (a group commit:
        a cluster's results arrive several at a time; a crash mid-write loses
        at most the torn last line, as for one)."""
        if not results:
            return
        line = "".join(r.to_json() + "\n" for r in results).encode()
        if self.header is not None and (not self.path.exists() or self.path.stat().st_size == 0):
            line = (json.dumps(self.header, sort_keys=True, separators=(",", ":")) + "\n").encode() + line
        fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        try:
            view = memoryview(line)
            while view:
                view = view[os.write(fd, view):]
            os.fsync(fd)
        finally:
            os.close(fd)


class _StoreReader:
    """Checks a store's lines as :meth:`TrialStore.load` reads them: the
    header (first line; required when the store is read with one), each
    record, and one record per trial."""

    def __init__(self, path: Path, header: dict | None):
        self.path, self.want = path, header
        self.limits = None if header is None else header["limits"]
        self.seen: dict[int, int] = {}   # trial -> its line

    def fail(self, number: int, problem: str) -> ValueError:
        return ValueError(f"{self.path}: line {number} {problem}; move the file away to start afresh")

    def line(self, number: int, raw: bytes) -> TrialResult | None:
        """The record of line ``number`` (``None`` for the header), checked."""
        try:
            obj = json.loads(raw)
        except (ValueError, RecursionError) as e:
            raise self.fail(number, f"is not a trial record ({e})") from None
        if number == 1 and trial_checks.is_header(obj):
            problem = None if self.want is None else trial_checks.header_problem(obj, self.want)
            if problem:
                raise self.fail(number, f"(the store's header) {problem}")
            if self.want is None and isinstance(obj.get("limits"), dict):
                self.limits = obj["limits"]   # read without a run: its own limits (checked as it was written)
            return None
        if number == 1 and self.want is not None:
            raise self.fail(number, "is a trial record, not the store's header (a store written before stores "
                                    "recorded their run, or by another tool): its trials cannot be checked "
                                    "against this run's settings")
        try:
            rec = TrialResult.from_dict(obj)
            problem = trial_checks.record_problem(obj, rec, self.limits)
        except (ValueError, TypeError, KeyError, RecursionError) as e:
            raise self.fail(number, f"is not a trial record ({e})") from None
        if problem:
            raise self.fail(number, f"(trial {rec.trial}): {problem}")
        if rec.trial in self.seen:
            raise self.fail(number, f"records trial {rec.trial} again (first on line {self.seen[rec.trial]})")
        self.seen[rec.trial] = number
        return rec


@dataclasses.dataclass(frozen=True)
class ObjectRow:
    label: str  # "0".."M-1" (0-based, as the manifest and the CLI; the thesis counts from 1) or "Average"
    trials: int
    rate: float  # percent
    exit_prob: float
    views: float
    #: wrong and stopped on the threshold (p >= P_th), % of the row's trials:
    #: the number that shows an over-confident belief (NaN: not recorded)
    confident_errors: float = math.nan
    #: mean seconds of travel per trial (NaN: not recorded)
    travel_s: float = math.nan
    #: 95 % Wilson interval of ``rate``, percent (:func:`wilson_interval`; the
    #: average row's is that of all its trials pooled); NaN: no trials
    rate_ci: tuple[float, float] = (math.nan, math.nan)
    #: 95 % Wilson interval of ``confident_errors``, percent
    confident_errors_ci: tuple[float, float] = (math.nan, math.nan)


def _mean_travel(rs: Sequence[TrialResult]) -> float:
    """Mean travel seconds, NaN unless every trial recorded it."""
    ts = [r.travel_s for r in rs]
    return math.nan if not ts or any(t != t for t in ts) else sum(ts) / len(ts)


def summarize(results: Iterable[TrialResult], n_objects: int) -> list[ObjectRow]:
    """Per-object rows and the average row (mean over objects, as the thesis).

    A trial is a *confident error* when it stopped on the threshold (its
    ``stopped`` flag: exit probability >= P_th) on the wrong object or pose.
    ``travel_s`` is the mean travel time per trial (NaN unless every trial of
    the row recorded one).  Each rate carries its 95 % Wilson interval
    (:func:`wilson_interval`); the average row's is that of the pooled
    trials (the average rate itself with equal trials per object)."""
    by_obj: dict[int, list[TrialResult]] = {m: [] for m in range(n_objects)}
    for r in results:
        by_obj[r.object].append(r)
    rows = []
    right = wrong = 0
    for m in range(n_objects):
        rs = by_obj[m]
        if rs:
            k = sum(r.correct for r in rs)
            e = sum(r.stopped and not r.correct for r in rs)
            right, wrong = right + k, wrong + e
            rows.append(
                ObjectRow(
                    str(m),
                    len(rs),
                    100.0 * k / len(rs),
                    sum(r.exit_prob for r in rs) / len(rs),
                    sum(r.steps for r in rs) / len(rs),
                    100.0 * e / len(rs),
                    _mean_travel(rs),
                    _pct_interval(k, len(rs)),
                    _pct_interval(e, len(rs)),
                )
            )
        else:
            rows.append(ObjectRow(str(m), 0, math.nan, math.nan, math.nan))
    filled = [r for r in rows if r.trials]
    if filled:
        n = sum(r.trials for r in filled)
        rows.append(
            ObjectRow(
                "Average",
                n,
                sum(r.rate for r in filled) / len(filled),
                sum(r.exit_prob for r in filled) / len(filled),
                sum(r.views for r in filled) / len(filled),
                sum(r.confident_errors for r in filled) / len(filled),
                sum(r.travel_s for r in filled) / len(filled),
                _pct_interval(right, n),
                _pct_interval(wrong, n),
            )
        )
    return rows


def _num(x: float, digits: int) -> str:
    """A thesis value, or an em dash where the thesis does not report it (NaN)."""
    return "\u2014" if x != x else f"{x:.{digits}f}"


def table_markdown(rows: Sequence[ObjectRow], title: str = "", reference: Sequence[tuple[float, float, float]] | None = None) -> str:
    """The thesis-shaped table as Markdown, with the confident-error column
    (wrong and stopped at p >= P_th, % of trials; the thesis does not report
    it); both rates with their 95 % Wilson interval in brackets; ``reference`` adds the thesis's (rate, exit prob, views) per row for
    comparison.  A mean-travel column (seconds per trial) is added when some
    row recorded travel times."""
    travel = any(r.travel_s == r.travel_s for r in rows)
    head = ("| Object | Trials | Recog. rate (%) [95 % CI] | Mean exit prob. | Mean no. of views "
            "| Confident errors (%) [95 % CI] |")
    sep = "|---|---:|---:|---:|---:|---:|"
    if travel:
        head += " Mean travel (s) |"
        sep += "---:|"
    if reference is not None:
        head += " Thesis rate / exit / views |"
        sep += "---|"
    lines = ([f"**{title}**", ""] if title else []) + [head, sep]
    for i, r in enumerate(rows):
        line = (f"| {r.label} | {r.trials} | {format_rate(r.rate, r.rate_ci)} | {_num(r.exit_prob, 2)} | "
                f"{_num(r.views, 2)} | {format_rate(r.confident_errors, r.confident_errors_ci)} |")
        if travel:
            line += f" {_num(r.travel_s, 2)} |"
        if reference is not None:
            ref = reference[i] if i < len(reference) else None
            line += f" {_num(ref[0], 1)} / {_num(ref[1], 2)} / {_num(ref[2], 1)} |" if ref else " |"
        lines.append(line)
    return "\n".join(lines) + "\n"


def table_json(rows: Sequence[ObjectRow]) -> list[dict]:
    return [dataclasses.asdict(r) for r in rows]
