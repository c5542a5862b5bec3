"""Rig pools: the rigs of a campaign's lockstep slots, and who runs their captures.

The trial driver (:func:`jaxrecog.driver.run_trials`) asks for one capture per
active slot at every step.  On a rendered rig those captures are most of a
campaign's time (case (iii), 800 trials, ``mi-class-pairwise``: ~21 s of
rendering against ~2 s of recognizer steps), and they are independent of each
other, so they can run side by side.  A pool takes the whole step's requests
at once (:meth:`RigPool.capture_batch`):

- :class:`LocalRigs` runs them one after another in this process (the default;
  what a single rig or a list of rigs becomes);
- :class:`ProcessRigs` spreads the pool's rigs over worker processes, each of
  which builds its own rigs from a picklable factory and renders its share.

A capture depends only on the rig's scene, its reseed value and the
configuration (campaigns reseed every capture with ``(seed, trial, step)``),
and rig ``r`` gets the same requests in the same order in either pool, so a
campaign's results are the same with any number of workers (tested).
"""

from __future__ import annotations

import multiprocessing as mp
import traceback
import weakref
from multiprocessing.reduction import ForkingPickler
from typing import Callable, Sequence

from .rig import Capture, CaptureJob, Rig, RigError, RigPool, SceneSpec, WorkerPool  # the pool's interface (re-exported)

__all__ = ["SceneSpec", "CaptureJob", "RigPool", "LocalRigs", "ProcessRigs", "as_rig_pool"]


def run_job(rig: Rig, job: CaptureJob) -> Capture:
    """``reset`` (if ``job.scene``), ``reseed``, ``move``, ``capture``: the one
    place the order of a capture's rig calls is written."""
    s = job.scene
    if s is not None:
        if s.yaw_offset is None:
            rig.reset(s.object, s.pose, s.occluders)
        else:
            rig.reset(s.object, s.pose, s.occluders, yaw_offset_deg=s.yaw_offset)
    rig.reseed(job.seed)
    rig.move(job.config)
    return rig.capture()


def _check_rigs(rigs: Sequence[Rig]) -> None:
    if not rigs:
        raise ValueError("a rig pool needs at least one rig")
    first = tuple(rigs[0].positions)
    for r in rigs[1:]:
        if tuple(r.positions) != first:
            raise ValueError(f"the pool's rigs differ: positions {tuple(r.positions)} vs {first}")


def _check_jobs(jobs: Sequence[CaptureJob], n_rigs: int) -> None:
    for j in jobs:
        if not 0 <= j.rig < n_rigs:
            raise ValueError(f"capture job for rig {j.rig}: the pool has rigs 0..{n_rigs - 1}")


class LocalRigs:
    """The pool's rigs in this process, captured one after another."""

    def __init__(self, rigs: Sequence[Rig]):
        self.rigs = list(rigs)
        _check_rigs(self.rigs)

    @property
    def n_rigs(self) -> int:
        return len(self.rigs)

    @property
    def positions(self) -> tuple[int, ...]:
        return tuple(self.rigs[0].positions)

    @property
    def image_shape(self) -> tuple[int, int]:
        return tuple(self.rigs[0].image_shape)

    def capture_batch(self, jobs: Sequence[CaptureJob]) -> list[Capture]:
        _check_jobs(jobs, self.n_rigs)
        return [run_job(self.rigs[j.rig], j) for j in jobs]

    def close(self) -> None:
        for r in self.rigs:
            r.close()

    def __enter__(self) -> "LocalRigs":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def as_rig_pool(rigs: Rig | Sequence[Rig] | RigPool) -> RigPool:
    """A pool as it is; one rig or a list of rigs as a :class:`LocalRigs`."""
    if hasattr(rigs, "capture_batch"):
        return rigs
    if isinstance(rigs, Rig):
        return LocalRigs([rigs])
    return LocalRigs(list(rigs))


# -- worker processes

