"""A short occluded campaign where myopic planning is expected to be weakest:
the sticker look-alike pairs, lookahead planners against their myopic ones.

Rig: camera 1 = the 8 pans at 30° tilt (each pose of a look-alike pair shows
its sticker from about one of them) + pans 0° and 180° at 60°; camera 2 = pans
-40°, 0°, 40° (10 x 3 = 30 configurations).  Objects: duck, mug and both
look-alike pairs (thesis 5/6, 7/8) = 6 objects x 4 poses.  DB2 model (occlusion
levels), cardboard occluders in front of the initial views (case iii's scene),
capture noise as the campaigns'.  All planners run on the same trials.

    python scripts/lookalike_campaign.py [--trials 4] [--planners mi-class,mi-class-lookahead]
        [--top-k 8] [--outcomes 16] [--out out/lookalike]

Writes ``results.json`` (per planner: rate, views, confident errors, per object,
per trial configurations) and prints how many trials each lookahead planner
spent on another path than the myopic planner with the same one-step score
(``mi-pairwise`` / ``mi-class-pairwise``).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax.random as jr
import numpy as np

from jaxrecog import load_database, train_model
from jaxrecog.campaign import plan_trials, run_campaign
from jaxrecog.scene import CAPTURE_NOISE
from jaxrecog.hardware import Noise, OccluderLayout, SyntheticRig, default_objects, random_occluders, render_database
from jaxrecog.hardware.render.occluders import OCCLUDER_OFFSET, OCCLUDER_SIZE
from jaxrecog.hardware.geometry.positions import CameraTable, default_table
from jaxrecog.planners import make_planner
from jaxrecog.recognizer import Recognizer
from jaxrecog.results import wilson_interval

OBJECTS = (0, 2, 4, 5, 6, 7)  # duck, mug, house, house+sticker, truck, truck+sticker
LOOKALIKE = (2, 3, 4, 5)  # their indices in OBJECTS


def table() -> CameraTable:
    full = default_table()
    v0 = tuple(full.views[0][i] for i in (*range(8), 16, 20))
    v1 = tuple(full.views[1][i] for i in (1, 3, 5))
    return CameraTable(full.workspace, (v0, v1))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trials", type=int, default=4, help="trials per object")
    ap.add_argument("--planners", default="mi-class,mi-class-pairwise,mi-class-lookahead,mi,mi-pairwise,mi-lookahead")
    ap.add_argument("--top-k", type=int, default=8)
    ap.add_argument("--outcomes", type=int, default=16)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path("out/lookalike"))
    args = ap.parse_args(argv)

    tab = table()
    objects = tuple(default_objects()[i] for i in OBJECTS)
    db_dir = args.out / "database"
    t0 = time.perf_counter()
    if not (db_dir / "manifest.csv").exists():
        render_database(db_dir, tab, objects, 4)
    model_path = args.out / "model-db2.npz"
    db = load_database(db_dir)
    model = train_model(db, kind="DB2", n_components=10, samples_per_image=30, seed=args.seed)
    print(f"render + train: {time.perf_counter() - t0:.0f} s", flush=True)
    del model_path

    b, p, s = CAPTURE_NOISE
    rig = SyntheticRig(tab, objects=objects, noise=Noise(brightness=b, pixel=p, max_shift=s), seed=args.seed + 1)

    def occluders(rng, initial):
        first = CameraTable(tab.workspace, tuple((views[v],) for views, v in zip(tab.views, initial)))
        return OccluderLayout(random_occluders(rng, first, radius=rig.radius, size=OCCLUDER_SIZE, offset=OCCLUDER_OFFSET).boards)

    specs = plan_trials(len(OBJECTS), 4, rig.positions, args.trials, seed=args.seed + 7, occluders=occluders)
    out = {"objects": OBJECTS, "positions": rig.positions, "trials_per_object": args.trials,
           "top_k": args.top_k, "outcomes": args.outcomes, "planners": {}}
    for name in args.planners.split(","):
        options = {"top_k": args.top_k, "outcomes": args.outcomes} if "lookahead" in name else {}
        planner = make_planner(name, model, key=jr.PRNGKey(args.seed), samples=1024, **options)
        rec = Recognizer(model, planner)
        t1 = time.perf_counter()
        res = run_campaign(rec, rig, specs, key=jr.PRNGKey(args.seed + 1), batch=8, seed=args.seed)
        secs = time.perf_counter() - t1

        def stats(rs):
            ok = np.array([r.correct for r in rs])
            ci = [round(100 * x, 1) for x in wilson_interval(int(ok.sum()), len(rs))]  # 95 %
            return {"n": len(rs), "rate": round(100 * float(ok.mean()), 1), "rate_ci": ci,
                    "views": round(float(np.mean([r.steps for r in rs])), 2),
                    "confident_errors": int(sum((not r.correct) and r.stopped for r in rs))}

        row = {"all": stats(res), "lookalike": stats([r for r in res if r.object in LOOKALIKE]),
               "others": stats([r for r in res if r.object not in LOOKALIKE]),
               "per_object": {str(OBJECTS[m]): stats([r for r in res if r.object == m]) for m in range(len(OBJECTS))},
               "seconds": round(secs, 1),
               "trials": [{"object": OBJECTS[r.object], "pose": r.pose, "correct": r.correct, "steps": r.steps,
                           "exit_prob": round(r.exit_prob, 4), "configurations": r.configurations} for r in res]}
        out["planners"][name] = row
        print(name, json.dumps({k: row[k] for k in ("all", "lookalike", "others", "seconds")}), flush=True)
    # how often a lookahead planner took another path than its myopic one-step score
    for name, row in out["planners"].items():
        base = name.replace("-lookahead", "-pairwise")
        if "lookahead" in name and base in out["planners"]:
            paths = [(a["configurations"], b["configurations"]) for a, b in zip(row["trials"], out["planners"][base]["trials"])]
            differ = sum(x != y for x, y in paths)
            row["trials_with_another_path_than_" + base] = differ
            print(f"{name}: {differ}/{len(paths)} trials took another path than {base}", flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "results.json").write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
