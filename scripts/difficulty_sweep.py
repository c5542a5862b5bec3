#!/usr/bin/env python
"""Difficulty sweep: recognition against occlusion and
against off-grid captures, for DB1 vs DB2, one camera vs two, MI vs random.

Two axes, each run for every combination of model (DB1, DB2), cameras
(camera 1 alone, both) and planner (``mi-class-pairwise``, the fast
deterministic class-MI estimate, standing in for MI; and ``random``):

* **occlusion**: occluded trials (boards in front of the first views and one
  more per camera, as the thesis cases, but with a wider board-size range,
  :data:`SWEEP_OCCLUDER_SIZE` / :data:`SWEEP_OCCLUDER_OFFSET`, so the first
  views lose 0 to ~50 % of the object); trials are **binned by the measured
  first-view occluded fraction** (``TrialResult.occluded_fraction[0]``, from
  the segmentation masks; with two cameras the mean of the two) into
  :data:`OCCLUSION_BINS`; trials above 40 % are counted, not plotted.  The
  boards are not scaled to a target fraction.
* **off-grid angle** A in :data:`ANGLES` (degrees): clean scenes, each
  trial's object turned ``U(-A, A)`` off its training pose, and per capture
  the eye offset ``0.002 A`` and light jitter ``0.01 A``
  (:class:`~jaxrecog.hardware.render.synthetic.OffGrid`; A = 20 is case ``jitter``,
  :data:`jaxrecog.campaigns.JITTER`).  A = 0 is case (i)'s on-grid capture.

Within one camera count every model and planner sees the same trials (poses,
starts, boards, yaw offsets, capture noise).  Writes into ``--out``:
``difficulty_sweep.json`` and ``.md`` (per point: trials, recognition rate,
mean views, confident errors = wrong and stopped at p >= P_th in % of trials,
mean exit probability, ECE of the exit probability) and the figures
``difficulty_occlusion.png`` and ``difficulty_off_grid.png``.

    python scripts/difficulty_sweep.py --quick                 # stride 8, small models, seconds-a-minute
    python scripts/difficulty_sweep.py --stride 2 --trials 10  # 16 x 4 table
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from pathlib import Path

import jax.random as jr

from jaxrecog import campaigns as ex
from jaxrecog.scene import occluder_factory
from jaxrecog.campaign import plan_trials, run_campaign
from jaxrecog.hardware.rigs.capture_memo import CaptureMemo
from jaxrecog.cluster import ClusterError, connect
from jaxrecog.metrics import expected_calibration_error
from jaxrecog.plots import save_png
from jaxrecog.results import format_rate, summarize, wilson_interval

PLANNERS = ("mi-class-pairwise", "random")
DATABASES = ("DB1", "DB2")
CAMERAS = {"1 camera": (0,), "2 cameras": None}
ANGLES = (0.0, 5.0, 10.0, 20.0, 30.0)
#: first-view occluded fraction bins (%), [lo, hi) (the last one closed)
OCCLUSION_BINS = ((0.0, 5.0), (5.0, 10.0), (10.0, 20.0), (20.0, 30.0), (30.0, 40.0))
#: board half-size and offset ranges of the occlusion axis (units of the
#: object radius): wider than the campaign's (0.18-0.38, 0.2-0.8), so the
#: measured first-view fractions spread over 0-50 %
SWEEP_OCCLUDER_SIZE = (0.05, 0.5)
SWEEP_OCCLUDER_OFFSET = (0.1, 1.0)
#: --quick: the stride-8 table (4 x 1), small models, 1 trial per object, 2 angles
QUICK = dict(stride=8, trials_per_object=1, samples=256, min_per_stratum=2, samples_per_image=30, n_components=12)
QUICK_ANGLES = (0.0, 20.0)


def off_grid_amounts(angle: float) -> tuple[float, float, float]:
    """(yaw bound, eye offset, light jitter) of off-grid angle ``angle``."""
    return (float(angle), 0.002 * angle, 0.01 * angle)


def _point(results, n_objects: int) -> dict:
    if not results:
        return {"trials": 0, "rate": math.nan, "views": math.nan, "confident_errors": math.nan,
                "rate_ci": [math.nan, math.nan], "confident_errors_ci": [math.nan, math.nan],
                "exit_prob": math.nan, "ece": math.nan}
    n = len(results)
    # pooled over trials (a bin holds unequal numbers per object, so no per-object mean)
    return {
        "trials": n,
        "rate": 100.0 * sum(r.correct for r in results) / n,
        "views": sum(r.steps for r in results) / n,
        "confident_errors": 100.0 * sum(r.stopped and not r.correct for r in results) / n,
        "rate_ci": [100.0 * x for x in wilson_interval(sum(r.correct for r in results), n)],
        "confident_errors_ci": [100.0 * x for x in wilson_interval(sum(r.stopped and not r.correct for r in results), n)],
        "exit_prob": sum(r.exit_prob for r in results) / n,
        "ece": float(expected_calibration_error(results)),
    }


def first_view_fraction(result) -> float:
    """Mean over the cameras of the first image set's occluded fraction, in %."""
    f = result.occluded_fraction[0] if result.occluded_fraction else ()
    return 100.0 * sum(f) / len(f) if f else 0.0


