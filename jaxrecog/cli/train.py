"""``jaxrecog train``: a sensor model (DB1/DB2) from an image database."""

from __future__ import annotations

import argparse

from ..augment import AugmentParams
from ..calibration import calibrate_model
from ..database import load_database
from ..kernels import likelihood_class, likelihood_names
from ..modelfile import save_model
from .._progress import bar
from ..train import train_model
from ._common import UsageError
from ._options import int_at_least, positive

NAME = "train"
ORDER = 20
HELP = "train a sensor model (DB1/DB2) from an image database"
DESCRIPTION = ("Train the eigenspace + likelihood sensor model of an image database and write the\n"
               "model file (.npz).  DB1 = noise and shifts; DB2 adds occluders of 5..25 %.\n"
               "Likelihoods: gaussian-diag (the thesis), gaussian-full, gaussian-lowrank (--rank),\n"
               "student-t (--nu; heavy tails, so one unmodelled deviation cannot drive a belief to 1).")

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
    p.add_argument("--likelihood", choices=likelihood_names(), default=None,
                   help="sensor-model family (default: gaussian-diag, the thesis's)")
    p.add_argument("--covariance", choices=tuple(_COVARIANCE), default=None,
                   help="older alias: 'diag' = --likelihood gaussian-diag, 'full' = --likelihood gaussian-full")
    p.add_argument("--rank", type=positive, default=None,
                   help="gaussian-lowrank: factors R, 1 <= R < K (default: min(4, K - 1))")
    p.add_argument("--nu", type=_nu, default=None,
                   help="student-t: degrees of freedom, a number > 2, or 'auto' (chosen per level on held-out "
                        "training samples; the default)")
    p.add_argument("--seed", type=int, default=0, help="seed of the augmentation")
    p.add_argument("--calibrate", action="store_true",
                   help="calibrate the model on the database's 'calib' split (jaxrecog.calibration)")
    g = p.add_argument_group("capture augmentation (what a real capture does off the training grid; off by default)")
    g.add_argument("--rotation", type=_fraction_or_angle(180.0, "degrees", inclusive=True), default=0.0,
                   metavar="DEG", help="in-plane rotation by a uniform angle in +-DEG degrees about the image centre")
    g.add_argument("--scale", type=_fraction_or_angle(1.0, "a fraction"), default=0.0, metavar="FRAC",
                   help="scaling by 1 + a, a uniform in +-FRAC, about the image centre")
    g.add_argument("--blur", type=_sigma_range, default="0", metavar="SIGMA|LO,HI",
                   help="Gaussian blur, sigma uniform in [LO, HI] pixels (one number: [0, SIGMA])")
    g.add_argument("--gain", type=_fraction_or_angle(1.0, "a fraction"), default=0.0, metavar="FRAC",
                   help="local gain: a smooth multiplicative field 1 + c, |c| <= FRAC, bilinearly upsampled "
                        "from a CELLS x CELLS grid of uniform values")
    g.add_argument("--gain-cells", type=int_at_least(2, "an integer >= 2"), default=3, metavar="CELLS",
                   help="control grid of the --gain field")


def run(args) -> int:
    comps: int | float = args.components
    if float(comps).is_integer() and comps >= 1:
        comps = int(comps)
    elif not 0 < comps <= 1:
        raise UsageError(f"--components must be an integer >= 1 or a fraction in (0, 1], got {args.components}")
    name, options = _likelihood(args)
    blur = args.blur  # a TOML file may give a number or a list [LO, HI]
    if not isinstance(blur, tuple):
        try:
            blur = _sigma_range(",".join(map(str, blur)) if isinstance(blur, list) else str(blur))
        except argparse.ArgumentTypeError as e:
            raise UsageError(f"blur: {e}") from None
    try:
        augment = AugmentParams(max_rotation=float(args.rotation), max_scale=float(args.scale), blur_sigma=blur,
                                gain_amplitude=float(args.gain), gain_cells=int(args.gain_cells))
    except ValueError as e:
        raise UsageError(str(e)) from None
    db = load_database(args.database)
    with bar(sum(db.positions), f"train {args.kind}", "pos") as b:
        model, info = train_model(db, kind=args.kind, n_components=comps, samples_per_image=args.samples,
                                  likelihood=name, likelihood_options=options, seed=args.seed,
                                  progress=b.set, augment=augment, return_info=True)
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


def _fraction_or_angle(high: float, what: str, inclusive: bool = False):
    """An argparse type: a number in ``[0, high)`` (``[0, high]`` if ``inclusive``)."""

    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            v = float("nan")
        if not (0.0 <= v <= high if inclusive else 0.0 <= v < high):
            raise argparse.ArgumentTypeError(
                f"expected {what} in [0, {high:g}{']' if inclusive else ')'}, got {text!r}")
        return v

    return parse


def _sigma_range(text: str) -> tuple[float, float]:
    """An argparse type: ``SIGMA`` (= ``0,SIGMA``) or ``LO,HI`` with ``0 <= LO <= HI``."""
    try:
        vals = [float(x) for x in str(text).replace(" ", "").split(",")]
    except ValueError:
        vals = []
    if len(vals) == 1:
        vals = [0.0, vals[0]]
    if len(vals) != 2 or not all(0.0 <= v < float("inf") for v in vals) or vals[0] > vals[1]:
        raise argparse.ArgumentTypeError(f"expected SIGMA or LO,HI with 0 <= LO <= HI (pixels), got {text!r}")
    return vals[0], vals[1]


def _nu(text: str) -> str | float:
    """An argparse type: ``auto`` or a number > 2."""
    if text.strip().lower() == "auto":
        return "auto"
    try:
        v = float(text)
    except ValueError:
        v = float("nan")
    if not v > 2.0 or v == float("inf"):
        raise argparse.ArgumentTypeError(f"expected 'auto' or a number > 2, got {text!r}")
    return v


def _likelihood(args) -> tuple[str, dict]:
    """The ``--likelihood`` (or its ``--covariance`` alias) and the family's options."""
    name = args.likelihood
    if args.covariance is not None:
        alias = _COVARIANCE[args.covariance]
        if name is not None and likelihood_class(name) is not likelihood_class(alias):
            raise UsageError(f"--covariance {args.covariance} means --likelihood {alias}, "
                             f"which contradicts --likelihood {name}")
        name = alias
    name = name or "gaussian-diag"
    family = likelihood_class(name)
    options = {k: v for k, v in (("rank", args.rank), ("nu", args.nu)) if v is not None}
    for k in options:
        if k not in family.fit_options:
            raise UsageError(f"--{k} applies to {'gaussian-lowrank' if k == 'rank' else 'student-t'}, "
                             f"not to --likelihood {name}")
    return name, options
