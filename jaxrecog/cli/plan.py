"""``jaxrecog plan``: score every camera configuration, print the best ones."""

from __future__ import annotations

import equinox as eqx
import jax.random as jr
import numpy as np

from .. import kernels as K
from .. import plots
from ..hardware.rigs.rig import config_from_index
from ..modelfile import load_model
from ..planners import DEFAULT_PLANNER
from ..recognizer_factory import make_recognizer
from ._common import UsageError, fmt_cfg, format_table, key, model_positions
from ._images import read_gray, usable
from ._json import SCHEMA_VERSION, json_option, run_reporting
from ._options import (PLANNERS, adaptive_scale, config_tuple, model_recipe, planner_size_options, positive,
                       skip_invalid_option)

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
    p.add_argument("--adaptive-scale", type=adaptive_scale, metavar="S", default=None,
                   help="the evidence of --images as recognize weighs it: a capture that no class explains is "
                        "weakened by a variance factor up to S (default: the model's recipe's: robust 32, "
                        "thesis 1 = off)")
    planner_size_options(p)
    skip_invalid_option(p)
    p.add_argument("--top", type=positive, default=10, help="how many configurations to list")
    p.add_argument("--plot", metavar="PNG", help="also write the scores as a heat map (PNG + SVG)")
    p.add_argument("--seed", type=int, default=0, help="PRNG seed")
    json_option(p)


def shown_scores(scores) -> np.ndarray:
    """The scores as reported: float, with round-off below 1e-6 of the
    largest finite ``|score|`` set to 0 (an MI of ``-2.2e-08`` is 0)."""
    s = np.asarray(scores, dtype=float)
    finite = np.isfinite(s)
    scale = float(np.max(np.abs(s[finite]))) if finite.any() else 0.0
    return np.where(finite & (np.abs(s) <= 1e-6 * scale), 0.0, s)


@eqx.filter_jit
def _scores_as_is(planner, belief, positions: tuple[int, ...], key):
    """The planner's scores of ``belief`` as it is at every configuration, as
    one compiled program (op by op, the pairwise kernel compiled ~30 small ones)."""
    return planner.scores(K.at_every_position(belief, positions), key)


def _ranking(scores, positions, top: int) -> list[dict]:
    """The ``top`` best configurations, best first (a non-finite score last)."""
    s = shown_scores(scores)
    order = np.argsort(np.where(np.isfinite(s), -s, np.inf), kind="stable")[:top]
    return [{"rank": r + 1, "config": [int(v) for v in config_from_index(int(a), positions)], "index": int(a),
             "score": float(s[a])} for r, a in enumerate(order)]


def _report(args) -> tuple[dict, str]:
    recipe = model_recipe(args.model)   # the planner and the evidence: the model's recipe unless an option gives them
    if args.planner is None:
        args.planner = recipe.planner
    if args.adaptive_scale is None:
        args.adaptive_scale = recipe.adaptive_scale
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
    # the recognizer `recognize` builds from this model (its recipe's evidence and stop rule), so the belief
    # after --images is the one its first step would hold; the scores are the planner's, before any exclusion
    rec = make_recognizer(model, args.planner, recipe=recipe.replace(adaptive_scale=args.adaptive_scale), key=k_plan,
                          samples=args.samples, min_per_stratum=args.min_per_stratum)
    planner = rec.planner
    images = None
    if imgs is not None:
        state = rec.init(config=args.at)
        _, dec = rec.step(state, imgs, k_score, trace=True)
        scores = np.asarray(dec.trace.scores)
        images = {"paths": [str(p) for p in args.images], "at": [int(v) for v in args.at], "used": bool(dec.valid),
                  "object": int(dec.object), "pose": int(dec.pose), "probability": float(dec.probability)}
    else:
        state = rec.init(config=(0,) * len(positions))
        scores = np.asarray(_scores_as_is(planner, rec.belief(state.prior), positions, k_score))
    ranking = _ranking(scores, positions, args.top)
    written = []
    if args.plot:
        what = _belief_words(images)
        written = plots.score_heatmap(scores, positions, args.plot, chosen=tuple(ranking[0]["config"]),
                                      title=f"{args.planner} scores, {what}",
                                      label=f"{args.planner} score (higher = better)")
    doc = {"command": NAME, "schema_version": SCHEMA_VERSION, "model": str(args.model), "planner": args.planner,
           "samples": args.samples, "min_per_stratum": args.min_per_stratum, "seed": args.seed,
           "adaptive_scale": float(args.adaptive_scale),
           "positions": list(positions), "belief": "uniform" if images is None else "images", "images": images,
           "configurations": int(np.asarray(scores).size), "best": ranking[0], "ranking": ranking,
           "written": [str(p) for p in written]}
    return doc, _text(doc)


def _belief_words(images: dict | None) -> str:
    if images is None:
        return "uniform belief"
    return f"belief after images at ({fmt_cfg(images['at'])})" + ("" if images["used"] else " (not used)")


def _text(doc: dict) -> str:
    lines = []
    images = doc["images"]
    if images is not None:
        lines.append(f"after the images at {fmt_cfg(images['at'])}{'' if images['used'] else ' (not used)'}: best "
                     f"(object, pose) = ({images['object']}, {images['pose']}), P = {images['probability']:.3f}")
    best = doc["best"]
    lines.append(f"{doc['planner']} scores of {doc['configurations']} configurations ({_belief_words(images)}); "
                 f"best: ({fmt_cfg(best['config'])}) index {best['index']}, score {best['score']:.4g}")
    lines.append(format_table(["rank", "config", "index", "score"],
                              [(r["rank"], fmt_cfg(r["config"]), r["index"], f"{r['score']:.4g}")
                               for r in doc["ranking"]]))
    return "\n".join(lines + [f"wrote {p}" for p in doc["written"]])


def run(args) -> int:
    return run_reporting(args, _report)
