"""``jaxrecog train``: a sensor model (DB1/DB2) from an image database."""

from __future__ import annotations

import argparse
import sys

from ..augment import AugmentParams
from ..calibration import calibrate_model
from ..calibration_data import features_from_database
from ..database import load_database
from ..eigenspace import ComponentsError
from ..kernels import likelihood_class
from .._lock import file_lock
from ..modelfile import check_writable, load_model, load_model_meta, save_model
from .._progress import bar
from ..recipes import AUTO, DEFAULT_RECIPE, RECIPES, Recipe, get_recipe, recipe_from_meta
from ..stability_fit import with_stability
from ..train import add_objects, added_calibration_features, train_model
from ._common import UsageError
from ._options import (PLANNERS, adaptive_scale, capture_options, capture_params, default_likelihood, given_likelihood_options,
                       likelihood_choice, likelihood_options, nonneg, positive, probability, stability_weight)

NAME = "train"
ORDER = 20
HELP = "train a sensor model (DB1/DB2) from an image database"
DESCRIPTION = ("Train the eigenspace + likelihood sensor model of an image database and write the\n"
               "model file (.npz).  DB1 = noise and shifts; DB2 adds occluders of 5..25 %.\n"
               f"--recipe (default {DEFAULT_RECIPE}) bundles the likelihood, interpolated views, view jitter,\n"
               "calibration, shift range and the stop rule (`jaxrecog recipes` lists them); the options\n"
               "below override its parts, and the model file records the recipe as used.\n"
               "Likelihoods: gaussian-diag (the thesis), gaussian-full, gaussian-lowrank (--rank),\n"
               "student-t (--nu; heavy tails, so one unmodelled deviation cannot drive a belief to 1),\n"
               "view-mixture and view-mixture-lowrank (--rank; one component per rendered view near each\n"
               "training view: needs --view-jitter and a database with 'jitter' rows).\n"
               "--add NEW_DB --to MODEL adds the objects of NEW_DB to a trained model without retraining\n"
               "its classes: the model's eigenspaces stay, only the new classes are fitted, by the model's\n"
               "own training settings and recipe (no other training option applies), then the model is\n"
               "recalibrated on NEW_DB's 'calib' split if it was calibrated (--no-calibrate: keep its\n"
               "factors).  NEW_DB needs the model's cameras, positions, poses and image size; its object m\n"
               "becomes object M_old + m of the result (M_old = the model's objects).  An object whose\n"
               "training image is identical to one of the model's is already in it: an error.")

#: K when ``--components`` is not given (or less: the database's smallest eigenspace rank)
DEFAULT_COMPONENTS = 20

#: ``--covariance`` (the older option) -> the ``--likelihood`` it stands for
_COVARIANCE = {"diag": "gaussian-diag", "full": "gaussian-full"}


