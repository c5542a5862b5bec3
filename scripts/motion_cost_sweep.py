#!/usr/bin/env python
"""Motion-cost sweep: views against travel time as λ grows.

For each λ (score units per second: nats/s for the MI planners) the same
trials (poses, initial configurations, occluders, capture noise) run with
``score(a) − λ · seconds to move to a`` (:mod:`jaxrecog.motion`; travel times
from the appendix-C kinematics and the default axis speeds of
:mod:`jaxrecog.hardware.geometry.motion`).  One recognizer is built and λ is swapped
as an array leaf, so the step compiles once for the whole sweep.

Writes ``motion_cost_sweep.json`` (per λ: recognition rate, mean views, mean
travel seconds per trial, mean exit probability, confident errors) and
``motion_cost_sweep.png`` (views and travel time against λ, and travel
against views) into ``--out``.

Reduced run (about a minute on 2 cores; numbers from an 8 x 2 table and a few
trials, not the thesis protocol)::

    python scripts/motion_cost_sweep.py --quick
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax.random as jr

from jaxrecog import campaigns as ex
from jaxrecog.campaign import run_campaign
from jaxrecog.hardware.rigs.capture_memo import CaptureMemo, MemoRigs
from jaxrecog.hardware.rigs.rig_pool import LocalRigs
from jaxrecog.motion import check_weight, rig_travel_times, with_motion_cost
from jaxrecog.plots import save_png
from jaxrecog.results import format_rate, summarize

DEFAULT_LAMBDAS = (0.0, 0.01, 0.03, 0.1, 0.3, 1.0, 10.0)
#: --quick: a (8, 2) table (stride 4), small models, 3 trials per object
QUICK = dict(stride=4, trials_per_object=3, samples=256, min_per_stratum=2, samples_per_image=30, n_components=12)


def sweep(settings: ex.Settings, case: str = "i", planner: str = "mi-class", lambdas=DEFAULT_LAMBDAS,
          progress: bool = False) -> dict:
    """Run the case's trials once per λ; returns the JSON-ready summary."""
    lambdas = [check_weight(x) for x in lambdas]
    c = ex.CASES[case]
    prepared = ex.prepare(settings, progress=progress, databases=(c.database,))
    model = ex.case_model(prepared, c)
    rigs = ex.rig_pool(settings, c.cameras, seed=settings.seed)
    specs = ex.case_trials(c, settings, rigs[0], model.n_objects, model.n_poses)
    travel = rig_travel_times(rigs[0])
    base = ex.campaign_recognizer(model, planner, settings, travel)
    # every λ runs the same trials: the captures they agree on are rendered once
    pool = MemoRigs(LocalRigs(rigs), CaptureMemo(), tag=None)
    rows = []
    for lam in lambdas:
        rec = with_motion_cost(base, lam)
        t0 = time.perf_counter()
        res = run_campaign(rec, pool, specs, key=jr.PRNGKey(settings.seed + 1), batch=settings.batch,
                           seed=settings.seed, devices=settings.devices)
        avg = summarize(res, model.n_objects)[-1]
        rows.append({
            "lambda": lam,
            "trials": avg.trials,
            "rate": avg.rate,
            "rate_ci": list(avg.rate_ci),
            "views": avg.views,
            "travel_s": avg.travel_s,
            "travel_s_per_move": sum(r.travel_s for r in res) / max(1, sum(r.steps - 1 for r in res)),
            "exit_prob": avg.exit_prob,
            "confident_errors": avg.confident_errors,
            "seconds": time.perf_counter() - t0,
        })
        print(f"lambda {lam:g}: rate {format_rate(avg.rate, avg.rate_ci)} %, views {avg.views:.2f}, travel {avg.travel_s:.2f} s/trial, "
              f"exit {avg.exit_prob:.2f} ({rows[-1]['seconds']:.0f} s)", flush=True)
    return {
        "case": case,
        "planner": planner,
        "positions": list(model.positions),
        "lambda_units": "planner score per second (nats/s for MI)",
        "settings": {k: (str(v) if isinstance(v, Path) else v) for k, v in settings.flat().items()},
        "rows": rows,
    }


def plot(summary: dict, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = summary["rows"]
    lam = [r["lambda"] for r in rows]
    x = [max(v, 1e-3) for v in lam]  # λ = 0 on a log axis
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    a.plot(x, [r["views"] for r in rows], "o-")
    a.set_xscale("log")
    a.set_xlabel("λ (score per s; 0 drawn at 1e-3)")
    a.set_ylabel("mean views per trial")
    a2 = a.twinx()
    a2.plot(x, [r["travel_s"] for r in rows], "s--", color="C1")
    a2.set_ylabel("mean travel per trial (s)")
    a.legend(a.get_lines() + a2.get_lines(), ["mean views", "mean travel (s)"], loc="center left", fontsize=8)
    a.set_title(f"{summary['planner']}, case {summary['case']}, positions {summary['positions']}")
    b.plot([r["travel_s"] for r in rows], [r["views"] for r in rows], "o-")
    for r in rows:
        b.annotate(f"λ={r['lambda']:g}\n{r['rate']:.0f}%", (r["travel_s"], r["views"]), fontsize=7)
    b.set_xlabel("mean travel per trial (s)")
    b.set_ylabel("mean views per trial")
    b.set_title("views vs travel (labels: λ, recognition rate)")
    return save_png(fig, path, dpi=120)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path("out/motion_cost"))
    ap.add_argument("--workdir", type=Path, help="database and model cache (default: OUT/work)")
    ap.add_argument("--case", default="i", choices=sorted(ex.CASES))
    ap.add_argument("--planner", default="mi-class")
    ap.add_argument("--lambdas", type=float, nargs="+", default=list(DEFAULT_LAMBDAS))
    ap.add_argument("--trials", type=int, help="trials per object")
    ap.add_argument("--stride", type=int)
    ap.add_argument("--batch", type=int, default=16)
    ap.add_argument("--devices", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--quick", action="store_true", help="a small table and models, few trials (about a minute)")
    args = ap.parse_args(argv)
    values = dict(QUICK) if args.quick else {}
    for k, v in (("trials_per_object", args.trials), ("stride", args.stride)):
        if v is not None:
            values[k] = v
    try:
        settings = ex.Settings(workdir=args.workdir or args.out / "work", batch=args.batch, seed=args.seed,
                               devices=args.devices, **values)
        summary = sweep(settings, args.case, args.planner, args.lambdas)
    except ValueError as e:
        print(f"motion_cost_sweep: error: {e}", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    js = args.out / "motion_cost_sweep.json"
    js.write_text(json.dumps(summary, indent=1))
    png = plot(summary, args.out / "motion_cost_sweep.png")
    print(f"wrote {js}\nwrote {png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
