"""``jaxrecog plan``: score every camera configuration, print the best ones."""

from __future__ import annotations

import jax.random as jr
import numpy as np

from .. import plots
from ..hardware.rig import config_from_index
from ..modelfile import load_model
from ..planners import DEFAULT_PLANNER, make_planner
from ..recognizer import Recognizer
from ._common import UsageError, fmt_cfg, key, model_positions, print_table
from ._images import read_gray, usable
from ._options import PLANNERS, config_tuple, model_recipe, planner_size_options, positive, skip_invalid_option

NAME = "plan"
ORDER = 40
HELP = "score all camera configurations and print the best ones"
DESCRIPTION = ("Score every configuration with a planner, for the uniform belief or for the belief\n"
               "after a set of images taken at --at; print the best and the top configurations.")


def add_arguments(p) -> None:
    p.add_argument("model", metavar="MODEL.NPZ", help="model file")
    p.add_argument("--planner", choices=PLANNERS, default=None,
                   help=f"scoring rule (default: the model's recipe's; thesis-recipe and older files: {DEFAULT_PLANNER})")
    p.add_argument("--images", nargs="+", metavar="PNG",
                   help="one gray image per camera (8-bit, or float such as a 32-bit TIFF), taken at --at "
                        "(default: score the uniform belief)")
    p.add_argument("--at", type=config_tuple, metavar="V1,V2",
                   help="configuration the --images were taken at (one position per camera)")
    planner_size_options(p)
    skip_invalid_option(p)
    p.add_argument("--top", type=positive, default=10, help="how many configurations to list")
    p.add_argument("--plot", metavar="PNG", help="also write the scores as a heat map (PNG + SVG)")
    p.add_argument("--seed", type=int, default=0, help="PRNG seed")


def _scores_report(scores, positions, top: int) -> tuple[int, list]:
    s = np.asarray(scores, dtype=float)
    order = np.argsort(np.where(np.isfinite(s), -s, np.inf), kind="stable")[:top]
    rows = [(r + 1, fmt_cfg(config_from_index(int(a), positions)), int(a), f"{s[a]:.4g}") for r, a in enumerate(order)]
    return int(order[0]), rows


def run(args) -> int:
    if args.planner is None:
        args.planner = model_recipe(args.model).planner
    model = load_model(args.model)
    positions = model_positions(model)
    imgs = None
    if args.images:  # check everything before the (costly) planner tables
        if args.at is None:
            raise UsageError("--images needs --at V1,V2 (where they were taken)")
        if len(args.images) != len(positions) or len(args.at) != len(positions):
            raise UsageError(f"the model has {len(positions)} camera(s): give that many --images and --at positions")
        if any(v >= n for v, n in zip(args.at, positions)):
            raise UsageError(f"--at {fmt_cfg(args.at)} is outside the model's positions {positions}")
        imgs = usable([read_gray(p) for p in args.images], model.image_shape,
                      [f"image {p}" for p in args.images], args.skip_invalid)
    elif args.at is not None:
        raise UsageError("--at is only used with --images")
    k_plan, k_score = jr.split(key(args.seed))
    planner = make_planner(args.planner, model, key=k_plan, samples=args.samples,
                           min_per_stratum=args.min_per_stratum)
    rec = Recognizer(model, planner)
    if imgs is not None:
        state = rec.init(config=args.at)
        _, dec = rec.step(state, imgs, k_score, trace=True)
        scores = np.asarray(dec.trace.scores)
        unused = "" if bool(dec.valid) else " (not used)"
        print(f"after the images at {fmt_cfg(args.at)}{unused}: best (object, pose) = ({int(dec.object)}, "
              f"{int(dec.pose)}), P = {float(dec.probability):.3f}")
        what = f"belief after images at ({fmt_cfg(args.at)}){unused}"
    else:
        state = rec.init(config=(0,) * len(positions))
        scores = np.asarray(planner.scores(rec.belief(state.prior), k_score))
        what = "uniform belief"
    best, rows = _scores_report(scores, positions, args.top)
    cfg = config_from_index(int(best), positions)
    print(f"{args.planner} scores of {scores.size} configurations ({what}); best: ({fmt_cfg(cfg)}) "
          f"index {best}, score {scores[best]:.4g}")
    print_table(["rank", "config", "index", "score"], rows)
    if args.plot:
        for p in plots.score_heatmap(scores, positions, args.plot, chosen=cfg,
                                     title=f"{args.planner.upper()} scores, {what}",
                                     label=f"{args.planner} score (higher = better)"):
            print(f"wrote {p}")
    return 0
