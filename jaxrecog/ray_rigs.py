"""Rigs in Ray actors and trials in Ray actor calls: a campaign on a cluster.

:class:`RayRigs` is a rig pool (the interface of
:class:`~jaxrecog.hardware.rigs.rig_pool.ProcessRigs`: ``n_rigs``, ``positions``,
``image_shape``, ``capture_batch``, ``close``) whose rigs live in Ray actors,
one actor per worker, each holding its own ``n_rigs`` rigs built from a
picklable factory (put into the object store once).  It can also run whole
trials itself (:meth:`RayRigs.run_trials`; :func:`jaxrecog.campaign.run_campaign`
hands them over when a pool can): the trials go out in batches of
``trials_per_task``, one actor call each, that runs the ordinary trial driver
(:func:`jaxrecog.driver.run_trials`) beside that actor's rigs and streams
the finished trials (:class:`~jaxrecog.results.TrialResult`) back as they finish
(all that are ready at once in one message; through Ray Client, which has no
streaming calls, at the batch's end).
The recognizer is put into the object store once per campaign; each actor
reads it once.

Lost workers: when an actor dies (its process killed, its node gone), the
trials of its batches that have not come back go into the queue again, a
new actor takes its place, and the campaign goes on; a trial that came back
is never sent again, and one that comes back twice is counted once.  A trial
whose worker dies ``max_attempts`` times stops the campaign with a
:class:`~jaxrecog.cluster.ClusterError` (the finished trials are stored:
run again to resume).  An exception raised in a worker (a bad configuration,
a rig fault) is raised here as itself, and the pool closes.

Imported only when a cluster is used (``jaxrecog.cluster``).
"""

from __future__ import annotations

import collections
import math
import queue
import threading
import weakref
from typing import Callable, Iterable, Sequence

from .cluster import ClusterError, connect, import_ray, local_versions, version_problems

ray = import_ray()  # without Ray installed: one line saying how to install it
from ray.exceptions import (ActorDiedError, ActorUnavailableError, GetTimeoutError, OutOfMemoryError,  # noqa: E402
                            RayTaskError, WorkerCrashedError)

from .driver import TrialSpec, run_trials  # noqa: E402
from .hardware.rigs.rig import Capture, CaptureJob, Rig, RigError, WorkerPool  # noqa: E402
from .results import TrialResult  # noqa: E402

__all__ = ["RayRigs", "START_TIMEOUT_S"]

#: Seconds to wait for the first worker of a pool (or a replacement) to start.
START_TIMEOUT_S = 300.0
#: A worker holds at most this many trial batches (one runs, the next waits
#: in its queue, so it never idles between batches).
_IN_FLIGHT = 2
#: a worker gone: its process died, its node left, or Ray's memory monitor killed it
_LOST = (ActorDiedError, ActorUnavailableError, WorkerCrashedError, OutOfMemoryError)


class _End:
    pass


class _Raised:
    def __init__(self, error: BaseException):
        self.error = error


class _Worker:
    """One Ray actor: ``n_rigs`` rigs (built on first use) and the last
    recognizer it was sent."""

    def __init__(self, factory_box: list, n_rigs: int):
        self._factory_box, self._n_rigs = factory_box, n_rigs
        self._pool = None
        self._recognizer: tuple[str, object] | None = None

    def _rigs(self):
        if self._pool is None:
            from .hardware.rigs.rig_pool import LocalRigs

            factory = ray.get(self._factory_box[0])
            self._pool = LocalRigs([factory() for _ in range(self._n_rigs)])
        return self._pool

    def info(self) -> dict:
        """Versions, node and the rigs' shape (building the rigs)."""
        import os

        pool = self._rigs()
        return {"versions": local_versions(), "node": ray.get_runtime_context().get_node_id()[:8],
                "pid": os.getpid(), "shape": (pool.positions, pool.image_shape)}

    def capture(self, jobs: Sequence[CaptureJob]) -> list[Capture]:
        return self._rigs().capture_batch(jobs)

    def run(self, recognizer_box: list, specs: list[TrialSpec], key, batch: int, seed: int, trace: bool,
            devices):
        """Run ``specs`` with the trial driver on this actor's rigs and yield
        the results (:class:`TrialResult`) as their trials finish (a streaming call):
        a list of every result that is ready, so a busy worker sends one
        message per step, not one per trial."""
        ref = recognizer_box[0]
        if self._recognizer is None or self._recognizer[0] != ref.hex():
            self._recognizer = (ref.hex(), ray.get(ref))  # once per actor and campaign
        rec, pool = self._recognizer[1], self._rigs()
        out: queue.Queue = queue.Queue()

        def work():
            try:
                run_trials(rec, pool, specs, key=key, batch=batch, seed=seed, trace=trace, on_result=out.put,
                           devices=devices)
                out.put(_End())
            except BaseException as e:  # noqa: BLE001 -- raised below, in the actor call
                out.put(_Raised(e))

        threading.Thread(target=work, daemon=True, name="jaxrecog-trials").start()
        while True:
            items = [out.get()]
            while not out.empty():
                items.append(out.get())
            results = [r for r in items if isinstance(r, TrialResult)]
            if results:
                yield results
            for item in items:
                if isinstance(item, _Raised):
                    raise item.error
                if isinstance(item, _End):
                    return

    def run_all(self, *args) -> list[TrialResult]:
        """:meth:`run`'s results in one answer, at the batch's end (Ray
        Client, ``ray://``, has no streaming calls)."""
        return [r for group in self.run(*args) for r in group]