def add_arguments(p) -> None:
    p.add_argument("database", metavar="DATABASE", nargs="?", default=None,
                   help="image database folder (with manifest.csv); not with --add")
    p.add_argument("--out", required=True, metavar="MODEL.NPZ", help="model file to write (in a folder that exists; one train per file at a time)")
    p.add_argument("--add", default=None, metavar="NEW_DB",
                   help="add the objects of this image database to the model --to (its object m becomes object "
                        "M_old + m); the model's training settings are used")
    p.add_argument("--to", default=None, metavar="MODEL.NPZ",
                   help="with --add: the trained model to add to (read only; --out may name it to replace it)")
    p.add_argument("--recipe", choices=tuple(RECIPES), default=DEFAULT_RECIPE,
                   help=f"training and stop-rule recipe (default {DEFAULT_RECIPE}; 'thesis' = the thesis's protocol)")
    p.add_argument("--kind", choices=("DB1", "DB2"), default="DB2", help="augmentation kind")
    p.add_argument("--components", type=float, default=None,
                   help=f"eigenvectors K per position (an integer), or the energy fraction to keep, in (0, 1] "
                        f"(default: {DEFAULT_COMPONENTS}, or the database's smallest eigenspace rank where that is "
                        f"less)")
    p.add_argument("--samples", type=positive, default=100,
                   help="augmented samples per training image and occlusion level")
    likelihood_options(p)
    p.add_argument("--covariance", choices=tuple(_COVARIANCE), default=None,
                   help="older alias: 'diag' = --likelihood gaussian-diag, 'full' = --likelihood gaussian-full")
    p.add_argument("--seed", type=int, default=0, help="seed of the augmentation")
    g = p.add_argument_group("recipe parts (default: the recipe's)")
    g.add_argument("--interpolate", type=nonneg, default=None, metavar="N",
                   help="N interpolated views per side toward each neighbouring position (view-mixture "
                        "components between the training views; 0 = none)")
    g.add_argument("--interpolation", choices=("linear", "flow"), default=None,
                   help="how the interpolated views are made: 'linear' (cross-fade) or 'flow' (optical-flow morph)")
    g.add_argument("--calibrate", action=argparse.BooleanOptionalAction, default=None,
                   help="calibrate the model on the database's 'calib' split (jaxrecog.calibration)")
    g.add_argument("--calib-pool", action=argparse.BooleanOptionalAction, default=None,
                   help="shrink each position's calibration factor toward its camera's pooled one "
                        "(jaxrecog.calibration.pooled_log_factors; a position without calib images takes it)")
    g.add_argument("--view-jitter", action=argparse.BooleanOptionalAction, default=None,
                   help="use the database's 'jitter' rows (images near a training view, each labelled with that "
                        "view) as extra base images of their view: each gets --samples augmented samples like "
                        "the training image (jaxrecog.train.train_model)")
    g.add_argument("--threshold", type=probability, default=None, help="stop rule recorded in the model: P_th")
    g.add_argument("--min-views", type=positive, default=None, metavar="N",
                   help="stop rule recorded in the model: never stop on P_th before N image sets")
    g.add_argument("--exclude-visited", action=argparse.BooleanOptionalAction, default=None,
                   help="stop rule recorded in the model: never send a camera back to a visited position")
    g.add_argument("--adaptive-scale", type=adaptive_scale, default=None, metavar="S",
                   help="recorded in the model: the largest per-capture variance factor of the adaptive scale "
                        "(1 = off; jaxrecog.kernels.adaptive_scale)")
    g.add_argument("--planner", choices=PLANNERS, default=None,
                   help="view planner recorded in the model (recognize, plan and experiment --rig dataset: use it)")
    g.add_argument("--stability", type=stability_weight, default=None, metavar="W|auto",
                   help="weight of mi-class-pairwise-stable's view-instability term recorded in the model: a number "
                        ">= 0, or 'auto' (fitted on the 'calib' split: 1 where instability predicts the captures no "
                        "class explains, else 0; 1 without a calib split; jaxrecog.stability_fit)")
    capture_options(p, unset=True)


def resolve_recipe(args, db=None) -> Recipe:
    """The recipe of ``--recipe`` with the parts the options give, and with
    ``"auto"`` resolved against ``db`` (when given).  A part that contradicts
    an option, or a split the recipe needs that ``db`` lacks, is a
    :class:`UsageError` of one line."""
    try:
        recipe = get_recipe(args.recipe)
    except ValueError as e:
        raise UsageError(str(e)) from None
    parts: dict = {}
    name = _likelihood_name(args)
    given = given_likelihood_options(args)
    if name is None and args.view_jitter and not likelihood_class(recipe.likelihood).view_components:
        name = default_likelihood(True)   # --view-jitter on a single-Gaussian recipe: the thesis-era default family
    if given:
        try:
            likelihood_choice(name or recipe.likelihood, given)   # an option of another family: one line
        except ValueError as e:
            raise UsageError(str(e)) from None
    if name is not None:
        parts["likelihood"] = name
        parts["likelihood_options"] = given
    elif given:
        parts["likelihood_options"] = {**recipe.options, **given}
    for opt, part in (("interpolate", "interpolate"), ("interpolation", "interpolation"), ("calibrate", "calibrate"),
                      ("calib_pool", "calib_pool"), ("view_jitter", "view_jitter"),
                      ("threshold", "p_threshold"), ("min_views", "min_views"),
                      ("exclude_visited", "exclude_visited"), ("adaptive_scale", "adaptive_scale"),
                      ("max_shift", "max_shift"), ("occluder_gray", "occluder_gray"), ("planner", "planner"),
                      ("stability", "stability")):
        if getattr(args, opt, None) is not None:
            parts[part] = getattr(args, opt)
    try:
        recipe = recipe.replace(**parts)
    except ValueError as e:
        raise UsageError(str(e)) from None
    if parts.get("calib_pool") and recipe.calibrate is False:
        raise UsageError(f"--calib-pool pools calibration factors, and recipe {recipe.name} is not calibrated here: "
                         f"add --calibrate, or leave --calib-pool out")
    family = likelihood_class(recipe.likelihood)
    if recipe.interpolate and not family.view_components:
        if "interpolate" in parts:
            raise UsageError(f"--interpolate {recipe.interpolate} needs a mixture likelihood (interpolated views are "
                             f"its components), and recipe {recipe.name} trains {recipe.likelihood}: add "
                             f"--likelihood view-mixture")
        raise UsageError(f"--likelihood {recipe.likelihood} contradicts recipe {recipe.name}'s interpolate = "
                         f"{recipe.interpolate} (interpolated views are mixture components): add --interpolate 0, "
                         f"or use view-mixture / view-mixture-lowrank")
    if family.view_components and not recipe.interpolate and recipe.view_jitter is False:
        raise UsageError(f"--likelihood {recipe.likelihood} needs mixture components: --interpolate N or "
                         f"--view-jitter (recipe {recipe.name} has neither)")
    for k in recipe.options:
        if k not in family.fit_options:
            raise UsageError(f"recipe {recipe.name}: option {k!r} does not apply to --likelihood {recipe.likelihood}")
    if db is None:
        return recipe
    has = {s: int((db.split == s).sum()) for s in ("calib", "jitter")}
    resolved = {}
    for part, split, flag in (("calibrate", "calib", "--calibrate"), ("view_jitter", "jitter", "--view-jitter")):
        want = getattr(recipe, part)
        if want is True and not has[split]:
            raise UsageError(f"{flag} (recipe {recipe.name}) needs a '{split}' split; database {db.root or ''} "
                             f"has none (add '{split}' rows, or --no-{flag[2:]})")
        if want == AUTO:
            resolved[part] = bool(has[split])
            if not has[split] and part == "calibrate":
                print(f"recipe {recipe.name}: the database has no 'calib' split, so the model is not calibrated")
    if family.view_components and not recipe.interpolate and not resolved.get("view_jitter", recipe.view_jitter):
        raise UsageError(f"--likelihood {recipe.likelihood} takes its components from 'jitter' rows, and the "
                         f"database has none: add --interpolate N")
    return recipe.replace(**resolved)