def _rows(axis: str, x, base: dict, res, n_objects: int, dt: float, say) -> tuple[list[dict], dict | None]:
    """One point's rows (off-grid: one; occlusion: one per bin, and the count
    above the last bin), said as they are made."""
    if axis == "off_grid":
        row = {**base, "angle": x, **_point(res, n_objects)}
        say(f"off-grid {x:g} deg, {base['database']}, {base['cameras']}, {base['planner']}: rate {format_rate(row['rate'], row['rate_ci'])} %, "
            f"views {row['views']:.2f}, confident errors {format_rate(row['confident_errors'], row['confident_errors_ci'])} % "
            f"({dt:.0f} s)")
        return [row], None
    fr = [first_view_fraction(r) for r in res]
    made = []
    for lo, hi in OCCLUSION_BINS:
        last = hi == OCCLUSION_BINS[-1][1]
        inside = [r for r, f in zip(res, fr) if lo <= f < hi or (last and f == hi)]
        xs = [f for f in fr if lo <= f < hi or (last and f == hi)]
        made.append({**base, "bin": [lo, hi], "mean_fraction": sum(xs) / len(xs) if xs else math.nan,
                     **_point(inside, n_objects)})
    above = sum(f > OCCLUSION_BINS[-1][1] for f in fr)
    overall = summarize(res, n_objects)[-1]
    say(f"occlusion, {base['database']}, {base['cameras']}, {base['planner']}: {len(res)} trials ({above} above "
        f"{OCCLUSION_BINS[-1][1]:g} %), overall rate {format_rate(overall.rate, overall.rate_ci)} % ({dt:.0f} s)")
    return made, {**base, "trials": above}