_REMOTE: list = []


def _remote_worker():
    """The actor class (made once per process): spread over the nodes, never
    restarted by Ray (a lost worker is replaced here, so no batch is run
    twice behind the pool's back).  Ray's default resources for an actor:
    placed where a CPU is free, holding none while it lives, so pools left
    open (or a render's tasks) never wait for each other's CPUs; the pool
    starts one worker per CPU of the cluster, not more."""
    if not _REMOTE:
        _REMOTE.append(ray.remote(max_restarts=0, max_task_retries=0, scheduling_strategy="SPREAD")(_Worker))
    return _REMOTE[0]


def _kill(actors: list) -> None:
    for a in actors:
        try:
            ray.kill(a)
        except Exception:  # noqa: BLE001 -- already gone, or Ray shut down first
            pass
    actors.clear()


def _cause(err: RayTaskError) -> BaseException:
    """A worker's exception as its own type where Ray can rebuild it."""
    try:
        return err.as_instanceof_cause()
    except Exception:  # noqa: BLE001
        return err


class _Batch:
    """A trial batch in flight on worker ``w``: its trials not yet back."""

    def __init__(self, w: int, specs: list[TrialSpec]):
        self.w = w
        self.pending = {s.trial: s for s in specs}


class RayRigs(WorkerPool):
    """``n_rigs`` rigs in each of ``workers`` Ray actors.

    Args:
        factory: a picklable callable that builds one rig (as for
            :class:`~jaxrecog.hardware.rigs.rig_pool.ProcessRigs`); called
            ``n_rigs`` times in every actor, on first use.
        n_rigs: rigs per actor (one per lockstep slot of the trial driver).
        workers: actors, each running one trial batch at a time; 0 = one
            per CPU of the cluster (at most that many in any case).
        cluster: ``"ray"`` or ``"ray://HOST:PORT"`` (:func:`jaxrecog.cluster.connect`).
        trials_per_task: trials per batch (:meth:`run_trials`); default
            ``max(2 * batch, ceil(trials / (4 * workers)))``: about four
            batches a worker, each long enough that its slots stay full.
        max_attempts: a trial whose worker dies this many times stops the run.

    ``capture_batch`` sends rig ``r``'s jobs to actor ``r % workers``.
    """

    def __init__(self, factory: Callable[[], Rig], n_rigs: int, workers: int = 0, *, cluster: str = "ray",
                 trials_per_task: int | None = None, max_attempts: int = 3):
        n_rigs, workers = int(n_rigs), int(workers)
        if n_rigs < 1:
            raise ValueError(f"n_rigs must be >= 1, got {n_rigs}")
        if workers < 0:
            raise ValueError(f"workers must be >= 0 (0: one per CPU of the cluster), got {workers}")
        if trials_per_task is not None and int(trials_per_task) < 1:
            raise ValueError(f"trials_per_task must be >= 1, got {trials_per_task}")
        connect(cluster)
        self.cluster, self._n_rigs = cluster, n_rigs
        self.trials_per_task, self.max_attempts = trials_per_task, int(max_attempts)
        cpus = max(1, int(ray.cluster_resources().get("CPU", 1)))
        self.workers = min(workers or cpus, cpus)
        self._factory_box = [ray.put(factory)]
        self._actors: list = []
        self._finalizer = weakref.finalize(self, _kill, self._actors)
        self._live: list[bool] = []
        self._info: list[dict | None] = []
        for _ in range(self.workers):
            self._start()
        self._shape: tuple | None = None
        #: what the last :meth:`run_trials` did: workers lost, trials sent again
        self.last_run: dict = {}

    # -- workers
    def _start(self) -> int:
        self._actors.append(_remote_worker().remote(self._factory_box, self._n_rigs))
        self._live.append(True)
        self._info.append(None)
        return len(self._actors) - 1

    def _replace(self, w: int) -> tuple[int, object]:
        """Worker ``w`` is gone: make sure, and start another; returns its
        index and the reference its :meth:`_Worker.info` answers on."""
        self._live[w] = False
        try:
            ray.kill(self._actors[w])
        except Exception:  # noqa: BLE001 -- already gone
            pass
        new = self._start()
        return new, self._actors[new].info.remote()

    def _usable(self, w: int) -> bool:
        return self._live[w] and self._info[w] is not None

    def _check_info(self, w: int, info: dict) -> None:
        problem = version_problems(local_versions(), info["versions"], f"{w} (node {info['node']})")
        if problem:
            raise ClusterError(problem)
        if self._shape is not None and tuple(info["shape"]) != tuple(self._shape):
            raise ValueError(f"the pool's rigs differ: {info['shape']} vs {self._shape}")
        self._info[w] = info

    def _ready(self) -> tuple:
        if self._shape is None:
            self._check_open()
            try:
                refs = [a.info.remote() for a in self._actors]
                infos = ray.get(refs, timeout=START_TIMEOUT_S)
            except GetTimeoutError:
                self.close()
                raise ClusterError(f"the cluster's {self.workers} workers did not start within "
                                   f"{START_TIMEOUT_S:g} s (too few free CPUs?)") from None
            except RayTaskError as e:
                self.close()
                raise _cause(e) from None
            except BaseException:
                self.close()
                raise
            try:
                for w, info in enumerate(infos):
                    self._check_info(w, info)
                    self._shape = self._shape or tuple(info["shape"])
            except BaseException:
                self.close()
                raise
        return self._shape

    @property
    def n_rigs(self) -> int:
        return self._n_rigs

    @property
    def positions(self) -> tuple[int, ...]:
        return tuple(self._ready()[0])

    @property
    def image_shape(self) -> tuple[int, int]:
        return tuple(self._ready()[1])

    def worker_pids(self) -> list[int]:
        """The process ids of the live workers (after first use)."""
        return [i["pid"] for i, live in zip(self._info, self._live) if live and i is not None]

    # -- the pool interface
    def capture_batch(self, jobs: Sequence[CaptureJob]) -> list[Capture]:
        self._check_open()
        self._ready()
        jobs = list(jobs)
        for j in jobs:
            if not 0 <= j.rig < self._n_rigs:
                raise ValueError(f"capture job for rig {j.rig}: the pool has rigs 0..{self._n_rigs - 1}")
        share: dict[int, list[int]] = collections.defaultdict(list)
        for i, j in enumerate(jobs):
            share[j.rig % self.workers].append(i)
        refs = {w: self._actors[w].capture.remote([jobs[i] for i in idx]) for w, idx in share.items()}
        out: list[Capture | None] = [None] * len(jobs)
        try:
            for w, ref in refs.items():
                for i, cap in zip(share[w], ray.get(ref)):
                    out[i] = cap
        except RayTaskError as e:  # the pool stays usable: each actor answers its calls in order
            raise _cause(e) from None
        except _LOST as e:
            self.close()
            raise RigError(f"rig worker {w} on the cluster is gone ({type(e).__name__})") from None
        return out

    # -- whole trials
    def run_trials(self, recognizer, specs: Iterable[TrialSpec], *, key, batch: int = 16, seed: int = 0,
                   trace: bool = False, on_result: Callable[[TrialResult], None] | None = None,
                   on_results: Callable[[list[TrialResult]], None] | None = None,
                   devices=None) -> list[TrialResult]:
        """:func:`jaxrecog.driver.run_trials` on the cluster: the same
        arguments (no ``on_step``) and the same results, returned in the order
        they finished; here, in this process, ``on_result`` is called with
        each trial as it comes back and ``on_results`` with each group of
        trials that came back together (one message of a worker)."""
        from .counts import check_counts

        self._check_open()
        self._ready()
        check_counts(recognizer.model, self, other_name="rig")
        specs = list(specs)
        ids = [s.trial for s in specs]
        if len(set(ids)) != len(ids):
            raise ValueError("trial ids in `specs` must be unique")
        if batch < 1:
            raise ValueError(f"batch must be >= 1, got {batch}")
        size = self.trials_per_task or max(2 * batch, math.ceil(len(specs) / (4 * self.workers)))
        run = _Run(self, [specs[i:i + size] for i in range(0, len(specs), size)],
                   ([ray.put(recognizer)], key, batch, seed, trace, devices))  # the model and tables, once
        self.last_run = run.stats
        results: list[TrialResult] = []

        def deliver():
            new, run.out = run.out, []
            results.extend(new)
            if new and on_results is not None:
                on_results(new)
            for res in new if on_result is not None else ():
                on_result(res)

        try:
            while run.todo or run.flying:
                try:
                    run.step()
                finally:
                    deliver()  # what came back is stored, whatever happens next
        except BaseException:
            self.close()  # batches cut short: the workers' state is unknown
            raise
        return results


