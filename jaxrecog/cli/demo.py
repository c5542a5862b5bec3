"""``jaxrecog demo``: what ``make demo`` runs (render, train, a short campaign, plots)."""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import jax.random as jr
import numpy as np

from .. import campaigns  # as a module: tests stub its prepare / run_case / run_trace
from .. import kernels as K
from .. import plots
from ..modelfile import load_model
from .._progress import enabled as progress_bars
from ..recognizer_factory import make_recognizer
from ._common import key, model_positions, model_report
from ._options import PLANNERS, positive
from ._reports import QUICK, make_settings, trace_plot, write_report

NAME = "demo"
ORDER = 80
HELP = "what `make demo` runs: render, train, a short campaign, plots"
DESCRIPTION = ("Render the synthetic database, train DB1 and DB2 (and print their summaries), run\n"
               "a short case (iii) campaign (occluded scenes, DB2 model) with two class-target MI planners\n"
               "(the deterministic pairwise estimate and the Monte Carlo one), print the table and write\n"
               "the plots.  --quick (--stride 8, 2 trials per object) makes it a smoke\n"
               "run of well under a minute (positions (4, 1), 160 images).")

#: ``--quick``: every 8th position and 2 trials per object, unless given
QUICK_DEMO = {"stride": 8, "trials": 2}


def add_arguments(p) -> None:
    p.add_argument("--out", default="out/demo", metavar="FOLDER", help="output folder")
    p.add_argument("--trials", type=positive, default=None, help="trials per object (default 10; --quick: 2)")
    p.add_argument("--planners", nargs="+", choices=PLANNERS, default=["mi-class-pairwise", "mi-class"],
                   metavar="PLANNER",
                   help=f"planners to run, from {', '.join(PLANNERS)}; the first also draws the trace "
                        "(default: mi-class-pairwise mi-class: with the demo's quick 2 samples per "
                        "stratum the Monte Carlo estimate misjudges the sticker view and the trace's "
                        "look-alike trial stays at 0.50 / 0.50, the pairwise one takes it in 2 views)")
    p.add_argument("--stride", type=positive, default=None,
                   help="keep every STRIDE-th position of each camera (default 1 = the thesis's 32 x 7 table; "
                        "--quick: 8)")
    p.add_argument("--quick", action="store_true",
                   help="a smoke run of well under a minute: --stride 8 and --trials 2 unless given")
    p.add_argument("--seed", type=int, default=0, help="campaign seed")


def demo_sizes(args) -> tuple[int, int]:
    """``(stride, trials)``: the given ones, else ``--quick``'s, else 1 and 10."""
    quick = QUICK_DEMO if args.quick else {"stride": 1, "trials": 10}
    return (args.stride if args.stride is not None else quick["stride"],
            args.trials if args.trials is not None else quick["trials"])


def run(args) -> int:
    out = Path(args.out)
    args.stride, args.trials = demo_sizes(args)
    t0 = time.perf_counter()
    values = {"workdir": str(out / "work"), "trials_per_object": args.trials, "seed": args.seed,
              "stride": args.stride, **QUICK}
    settings = make_settings(values, "demo")
    prepared = campaigns.prepare(settings, progress=progress_bars(), databases=("DB1", "DB2"))
    print(f"database and DB1/DB2 models ready in {time.perf_counter() - t0:.0f} s ({settings.workdir})")
    for kind, path in sorted(prepared.models.items()):
        print(f"{kind} model:")
        print(model_report(path))
    report = campaigns.run_case("iii", settings, planners=list(args.planners), progress=progress_bars(), prepared=prepared)
    print(report.markdown())
    written = write_report(report, "iii", out)
    written += trace_plot(settings, out, planner=args.planners[0], prepared=prepared)
    written += _model_plots(prepared, settings, out, args.seed)
    print(f"demo finished in {time.perf_counter() - t0:.0f} s; tables and plots:")
    for p in written:
        print(f"  {p}")
    return 0


def _model_plots(prepared, settings, out: Path, seed: int) -> list[Path]:
    """:func:`jaxrecog.plots.model_figures` of the DB2 model, with its MI
    scores for the uniform belief and a training image of the database."""
    path = prepared.models.get("DB2")
    if path is None:
        print("(no DB2 model found in the work folder: skipping the heat map and eigenimages)")
        return []
    model = load_model(str(path))
    k1, k2 = jr.split(key(seed))
    rec = make_recognizer(model, "mi", key=k1, samples=settings.samples, min_per_stratum=settings.min_per_stratum)
    positions = model_positions(model)
    prior = rec.init(config=(0,) * len(positions)).prior
    scores = np.asarray(rec.planner.scores(K.at_every_position(prior, positions), k2))
    return plots.model_figures(model, scores, out, image=_first_train_image(Path(settings.workdir)))


def _first_train_image(workdir: Path):
    for m in sorted(workdir.rglob("manifest.csv")):
        for cand in sorted((m.parent / "train").rglob("*.png"))[:1]:
            img = cv2.imread(str(cand), cv2.IMREAD_GRAYSCALE)
            if img is not None:
                return img
    return None
