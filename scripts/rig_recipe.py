#!/usr/bin/env python
"""A recipe on a synthetic case, every part of it: the case's model trained by
the recipe, calibrated on held-out captures of the case, the planner's
stability weight fitted on them, then the case's trials.

``jaxrecog experiment CASE`` trains a case's models uncalibrated (the rig
renders no ``calib`` split), so a recipe's parts that read a ``calib`` split
(``calibrate``, ``stability``) do not apply there.  This script renders the
split (:mod:`jaxrecog.campaigns.held_out`): one held-out capture per (camera,
position, object, pose), drawn like the case's own captures
(:func:`~jaxrecog.campaigns.held_out.like_case`: on the grid for (i)-(iii),
the case's yaw, camera offset and light for the jitter cases; a board in
front of half the views of an occluded case), and then does what ``jaxrecog
train`` does with a database that has one: calibrate
(:func:`jaxrecog.calibration.calibrate_model`) when the recipe says so, fit
the stability weight (:func:`jaxrecog.stability_fit.fit_stability`) when it
is ``auto``.  The trials are those of ``jaxrecog experiment CASE`` (same
seed, poses, starts, occluders and capture noise); the planner default is the
recipe's.  The rig renders no views between its training positions, so the
recipe's ``view_jitter = auto`` is given rendered ones (``--view-jitter``,
default 8 renders within ±20°, as in docs/results.md).

Example (docs/results.md, "The synthetic cases with every part of the recipe")::

    python scripts/rig_recipe.py --case iii --trials 100 --workdir out/rig-recipe
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from jaxrecog.calibration import calibrate_model
from jaxrecog.cli._options import gray_range, positive, probability, stability_weight
from jaxrecog.calibration_data import CalibrationFeatures, features_from_database
from jaxrecog.campaigns import CASES, Settings, capture_pool, case_settings, case_trials, compare_planners, make_rig, prepare
from jaxrecog.campaigns.held_out import like_case, render_held_out
from jaxrecog.campaigns.naming import run_id
from jaxrecog.database import load_database
from jaxrecog.modelfile import load_model
from jaxrecog.recipes import AUTO, RECIPES, get_recipe
from jaxrecog.recognizer import restrict_cameras
from jaxrecog.stability_fit import with_stability


def build_parser() -> argparse.ArgumentParser:
    """The command line of this script (the docs tests parse the docs' commands with it)."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--case", default="iii", choices=sorted(CASES))
    ap.add_argument("--recipe", default="robust", choices=sorted(RECIPES))
    ap.add_argument("--planners", default=None, help="comma-separated planners (default: the recipe's)")
    ap.add_argument("--trials", type=int, default=25, help="trials per object")
    ap.add_argument("--workdir", type=Path, default=Path("out/rig-recipe"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--stride", type=int, default=1, help="every STRIDE-th position of each camera (quick runs)")
    ap.add_argument("--n-components", type=int, default=20)
    ap.add_argument("--samples-per-image", type=int, default=100)
    ap.add_argument("--view-jitter", type=int, default=8, help="rendered views per training view (0: none)")
    ap.add_argument("--view-jitter-deg", type=float, default=20.0, help="their yaw range, +-degrees")
    ap.add_argument("--occluder-gray", type=gray_range, default=None, metavar="LO,HI",
                    help="DB2 training occluders with a gray level uniform in [LO, HI] (default: the recipe's; "
                         "robust 0,255, thesis 0,0 = black)")
    ap.add_argument("--stability", type=stability_weight, default=None, metavar="W|auto",
                    help="the planner's stability weight (default: the recipe's; auto = fitted on the held-out captures)")
    ap.add_argument("--calibrate", action=argparse.BooleanOptionalAction, default=None,
                    help="override the recipe's calibration on the held-out captures")
    ap.add_argument("--calib-pool", action=argparse.BooleanOptionalAction, default=None,
                    help="pool the calibration factors per camera (default: the recipe's calib_pool)")
    ap.add_argument("--exclude-visited", action=argparse.BooleanOptionalAction, default=None,
                    help="override the recipe's revisit exclusion")
    ap.add_argument("--calib-per-view", type=positive, default=1,
                    help="held-out captures per (camera, position, object, pose)")
    ap.add_argument("--occluded-fraction", type=probability, default=0.5,
                    help="occluded cases: share of held-out views with a board in front")
    return ap


def fitted_model(settings: Settings, case, prepared, *, occluded_fraction: float = 0.5, calib_per_view: int = 1):
    """The case's model with the recipe's ``calib``-split parts applied on its
    held-out captures; returns ``(model, notes)`` (``notes``: what was fitted, for the report)."""
    recipe = settings.recipe
    folder = settings.workdir / (f"held-out-{case.name}-stride{settings.stride}-seed{settings.seed}"
                                 f"{f'-n{calib_per_view}' if calib_per_view != 1 else ''}"
                                 f"{f'-front{occluded_fraction:g}' if case.occluded else ''}")
    db = load_database(render_held_out(folder, settings, case, like_case(case, settings), calib_per_view=calib_per_view,
                                       occluded_fraction=occluded_fraction, seed=settings.seed + 2000))
    model = load_model(prepared.models[case.database])
    notes = {"held_out": str(folder)}
    if recipe.calibrate:                      # True or auto: the split is here
        model, info = calibrate_model(model, db, pool=recipe.calib_pool)
        notes["calibration"] = info.summary()
    feats = features_from_database(model, db, "calib") if recipe.stability == AUTO else None
    if case.cameras is not None:   # a single-camera case: its cameras' model and held-out captures
        model = restrict_cameras(model, case.cameras)
        if feats is not None:
            feats = CalibrationFeatures(tuple(feats.cameras[i] for i in case.cameras))
    model, fit = with_stability(model, recipe, feats)
    if fit is not None:
        notes["stability_fit"] = fit.to_dict()
        notes["stability"] = fit.summary()
    return model, notes


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    case = CASES[args.case]
    given = {part: getattr(args, part) for part in ("stability", "exclude_visited", "calibrate", "calib_pool")}
    recipe = get_recipe(args.recipe).replace(**{part: v for part, v in given.items() if v is not None})
    settings = Settings(recipe=recipe, workdir=args.workdir, trials_per_object=args.trials, seed=args.seed,
                        stride=args.stride, n_components=args.n_components, samples_per_image=args.samples_per_image,
                        view_jitter=args.view_jitter, view_jitter_deg=args.view_jitter_deg,
                        **({} if args.occluder_gray is None else {"occluder_gray": args.occluder_gray}))
    settings = case_settings(case, settings)
    t0 = time.perf_counter()
    prepared = prepare(settings, progress=False, databases=(case.database,))
    model, notes = fitted_model(settings, case, prepared, occluded_fraction=args.occluded_fraction,
                                calib_per_view=args.calib_per_view)
    for k in ("calibration", "stability"):
        if k in notes:
            print(notes[k], flush=True)
    planners = args.planners.split(",") if args.planners else [recipe.planner]
    probe = make_rig(settings, case.cameras, seed=settings.seed)
    specs = case_trials(case, settings, probe, model.n_objects, model.n_poses)
    tag = (f"{recipe.name}{recipe.version}-w{model.stability:g}-cal{int(bool(recipe.calibrate))}"
           f"{'-pool' if recipe.calibrate and recipe.calib_pool else ''}"
           f"{'' if recipe.exclude_visited else '-noxv'}"
           f"-front{args.occluded_fraction:g}-c{args.calib_per_view}-{run_id(settings, prepared.models[case.database])}")
    with capture_pool(settings, case.cameras, seed=settings.seed) as rigs:
        report = compare_planners(case, model, rigs, specs, settings, planners,
                                  lambda planner: f"recipe-{case.name}-{planner}-{tag}", progress=False,
                                  on_result=None, probe=probe)
    rows, metrics = report.metrics_table(digits=2)
    table = "\n".join([f"Case {case.name} ({case.title}), recipe {recipe.name} version {recipe.version}, "
                       f"{args.trials} trials per object, P_th = {settings.p_threshold}", "", *rows])
    print(table)
    out = settings.workdir / "results"
    out.mkdir(parents=True, exist_ok=True)
    lo, hi = settings.occluder_gray
    gray = f"-gray{lo:g}-{hi:g}" if case.database == "DB2" else ""
    extra = f"-w{model.stability:g}" if args.stability is not None else ""
    extra += f"-c{args.calib_per_view}" if args.calib_per_view != 1 else ""
    extra += "" if args.exclude_visited is None else f"-xv{int(args.exclude_visited)}"
    extra += "" if args.calibrate is None else f"-cal{int(args.calibrate)}"
    extra += "" if args.calib_pool is None else f"-pool{int(args.calib_pool)}"
    extra += f"-seed{args.seed}" if args.seed else ""
    stem = f"rig-recipe-{case.name}-{recipe.name}-n{args.trials}-stride{args.stride}{gray}{extra}"
    (out / f"{stem}.md").write_text(table + "\n")
    ran = settings.recipe.replace(stability=model.stability, calibrate=bool(settings.recipe.calibrate))
    (out / f"{stem}.json").write_text(json.dumps({"metrics": metrics, "notes": notes, "recipe": ran.to_dict(),
                                                  "stability": model.stability, "case": case.name}, indent=1))
    print(f"wrote {out / stem}.{{md,json}} ({time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
