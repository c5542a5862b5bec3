"""Planning cost against the number of classes: the default planner
``mi-class-pairwise-stable`` on its tables and on the belief's live classes.

Random thesis-layout models (two cameras with 32 and 7 positions, L = 6
occlusion levels, K = 12, 4 poses per object, diagonal Gaussians, float32),
C = 4 x objects classes.  Each (C, variant) runs in its own subprocess, so its
peak RSS is its own: ``pruned`` (``prune=True``: the live classes, default
mass 1e-3) and, up to ``--unpruned-max`` classes, ``tables`` (``prune=False``:
the divergence tables of every class pair).  Per run: the planner's build
time, the compile time of the scoring call (the planner passed as an
argument, as the recognizer does), the median / min of repeated calls
(``block_until_ready``) for each belief, and the peak RSS.  Beliefs:

- ``uniform``: the first step (uniform classes and level rows);
- ``2 classes``: 0.6 / 0.4 - 1e-4 on two classes, 1e-4 spread over the rest,
  random level rows at the current positions (3, 2);
- ``8 classes 99.9%``: 99.9 % on eight classes (Dirichlet), the rest spread;
- ``dirichlet 0.05``: a Dirichlet(0.05) over every class (mass on tens).

Where both variants ran, the parent compares them on the same beliefs: the
ratio of the medians, the largest score difference, the bound of
:func:`jaxrecog.kernels.pruning_bound` and the argmax regret of the pruned
planner under the tables planner's scores (nats).  Writes JSON (default
out/bench/scale.json).  Numbers from a shared 2-core machine are noisy; the
ratios compare runs of one invocation.

    python benchmarks/bench_scale.py [--classes 32,128,512,4000] [--unpruned-max 512] [--repeat 7] [--out PATH]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxrecog import kernels as K
from jaxrecog.kernels import pruned_mi
from jaxrecog.planners import make_planner
from jaxrecog.sensor_model import CameraModel, SensorModel

POSITIONS, N_LEVELS, DIM, POSES = (32, 7), 6, 12, 4
BELIEFS = ("uniform", "2 classes", "8 classes 99.9%", "dirichlet 0.05")


def random_model(n_classes: int, seed: int = 0) -> SensorModel:
    """A random diagonal-Gaussian model of the thesis layout (module docstring)."""
    rng = np.random.default_rng(seed)
    hw = (2, 8)
    cams = []
    for v in POSITIONS:
        cams.append(CameraModel(
            mean_image=jnp.zeros((v, hw[0] * hw[1]), jnp.float32),
            basis=jnp.asarray(np.linalg.qr(rng.normal(size=(v, hw[0] * hw[1], DIM)))[0], jnp.float32),
            eigenvalues=jnp.ones((v, DIM), jnp.float32),
            likelihood=K.gaussian(jnp.asarray(rng.normal(0, 0.3, (v, n_classes, N_LEVELS, DIM)), jnp.float32),
                                  jnp.asarray(rng.uniform(0.01, 0.05, (v, n_classes, N_LEVELS, DIM)), jnp.float32))))
    levels = tuple(round(0.1 * i, 1) for i in range(N_LEVELS))
    return SensorModel(tuple(cams), n_classes // POSES, POSES, levels, hw, "diag")


def belief(name: str, n_classes: int, seed: int = 1) -> K.PredictedBelief:
    """The predicted prior of belief ``name`` (module docstring)."""
    rng = np.random.default_rng(seed)
    levels = (N_LEVELS,) * len(POSITIONS)
    if name == "uniform":
        return K.transition_per_position(K.uniform_belief(n_classes, levels), (0, 0), POSITIONS)
    p = np.full(n_classes, 0.0)
    order = rng.permutation(n_classes)
    if name == "2 classes":
        p[order[:2]] = (0.6, 0.4 - 1e-4)
        p[order[2:]] = 1e-4 / (n_classes - 2)
    elif name == "8 classes 99.9%":
        p[order[:8]] = 0.999 * rng.dirichlet(np.ones(8))
        p[order[8:]] = 1e-3 / (n_classes - 8)
    else:
        p = rng.dirichlet(np.full(n_classes, 0.05))
    log_pc = np.log(np.maximum(p, 1e-30))
    log_pc -= np.logaddexp.reduce(log_pc)
    pk = tuple(jnp.asarray(np.log(rng.dirichlet(np.ones(N_LEVELS), size=n_classes)), jnp.float32) for _ in levels)
    return K.transition_per_position(K.Belief(jnp.asarray(log_pc, jnp.float32), pk), (3, 2), POSITIONS)


def child(n_classes: int, variant: str, repeat: int, scores_dir: Path) -> dict:
    """One (C, variant) run in this process (module docstring)."""
    model = random_model(n_classes)
    t0 = time.perf_counter()
    planner = make_planner("mi-class-pairwise-stable", model, key=jax.random.PRNGKey(0), prune=variant == "pruned")
    jax.block_until_ready(planner)
    out = {"C": n_classes, "variant": variant, "planner": type(planner).__name__,
           "build_s": round(time.perf_counter() - t0, 3)}
    score = jax.jit(lambda p, b, k: p.scores(b, k))
    key = jax.random.PRNGKey(0)
    t0 = time.perf_counter()
    jax.block_until_ready(score(planner, belief("uniform", n_classes), key))
    out["compile_s"] = round(time.perf_counter() - t0, 3)
    for name in BELIEFS:
        b = belief(name, n_classes)
        s = np.asarray(score(planner, b, key))
        times = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            jax.block_until_ready(score(planner, b, key))
            times.append(time.perf_counter() - t0)
        live = n_classes
        if variant == "pruned":  # the first step reads the belief-free table where the planner has one
            table = name == "uniform" and planner.tables.u_class is not None
            live = "table" if table else pruned_mi.live_count(b.log_pc)
        out[name] = {"median_ms": round(1e3 * float(np.median(times)), 3),
                     "min_ms": round(1e3 * float(np.min(times)), 3),
                     "live_classes": live}
        np.save(scores_dir / f"{n_classes}-{variant}-{BELIEFS.index(name)}.npy", s)
    out["peak_rss_gb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20, 3)
    return out


def compare(n_classes: int, runs: dict, scores_dir: Path) -> dict:
    """Pruned against tables on the same beliefs (module docstring)."""
    out = {}
    for i, name in enumerate(BELIEFS):
        sp = np.load(scores_dir / f"{n_classes}-pruned-{i}.npy")
        su = np.load(scores_dir / f"{n_classes}-tables-{i}.npy")
        b = belief(name, n_classes)
        live = runs["pruned"][name]["live_classes"]
        live = n_classes if live == "table" else live  # exact: the same estimator on every class
        out[name] = {
            "time_ratio_tables_over_pruned": round(runs["tables"][name]["median_ms"]
                                                   / runs["pruned"][name]["median_ms"], 2),
            "max_abs_diff_nats": float(np.max(np.abs(sp - su))),
            "bound_nats": pruned_mi.pruning_bound(np.asarray(b.log_pc), live, N_LEVELS ** len(POSITIONS)),
            "argmax_regret_nats": float(np.max(su) - su[int(np.argmax(sp))]),
        }
    out["rss_ratio_tables_over_pruned"] = round(runs["tables"]["peak_rss_gb"] / runs["pruned"]["peak_rss_gb"], 2)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--classes", default="32,128,512,4000", help="comma-separated class counts C")
    ap.add_argument("--unpruned-max", type=int, default=512, help="largest C also run on the tables")
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--out", type=Path, default=Path("out/bench/scale.json"))
    ap.add_argument("--child", nargs=3, metavar=("C", "VARIANT", "SCORES_DIR"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        c, variant, folder = args.child
        print(json.dumps(child(int(c), variant, args.repeat, Path(folder))))
        return 0
    sizes = [int(c) for c in args.classes.split(",")]
    report = {"layout": {"positions": POSITIONS, "levels": N_LEVELS, "K": DIM, "poses": POSES, "dtype": "float32",
                         "planner": "mi-class-pairwise-stable", "mass": pruned_mi.DEFAULT_PRUNE_MASS},
              "machine": {"platform": platform.platform(), "cpus": os.cpu_count(), "backend": jax.default_backend()},
              "runs": [], "compare": {}}
    with tempfile.TemporaryDirectory() as tmp:
        for c in sizes:
            runs = {}
            for variant in ("pruned", "tables") if c <= args.unpruned_max else ("pruned",):
                cmd = [sys.executable, __file__, "--repeat", str(args.repeat), "--child", str(c), variant, tmp]
                done = subprocess.run(cmd, capture_output=True, text=True)
                if done.returncode != 0:
                    runs[variant] = {"C": c, "variant": variant, "error": done.stderr.strip().splitlines()[-1:]}
                else:
                    runs[variant] = json.loads(done.stdout.strip().splitlines()[-1])
                report["runs"].append(runs[variant])
                print(json.dumps(runs[variant]), flush=True)
            if all("error" not in r for r in runs.values()) and len(runs) == 2:
                report["compare"][str(c)] = compare(c, runs, Path(tmp))
                print(json.dumps({str(c): report["compare"][str(c)]}), flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
