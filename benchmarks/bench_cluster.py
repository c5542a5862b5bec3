"""Campaign throughput on Ray against the number of workers.

A case (iii) campaign (occluded scenes, DB2 model, 8 objects x
``--trials`` trials, 800 by default) on a local Ray instance with
``--workers`` Ray workers (default 1 and 2), each run on a fresh pool:
start-up (actors, rigs, the first compile: a warm-up batch on every worker,
``--warmup`` trials in all) is timed apart from the campaign itself.  The worker counts are
interleaved within every repeat, so a machine shared with other work slows
all of them alike; the ratios are taken per repeat (same moment) and their
median reported.  ``--local`` adds the same campaign in this process (no Ray)
as a reference.  Every run's results are checked equal to the first's.

Target: 2 workers >= 1.7x the throughput of 1 on a 2-core machine.
On a machine shared with other work the wall-clock ratio measures the
neighbours as much as the pool, so the processes' CPU seconds are counted
too, per thread: on dedicated cores a campaign cannot end before its busiest
worker's trial-driver thread (rendering, dispatch; XLA computes beside it on
other threads) has run, nor before the busiest worker's CPU seconds over the
cores it can use (``dedicated_cores_s``; their ratio is
``dedicated_cores_ratio``, what the machine would allow at best).  Writes JSON (default out/bench/cluster.json): per worker count the median
campaign seconds and trials/s, per repeat the ratios to 1 worker, and the
machine's load average before and after.

    python benchmarks/bench_cluster.py                       # 800 trials, workers 1 and 2, 3 repeats
    python benchmarks/bench_cluster.py --trials 25 --repeats 2  # 200 trials
    python benchmarks/bench_cluster.py --workers 1 2 4 8 --local
    python benchmarks/bench_cluster.py --driver 1000 4 --workers 2 8 --out out/bench/cluster-driver.json
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import os
import platform
import statistics
import tempfile
import threading
import time
import warnings
from pathlib import Path

import jax.random as jr

from jaxrecog.campaign import run_campaign
from jaxrecog.campaigns import CASES, Settings, campaign_recognizer, capture_pool, case_model, case_settings, case_trials, \
    make_rig, prepare
from jaxrecog.motion import rig_travel_times
from jaxrecog.recipes import DEFAULT_RECIPE, RECIPES


def _signature(results) -> list:
    return sorted((r.trial, r.predicted_object, r.predicted_pose, r.steps, r.configurations, r.exit_prob)
                  for r in results)


def _run(rec, settings: Settings, specs, warm, workers: int | None, per_task: int | None = None) -> dict:
    """One campaign on a fresh pool: ``workers`` Ray workers (None: this process)."""
    from jaxrecog.ray_rigs import RayRigs

    key = jr.PRNGKey(settings.seed + 1)
    t0 = time.perf_counter()
    if workers is None:
        pool = capture_pool(settings)
    else:
        pool = RayRigs(functools.partial(make_rig, settings, None, seed=settings.seed, clean_counts={}),
                       settings.batch, workers, cluster="ray", trials_per_task=per_task)
    with pool:
        pool.positions  # every worker up, its rigs built
        if warm:  # every worker compiles the step on its first batch: one warm-up batch each
            if workers is not None:
                pool.trials_per_task = max(1, len(warm) // workers)
            run_campaign(rec, pool, warm, key=key, batch=settings.batch, seed=settings.seed)
            if workers is not None:
                pool.trials_per_task = per_task
        start = time.perf_counter() - t0
        procs = pool.worker_pids() if workers is not None else []
        cpu0 = [_cpu(p) for p in procs], time.process_time()
        t1 = time.perf_counter()
        with _Threads(procs) as threads:
            res = run_campaign(rec, pool, specs, key=key, batch=settings.batch, seed=settings.seed)
        seconds = time.perf_counter() - t1
        cpu = [_cpu(p) - c for p, c in zip(procs, cpu0[0])], time.process_time() - cpu0[1]
        names = [threads.by_name(p) for p in procs]
    # the trial driver's thread: the busiest Python thread (named as its process)
    serial = [max(v for k, v in n.items() if k.startswith("ray::")) if n else 0.0 for n in names]
    return {"workers": workers, "start_s": start, "campaign_s": seconds, "trials_per_s": len(specs) / seconds,
            "worker_cpu_s": cpu[0], "driver_cpu_s": cpu[1], "worker_threads_cpu_s": names,
            "worker_python_threads_cpu_s": serial, "signature": _signature(res)}


class _Threads:
    """CPU seconds per thread of some processes, sampled every 0.2 s while
    it runs (a thread that ends between samples loses < 0.2 s): summed by
    the thread's name, so the trial driver's Python thread (named as its
    process) is told from XLA's and Ray's threads."""

    def __init__(self, pids):
        self.pids, self.seen, self.stop = list(pids), {}, threading.Event()
        self.thread = threading.Thread(target=self._loop, daemon=True)

    def _sample(self):
        for pid in self.pids:
            for task in Path(f"/proc/{pid}/task").glob("*"):
                try:
                    name = (task / "comm").read_text().strip()
                    f = (task / "stat").read_text().rsplit(")", 1)[1].split()
                except OSError:
                    continue
                self.seen[(pid, task.name)] = (name, (int(f[11]) + int(f[12])) / os.sysconf("SC_CLK_TCK"))

    def _loop(self):
        while not self.stop.wait(0.2):
            self._sample()

    def __enter__(self):
        self._sample()
        self.before = dict(self.seen)
        self.thread.start()
        return self

    def __exit__(self, *exc):
        self.stop.set()
        self.thread.join()
        self._sample()

    def by_name(self, pid: int) -> dict[str, float]:
        out: dict[str, float] = {}
        for (p, tid), (name, cpu) in self.seen.items():
            if p == pid:
                out[name] = out.get(name, 0.0) + cpu - self.before.get((p, tid), (name, 0.0))[1]
        return out


def _cpu(pid: int) -> float:
    """CPU seconds (user + system, all threads) of process ``pid`` so far (Linux ``/proc``)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def driver_rate(groups: int, size: int, workers: int = 2) -> dict:
    """What this process can take: ``workers`` stand-in actors stream
    ``groups`` lists of ``size`` trial results each as fast as they can; this
    process takes every message that is in (as ``RayRigs`` does) and stores
    them with one ``TrialStore.extend`` (one fsync) per round.  Ray and the
    store's costs, without trials to run."""
    import ray

    from jaxrecog.results import TrialResult, TrialStore

    one = TrialResult(trial=0, object=3, pose=1, predicted_object=3, predicted_pose=1, exit_prob=0.97, steps=3,
                      stopped=True, invalid_steps=0, occluded_fraction=((0.2, 0.1),) * 3,
                      configurations=((1, 2), (3, 4), (5, 6)))

    @ray.remote
    class Sender:
        def send(self, start: int, n: int, k: int):
            for i in range(n):
                yield [dataclasses.replace(one, trial=start + i * k + j) for j in range(k)]

    senders = [Sender.remote() for _ in range(workers)]
    out = {}
    for label, n in (("warm-up", 50), ("timed", groups)):
        with tempfile.TemporaryDirectory() as tmp:
            store = TrialStore(Path(tmp) / "trials.jsonl")
            calls = [s.send.options(num_returns="streaming").remote(w * n * size, n, size)
                     for w, s in enumerate(senders)]
            t0, messages, rounds, trials = time.perf_counter(), 0, 0, 0
            while calls:
                ready, rest = ray.wait(calls, num_returns=1)
                if rest:
                    ready += ray.wait(rest, num_returns=len(rest), timeout=0)[0]
                got = []
                for c in ready:
                    try:
                        got += ray.get(next(c))
                        messages += 1
                    except StopIteration:
                        calls.remove(c)
                store.extend(got)
                rounds += 1
                trials += len(got)
            dt = time.perf_counter() - t0
        out = {"messages": messages, "trials": trials, "fsyncs": rounds, "seconds": dt,
               "messages_per_s": messages / dt, "trials_per_s": trials / dt, "group": size, "workers": workers}
    for a in senders:
        ray.kill(a)
    return out


