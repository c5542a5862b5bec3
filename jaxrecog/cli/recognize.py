"""``jaxrecog recognize``: one recognition trial on a rig, step by step."""

from __future__ import annotations

from pathlib import Path

import jax.random as jr
import numpy as np

from .. import plots
from .._files import check_output_file, check_output_folder
from ..driver import StepRecord, TrialSpec, run_trials
from ..counts import CountsMismatchError, check_counts
from ..scene import CAPTURE_NOISE, occluder_factory  # the thesis-case boards (first views occluded)
from ..hardware import Capture, DatasetRig, Noise, RigError, rig_from_config
from ..modelfile import load_model
from ..motion import rig_travel_times
from ..planners import DEFAULT_PLANNER
from ..recognizer_factory import make_recognizer
from ._common import CLIError, UsageError, fmt_cfg, format_table, key, model_positions, synthetic_rig
from ._images import usable
from ._live import HANDHELD, check_handheld_flags, handheld_options, handheld_rig, recorder, rerun_options
from ._json import SCHEMA_VERSION, json_option, run_reporting
from ._options import (PLANNERS, choice_options, model_recipe, config_tuple, nonneg, planner_size_options, positive, probability,
                       skip_invalid_option, table_options)

NAME = "recognize"
ORDER = 50
HELP = "run one recognition trial on a rig"
DESCRIPTION = ("Place an object, then take image sets and move the cameras where the planner says\n"
               "until the best (object, pose) reaches --threshold or --max-steps; print each step.")


def add_arguments(p) -> None:
    p.add_argument("model", metavar="MODEL.NPZ", help="model file")
    p.add_argument("--rig", default="synthetic", metavar="RIG",
                   help="'synthetic' (pybullet scene), 'dataset:FOLDER' (replay a database's test split), "
                        "'handheld:DEVICE' (a person moves one camera; with --layout) "
                        "or a rig TOML file (simulated or real hardware)")
    p.add_argument("--object", type=nonneg, default=0, help="object to place (0-based)")
    p.add_argument("--pose", type=nonneg, default=0, help="its pose (0-based)")
    p.add_argument("--start", type=config_tuple, metavar="V1,V2",
                   help="initial configuration (default: random from --seed)")
    p.add_argument("--planner", choices=PLANNERS, default=None,
                   help="view planner (default: the model's recipe's; thesis-recipe and older model files: "
                        f"{DEFAULT_PLANNER})")
    p.add_argument("--threshold", type=probability, default=None,
                   help="stop probability P_th (default: the model's recipe's: robust 0.99, thesis 0.95)")
    p.add_argument("--max-steps", type=positive, default=7, help="largest number of image sets")
    planner_size_options(p)
    skip_invalid_option(p)
    p.add_argument("--occluders", action="store_true", help="synthetic rig: cardboard boards in front of the first views (as thesis case ii/iii)")
    p.add_argument("--noise", type=float, default=CAPTURE_NOISE[1], help="synthetic rig: per-pixel noise (gray levels)")
    p.add_argument("--plot", metavar="PNG", help="also plot the belief over objects per step")
    p.add_argument("--seed", type=int, default=0, help="PRNG seed (start, planner, rig noise)")
    choice_options(p, unset=True)  # the stop rule's parts default to the model's recipe
    table_options(p)
    json_option(p)
    handheld_options(p)
    rerun_options(p)


def _make_rig(args, model):
    """The rig of ``--rig``."""
    spec = args.rig
    if spec == "synthetic":
        if args.objects != model.n_objects or args.poses != model.n_poses:
            # the model's counts; random:N objects stay random (N from the model)
            random = isinstance(args.objects, str)
            args.objects = f"random:{model.n_objects}" if random else model.n_objects
            args.poses = model.n_poses
        brightness, _, max_shift = CAPTURE_NOISE  # a campaign's captures, with --noise per pixel
        return synthetic_rig(args, noise=Noise(brightness=brightness, pixel=args.noise, max_shift=max_shift),
                             seed=args.seed)
    if spec.startswith("dataset:"):
        folder = spec[len("dataset:"):]
        if not folder:
            raise UsageError("--rig dataset:FOLDER needs a folder")
        try:
            return DatasetRig.from_folder(folder, seed=args.seed)
        except RigError as e:  # a database that cannot be replayed: the user's input, one line
            raise CLIError(f"--rig {spec}: {e}") from None
    if spec.startswith(HANDHELD):
        return handheld_rig(args, model)
    if spec.endswith(".toml"):
        if not Path(spec).is_file():
            raise CLIError(f"rig file {spec} not found")
        return rig_from_config(spec)
    raise UsageError(f"--rig {spec!r}: expected 'synthetic', 'dataset:FOLDER', 'handheld:DEVICE' or a .toml rig file")


