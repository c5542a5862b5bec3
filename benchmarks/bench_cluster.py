"""Campaign throughput on Ray against the number of workers (issue 30, item 2).

A case (iii) campaign (occluded scenes, DB2 model, 8 objects x
``--trials`` trials, 800 by default) on a local Ray instance with
``--workers`` Ray workers (default 1 and 2), each run on a fresh pool:
start-up (actors, rigs, the first compile; a warm-up batch of ``--warmup``
trials) is timed apart from the campaign itself.  The worker counts are
interleaved within every repeat, so a machine shared with other work slows
all of them alike; the ratios are taken per repeat (same moment) and their
median reported.  ``--local`` adds the same campaign in this process (no Ray)
as a reference.  Every run's results are checked equal to the first's.

Target (issue 30): 2 workers >= 1.7x the throughput of 1 on a 2-core machine.
On a machine shared with other work the wall-clock ratio measures the
neighbours as much as the pool, so the processes' CPU seconds are counted
too: the work of the campaign with one worker (workers and this process)
over the busiest worker's share with more (``cpu_bound_ratio``: the ratio
dedicated cores would allow, at best).  Writes JSON (default out/bench/cluster.json): per worker count the median
campaign seconds and trials/s, per repeat the ratios to 1 worker, and the
machine's load average before and after.

    python benchmarks/bench_cluster.py                       # 800 trials, workers 1 and 2, 3 repeats
    python benchmarks/bench_cluster.py --trials 25 --repeats 2  # 200 trials
    python benchmarks/bench_cluster.py --workers 1 2 4 8 --local
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import os
import platform
import statistics
import time
import warnings
from pathlib import Path

import jax.random as jr

from jaxrecog.campaign import run_campaign
from jaxrecog.experiments import CASES, Settings, capture_pool, case_model, case_settings, case_trials, make_recognizer, \
    make_rig, prepare
from jaxrecog.motion import rig_travel_times
from jaxrecog.recipes import DEFAULT_RECIPE, RECIPES


def _signature(results) -> list:
    return sorted((r.trial, r.predicted_object, r.predicted_pose, r.steps, r.configurations, r.exit_prob)
                  for r in results)


def _run(rec, settings: Settings, specs, warm, workers: int | None) -> dict:
    """One campaign on a fresh pool: ``workers`` Ray workers (None: this process)."""
    from jaxrecog.ray_rigs import RayRigs

    key = jr.PRNGKey(settings.seed + 1)
    t0 = time.perf_counter()
    if workers is None:
        pool = capture_pool(settings)
    else:
        pool = RayRigs(functools.partial(make_rig, settings, None, seed=settings.seed, clean_counts={}),
                       settings.batch, workers, cluster="ray")
    with pool:
        pool.positions  # every worker up, its rigs built
        if warm:
            run_campaign(rec, pool, warm, key=key, batch=settings.batch, seed=settings.seed)  # compiles
        start = time.perf_counter() - t0
        procs = pool.worker_pids() if workers is not None else []
        cpu0 = [_cpu(p) for p in procs], time.process_time()
        t1 = time.perf_counter()
        res = run_campaign(rec, pool, specs, key=key, batch=settings.batch, seed=settings.seed)
        seconds = time.perf_counter() - t1
        cpu = [_cpu(p) - c for p, c in zip(procs, cpu0[0])], time.process_time() - cpu0[1]
    return {"workers": workers, "start_s": start, "campaign_s": seconds, "trials_per_s": len(specs) / seconds,
            "worker_cpu_s": cpu[0], "driver_cpu_s": cpu[1], "signature": _signature(res)}


def _cpu(pid: int) -> float:
    """CPU seconds (user + system, all threads) of process ``pid`` so far (Linux ``/proc``)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="out/bench/cluster.json")
    ap.add_argument("--workdir", default="out/thesis", help="where the trained models are (or are made)")
    ap.add_argument("--trials", type=int, default=100, help="trials per object (8 objects)")
    ap.add_argument("--warmup", type=int, default=8, help="trials of the warm-up batch on each fresh pool")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--planner", default=RECIPES[DEFAULT_RECIPE].planner)
    ap.add_argument("--batch", type=int, default=16)
    ap.add_argument("--cpus", type=int, default=None, help="CPUs of the local Ray instance (default: all)")
    ap.add_argument("--local", action="store_true", help="also the campaign in this process, without Ray")
    args = ap.parse_args(argv)

    import ray

    load0 = os.getloadavg()
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "os.fork", RuntimeWarning)
        ray.init(num_cpus=args.cpus, include_dashboard=False, logging_level="ERROR", log_to_driver=False)
    case = CASES["iii"]
    settings = case_settings(case, Settings(workdir=Path(args.workdir), trials_per_object=args.trials,
                                            batch=args.batch))
    model = case_model(prepare(settings, databases=(case.database,)), case)
    probe = make_rig(settings, case.cameras, seed=settings.seed)
    rec = make_recognizer(model, args.planner, settings, rig_travel_times(probe))
    specs = case_trials(case, settings, probe, model.n_objects, model.n_poses)
    # the warm-up: other trials (a later seed's), so the timed campaign starts from nothing
    warm = case_trials(case, Settings(workdir=settings.workdir, trials_per_object=1, seed=settings.seed + 99),
                       probe, model.n_objects, model.n_poses)[: args.warmup]
    warm = [dataclasses.replace(s, trial=10**6 + i) for i, s in enumerate(warm)]
    probe.close()
    order = ([None] if args.local else []) + list(args.workers)
    runs = []
    for r in range(args.repeats):
        for w in order:
            row = _run(rec, settings, specs, warm, w)
            row["repeat"] = r
            runs.append(row)
            print(f"repeat {r}: {'local' if w is None else f'{w} worker(s)'}: campaign {row['campaign_s']:.1f} s "
                  f"({row['trials_per_s']:.1f} trials/s), start-up {row['start_s']:.1f} s", flush=True)
    same = all(row.pop("signature") == runs[0]["signature"] for row in runs[1:]) if runs else True
    runs[0].pop("signature", None)
    label = {w: "local" if w is None else str(w) for w in order}
    med = {label[w]: statistics.median(x["campaign_s"] for x in runs if x["workers"] == w) for w in order}
    base = min(w for w in args.workers)
    ratios = {}
    for w in args.workers:
        per = [b["campaign_s"] / a["campaign_s"] for r in range(args.repeats)
               for a in runs if a["workers"] == w and a["repeat"] == r
               for b in runs if b["workers"] == base and b["repeat"] == r]
        ratios[str(w)] = {"per_repeat": per, "median": statistics.median(per)}
    # what the CPU time says, free of the machine's other load: the work a
    # campaign needs with one worker, and the busiest worker's share with more
    # (on dedicated cores the campaign cannot end before that worker does)
    cpu = {}
    for w in args.workers:
        rows = [x for x in runs if x["workers"] == w]
        work = statistics.median(sum(x["worker_cpu_s"]) + x["driver_cpu_s"] for x in rows)
        busiest = statistics.median(max(x["worker_cpu_s"]) for x in rows)
        cpu[str(w)] = {"total_cpu_s": work, "busiest_worker_cpu_s": busiest,
                       "driver_cpu_s": statistics.median(x["driver_cpu_s"] for x in rows)}
    one = cpu[str(base)]["total_cpu_s"]
    for w in args.workers:
        cpu[str(w)]["cpu_bound_ratio"] = one / max(cpu[str(w)]["busiest_worker_cpu_s"], cpu[str(w)]["driver_cpu_s"])
    out = {
        "what": f"case (iii), {len(specs)} trials, planner {args.planner}, batch {args.batch}, DB2 model; "
                f"campaign seconds after start-up and a {len(warm)}-trial warm-up on each fresh pool",
        "machine": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
        "ray": ray.__version__, "ray_cpus": ray.cluster_resources().get("CPU"),
        "load_average_before": load0, "load_average_after": os.getloadavg(),
        "trials": len(specs), "repeats": args.repeats, "same_results_every_run": same,
        "median_campaign_s": med,
        "median_trials_per_s": {k: len(specs) / v for k, v in med.items()},
        f"throughput_ratio_to_{base}_worker": ratios,
        "cpu_time": cpu,
        "runs": runs,
    }
    path = Path(args.out)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=1) + "\n")
    print(json.dumps({k: out[k] for k in ("median_campaign_s", "median_trials_per_s",
                                          f"throughput_ratio_to_{base}_worker", "cpu_time", "same_results_every_run",
                                          "load_average_before", "load_average_after")}, indent=1))
    print(f"wrote {path}")
    ray.shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