def build_parser() -> argparse.ArgumentParser:
    """The command line of this benchmark (the docs tests parse the docs' commands with it)."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="out/bench/cluster.json")
    ap.add_argument("--workdir", default="out/thesis", help="where the trained models are (or are made)")
    ap.add_argument("--trials", type=int, default=100, help="trials per object (8 objects)")
    ap.add_argument("--warmup", type=int, default=8, help="trials of the warm-up batch on each fresh pool")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--planner", default=RECIPES[DEFAULT_RECIPE].planner)
    ap.add_argument("--batch", type=int, default=16)
    ap.add_argument("--trials-per-task", type=int, default=None,
                    help="trials per Ray call (default: RayRigs's, about four batches a worker)")
    ap.add_argument("--cpus", type=int, default=None, help="CPUs of the local Ray instance (default: all)")
    ap.add_argument("--local", action="store_true", help="also the campaign in this process, without Ray")
    ap.add_argument("--driver", type=int, nargs=2, metavar=("GROUPS", "SIZE"),
                    help="only measure what this process can take: GROUPS messages of SIZE results from each of "
                         "the --workers stand-in workers (driver_rate)")
    ap.add_argument("--one-xla-thread", action="store_true",
                    help="XLA's CPU backend on one thread in the workers (XLA_FLAGS for the Ray instance)")
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)

    import ray

    # Ray's memory monitor kills workers when the *machine* is at 95 % of its
    # memory, whoever uses it; on a machine shared with other work it is off here
    os.environ.setdefault("RAY_memory_monitor_refresh_ms", "0")
    if args.one_xla_thread:  # the workers inherit the Ray instance's environment
        os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_cpu_multi_thread_eigen=false "
                                   "intra_op_parallelism_threads=1").strip()
    load0 = os.getloadavg()
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "os.fork", RuntimeWarning)
        ray.init(num_cpus=args.cpus, include_dashboard=False, logging_level="ERROR", log_to_driver=False)
    if args.driver:
        out = {"driver_rate": [driver_rate(args.driver[0], args.driver[1], w) for w in args.workers],
               "load_average_before": load0, "load_average_after": os.getloadavg(), "ray": ray.__version__}
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(out, indent=1) + "\n")
        print(json.dumps(out, indent=1))
        ray.shutdown()
        return 0
    case = CASES["iii"]
    settings = case_settings(case, Settings(workdir=Path(args.workdir), trials_per_object=args.trials,
                                            batch=args.batch))
    model = case_model(prepare(settings, databases=(case.database,)), case)
    probe = make_rig(settings, case.cameras, seed=settings.seed)
    rec = campaign_recognizer(model, args.planner, settings, rig_travel_times(probe))
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
            row = _run(rec, settings, specs, warm, w, args.trials_per_task)
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
        cpu[str(w)]["trial_thread_cpu_s"] = statistics.median(max(x["worker_python_threads_cpu_s"]) for x in rows)
    # on C dedicated cores a campaign takes at least its busiest worker's serial
    # part (the trial driver's thread: rendering, dispatch) and its CPU over the
    # cores it can use (min(C / workers, 1) each when workers >= C... one core each)
    cores = os.cpu_count() or 1

    def bound(w: int) -> float:
        c = cpu[str(w)]
        share = max(1.0, cores / w)  # cores a worker can use
        return max(c["trial_thread_cpu_s"], c["busiest_worker_cpu_s"] / share, c["driver_cpu_s"])

    for w in args.workers:
        cpu[str(w)]["dedicated_cores_s"] = bound(w)
        cpu[str(w)]["dedicated_cores_ratio"] = bound(base) / bound(w)
    out = {
        "what": f"case (iii), {len(specs)} trials, planner {args.planner}, batch {args.batch}, DB2 model; "
                f"campaign seconds after start-up and a {len(warm)}-trial warm-up on each fresh pool",
        "machine": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
        "ray": ray.__version__, "ray_cpus": ray.cluster_resources().get("CPU"),
        "load_average_before": load0, "load_average_after": os.getloadavg(),
        "trials": len(specs), "repeats": args.repeats, "one_xla_thread": args.one_xla_thread,
        "trials_per_task": args.trials_per_task, "same_results_every_run": same,
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
