#!/usr/bin/env python
"""Reproduce the thesis's chapter-7 experiments on the synthetic rig.

    python scripts/reproduce_thesis.py --case i            # one case, its default planners
    python scripts/reproduce_thesis.py --case all          # every case + the Table 7.8 trace
    python scripts/reproduce_thesis.py --case iii --planners mi,mi-class,crlb --trials 100
    python scripts/reproduce_thesis.py --case i --trials 1 --stride 8   # a smoke run of seconds
    python scripts/reproduce_thesis.py --case iii --likelihood student-t --rotation 3 --scale 0.03 --blur 1 --gain 0.05

Renders the database and trains DB1/DB2 on first use (cached in --workdir),
prints each case's thesis-shaped table (with the thesis's numbers beside
ours) and writes it as Markdown and JSON under WORKDIR/results.
--likelihood / --nu / --rank and the capture augmentation flags
(--rotation, --scale, --blur, --gain, --gain-cells; as ``jaxrecog train``)
train the models with another family or augmentation, cached under their
own file names; the tables then go to the same WORKDIR/results (pass
another --workdir to keep them apart).  Finished
trials are kept in WORKDIR/trials, so an interrupted run resumes.

--case turntable (or turntable-occluded) runs the turntable set (not in the
thesis) instead: --objects N random_urdfs meshes (default 50), one camera
(--cameras 2 for two), 18 turntable positions, test views 10 degrees off the
training grid (with a board in front of each for turntable-occluded), a
calibrated DB1 (DB2) model, planners mi-class-pairwise and random by default:

    python scripts/reproduce_thesis.py --case turntable --objects 50 --trials 10

--stride N keeps every N-th position of each camera (8: a 4 x 1 table of
160 images): a quick check of the whole pipeline, not the thesis's rig, so
its tables carry no thesis numbers and go to WORKDIR/results-strideN (its
database and models are cached apart from the full table's too).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

from jaxrecog.cli._options import (capture_options, capture_params, given_likelihood_options, likelihood_choice,
                                   likelihood_options, render_jitter_options, render_jitter_values,
                                   render_workers_option)
from jaxrecog.hardware.rigs.capture_memo import CaptureMemo
from jaxrecog.metrics import campaign_metrics
from jaxrecog.results import format_rate
from jaxrecog.campaigns import CASES, Settings, prepare, results_dir, run_case, run_trace

#: Worker processes that render the campaigns' captures (``--render-workers``):
#: one per core this process may use, at most 4; none on one core (a worker
#: there only adds its start).
_CORES = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
DEFAULT_RENDER_WORKERS = min(_CORES, 4) if _CORES > 1 else 0

#: The turntable cases (not in the thesis), run apart from CASES: name -> occluded test views.
TURNTABLE_CASES = {"turntable": False, "turntable-occluded": True}
from jaxrecog.kernels import DEFAULT_LIKELIHOOD
from jaxrecog.recipes import RECIPES, get_recipe
from jaxrecog.thesis import TABLE_7_8


def trace_markdown(res, thesis: bool = True) -> str:
    steps = len(res.object_probs)
    n_objects = len(res.object_probs[0])
    head = "| Step | Initial | " + " | ".join(f"Step {i + 1}" for i in range(steps)) + " |"
    lines = [head, "|---|" + "---:|" * (steps + 1)]
    for m in range(n_objects):
        vals = [1.0 / n_objects] + [p[m] for p in res.object_probs]
        lines.append(f"| Obj. {m} | " + " | ".join(f"{v:.4f}" for v in vals) + " |")
    occ = " / ".join("(" + ", ".join(f"{x:.2f}" for x in f) + ")" for f in res.occluded_fraction)
    cfg = " / ".join(str(c) for c in res.configurations)
    lines += ["", f"Configurations per step: {cfg}", f"True occluded fraction per step (camera 0, camera 1): {occ}",
              f"Decision: object {res.predicted_object}, pose {res.predicted_pose} (true object {res.object}, pose {res.pose}), p = {res.exit_prob:.3f}"]
    if thesis:
        lines += ["", "Thesis Table 7.8 (the thesis's object 6 = object 5, occluded): "
                  + " -> ".join(f"{row[5]:.4f}" for row in TABLE_7_8)]
    return "\n".join(lines) + "\n"


def _case(name: str) -> str:
    """``--case``: a case of ``CASES``, ``trace``, ``all`` or a turntable case."""
    if name in CASES or name in TURNTABLE_CASES or name in ("trace", "all"):
        return name
    raise argparse.ArgumentTypeError(f"{name!r}: choose one of {', '.join(CASES)}, 'trace' or 'all' "
                                     f"(or {', '.join(TURNTABLE_CASES)})")


def build_parser() -> argparse.ArgumentParser:
    """The command line of this script (the docs tests parse the docs' commands with it)."""
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--case", default="all", type=_case, help=f"one of {', '.join(CASES)}, 'trace', 'all' (default: all), "
                        "or turntable / turntable-occluded (not in the thesis, nor in 'all')")
    p.add_argument("--planners", default=None, help="comma-separated planners (default: the case's own)")
    p.add_argument("--trials", type=int, default=100, help="trials per object (default: 100, as the thesis)")
    p.add_argument("--workdir", default="out/thesis", help="database, models, trials and tables (default: out/thesis)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--samples", type=int, default=1024, help="Monte Carlo samples per configuration (default: 1024)")
    p.add_argument("--batch", type=int, default=16, help="trials run in lockstep (default: 16)")
    p.add_argument("--stride", type=int, default=1,
                   help="keep every STRIDE-th position of each camera (default: 1, the thesis's 32 x 7 table)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    render_workers_option(p, default=DEFAULT_RENDER_WORKERS)
    g = p.add_argument_group("training (each choice has its own cached models; default: the thesis's)")
    likelihood_options(g)
    render_jitter_options(g)
    capture_options(p, unset=True)   # not given: the recipe's (its max_shift, occluder_gray) and the thesis's defaults
    p.add_argument("--recipe", choices=sorted(RECIPES), default="thesis",
                   help="training and stop rule (default: thesis, the thesis's protocol this script reproduces; "
                        "robust: the product's default, `jaxrecog recipes`); --likelihood and the capture options "
                        "override its parts")
    p.add_argument("--objects", type=int, default=50, help="turntable cases: random objects (default: 50)")
    p.add_argument("--cameras", type=int, choices=(1, 2), default=1, help="turntable cases: cameras (default: 1)")
    return p


def _settings(args, **run) -> Settings:
    """The campaign settings of the command line: ``--recipe`` with the parts
    the options give.  The thesis recipe names its likelihood as before (the
    diagonal Gaussian, or with --view-jitter the low-rank view mixture); any
    other recipe keeps its own unless --likelihood or a fit option is given."""
    recipe = get_recipe(args.recipe)
    given = given_likelihood_options(args)
    parts = {}
    if recipe.name == "thesis" or args.likelihood is not None or given:
        name = args.likelihood or (None if recipe.name == "thesis" else recipe.likelihood)
        likelihood, options = likelihood_choice(name, given, view_jitter=bool(args.view_jitter))
        parts = {"likelihood": likelihood, "likelihood_options": options}
    return Settings(recipe=recipe, workdir=args.workdir, trials_per_object=args.trials, seed=args.seed,
                    samples=args.samples, batch=args.batch, **run, **parts, **capture_params(args),
                    **render_jitter_values(args))


def main(argv=None) -> int:
    p = build_parser()
    args = p.parse_args(argv)
    if args.case in TURNTABLE_CASES:
        return turntable_case(args)
    if args.stride < 1:
        p.error(f"--stride must be >= 1, got {args.stride}")
    try:
        settings = _settings(args, stride=args.stride, render_workers=args.render_workers)
    except (ValueError, argparse.ArgumentTypeError) as e:
        p.error(str(e))
    show = not args.quiet and sys.stderr.isatty()
    cases = list(CASES) + ["trace"] if args.case == "all" else [args.case]
    # train only the models the chosen cases use (the trace is a case-iii trial: DB2)
    databases = sorted({CASES[c].database if c != "trace" else CASES["iii"].database for c in cases})
    prepared = prepare(settings, progress=show, databases=databases)
    memo = CaptureMemo()  # the captures every case's planners share, and cases of the same scenes ((ii), (iii))
    for name in cases:
        if name == "trace":
            md = ""
            records = {}
            for planner in (args.planners or "mi,mi-class").split(","):
                res = run_trace(settings, prepared=prepared, planner=planner)
                md += f"### Trace of one hard trial (object 5, occluded, case iii), planner {planner}\n\n" + trace_markdown(res, settings.stride == 1) + "\n"
                records[planner] = res.__dict__
            out = results_dir(settings) / "trace.md"
            out.parent.mkdir(parents=True, exist_ok=True)
            out.write_text(md)
            (results_dir(settings) / "trace.json").write_text(json.dumps(records, default=list, indent=1))
            print(md)
            print(f"wrote {out}")
            continue
        planners = args.planners.split(",") if args.planners else None
        report = run_case(name, settings, planners, progress=show, prepared=prepared, memo=memo)
        md_path, _ = report.write()
        print(report.markdown())
        for planner, res in report.results.items():
            m = campaign_metrics(res, settings.p_threshold)
            print(f"case {name} {planner} [{settings.likelihood}{dict(settings.likelihood_options) or ''}]: "
                  f"{m['trials']} trials, rate {format_rate(m['recognition_rate'], m['recognition_rate_ci'], 2)} %, "
                  f"views {m['mean_views']:.2f}, confident errors {m['confident_errors']} "
                  f"({format_rate(m['confident_error_pct_of_trials'], m['confident_error_pct_of_trials_ci'])} % of trials), "
                  f"ECE {m['ece']:.3f}, {report.seconds[planner]:.0f} s")
        print(f"wrote {md_path}")
    return 0


def turntable_case(args) -> int:
    """``--case turntable`` / ``turntable-occluded``: render, train + calibrate
    (cached in WORKDIR), run the campaign, print and write its tables and metrics."""
    from jaxrecog.campaigns import run_turntable

    try:
        settings = _settings(args)
    except (ValueError, argparse.ArgumentTypeError) as e:
        print(f"reproduce_thesis: error: {e}", file=sys.stderr)
        return 2
    show = not args.quiet and sys.stderr.isatty()
    planners = args.planners.split(",") if args.planners else None
    report = run_turntable(settings, args.objects, args.cameras, TURNTABLE_CASES[args.case], planners, progress=show)
    rows, metrics = report.metrics_table()
    lines = [report.markdown(), "", *rows]
    md = "\n".join(lines) + "\n"
    tag = "" if settings.likelihood == DEFAULT_LIKELIHOOD else f"-{settings.likelihood}"
    tag += f"-vj{settings.view_jitter}x{settings.view_jitter_deg:g}" if settings.view_jitter else ""
    out = results_dir(settings) / f"{args.case}-n{args.objects}-c{args.cameras}{tag}.md"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(md)
    out.with_suffix(".json").write_text(json.dumps({"report": report.to_json(), "metrics": metrics}, indent=1))
    print(md)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