def sweep(settings: ex.Settings, *, angles=ANGLES, planners=PLANNERS, databases=DATABASES,
          axes=("occlusion", "off_grid"), progress=None) -> dict:
    prepared = ex.prepare(settings, databases=tuple(databases))
    say = progress or (lambda msg: None)
    rows = {"occlusion": [], "off_grid": []}
    timing = {}
    for cam_label, cams in CAMERAS.items():
        models = {}
        for db in databases:
            case = ex.Case(f"sweep-{db}", "", db, False, cams, tuple(planners))
            models[db] = ex.case_model(prepared, case)
        model0 = models[databases[0]]
        probe = ex.make_rig(settings, cams, seed=settings.seed)  # the table, the boards' geometry, travel times
        points = []  # (axis, x, specs, settings of the captures)
        if "occlusion" in axes:
            specs = plan_trials(model0.n_objects, model0.n_poses, probe.positions, settings.trials_per_object,
                                seed=settings.seed,
                                occluders=occluder_factory(probe, SWEEP_OCCLUDER_SIZE, SWEEP_OCCLUDER_OFFSET))
            points.append(("occlusion", None, specs, settings))
        if "off_grid" in axes:
            for a in angles:
                yaw, eye, light = off_grid_amounts(a)
                s = dataclasses.replace(settings, off_grid_deg=yaw, off_grid_eye=eye, off_grid_light=light)
                specs = plan_trials(model0.n_objects, model0.n_poses, probe.positions, settings.trials_per_object,
                                    seed=settings.seed, yaw_deg=yaw)
                points.append(("off_grid", float(a), specs, s))
        from jaxrecog.motion import rig_travel_times

        travel = rig_travel_times(probe)
        probe.close()
        recognizers = {(db, planner): ex.campaign_recognizer(models[db], planner, settings, travel)
                       for db in databases for planner in planners}
        done = {}
        # one point's rigs at a time (in worker processes or on a cluster: its workers), every
        # model and planner on them; the rows below keep the order model, planner, point
        for axis, x, specs, s in points:
            # the point's campaigns run the same trials: their common captures are rendered once
            with ex.capture_pool(s, cams, seed=settings.seed, memo=CaptureMemo()) as rigs:
                for db in databases:
                    for planner in planners:
                        t0 = time.perf_counter()
                        res = run_campaign(recognizers[(db, planner)], rigs, specs, key=jr.PRNGKey(settings.seed + 1),
                                           batch=settings.batch, seed=settings.seed, devices=settings.devices)
                        dt = time.perf_counter() - t0
                        base = {"database": db, "cameras": cam_label, "planner": planner}
                        done[(axis, x, db, planner)] = (dt, *_rows(axis, x, base, res, models[db].n_objects, dt, say))
        for db in databases:
            for planner in planners:
                for axis, x, *_ in points:
                    dt, made, above = done[(axis, x, db, planner)]
                    timing[f"{axis} {x} {db} {cam_label} {planner}"] = dt
                    rows[axis] += made
                    if above is not None:
                        rows.setdefault("occlusion_above_last_bin", []).append(above)
    return {
        "positions": list(ex.rig_table(settings).positions),
        "planners": list(planners),
        "note": "mi-class-pairwise (the deterministic pairwise class-MI estimate) stands in for MI: it is the fast one",
        "occluder_size": list(SWEEP_OCCLUDER_SIZE),
        "occluder_offset": list(SWEEP_OCCLUDER_OFFSET),
        "off_grid_rule": "angle A: yaw U(-A, A) per trial, eye offset 0.002 A and light jitter 0.01 A per capture",
        "settings": {k: (str(v) if isinstance(v, Path) else v) for k, v in settings.flat().items()},
        "seconds": timing,
        **rows,
    }


