"""``jaxrecog train``: a sensor model (DB1/DB2) from an image database."""

from __future__ import annotations

import argparse

from ..augment import AugmentParams
from ..calibration import calibrate_model
from ..database import load_database
from ..kernels import likelihood_class
from ..modelfile import check_writable, save_model
from .._progress import bar
from ..train import train_model
from ._common import UsageError
from ._options import (capture_options, capture_params, given_likelihood_options, likelihood_choice,
                       likelihood_options, positive, view_jitter_option)

NAME = "train"
ORDER = 20
HELP = "train a sensor model (DB1/DB2) from an image database"
DESCRIPTION = ("Train the eigenspace + likelihood sensor model of an image database and write the\n"
               "model file (.npz).  DB1 = noise and shifts; DB2 adds occluders of 5..25 %.\n"
               "Likelihoods: gaussian-diag (the thesis), gaussian-full, gaussian-lowrank (--rank),\n"
               "student-t (--nu; heavy tails, so one unmodelled deviation cannot drive a belief to 1),\n"
               "view-mixture and view-mixture-lowrank (--rank; one component per rendered view near each\n"
               "training view: needs --view-jitter and a database with 'jitter' rows).")

#: ``--covariance`` (the older option) -> the ``--likelihood`` it stands for
_COVARIANCE = {"diag": "gaussian-diag", "full": "gaussian-full"}


def add_arguments(p) -> None:
    p.add_argument("database", metavar="DATABASE", help="image database folder (with manifest.csv)")
    p.add_argument("--out", required=True, metavar="MODEL.NPZ", help="model file to write")
    p.add_argument("--kind", choices=("DB1", "DB2"), default="DB2", help="augmentation kind")
    p.add_argument("--components", type=float, default=20,
                   help="eigenvectors K per position (integer), or the energy fraction to keep (0..1)")
    p.add_argument("--samples", type=positive, default=100,
                   help="augmented samples per training image and occlusion level")
    likelihood_options(p)
    p.add_argument("--covariance", choices=tuple(_COVARIANCE), default=None,
                   help="older alias: 'diag' = --likelihood gaussian-diag, 'full' = --likelihood gaussian-full")
    p.add_argument("--seed", type=int, default=0, help="seed of the augmentation")
    p.add_argument("--calibrate", action="store_true",
                   help="calibrate the model on the database's 'calib' split (jaxrecog.calibration)")
    view_jitter_option(p)
    capture_options(p)


def run(args) -> int:
    comps: int | float = args.components
    if float(comps).is_integer() and comps >= 1:
        comps = int(comps)
    elif not 0 < comps <= 1:
        raise UsageError(f"--components must be an integer >= 1 or a fraction in (0, 1], got {args.components}")
    name, options = _likelihood(args)
    try:
        augment = AugmentParams(**capture_params(args))
    except (ValueError, argparse.ArgumentTypeError) as e:
        raise UsageError(f"capture augmentation: {e}") from None
    check_writable(args.out)  # before minutes of training, not after (nothing is left behind)
    db = load_database(args.database)
    with bar(sum(db.positions), f"train {args.kind}", "pos") as b:
        model, info = train_model(db, kind=args.kind, n_components=comps, samples_per_image=args.samples,
                                  likelihood=name, likelihood_options=options, seed=args.seed,
                                  progress=b.set, augment=augment, view_jitter=args.view_jitter,
                                  return_info=True)
    params = dict(info.params)
    calibration = None
    if args.calibrate:
        model, cal = calibrate_model(model, db)
        params["calibrated"] = True
        calibration = cal.to_dict()
        print(cal.summary())
    path = save_model(args.out, model, training=params, manifest_sha256=info.manifest_sha256,
                      calibration=calibration)
    print(f"trained {args.kind} (K={params['K']}) in {info.seconds:.1f} s -> {path}")
    print(model.summary())
    return 0


def _likelihood(args) -> tuple[str, dict]:
    """The ``--likelihood`` (or its ``--covariance`` alias) and the family's options."""
    name = args.likelihood
    if args.covariance is not None:
        alias = _COVARIANCE[args.covariance]
        if name is not None and likelihood_class(name) is not likelihood_class(alias):
            raise UsageError(f"--covariance {args.covariance} means --likelihood {alias}, "
                             f"which contradicts --likelihood {name}")
        name = alias
    try:
        return likelihood_choice(name, given_likelihood_options(args), view_jitter=bool(args.view_jitter))
    except ValueError as e:
        raise UsageError(str(e)) from None
