"""``jaxrecog train``: a sensor model (DB1/DB2) from an image database."""

from __future__ import annotations

import argparse
import sys

from ..augment import AugmentParams
from ..calibration import calibrate_model
from ..database import load_database
from ..eigenspace import ComponentsError
from ..kernels import likelihood_class
from ..modelfile import check_writable, save_model
from .._progress import bar
from ..recipes import AUTO, DEFAULT_RECIPE, RECIPES, Recipe, get_recipe
from ..train import train_model
from ._common import UsageError
from ._options import (PLANNERS, adaptive_scale, capture_options, capture_params, default_likelihood, given_likelihood_options,
                       likelihood_choice, likelihood_options, nonneg, positive, probability)

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
               "training view: needs --view-jitter and a database with 'jitter' rows).")

#: K when ``--components`` is not given (or less: the database's smallest eigenspace rank)
DEFAULT_COMPONENTS = 20

#: ``--covariance`` (the older option) -> the ``--likelihood`` it stands for
_COVARIANCE = {"diag": "gaussian-diag", "full": "gaussian-full"}


def add_arguments(p) -> None:
    p.add_argument("database", metavar="DATABASE", help="image database folder (with manifest.csv)")
    p.add_argument("--out", required=True, metavar="MODEL.NPZ", help="model file to write")
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
    for opt, part in (("interpolate", "interpolate"), ("interpolation", "interpolation"), ("calibrate", "calibrate"), ("view_jitter", "view_jitter"),
                      ("threshold", "p_threshold"), ("min_views", "min_views"),
                      ("exclude_visited", "exclude_visited"), ("adaptive_scale", "adaptive_scale"),
                      ("max_shift", "max_shift"), ("planner", "planner")):
        if getattr(args, opt, None) is not None:
            parts[part] = getattr(args, opt)
    try:
        recipe = recipe.replace(**parts)
    except ValueError as e:
        raise UsageError(str(e)) from None
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
        augment = AugmentParams(**{**capture, "max_shift": recipe.max_shift})
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
        model, cal = calibrate_model(model, db)
        params["calibrated"] = True
        calibration = cal.to_dict()
        print(cal.summary())
    path = save_model(args.out, model, training=params, manifest_sha256=info.manifest_sha256,
                      calibration=calibration, recipe=recipe.to_dict())
    print(f"trained {args.kind} (K={params['K']}, recipe {recipe.name}) in {info.seconds:.1f} s -> {path}")
    print(model.summary())
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