def run(args) -> int:
    if args.add is not None or args.to is not None or args.database is None:
        return _locked(args, _run_add)
    return _locked(args, _run)


def _locked(args, work) -> int:
    """``work(args)`` holding the lock on writing ``--out`` (one writer of a
    model file at a time: a second ``train --out`` of the same file is refused
    with one line naming the first's PID)."""
    if args.out is None:
        return work(args)
    check_writable(args.out)  # a folder that exists, a regular file or none: before the lock file is made
    with file_lock(args.out, what="jaxrecog train"):
        return work(args)


def _run(args) -> int:
    default_k = args.components is None  # the default fits the data; a K the user gives must
    comps: int | float = DEFAULT_COMPONENTS if default_k else args.components
    if float(comps).is_integer() and comps >= 1:
        comps = int(comps)
    elif not 0 < comps <= 1:
        raise UsageError(f"--components must be an integer >= 1 or a fraction in (0, 1], got {args.components}")
    resolve_recipe(args)  # an unknown recipe or a contradiction: one line before the database loads
    try:
        capture = capture_params(args)
    except (ValueError, argparse.ArgumentTypeError) as e:
        raise UsageError(f"capture augmentation: {e}") from None
    check_writable(args.out)
    db = load_database(args.database)
    recipe = resolve_recipe(args, db)
    try:
        augment = AugmentParams(**{**capture, "max_shift": recipe.max_shift, "occluder_gray": recipe.occluder_gray})
    except (ValueError, argparse.ArgumentTypeError) as e:
        raise UsageError(f"capture augmentation: {e}") from None
    with bar(sum(db.positions), f"train {args.kind}", "pos") as b:
        try:
            model, info = train_model(db, kind=args.kind, n_components=comps, samples_per_image=args.samples,
                                      likelihood=recipe.likelihood, likelihood_options=recipe.options,
                                      seed=args.seed, progress=b.set, augment=augment,
                                      view_jitter=bool(recipe.view_jitter), interpolate=recipe.interpolate,
                                      interpolation=recipe.interpolation, components_at_most=default_k,
                                      return_info=True)
        except ComponentsError as e:
            raise UsageError(f"--components {e.k}: the database's smallest eigenspace rank is {e.min_rank} (at "
                             f"most one less than its training images per position): give at most {e.min_rank}, "
                             f"or leave --components out to fit the data") from None
    params = dict(info.params)
    if default_k and params["K"] < comps:
        print(f"jaxrecog: K = {params['K']} components, the database's smallest eigenspace rank (the default "
              f"--components {comps} is more than the data holds)", file=sys.stderr)
    calibration = None
    if recipe.calibrate:
        model, cal = calibrate_model(model, db, pool=recipe.calib_pool)
        params["calibrated"] = True
        calibration = cal.to_dict()
        print(cal.summary())
    recipe, model = _resolve_stability(recipe, model, db, params)
    path = save_model(args.out, model, training=params, manifest_sha256=info.manifest_sha256,
                      calibration=calibration, recipe=recipe.to_dict())
    print(f"trained {args.kind} (K={params['K']}, recipe {recipe.name}) in {info.seconds:.1f} s -> {path}")
    print(model.summary())
    return 0


