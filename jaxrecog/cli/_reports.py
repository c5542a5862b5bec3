"""What ``experiment`` and ``demo`` share: Settings from option values, the
``--quick`` preset, and the files of a campaign report."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from .._files import check_output_folder, write_text
from .. import campaigns  # as a module: tests stub its prepare / run_case / run_trace
from .. import plots
from ..problems import problem_message
from ._common import UsageError

__all__ = ["QUICK", "make_settings", "trace_plot", "write_report"]

#: "Quick" runs (demo, ``experiment --quick``): fewer Monte Carlo and training
#: samples and a smaller eigenspace; the database is still the thesis's 32 x 7
#: (``--stride`` thins it).
QUICK = {"samples": 256, "min_per_stratum": 2, "samples_per_image": 30, "n_components": 12}


def make_settings(values: dict[str, Any], where: str) -> campaigns.Settings:
    """``campaigns.Settings(**values)``; an unknown name is a usage error naming ``where``."""
    known = set(campaigns.Settings.FIELDS)
    bad = sorted(set(values) - known)
    if bad:
        raise UsageError(problem_message(f"{where}: unknown setting(s) (known: {', '.join(sorted(known))})", bad))
    return campaigns.Settings(**values)


def write_report(report, name: str, out: Path, title: str | None = None) -> list[Path]:
    """``case_NAME.md`` / ``.json`` and the ``campaign_NAME`` bars (PNG + SVG,
    :func:`jaxrecog.plots.case_bars`)."""
    check_output_folder(out, "--out folder")
    md = write_text(out / f"case_{name}.md", report.markdown(), "report")
    js = write_text(out / f"case_{name}.json", json.dumps(report.to_json(), indent=2), "report")
    return [md, js, *plots.case_bars(report, out / f"campaign_{name}", title=title)]


def trace_plot(settings, out: Path, planner: str = "mi", prepared=None, case: str = "iii") -> list[Path]:
    """One traced trial of ``case`` (object 5, the thesis's object 6 of Table 7.8) as ``belief_trace`` (PNG + SVG)."""
    res = campaigns.run_trace(settings, object=5, planner=planner, prepared=prepared, case=case)
    return list(plots.belief_trace(res, out / "belief_trace", planner=planner, case=case,
                                   occluded=campaigns.CASES[case].occluded, thesis_rig=settings.stride == 1))