def _strict(x):
    """NaN (an empty bin) -> None, so the JSON is strict."""
    if isinstance(x, float) and x != x:
        return None
    if isinstance(x, dict):
        return {k: _strict(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_strict(v) for v in x]
    return x


def _num(x, fmt):
    return "—" if x != x else format(x, fmt)


def markdown(summary: dict) -> str:
    out = [f"Positions {summary['positions']}; trials per object {summary['settings']['trials_per_object']}; "
           f"{summary['note']}.", ""]
    head = "| model | cameras | planner | {x} | trials | rate (%) [95 % CI] | views | confident errors (%) [95 % CI] | exit prob. | ECE |"
    sep = "|---|---|---|---:|---:|---:|---:|---:|---:|---:|"
    for axis, xname, xfmt in (("occlusion", "first-view occluded (%)", None), ("off_grid", "off-grid angle (°)", "g")):
        if not summary.get(axis):
            continue
        out += [f"**{'Occlusion (binned by the measured first-view fraction)' if axis == 'occlusion' else 'Off-grid angle'}**",
                "", head.format(x=xname), sep]
        for r in summary[axis]:
            x = f"{r['bin'][0]:g}–{r['bin'][1]:g} (mean {_num(r['mean_fraction'], '.1f')})" if axis == "occlusion" \
                else format(r["angle"], xfmt)
            out.append(f"| {r['database']} | {r['cameras']} | {r['planner']} | {x} | {r['trials']} | "
                       f"{format_rate(r['rate'], r.get('rate_ci', (math.nan, math.nan)))} | {_num(r['views'], '.2f')} | "
                       f"{format_rate(r['confident_errors'], r.get('confident_errors_ci', (math.nan, math.nan)))} | "
                       f"{_num(r['exit_prob'], '.3f')} | {_num(r['ece'], '.3f')} |")
        out.append("")
    return "\n".join(out)


def plot(summary: dict, axis: str, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = summary[axis]
    fig, axs = plt.subplots(1, 3, figsize=(13, 4))
    combos = sorted({(r["database"], r["planner"], r["cameras"]) for r in rows})
    colours = {}
    for db, planner, cams in combos:
        c = colours.setdefault((db, planner), f"C{len(colours)}")
        pts = [r for r in rows if (r["database"], r["planner"], r["cameras"]) == (db, planner, cams) and r["trials"]]
        xs = [r["mean_fraction"] if axis == "occlusion" else r["angle"] for r in pts]
        style = "-" if cams.startswith("2") else "--"
        marker = "o" if cams.startswith("2") else "s"
        for a, key in zip(axs, ("rate", "confident_errors", "views")):
            a.plot(xs, [r[key] for r in pts], style, marker=marker, color=c, label=f"{db}, {planner}, {cams}")
    xl = "first-view occluded fraction (%, bin means)" if axis == "occlusion" else "off-grid angle A (°): yaw ±A, eye 0.002A, light 0.01A"
    for a, yl in zip(axs, ("recognition rate (%)", "confident errors (% of trials)", "mean views")):
        a.set_xlabel(xl, fontsize=8)
        a.set_ylabel(yl)
        a.grid(alpha=0.3)
    axs[0].legend(fontsize=6)
    fig.suptitle(f"{'Occlusion' if axis == 'occlusion' else 'Off-grid'} sweep, positions {summary['positions']}, "
                 f"{summary['settings']['trials_per_object']} trials/object per point "
                 f"(MI = mi-class-pairwise)", fontsize=9)
    return save_png(fig, path, dpi=90)


def build_parser() -> argparse.ArgumentParser:
    """The command line of this script (the docs tests parse the docs' commands with it)."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path("out/difficulty"))
    ap.add_argument("--workdir", type=Path, help="database and model cache (default: OUT/work)")
    ap.add_argument("--trials", type=int, help="trials per object per point (default 10; --quick 1)")
    ap.add_argument("--stride", type=int, help="thesis table stride (default 2; --quick 8)")
    ap.add_argument("--angles", type=float, nargs="+", help=f"off-grid angles in degrees (default {' '.join(f'{a:g}' for a in ANGLES)})")
    ap.add_argument("--planners", default=",".join(PLANNERS), help="comma-separated planners")
    ap.add_argument("--axes", default="occlusion,off_grid", help="occlusion, off_grid or both (comma-separated)")
    ap.add_argument("--batch", type=int, default=16)
    ap.add_argument("--devices", type=int, default=1)
    ap.add_argument("--render-workers", type=int, default=0,
                    help="render in N worker processes (with --cluster: N Ray workers, 0 = one per CPU)")
    ap.add_argument("--cluster", help="render and run on Ray: 'ray' (a local instance) or 'ray://HOST:PORT' "
                                      "(docs/cluster.md)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--quick", action="store_true", help="stride 8, small models, 1 trial per object, angles 0 and 20 (CI)")
    ap.add_argument("--quiet", action="store_true")
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    values = dict(QUICK) if args.quick else {"stride": 2, "trials_per_object": 10}
    for k, v in (("trials_per_object", args.trials), ("stride", args.stride)):
        if v is not None:
            values[k] = v
    angles = tuple(args.angles) if args.angles else (QUICK_ANGLES if args.quick else ANGLES)
    axes = tuple(a.strip().replace("-", "_") for a in args.axes.split(",") if a.strip())
    try:
        if not axes or set(axes) - {"occlusion", "off_grid"}:
            raise ValueError(f"--axes: choose occlusion, off_grid or both, got {args.axes!r}")
        for a in angles:
            if not 0 <= a < math.inf:
                raise ValueError(f"--angles must be finite and >= 0, got {a}")
        settings = ex.Settings(workdir=args.workdir or args.out / "work", batch=args.batch, seed=args.seed,
                               devices=args.devices, render_workers=args.render_workers, cluster=args.cluster,
                               **values)
        if settings.cluster:  # a cluster that is not there: said before anything renders
            connect(settings.cluster)
        t0 = time.perf_counter()
        summary = sweep(settings, angles=angles, planners=tuple(args.planners.split(",")), axes=axes,
                        progress=None if args.quiet else (lambda m: print(m, flush=True)))
        summary["total_seconds"] = time.perf_counter() - t0
    except (ValueError, ClusterError) as e:
        print(f"difficulty_sweep: error: {e}", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    js = args.out / "difficulty_sweep.json"
    js.write_text(json.dumps(_strict(summary), indent=1, allow_nan=False))
    md = args.out / "difficulty_sweep.md"
    md.write_text(markdown(summary))
    written = [js, md]
    for axis in axes:
        written.append(plot(summary, axis, args.out / f"difficulty_{axis}.png"))
    print("\n".join(f"wrote {p}" for p in written))
    return 0


if __name__ == "__main__":
    sys.exit(main())
