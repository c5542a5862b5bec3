"""A campaign's report: each planner's results table on the same trials, the
thesis's published rows beside it where the case is the thesis's, and its
Markdown / JSON files."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

from ..planners import planner_spec
from ..results import ObjectRow, TrialResult, format_rate, table_json, table_markdown
from ..thesis import ThesisTable, published
from .cases import Case
from .naming import results_dir
from .settings import Settings

__all__ = ["CaseReport"]


@dataclasses.dataclass
class CaseReport:
    case: Case
    settings: Settings
    rows: dict[str, list[ObjectRow]]
    results: dict[str, list[TrialResult]]
    seconds: dict[str, float]

    def thesis_table(self, planner: str) -> ThesisTable | None:
        """The thesis's published table for this case and planner
        (:func:`~jaxrecog.thesis.published`), if any; none on a strided table
        (not the thesis's rig).  The planner's thesis column comes from the
        registry (``planners.PLANNERS``: ``mi-class`` is compared with the
        thesis's ``mi``, ``crlb-det`` with its ``crlb``)."""
        if self.settings.stride != 1:
            return None
        n_objects = sum(r.label != "Average" for r in next(iter(self.rows.values()), []))
        return published(self.case.name, planner_spec(planner).thesis, n_objects)

    def reference(self, planner: str):
        """The thesis's (rate, exit, views) rows for this case and planner
        (``None`` per object where the thesis gives only the average), or
        ``None`` (:meth:`thesis_table`)."""
        t = self.thesis_table(planner)
        if t is None:
            return None
        rows = [None if math.isnan(r) else (r, e, v) for r, e, v in zip(t.rate, t.exit_prob, t.views)]
        return rows + [t.average]

    def markdown(self) -> str:
        parts = [f"### {self.case.title}", ""]
        for planner, rows in self.rows.items():
            ref = self.reference(planner)
            n = self.settings.trials_per_object
            parts.append(table_markdown(rows, f"{planner} — {n} trials per object, {self.seconds[planner]:.0f} s", reference=ref))
        return "\n".join(parts)

    def metrics_table(self, digits: int = 1) -> tuple[list[str], dict[str, dict]]:
        """One Markdown row per planner (rate, views, confident errors as %
        of trials with ``digits`` decimals and their 95 % Wilson intervals, ECE, seconds) under its header,
        and each planner's :func:`~jaxrecog.metrics.campaign_metrics` at the
        settings' P_th."""
        from ..metrics import campaign_metrics

        lines = ["| Planner | Trials | Rate (%) [95 % CI] | Mean views | Confident errors (% of trials) [95 % CI] "
                 "| ECE | Seconds |",
                 "|---|---:|---:|---:|---:|---:|---:|"]
        metrics = {}
        for planner, res in self.results.items():
            m = metrics[planner] = campaign_metrics(res, self.settings.p_threshold)
            rate = format_rate(m["recognition_rate"], m["recognition_rate_ci"], digits)
            errors = format_rate(m["confident_error_pct_of_trials"], m["confident_error_pct_of_trials_ci"], digits)
            lines.append(f"| {planner} | {m['trials']} | {rate} | {m['mean_views']:.2f} | {errors} | {m['ece']:.3f} | "
                         f"{self.seconds[planner]:.0f} |")
        return lines, metrics

    def to_json(self) -> dict:
        return {
            "case": dataclasses.asdict(self.case),
            "settings": {k: (str(v) if isinstance(v, Path) else v) for k, v in self.settings.flat().items()},
            "tables": {p: table_json(r) for p, r in self.rows.items()},
            "seconds": self.seconds,
        }

    def write(self, folder: Path | None = None) -> tuple[Path, Path]:
        folder = Path(folder or results_dir(self.settings))
        folder.mkdir(parents=True, exist_ok=True)
        md = folder / f"case-{self.case.name}.md"
        js = folder / f"case-{self.case.name}.json"
        md.write_text(self.markdown())
        js.write_text(json.dumps(self.to_json(), indent=1))
        return md, js
