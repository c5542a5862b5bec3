#!/usr/bin/env python
"""Our planners as baselines through the Gymnasium environment, beside
run_campaign on the same trials.

    python scripts/env_baselines.py --case iii --trials 100            # full size
    python scripts/env_baselines.py --case i --trials 2 --stride 8     # a smoke run

For each planner (default mi, mi-class, crlb, random), the case's trials
(:mod:`jaxrecog.campaigns`: same poses, starts, occluders and capture
noise) run once through ``ActiveRecognitionEnv`` with
``PlannerPolicy(planner)`` and once through ``run_campaign``; prints the
average recognition rate, views, confident errors (wrong and stopped at
p >= P_th) and wall time of each, and the fraction of trials where both
took the same path.  Renders the database and trains the case's model on
first use (cached in --workdir).  Writes JSON with --out.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def build_parser() -> argparse.ArgumentParser:
    """The command line of this script (the docs tests parse the docs' commands with it)."""
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--case", default="i", help="a case of jaxrecog.campaigns.CASES (default: i)")
    p.add_argument("--planners", default="mi,mi-class,crlb,random")
    p.add_argument("--trials", type=int, default=100, help="trials per object (default: 100)")
    p.add_argument("--stride", type=int, default=1, help="every STRIDE-th position of each camera (default: 1)")
    p.add_argument("--workdir", default="out/thesis", help="database and models (default: out/thesis)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-campaign", action="store_true", help="only the env, not run_campaign beside it")
    p.add_argument("--out", default=None, help="write the numbers as JSON here")
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)

    from jaxrecog.campaigns import CASES, Settings, case_model, case_trials, prepare

    if args.case not in CASES:
        print(f"env_baselines: unknown case {args.case!r}; choose one of {', '.join(CASES)}", file=sys.stderr)
        return 2

    from jaxrecog.envs import ActiveRecognitionEnv, PlannerPolicy, env_vs_campaign, run_episodes, summary
    from jaxrecog.results import format_rate

    case = CASES[args.case]
    settings = Settings(workdir=Path(args.workdir), trials_per_object=args.trials, stride=args.stride, seed=args.seed)
    model = case_model(prepare(settings, databases=(case.database,)), case)
    env = ActiveRecognitionEnv(model, "synthetic", case="occluded" if case.occluded else "clean", settings=settings,
                               cameras=case.cameras)
    specs = case_trials(case, settings, env.rig, model.n_objects, model.n_poses)
    print(f"{case.title}: {len(specs)} trials, positions {env.positions}")
    report = {"case": args.case, "trials": len(specs), "stride": args.stride, "planners": {}}
    for planner in args.planners.split(","):
        if args.no_campaign:
            import time

            t0 = time.perf_counter()
            res = run_episodes(env, PlannerPolicy(planner, env), specs, capture_seed=settings.seed)
            row = {"env": summary(res, model.n_objects), "env_s": time.perf_counter() - t0}
        else:
            cmp = env_vs_campaign(env, planner, specs, batch=settings.batch)
            row = {"env": summary(cmp["env"], model.n_objects), "env_s": cmp["env_s"],
                   "campaign": summary(cmp["campaign"], model.n_objects), "campaign_s": cmp["campaign_s"],
                   "same_path": cmp["same"]}
        report["planners"][planner] = row
        for kind in ("env", "campaign"):
            if kind in row:
                s = row[kind]
                print(f"{planner:9s} {kind:8s}: rate {format_rate(s['rate'], s['rate_ci'])} %, views {s['views']:.2f}, exit p {s['exit_prob']:.3f}, "
                      f"confident errors {s['confident_errors']}, {row[kind + '_s']:.0f} s")
        if "same_path" in row:
            print(f"{planner:9s} same path in {100 * row['same_path']:.1f} % of the trials")
    if args.out:
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        with out.open("w") as f:
            json.dump(report, f, indent=1)
        print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