def _serve(conn, factory: Callable[[], Rig], mine: Sequence[int]) -> None:
    """A worker: build the rigs ``mine`` (pool indices), report their shape,
    then run each batch of jobs it is sent until it receives ``None`` or the
    parent's end of the pipe closes."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle: it closes the pool
    rigs: dict = {}
    try:
        try:
            rigs = {r: factory() for r in mine}
            first = next(iter(rigs.values()))
            conn.send(("ok", (tuple(first.positions), tuple(first.image_shape))))
        except (OSError, EOFError):
            raise
        except BaseException as err:  # noqa: BLE001 -- reported to the parent, which raises
            conn.send(("error", _portable(err)))
            return
        while True:
            jobs = conn.recv()
            if jobs is None:
                break
            try:
                reply = ("ok", [run_job(rigs[j.rig], j) for j in jobs])
            except BaseException as err:  # noqa: BLE001
                reply = ("error", _portable(err))
            conn.send(reply)
    except (OSError, EOFError):
        pass  # the parent is gone or closed the pool: stop quietly
    finally:
        for r in rigs.values():
            r.close()


def _portable(err: BaseException) -> tuple[BaseException | None, str]:
    """An exception that survives pickling (or None), and its traceback text."""
    import pickle

    text = "".join(traceback.format_exception(err))
    try:
        pickle.loads(pickle.dumps(err))
        return err, text
    except Exception:  # noqa: BLE001
        return None, text


def _shutdown(conns, procs, timeout: float = 5.0) -> None:
    """Ask every worker to stop, close the pipes (a worker blocked on sending
    a reply then fails and stops) and wait for all of them within one shared
    ``timeout``; terminate the ones still running."""
    import time

    for c in conns:
        try:
            c.send(None)
        except (OSError, ValueError):
            pass
        c.close()
    deadline = time.monotonic() + timeout
    for p in procs:
        p.join(timeout=max(0.0, deadline - time.monotonic()))
    for p in procs:
        if p.is_alive():
            p.terminate()
            p.join(timeout=1.0)


class ProcessRigs(WorkerPool):
    """``n_rigs`` rigs spread over ``workers`` processes (rig ``r`` lives in
    worker ``r % workers``); a batch's jobs run in parallel across workers.

    Args:
        factory: a picklable callable that builds one rig (e.g.
            ``functools.partial(SyntheticRig, table, noise=..., seed=0)``);
            called once per rig, inside its worker.
        n_rigs: rigs in the pool (one per lockstep slot of the driver).
        workers: worker processes, ``1 <= workers``; more than ``n_rigs`` are
            not started.

    The workers are started with the ``spawn`` method (safe beside JAX's
    threads), so a script that makes a pool must guard its entry point with
    ``if __name__ == "__main__":``.  Close the pool (``close()`` or ``with``)
    to stop them; they also stop when the pool is garbage-collected or the
    parent exits.  The workers start in the background; the first use
    (:attr:`positions`, :meth:`capture_batch`) waits for them.

    Errors: an exception a worker raises while building its rigs or running
    a job (e.g. a :class:`RigError` for a bad configuration) is raised here
    and the pool stays usable (every worker's answer to that batch has been
    read); so does a job that cannot be pickled (every job is pickled before
    any is sent).  Anything that interrupts a batch in flight -- a worker that
    dies (a :class:`RigError` naming it), Ctrl-C -- closes the pool, so no
    stale answer can be taken for a later batch's.
    """

    def __init__(self, factory: Callable[[], Rig], n_rigs: int, workers: int):
        n_rigs, workers = int(n_rigs), int(workers)
        if n_rigs < 1:
            raise ValueError(f"n_rigs must be >= 1, got {n_rigs}")
        if workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        workers = min(workers, n_rigs)
        ctx = mp.get_context("spawn")
        self._n_rigs, self.workers = n_rigs, workers
        self._conns, self._procs = [], []
        self._finalizer = weakref.finalize(self, _shutdown, self._conns, self._procs)
        for w in range(workers):
            parent, child = ctx.Pipe()
            p = ctx.Process(target=_serve, args=(child, factory, list(range(w, n_rigs, workers))),
                            daemon=True, name=f"jaxrecog-rig-{w}")
            p.start()
            child.close()
            self._conns.append(parent)
            self._procs.append(p)
        self._shape: tuple | None = None  # (positions, image_shape), from the workers' first answers

    @property
    def n_rigs(self) -> int:
        return self._n_rigs

    @property
    def positions(self) -> tuple[int, ...]:
        return self._ready()[0]

    @property
    def image_shape(self) -> tuple[int, int]:
        return self._ready()[1]

    def _ready(self) -> tuple:
        # the workers start in the background (spawn + imports, ~2 s); the
        # first use waits for their answers, so a caller can build its model
        # and compile meanwhile
        if self._shape is None:
            self._check_open()
            try:
                answers = [self._recv(w) for w in range(self.workers)]
            except BaseException:
                self.close()
                raise
            failed = [(w, a[1]) for w, a in enumerate(answers) if a[0] != "ok"]
            if failed:
                self.close()
                _raise_reported(*failed[0])
            shapes = {a[1] for a in answers}
            if len(shapes) != 1:
                self.close()
                raise ValueError(f"the pool's rigs differ: {sorted(shapes)}")
            self._shape = answers[0][1]
        return self._shape

    def _recv(self, w: int) -> tuple:
        """Worker ``w``'s next answer, ``(status, payload)``; a closed pipe
        is a :class:`RigError` naming the worker."""
        try:
            return self._conns[w].recv()
        except (EOFError, OSError) as err:
            self._procs[w].join(timeout=1.0)
            raise RigError(f"rig worker {w} exited (exit code {self._procs[w].exitcode}) "
                           "without answering") from err

    def capture_batch(self, jobs: Sequence[CaptureJob]) -> list[Capture]:
        self._check_open()
        self._ready()
        jobs = list(jobs)
        _check_jobs(jobs, self._n_rigs)
        share: list[list[int]] = [[] for _ in range(self.workers)]
        for i, j in enumerate(jobs):
            share[j.rig % self.workers].append(i)
        busy = [w for w in range(self.workers) if share[w]]
        # pickle every share before sending any: a job that cannot be sent
        # fails here, with nothing in flight
        payloads = {w: bytes(ForkingPickler.dumps([jobs[i] for i in share[w]])) for w in busy}
        out: list[Capture | None] = [None] * len(jobs)
        reported = None
        try:
            for w in busy:
                try:
                    self._conns[w].send_bytes(payloads[w])
                except OSError as err:
                    self._procs[w].join(timeout=1.0)
                    raise RigError(f"rig worker {w} is gone (exit code {self._procs[w].exitcode})") from err
            for w in busy:  # read every answer, so none is left in a pipe
                status, payload = self._recv(w)
                if status == "ok":
                    for i, cap in zip(share[w], payload):
                        out[i] = cap
                elif reported is None:
                    reported = (w, payload)
        except BaseException:
            self.close()  # a batch cut short: the pipes' contents are unknown
            raise
        if reported is not None:
            _raise_reported(*reported)
        return out

    def close(self) -> None:
        """Stop the workers (idempotent); workers that have not answered yet
        (still starting) are terminated at once."""
        if self._shape is None and self._finalizer.alive:
            for p in self._procs:
                p.terminate()
        self._finalizer()


def _raise_reported(w: int, payload) -> None:
    """Raise the exception worker ``w`` reported (its own type where it
    survived pickling, else a :class:`RigError`), with its traceback text."""
    err, text = payload
    if err is not None:
        raise err from RigError(f"in rig worker {w}:\n{text}")
    raise RigError(f"rig worker {w} failed:\n{text}")