def _resolve_stability(recipe: Recipe, model, db, params: dict):
    """The recipe and model with the planner's stability weight as a number:
    ``auto`` fitted on ``db``'s ``calib`` split (its result in ``params``
    and one printed line), 1 without one; a number as given."""
    if recipe.stability == AUTO and recipe.adaptive_scale < 2.0:
        print(f"recipe {recipe.name}: adaptive scale {recipe.adaptive_scale:g} marks no capture unexplained, so "
              f"there is nothing to fit the planner's stability term on: it keeps its default weight 1 "
              f"(--adaptive-scale 2 or more to fit it)")
        recipe = recipe.replace(stability=1.0)
    elif recipe.stability == AUTO and not int((db.split == "calib").sum()):
        print(f"recipe {recipe.name}: the database has no 'calib' split, so the planner's stability term keeps "
              f"its default weight 1 instead of one fitted to this rig (add held-out 'calib' captures and retrain "
              f"to fit it)")
        recipe = recipe.replace(stability=1.0)
    calib = features_from_database(model, db, "calib") if recipe.stability == AUTO else None
    model, fit = with_stability(model, recipe, calib)
    if fit is not None:
        params["stability_fit"] = fit.to_dict()
        print(fit.summary())
    return recipe.replace(stability=model.stability), model


#: the options ``--add`` honours besides its own (every other training option is the model's)
_ADD_OPTIONS = ("database", "out", "add", "to", "calibrate")


def _given_options(args) -> list[str]:
    """The options of ``args`` that differ from the parser's defaults, as ``--name``
    (a TOML ``[train]`` table's settings count as given)."""
    p = argparse.ArgumentParser(add_help=False)
    add_arguments(p)
    defaults = vars(p.parse_args(["--out", "-"]))
    return [f"--{k.replace('_', '-')}" for k, v in vars(args).items()
            if k in defaults and k not in _ADD_OPTIONS and v != defaults[k]]


def _run_add(args) -> int:
    """``train --add NEW_DB --to MODEL --out OUT`` (:func:`jaxrecog.train.add_objects`)."""
    if args.add is None or args.to is None:
        if args.add is None and args.to is None:
            raise UsageError("give the image database to train on (DATABASE), or --add NEW_DB --to MODEL")
        if args.add is None and args.database is not None:
            raise UsageError("--to MODEL goes with --add NEW_DB (not with DATABASE)")
        raise UsageError("--add NEW_DB and --to MODEL go together")
    if args.database is not None:
        raise UsageError(f"DATABASE {args.database} and --add {args.add}: give one (--add NEW_DB --to MODEL adds "
                         f"NEW_DB's objects to MODEL)")
    given = _given_options(args)
    if given:
        raise UsageError(f"{given[0]} does not apply with --add: the new objects are trained with the model's own "
                         f"settings and recipe (only --calibrate / --no-calibrate may be given)")
    check_writable(args.out)
    meta = load_model_meta(args.to)
    model = load_model(args.to)
    db = load_database(args.add)
    recipe = recipe_from_meta(meta)
    has_calib = bool((db.split == "calib").sum())
    calibrate = bool(meta.get("calibrated")) if args.calibrate is None else args.calibrate
    if calibrate and not has_calib:
        if args.calibrate:
            raise UsageError(f"--calibrate needs a 'calib' split; database {db.root or ''} has none "
                             f"(add 'calib' rows, or --no-calibrate)")
        print(f"database {args.add} has no 'calib' split: the new objects take the model's calibration factors, "
              f"the model is not recalibrated")
        calibrate = False
    with bar(sum(model.positions), "add objects", "pos") as b:
        out, info = add_objects(model, db, meta.get("training") or {}, progress=b.set, return_info=True)
    params = dict(info.params)
    calibration = meta.get("calibration") or {}
    if calibrate:
        out, cal = calibrate_model(out, added_calibration_features(out, db), pool=recipe.calib_pool)
        params["calibrated"] = True
        calibration = {**cal.to_dict(), "previous": calibration}
        print(cal.summary())
    path = save_model(args.out, out, training=params, manifest_sha256=meta.get("manifest_sha256"),
                      calibration=calibration, recipe=meta.get("recipe") or recipe.to_dict())
    first = model.n_objects
    print(f"added {db.n_objects} object(s) of {args.add} as objects {first}..{out.n_objects - 1} to {args.to} "
          f"({'recalibrated' if calibrate else 'not recalibrated'}, recipe {recipe.name}) in "
          f"{info.seconds:.1f} s -> {path}")
    print(out.summary())
    return 0


def _likelihood_name(args) -> str | None:
    """The ``--likelihood`` (or its ``--covariance`` alias), ``None`` when neither is given."""
    name = args.likelihood
    if args.covariance is not None:
        alias = _COVARIANCE[args.covariance]
        if name is not None and likelihood_class(name) is not likelihood_class(alias):
            raise UsageError(f"--covariance {args.covariance} means --likelihood {alias}, "
                             f"which contradicts --likelihood {name}")
        name = alias
    return name