class _CheckedRig:
    """The command's rig, with every capture checked by :func:`usable` (one
    line naming a bad image, or a black frame in its place with
    ``--skip-invalid``), so the trial driver only ever sees usable images."""

    def __init__(self, rig, shape: tuple[int, int], skip_invalid: bool):
        self.rig, self.image_shape, self.skip_invalid = rig, tuple(shape), skip_invalid
        self.positions = tuple(rig.positions)
        self._step = 0

    def reset(self, object, pose, occluders=None):
        self.rig.reset(object, pose, occluders)

    def reseed(self, seed):
        self._step = int(seed[2])
        self.rig.reseed(seed)

    def move(self, configuration):
        self._config = tuple(configuration)
        self.rig.move(configuration)

    def capture(self) -> Capture:
        cap = self.rig.capture()
        names = [f"image of camera {i} at position {v} (step {self._step + 1})" for i, v in enumerate(self._config)]
        return Capture(usable(list(cap.images), self.image_shape, names, self.skip_invalid), cap.occluded)

    def close(self):
        self.rig.close()


#: (object, pose) states listed per step in ``--json`` (``belief``)
BELIEF_TOP = 5


def _step_doc(r: StepRecord, n_poses: int) -> dict:
    """One step of the trial (``--json``'s ``steps[]``)."""
    dec = r.decision
    pc = np.asarray(dec.trace.class_probs, dtype=float)
    top = np.argsort(-pc, kind="stable")[:BELIEF_TOP]
    return {"step": r.step + 1, "config": [int(v) for v in r.config], "object": int(dec.object),
            "pose": int(dec.pose), "probability": float(dec.probability), "valid": bool(dec.valid),
            "occluded": [float(x) for x in r.capture.occluded], "stop": bool(dec.stop),
            "next": None if bool(dec.stop) else [int(v) for v in np.asarray(dec.next_config)],
            "belief": [{"object": int(c) // n_poses, "pose": int(c) % n_poses, "probability": float(pc[c])}
                       for c in top],
            "object_probabilities": [float(x) for x in np.asarray(dec.trace.object_probs)]}


def _trial(args, model, rig, rec, state, k_run, live=None):
    """The trial on ``rig``, through the one trial driver (:func:`jaxrecog.driver.run_trials`).
    Returns the steps (:func:`_step_doc`), the last decision and the trial's result."""
    start = tuple(int(v) for v in np.asarray(state.config))
    occl = occluder_factory(rig)(np.random.default_rng(args.seed), start) if args.occluders else None
    steps, last = [], []

    def row(r: StepRecord) -> None:
        steps.append(_step_doc(r, model.n_poses))
        last[:] = [r.decision]
        if live is not None:  # --rerun: the live view
            live(r)

    spec = TrialSpec(0, args.object, args.pose, start, occl)
    (res,) = run_trials(rec, _CheckedRig(rig, model.image_shape, args.skip_invalid), [spec], key=k_run, batch=1,
                        seed=args.seed, trace=True, on_step=row)
    return steps, last[0], res


def _report(args) -> tuple[dict, str]:
    if args.min_views is not None and args.min_views > args.max_steps:  # before the model, the rig and the planner
        raise UsageError(f"--min-views {args.min_views} is above --max-steps {args.max_steps}")
    for f in plots.figure_paths(args.plot) if args.plot else ():  # before the trial, not after it
        check_output_file(f, "--plot file")
        check_output_folder(f.parent if str(f.parent) else ".", "--plot folder", create=False)
    recipe = model_recipe(args.model)   # the stop rule: the model's recipe unless an option gives it
    for opt, part in (("threshold", "p_threshold"), ("min_views", "min_views"), ("exclude_visited", "exclude_visited"),
                      ("adaptive_scale", "adaptive_scale"), ("planner", "planner")):
        if getattr(args, opt) is None:
            setattr(args, opt, getattr(recipe, part))
    args.min_views = min(args.min_views, args.max_steps)  # a recipe's rule within a shorter --max-steps
    args.shared_view = bool(args.shared_view)
    args.motion_cost = 0.0 if args.motion_cost is None else args.motion_cost
    model = load_model(args.model)
    positions = model_positions(model)
    if args.object >= model.n_objects or args.pose >= model.n_poses:
        raise UsageError(f"--object/--pose: the model has {model.n_objects} objects x {model.n_poses} poses")
    if args.start is not None and (len(args.start) != len(positions)
                                   or any(v >= n for v, n in zip(args.start, positions))):
        raise UsageError(f"--start {fmt_cfg(args.start)} does not fit the model's positions {positions}")
    if args.occluders and args.rig != "synthetic":
        raise UsageError("--occluders works with --rig synthetic only")
    check_handheld_flags(args)
    k_plan, k_init, k_run = jr.split(key(args.seed), 3)
    rig = _make_rig(args, model)
    live = None
    try:
        live = recorder(args, model, rig)  # a missing rerun: said before the trial
        try:  # cameras, positions, objects, poses, image size: every rig, before any step
            check_counts(model, rig, model_name=args.model, other_name=f"rig {args.rig}")
        except CountsMismatchError as e:
            hint = (" (use the --cameras/--stride the model's database was rendered with)"
                    if args.rig == "synthetic" else "")
            raise CLIError(f"{e}{hint}") from None
        travel = rig_travel_times(rig)
        if travel is None and args.motion_cost > 0:
            raise UsageError(f"--motion-cost needs the rig's geometry (travel times); --rig {args.rig} has none")
        rule = recipe.replace(p_threshold=args.threshold, min_views=args.min_views,
                              exclude_visited=args.exclude_visited, adaptive_scale=args.adaptive_scale)
        rec = make_recognizer(model, args.planner, recipe=rule, key=k_plan, samples=args.samples,
                              min_per_stratum=args.min_per_stratum, max_steps=args.max_steps,
                              shared_view=args.shared_view, travel=travel, motion_cost=args.motion_cost)
        state = rec.init(key=None if args.start is not None else k_init, config=args.start)
        start = [int(v) for v in np.asarray(state.config)]
        steps, dec, res = _trial(args, model, rig, rec, state, k_run, live)
    finally:
        rig.close()
        if live is not None:
            live.close()
    result = {"object": int(dec.object), "pose": int(dec.pose), "probability": float(dec.probability),
              "steps": len(steps), "correct": int(dec.object) == args.object and int(dec.pose) == args.pose,
              "travel_s": float(res.travel_s)}
    doc = {"command": NAME, "schema_version": SCHEMA_VERSION, "model": str(args.model), "rig": str(args.rig),
           "object": args.object, "pose": args.pose, "planner": args.planner, "threshold": float(args.threshold),
           "max_steps": args.max_steps, "min_views": int(args.min_views),
           "exclude_visited": bool(args.exclude_visited), "adaptive_scale": float(args.adaptive_scale),
           "shared_view": args.shared_view,
           "motion_cost": float(args.motion_cost), "recipe": recipe.name, "seed": args.seed, "start": start,
           "steps": steps, "result": result, "written": []}
    if args.plot:
        probs = np.stack([np.full(model.n_objects, 1.0 / model.n_objects)]
                         + [np.asarray(s["object_probabilities"], dtype=float) for s in steps])
        try:
            written = plots.belief_lines(probs, args.plot, true_object=args.object,
                                         title=f"Belief per step: object {args.object}, "
                                               f"pose {args.pose}, {args.planner}")
        except OSError as e:  # the trial is done: its result first (stdout; stderr with --json), then the error
            print(_text(doc))
            raise CLIError(f"--plot {args.plot} was not written ({e}); the trial's result is printed above") from None
        doc["written"] = [str(p) for p in written]
    if args.rerun_save:
        doc["written"].append(str(args.rerun_save))
    return doc, _text(doc)


def _text(doc: dict) -> str:
    rule = ""
    adaptive = doc["adaptive_scale"] > 1
    if doc["min_views"] > 1 or doc["exclude_visited"] or adaptive:
        rule = (f", recipe {doc['recipe']}: at least {doc['min_views']} " + ("explained " if adaptive else "")
                + "views" + (" from new positions" if doc["exclude_visited"] else "")
                + (f" (adaptive scale up to {doc['adaptive_scale']:g})" if adaptive else ""))
    lines = [f"object {doc['object']}, pose {doc['pose']} on rig {doc['rig']}; planner {doc['planner']}, "
             f"P_th {doc['threshold']}" + rule]
    lines.append(format_table(["step", "config", "object", "pose", "P", "occluded", "next"],
                              [(s["step"], fmt_cfg(s["config"]), s["object"], s["pose"], f"{s['probability']:.3f}",
                                " ".join(f"{100 * x:.0f}%" for x in s["occluded"]) or "-",
                                "stop" if s["stop"] else fmt_cfg(s["next"])) for s in doc["steps"]]))
    r = doc["result"]
    lines.append(f"result: object {r['object']}, pose {r['pose']} with P = {r['probability']:.3f} after "
                 f"{r['steps']} step(s) -- {'correct' if r['correct'] else 'WRONG'}")
    if r["travel_s"] == r["travel_s"]:
        lines.append(f"travel: {r['travel_s']:.2f} s of rig motion (motion cost {doc['motion_cost']:g} per s)")
    return "\n".join(lines + [f"wrote {p}" for p in doc["written"]])


def run(args) -> int:
    return run_reporting(args, _report)
