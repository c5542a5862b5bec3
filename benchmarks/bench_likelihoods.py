"""A small, cheap comparison of the sensor-model likelihoods off the training
grid: held-out log-likelihood and a short recognition run per
likelihood, uncalibrated and calibrated, written as JSON.

The database is the synthetic one of ``tests/builders.py`` (OpenCV shapes,
not the rendered rig): one clean ``train`` view per (camera, position,
object, pose) at the integer positions, and ``test`` / ``calib`` views taken
*between* them (position ``v + U(-offset, offset)``, plus a pixel shift of up
to 2 and gray noise sd 3), labelled with the nearest position ``v``.  These
are the views the augmentation does not model.  ``test`` and ``calib`` views
are independent draws.

Measured per likelihood (MI planner, P_th = 0.95, at most 7 image sets):
recognition rate, mean views, confident errors (wrong and stopped at
p >= P_th) and ECE of the exit probabilities; and on the single ``test``
views, the mean log-likelihood of the true class
``log p(g | c*, v)`` (levels averaged) and the mean single-view
``-log p(c* | g, v)`` (uniform prior).  A small run: a few hundred trials
at most, seconds to minutes on 2 cores.

    python benchmarks/bench_likelihoods.py --trials-per-object 12 --out out/bench/likelihoods.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))  # test support (builders)

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import jax.random as jr  # noqa: E402
import numpy as np  # noqa: E402
from builders import make_database  # noqa: E402

from jaxrecog import ImageDatabase  # noqa: E402
from jaxrecog.calibration import calibrate_model, features_from_database  # noqa: E402
from jaxrecog.metrics import campaign_metrics  # noqa: E402
from jaxrecog.planners import make_planner  # noqa: E402
from jaxrecog.recognizer import Recognizer  # noqa: E402
from jaxrecog.results import TrialResult, format_rate  # noqa: E402
from jaxrecog.train import train_model  # noqa: E402

VARIANTS = {
    "gaussian-diag": {},
    "gaussian-full": {},
    "gaussian-lowrank": {"rank": 2},
    "student-t": {"nu": "auto"},
}


def off_grid_database(positions=(4, 3), n_objects=4, n_poses=2, image_shape=(48, 64), n_test=3, n_calib=3,
                      offset=0.3, seed=0) -> ImageDatabase:
    """Clean train views on the grid; test / calib views between the positions (module docstring)."""
    return make_database(positions, n_objects, n_poses, image_shape, n_test, seed, n_calib=n_calib, view_offset=offset)


def held_out_scores(model, db) -> dict:
    """Mean ``log p(g | c*, v)`` and mean single-view ``-log p(c* | g, v)`` over the test views."""
    feats = features_from_database(model, db, "test")
    ll, nll, n = 0.0, 0.0, 0
    for cam, f in zip(model.cameras, feats.cameras):
        for v in range(cam.n_positions):
            sel = f.position == v
            if not sel.any():
                continue
            ld = np.asarray(cam.likelihood.at(v).log_density(jnp.asarray(f.g[sel], cam.likelihood.dtype)), np.float64)
            lc = np.logaddexp.reduce(ld, axis=-1) - np.log(ld.shape[-1])        # [N, C]
            true = lc[np.arange(sel.sum()), f.cls[sel]]
            ll += float(true.sum())
            nll += float(-(true - np.logaddexp.reduce(lc, axis=-1)).sum())
            n += int(sel.sum())
    return {"held_out_loglik": ll / n, "single_view_nll": nll / n, "test_views": n}


def recognition_run(model, db, trials_per_object: int, *, samples: int, seed: int) -> dict:
    """A short campaign on the test views: the recognizer's own step, one image per camera."""
    key = jr.PRNGKey(seed)
    rng = np.random.default_rng(seed)
    rec = Recognizer(model, make_planner("mi", model, key=key, samples=samples), max_steps=7)
    rows = {}
    test = np.flatnonzero(db.split == "test")
    for r in test:
        rows.setdefault((int(db.camera[r]), int(db.position[r]), int(db.object[r]), int(db.pose[r])), []).append(r)
    results, t = [], 0
    for obj in range(model.n_objects):
        for _ in range(trials_per_object):
            pose = int(rng.integers(model.n_poses))
            config = tuple(int(rng.integers(n)) for n in model.positions)
            state = rec.init(config=config)
            for step in range(7):
                images = np.stack([db.images[rng.choice(rows[(i, v, obj, pose)])] for i, v in enumerate(config)])
                state, dec = rec.step(state, jnp.asarray(images), jr.fold_in(jr.fold_in(key, t), step))
                if bool(dec.stop):
                    break
                config = tuple(int(x) for x in np.asarray(dec.next_config))
            results.append(TrialResult(trial=t, object=obj, pose=pose, predicted_object=int(dec.object),
                                       predicted_pose=int(dec.pose), exit_prob=float(dec.probability),
                                       steps=step + 1, stopped=bool(dec.reached)))
            t += 1
    return campaign_metrics(results)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trials-per-object", type=int, default=12)
    ap.add_argument("--components", type=int, default=6)
    ap.add_argument("--samples", type=int, default=100, help="augmented samples per training image")
    ap.add_argument("--planner-samples", type=int, default=128)
    ap.add_argument("--offset", type=float, default=0.3, help="off-grid offset, in position steps")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--only", choices=tuple(VARIANTS), action="append", default=None,
                    help="run only these likelihoods (repeatable; each costs a recognizer compile)")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    db = off_grid_database(offset=args.offset, seed=args.seed)
    rows = []
    for name, options in VARIANTS.items():
        if args.only and name not in args.only:
            continue
        t0 = time.perf_counter()
        model = train_model(db, kind="DB1", n_components=args.components, samples_per_image=args.samples,
                            likelihood=name, likelihood_options=options, seed=args.seed)
        for calibrated in (False, True):
            m = calibrate_model(model, db)[0] if calibrated else model
            row = {"likelihood": name, "options": options, "calibrated": calibrated,
                   **held_out_scores(m, db),
                   **recognition_run(m, db, args.trials_per_object, samples=args.planner_samples, seed=args.seed)}
            if name == "student-t":
                row["nu"] = sorted({round(float(x), 2) for c in m.cameras for x in np.asarray(c.likelihood.nu).ravel()})
            row["seconds"] = time.perf_counter() - t0
            rows.append(row)
            print(f"{name:17s} cal={calibrated!s:5s} LL {row['held_out_loglik']:8.2f}  NLL1 {row['single_view_nll']:6.3f}  "
                  f"rate {format_rate(row['recognition_rate'], row['recognition_rate_ci'])} %  views {row['mean_views']:.2f}  "
                  f"conf.err {row['confident_errors']}/{row['stopped']}  ECE {row['ece']:.3f}"
                  + (f"  nu {row['nu']}" if "nu" in row else ""), flush=True)
    out = {"settings": vars(args) | {"out": str(args.out)}, "jax": jax.__version__, "rows": rows}
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
