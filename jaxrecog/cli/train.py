"""``jaxrecog train``: a sensor model (DB1/DB2) from an image database."""

from __future__ import annotations

from ..calibration import calibrate_model
from ..database import load_database
from ..modelfile import save_model
from ..progress import bar
from ..train import train_model
from ._common import UsageError
from ._options import positive

NAME = "train"
ORDER = 20
HELP = "train a sensor model (DB1/DB2) from an image database"
DESCRIPTION = ("Train the eigenspace + Gaussian sensor model of an image database and write the\n"
               "model file (.npz).  DB1 = noise and shifts; DB2 adds occluders of 5..25 %.")


def add_arguments(p) -> None:
    p.add_argument("database", metavar="DATABASE", help="image database folder (with manifest.csv)")
    p.add_argument("--out", required=True, metavar="MODEL.NPZ", help="model file to write")
    p.add_argument("--kind", choices=("DB1", "DB2"), default="DB2", help="augmentation kind")
    p.add_argument("--components", type=float, default=20,
                   help="eigenvectors K per position (integer), or the energy fraction to keep (0..1)")
    p.add_argument("--samples", type=positive, default=100,
                   help="augmented samples per training image and occlusion level")
    p.add_argument("--covariance", choices=("diag", "full"), default="diag", help="Gaussian covariance form")
    p.add_argument("--seed", type=int, default=0, help="seed of the augmentation")
    p.add_argument("--calibrate", action="store_true",
                   help="calibrate the model on the database's 'calib' split (jaxrecog.calibration)")


def run(args) -> int:
    comps: int | float = args.components
    if float(comps).is_integer() and comps >= 1:
        comps = int(comps)
    elif not 0 < comps <= 1:
        raise UsageError(f"--components must be an integer >= 1 or a fraction in (0, 1], got {args.components}")
    db = load_database(args.database)
    with bar(sum(db.positions), f"train {args.kind}", "pos") as b:
        model, info = train_model(db, kind=args.kind, n_components=comps, samples_per_image=args.samples,
                                  covariance=args.covariance, seed=args.seed, progress=b.set,
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