class _Run:
    """One :meth:`RayRigs.run_trials`: the batches to send, those in flight
    (streaming calls) and the replacements starting; :meth:`step` takes every
    message that is in and leaves its new results in ``out``."""

    def __init__(self, pool: RayRigs, batches: list[list[TrialSpec]], args: tuple):
        self.pool, self.args = pool, args
        self.todo = collections.deque(batches)
        self.flying: dict = {}      # streaming call -> _Batch
        self.starting: dict = {}    # info() ref of a replacement -> worker index
        self.done: set[int] = set()
        self.attempts: collections.Counter = collections.Counter()
        self.stats = {"workers_lost": 0, "sent_again": [], "repeats_ignored": 0}
        self.out: list[TrialResult] = []
        from ray.util.client import ray as client

        # through Ray Client (ray://) a batch's results come back at its end, not trial by trial
        self.streaming = not client.is_connected()

    def step(self) -> None:
        self._submit()
        waitable = list(self.flying) + list(self.starting)
        if not waitable:
            raise ClusterError(f"every worker of the cluster was lost; {sum(map(len, self.todo))} trials are not "
                               "done (the finished ones are stored: run again to resume)")
        ready, rest = ray.wait(waitable, num_returns=1, timeout=None if self.flying else START_TIMEOUT_S)
        if not ready:
            raise ClusterError(f"no replacement worker started within {START_TIMEOUT_S:g} s")
        if rest:  # and every other message already in: one group, one fsync of the store
            ready += ray.wait(rest, num_returns=len(rest), timeout=0)[0]
        for item in ready:
            if item in self.starting:
                self._started(self.starting.pop(item), item)
            else:
                self._take(item)

    def _take(self, item) -> None:
        b = self.flying[item]
        try:
            group = ray.get(next(item) if self.streaming else item)
            if not self.streaming:
                del self.flying[item]
        except StopIteration:
            del self.flying[item]
            if b.pending:  # a batch that ended without all its trials: not the driver's way
                raise ClusterError(f"worker {b.w} ended a batch with trials {sorted(b.pending)} not done") from None
            return
        except RayTaskError as e:
            raise _cause(e) from None
        except _LOST:
            del self.flying[item]
            self._lost(b)
            return
        for res in group:
            if res.trial in self.done or res.trial not in b.pending:
                self.stats["repeats_ignored"] += 1
                continue
            del b.pending[res.trial]
            self.done.add(res.trial)
            self.out.append(res)
        if not self.streaming and b.pending:
            raise ClusterError(f"worker {b.w} ended a batch with trials {sorted(b.pending)} not done")

    def _submit(self) -> None:
        """Give every live, started worker batches up to :data:`_IN_FLIGHT`,
        one at a time round the workers (the first batches go one to each)."""
        pool = self.pool
        load = collections.Counter(b.w for b in self.flying.values())
        for level in range(_IN_FLIGHT):
            for w, actor in enumerate(pool._actors):
                if self.todo and pool._usable(w) and load[w] <= level:
                    chunk = self.todo.popleft()
                    if self.streaming:
                        call = actor.run.options(num_returns="streaming").remote(self.args[0], chunk, *self.args[1:])
                    else:
                        call = actor.run_all.remote(self.args[0], chunk, *self.args[1:])
                    self.flying[call] = _Batch(w, chunk)
                    load[w] += 1

    def _lost(self, b: _Batch) -> None:
        """Worker ``b.w`` died: its batch's unfinished trials go back to the
        front of the queue, and (once per worker) a replacement starts."""
        pool = self.pool
        again = list(b.pending.values())
        for s in again:
            self.attempts[s.trial] += 1
            if self.attempts[s.trial] >= pool.max_attempts:
                raise ClusterError(f"trial {s.trial}: its worker died {self.attempts[s.trial]} times; giving up "
                                   "(the finished trials are stored; run without --cluster to see the error)")
        if again:
            self.todo.appendleft(again)
            self.stats["sent_again"].extend(s.trial for s in again)
        if pool._live[b.w]:
            self.stats["workers_lost"] += 1
            w, ref = pool._replace(b.w)
            self.starting[ref] = w

    def _started(self, w: int, ref) -> None:
        try:
            self.pool._check_info(w, ray.get(ref))
        except _LOST:
            self.pool._live[w] = False  # the replacement could not start either; the others carry on
        except RayTaskError as e:
            raise _cause(e) from None
