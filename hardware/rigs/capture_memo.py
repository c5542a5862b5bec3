"""Captures remembered across campaigns of the same trials.

A rendered rig's capture depends only on its scene, its reseed value and the
configuration (:mod:`.rig_pool`), and a thesis case runs every planner on the
same trials with the same ``(seed, trial, step)`` reseeds: every planner's
first capture of a trial is the same image set, and two planners that agree on
a trial's next view get the same second capture too.  Case (ii) and case (iii)
even show the same scenes (they differ in the model, not the rig).  Of the
36 008 captures of ``reproduce_thesis.py --case all`` only 21 305 differ.

:class:`MemoRigs` wraps a :class:`~.rig.RigPool` and answers a job whose
capture it has kept without sending it to the pool; the others go to the pool
as they would have (a rig that missed a scene change because its job was
answered here gets that scene with its next job), so the captures, and every
result, are those of the pool alone.  :class:`CaptureMemo` keeps them, the
most recently used first, up to a size in bytes; one memo may serve several
pools (a case after another), each under its own ``tag`` (what makes its rigs
render alike: the rig settings), so unlike rigs never share a capture.

Only for rigs whose captures are such a function (the synthetic rig, reseeded
per capture as the campaigns do): a physical rig's next image is not its last
one.
"""

from __future__ import annotations

import collections
import dataclasses
from typing import Any, Hashable, Sequence

from .rig import Capture, CaptureJob, RigPool, SceneSpec

__all__ = ["CaptureMemo", "MemoRigs"]

#: default size of a :class:`CaptureMemo`: ~6 800 two-camera captures of 120 x 160
DEFAULT_MEMO_BYTES = 256 << 20


class CaptureMemo:
    """Captures by key, least recently used dropped first beyond ``max_bytes``.

    ``hits`` and ``misses`` count the lookups (what the memo saved)."""

    def __init__(self, max_bytes: int = DEFAULT_MEMO_BYTES):
        if int(max_bytes) < 0:
            raise ValueError(f"max_bytes must be >= 0, got {max_bytes}")
        self.max_bytes = int(max_bytes)
        self._kept: collections.OrderedDict[Hashable, Capture] = collections.OrderedDict()
        self._bytes = 0
        self.hits = self.misses = 0

    def __len__(self) -> int:
        return len(self._kept)

    @property
    def nbytes(self) -> int:
        return self._bytes

    def get(self, key: Hashable) -> Capture | None:
        cap = self._kept.get(key)
        if cap is None:
            self.misses += 1
            return None
        self._kept.move_to_end(key)
        self.hits += 1
        return cap

    def put(self, key: Hashable, capture: Capture) -> None:
        size = capture.images.nbytes
        if size > self.max_bytes or key in self._kept:
            return
        capture.images.setflags(write=False)  # one array may answer many jobs: nobody writes into it
        self._kept[key] = capture
        self._bytes += size
        while self._bytes > self.max_bytes:
            _, old = self._kept.popitem(last=False)
            self._bytes -= old.images.nbytes


def _key(tag, scene: SceneSpec | None, job: CaptureJob):
    """The memo's key of ``job`` on a rig showing ``scene``; ``None`` (not
    kept) where the rig's scene is unknown or the seed cannot key a dict."""
    if scene is None or job.seed is None:  # no seed: the rig draws fresh entropy, a capture of its own
        return None
    key = (tag, scene, job.seed, tuple(job.config))
    try:
        hash(key)
    except TypeError:
        return None
    return key


class MemoRigs:
    """``pool`` with its captures kept in ``memo`` under ``tag`` (module doc).

    Args:
        pool: a rig pool whose captures depend only on (scene, seed, configuration).
        memo: where the captures are kept (shared with other pools of other tags).
        tag: hashable, the same for pools whose rigs render alike (e.g. the rig settings).

    Closing this closes ``pool``; the memo stays."""

    def __init__(self, pool: RigPool, memo: CaptureMemo, tag: Hashable):
        hash(tag)  # a tag that cannot key the memo fails here, not at the first capture
        self.pool, self.memo, self.tag = pool, memo, tag
        self._told: dict[int, SceneSpec] = {}   # the scene the caller last gave each rig
        self._shows: dict[int, SceneSpec] = {}  # the scene each of the pool's rigs was last given

    @property
    def n_rigs(self) -> int:
        return self.pool.n_rigs

    @property
    def positions(self) -> tuple[int, ...]:
        return self.pool.positions

    @property
    def image_shape(self) -> tuple[int, int]:
        return self.pool.image_shape

    def capture_batch(self, jobs: Sequence[CaptureJob]) -> list[Capture]:
        for job in jobs:  # as the pool would: a hit must not hide a bad job
            if not 0 <= job.rig < self.n_rigs:
                raise ValueError(f"capture job for rig {job.rig}: the pool has rigs 0..{self.n_rigs - 1}")
        out: list[Capture | None] = [None] * len(jobs)
        send: list[tuple[int, CaptureJob, Any]] = []
        told, shows = dict(self._told), dict(self._shows)  # kept only once the pool has run the batch
        try:
            for i, job in enumerate(jobs):
                if job.scene is not None:
                    told[job.rig] = job.scene
                scene = told.get(job.rig)
                key = _key(self.tag, scene, job)
                cap = None if key is None else self.memo.get(key)
                if cap is not None:
                    out[i] = cap
                    continue
                if scene is not None and shows.get(job.rig) != scene:
                    job = dataclasses.replace(job, scene=scene)  # the rig missed a scene answered here
                if job.scene is not None:
                    shows[job.rig] = job.scene
                send.append((i, job, key))
            caps = self.pool.capture_batch([job for _, job, _ in send]) if send else []
        except BaseException:
            # what the rigs show is unknown now: each gets the scene it was last given with its next job
            self._told.update(told)
            self._shows.clear()
            raise
        for (i, _, key), cap in zip(send, caps):
            if key is not None:
                self.memo.put(key, cap)
            out[i] = cap
        self._told, self._shows = told, shows
        return out

    def close(self) -> None:
        self.pool.close()

    def __enter__(self) -> "MemoRigs":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
