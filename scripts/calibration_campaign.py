#!/usr/bin/env python
"""Calibrated vs. uncalibrated recognizer, side by side, on the synthetic rig.

1. ``campaigns.prepare``: renders the training database and trains the
   case's model (cached in ``--workdir``);
2. renders a held-out ``calib`` database (views near the training views:
   object yaw, camera offset, lighting, capture noise; occluded when the case
   is) and fits the variance factors (:func:`jaxrecog.calibration.calibrate_model`),
   saving the calibrated model file next to the uncalibrated one;
3. runs the *same* trials (poses, initial configurations, occluders, capture
   noise) with both models and prints recognition rate, mean views, ECE and
   the confident-error rate (stopped at >= P_th and wrong), writes a JSON
   summary and a reliability diagram PNG.

Reduced example (a few minutes on a laptop CPU)::

    python scripts/calibration_campaign.py --workdir out/calib --case i --trials 4 --samples 256
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import jax.random as jr

from jaxrecog.calibration import calibrate_model
from jaxrecog.cli._options import (given_likelihood_options, gray_range, likelihood_choice, likelihood_options, positive,
                                   render_jitter_options, render_jitter_values)
from jaxrecog.calibration_plots import reliability_plot
from jaxrecog.campaign import run_campaign
from jaxrecog.database import load_database
from jaxrecog.campaigns import CASES, Settings, campaign_recognizer, case_settings, case_trials, make_rig, prepare
from jaxrecog.campaigns.held_out import render_held_out
from jaxrecog.hardware.render.synthetic import Noise, Perturb
from jaxrecog.metrics import campaign_metrics
from jaxrecog.modelfile import load_model, save_model
from jaxrecog.recognizer import restrict_cameras
from jaxrecog.results import TrialStore, format_rate


def build_parser() -> argparse.ArgumentParser:
    """The command line of this script (the docs tests parse the docs' commands with it)."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--workdir", type=Path, default=Path("out/calibration"))
    ap.add_argument("--case", default="i", choices=sorted(CASES))
    ap.add_argument("--planner", default="mi")
    ap.add_argument("--trials", type=int, default=10, help="trials per object")
    ap.add_argument("--samples", type=int, default=512, help="Monte Carlo samples of the planner")
    ap.add_argument("--batch", type=int, default=16)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--n-components", type=int, default=20)
    ap.add_argument("--samples-per-image", type=int, default=100)
    ap.add_argument("--calib-per-view", type=int, default=1, help="held-out renders per (camera, position, object, pose)")
    ap.add_argument("--yaw", type=float, default=3.0, help="object yaw perturbation (deg)")
    ap.add_argument("--eye-offset", type=float, default=0.02, help="camera offset (fraction of distance)")
    ap.add_argument("--light", type=float, default=0.1, help="relative lighting jitter")
    ap.add_argument("--per-level", action="store_true", help="one factor per (position, level)")
    ap.add_argument("--prior-sd", type=float, default=1.0)
    ap.add_argument("--min-factor", type=float, default=1.0, help="lower bound on the factors (<= 0: unbounded)")
    ap.add_argument("--bins", type=int, default=10)
    ap.add_argument("--occluded-fraction", type=float, default=0.5,
                    help="occluded cases: share of calib views with a board in front of that view")
    ap.add_argument("--exclude-visited", action="store_true", help="never send a camera back to a position it used")
    ap.add_argument("--min-views", type=positive, default=1, metavar="N",
                    help="never stop on the threshold before N image sets (Recognizer(min_views=N); the thesis: 1)")
    ap.add_argument("--occluder-gray", type=gray_range, default=(0.0, 0.0), metavar="LO,HI",
                    help="DB2 training occluders with a gray level uniform in [LO, HI] (default black, the thesis's)")
    ap.add_argument("--shared-view", action="store_true",
                    help="keep a view mixture's component in the belief, one per trial (Recognizer(shared_view=True))")
    likelihood_options(ap)
    render_jitter_options(ap)
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)

    case = CASES[args.case]
    likelihood, options = likelihood_choice(args.likelihood, given_likelihood_options(args),
                                            view_jitter=bool(args.view_jitter))
    settings = Settings(workdir=args.workdir, trials_per_object=args.trials, seed=args.seed, samples=args.samples,
                        batch=args.batch, n_components=args.n_components, samples_per_image=args.samples_per_image,
                        likelihood=likelihood, likelihood_options=options, exclude_visited_positions=args.exclude_visited,
                        min_views=args.min_views, shared_view=args.shared_view, occluder_gray=args.occluder_gray, **render_jitter_values(args))
    settings = case_settings(case, settings)  # the case's off-grid amounts (jitter cases)
    t0 = time.perf_counter()
    prepared = prepare(settings, progress=True, databases=(case.database,))

    # held-out calibration views (occluded when the case is)
    b, p, s = settings.capture_noise
    perturb = Perturb(yaw_deg=args.yaw, eye_offset=args.eye_offset, light=args.light,
                      noise=Noise(brightness=b, pixel=p, max_shift=int(s)))
    calib_dir = args.workdir / (f"calib-{'occ' if case.occluded else 'clean'}-n{args.calib_per_view}"
                                f"-y{args.yaw:g}-e{args.eye_offset:g}-l{args.light:g}-seed{args.seed}")
    if case.occluded:
        calib_dir = calib_dir.with_name(calib_dir.name + f"-front{args.occluded_fraction:g}")
    if not (calib_dir / "manifest.csv").exists():
        print(f"rendering calibration views into {calib_dir} ...", flush=True)
        render_held_out(calib_dir, settings, case, perturb, calib_per_view=args.calib_per_view,
                        occluded_fraction=args.occluded_fraction, seed=args.seed + 1000)
    calib_db = load_database(calib_dir)

    model_path = prepared.models[case.database]
    full = load_model(model_path)
    min_factor = args.min_factor if args.min_factor > 0 else None
    cal_full, info = calibrate_model(full, calib_db, per_level=args.per_level, prior_sd=args.prior_sd,
                                     min_factor=min_factor)
    print(info.summary(), flush=True)
    cal_path = model_path.with_name(model_path.stem + "-calibrated.npz")
    save_model(cal_path, cal_full, calibration=info.to_dict())
    models = {"uncalibrated": full, "calibrated": cal_full}
    if case.cameras is not None:
        models = {k: restrict_cameras(m, case.cameras) for k, m in models.items()}

    results, metrics = {}, {}
    tag = (f"-{model_path.stem.removeprefix('model-')}{'-xv' if args.exclude_visited else ''}{'-sv' if args.shared_view else ''}{f'-mv{args.min_views}' if args.min_views > 1 else ''}"
           f"-{'perlevel' if args.per_level else 'perpos'}-sd{args.prior_sd:g}-min{min_factor or 0:g}"
           f"-y{args.yaw:g}-e{args.eye_offset:g}-l{args.light:g}-c{args.calib_per_view}"
           f"{f'-front{args.occluded_fraction:g}' if case.occluded else ''}")
    for label, model in models.items():
        rig = make_rig(settings, case.cameras, seed=settings.seed)      # same capture noise for both
        specs = case_trials(case, settings, rig, model.n_objects, model.n_poses)
        rec = campaign_recognizer(model, args.planner, settings)
        store = TrialStore(args.workdir / "trials" / (
            f"calib-{label}-case-{case.name}-{args.planner}-n{args.trials}-seed{args.seed}-v3"
            f"{tag if label == 'calibrated' else tag.split('-perl')[0].split('-perp')[0]}.jsonl"))
        t1 = time.perf_counter()
        res = run_campaign(rec, rig, specs, key=jr.PRNGKey(settings.seed + 1), batch=settings.batch, seed=settings.seed, store=store)
        rig.close()
        results[label] = res
        metrics[label] = {**campaign_metrics(res, settings.p_threshold, args.bins),
                          "seconds": time.perf_counter() - t1}

    head = ("| model | trials | recog. rate (%) [95 % CI] | mean views | mean exit prob. | ECE | stopped "
            "| confident errors (% of trials; % of stopped) [95 % CI] |")
    lines = [f"Case {case.name} ({case.title}), planner {args.planner}, {args.trials} trials/object, "
             f"P_th = {settings.p_threshold}", "", head, "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for label, m in metrics.items():
        lines.append(f"| {label} | {m['trials']} | {format_rate(m['recognition_rate'], m['recognition_rate_ci'])} | {m['mean_views']:.2f} | "
                     f"{m['mean_exit_prob']:.3f} | {m['ece']:.3f} | {m['stopped']} | "
                     f"{m['confident_errors']} ({format_rate(m['confident_error_pct_of_trials'], m['confident_error_pct_of_trials_ci'])} %; "
                     f"{format_rate(m['confident_error_rate'], m['confident_error_rate_ci'])} %) |")
    table = "\n".join(lines)
    print(table)
    out = args.workdir / "results"
    out.mkdir(parents=True, exist_ok=True)
    stem = f"calibration-case-{case.name}-{args.planner}-n{args.trials}{tag}"
    png = reliability_plot(results, out / f"{stem}.png", n_bins=args.bins, p_threshold=settings.p_threshold,
                           title=f"Reliability, case {case.name}, {args.planner}")
    (out / f"{stem}.md").write_text(table + "\n")
    (out / f"{stem}.json").write_text(json.dumps(
        {"metrics": metrics, "calibration": info.to_dict(), "settings": {
            **{k: (str(v) if isinstance(v, Path) else v) for k, v in settings.flat().items()},
            "case": case.name, "planner": args.planner, "perturb": dataclasses.asdict(perturb)}}, indent=1))
    print(f"wrote {png} and {out / stem}.{{md,json}} ({time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
