"""Rendering an image database on a Ray cluster: (object, pose) blocks as Ray tasks.

:func:`render_database_on` and :func:`render_turntable_on` write the same
folder, byte for byte, as :func:`~jaxrecog.hardware.render_database` and
:func:`~jaxrecog.hardware.render.turntable.render_turntable` (tested).  The work is
split by (object, pose): each Ray task builds its own rig, renders a run of
consecutive blocks (the render functions' ``blocks`` hook) and returns the
PNG files' bytes and manifest rows; this process writes them as they come
back, then the manifest.  Nothing needs a shared file system.

The random splits (``test``, ``calib``) draw from generators that run
through the whole database in order, so a block's images depend on every
block before it.  A *dry pass* here replays that order first with the
rendering itself stubbed out (the draws do not depend on the pixels) and
notes each generator's state at the start of every block; each task starts
its blocks from those states.  The dry pass costs the draws, not the
renders (measured in ``docs/cluster.md``); a database without random
splits (the thesis rig's training set) needs none.

Ray retries a task whose worker died (a task is a pure function of its
blocks), and this process takes each block's files once.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from .cluster import connect, import_ray
from .dbformat import write_manifest

ray = import_ray()  # without Ray installed: one line saying how to install it

__all__ = ["render_database_on", "render_turntable_on"]

Block = tuple[int, int]


def _blank_renderer(rig):
    """``scene.render`` for the dry pass: a blank image whose every pixel is
    the object (so occluded fractions stay defined), without pybullet."""
    h, w = rig.image_shape
    scene = rig.scene

    def render(eye, fov, intrinsics, shift=(0, 0)):
        return np.zeros((h, w), np.uint8), np.full((h, w), next(iter(scene.object_ids)))

    return render


class _Recorder:
    """The dry pass's ``blocks``: renders nothing, notes the generators'
    states at the start of every block."""

    def __init__(self):
        self.states: dict[Block, list] = {}

    def start(self, m: int, p: int, rig, generators) -> bool:
        if not self.states:
            rig.scene.render = _blank_renderer(rig)
        self.states[(m, p)] = [g.bit_generator.state for g in generators]
        return True

    def write(self, row, image) -> None:
        pass


class _Share:
    """A task's ``blocks``: its own blocks, each from its noted states; the
    images as PNG bytes."""

    def __init__(self, states: dict[Block, list | None]):
        self.states = states
        self.out: list[tuple[tuple, bytes]] = []

    def start(self, m: int, p: int, rig, generators) -> bool:
        if (m, p) not in self.states:
            return False
        for g, s in zip(generators, self.states[(m, p)] or ()):
            g.bit_generator.state = s
        return True

    def write(self, row, image) -> None:
        import cv2

        ok, buf = cv2.imencode(".png", image)
        if not ok:
            raise OSError(f"could not encode image '{row[0]}'")
        self.out.append((tuple(row), buf.tobytes()))


def _task(render: Callable, kwargs: dict, rig_box: list | None, states: dict[Block, list | None]):
    share = _Share(states)
    rig = None
    if rig_box is not None:
        rig = kwargs["rig"] = ray.get(rig_box[0])()
    try:
        render(".", blocks=share, **kwargs)
    finally:
        if rig is not None:
            rig.close()
    return share.out


_REMOTE: list = []


def _remote_task():
    if not _REMOTE:
        _REMOTE.append(ray.remote(num_cpus=1, max_retries=3)(_task))
    return _REMOTE[0]


def _on_cluster(cluster: str, render: Callable, out_dir, kwargs: dict, blocks: Sequence[Block], *,
                rig_factory: Callable | None, random_splits: bool, progress, tasks: int | None) -> Path:
    connect(cluster)
    states: dict[Block, list | None] = {b: None for b in blocks}
    if random_splits:  # the generators' states at every block, from a pass that draws but does not render
        rec = _Recorder()
        dry = dict(kwargs)
        rig = None
        if rig_factory is not None:
            rig = dry["rig"] = rig_factory()
        try:
            render(".", blocks=rec, **dry)
        finally:
            if rig is not None:
                rig.close()
        states = rec.states
    cpus = max(1, int(ray.cluster_resources().get("CPU", 1)))
    n = max(1, min(len(blocks), tasks or 4 * cpus))
    size = math.ceil(len(blocks) / n)
    rig_box = None if rig_factory is None else [ray.put(rig_factory)]
    remote = _remote_task()
    pending = [remote.remote(render, kwargs, rig_box, {b: states[b] for b in blocks[i:i + size]})
               for i in range(0, len(blocks), size)]
    out = Path(out_dir)
    rows: list[tuple] = []
    made: set[Path] = set()
    try:
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            files = ray.get(ready[0])
            for row, data in files:
                path = out / row[0]
                if path.parent not in made:
                    path.parent.mkdir(parents=True, exist_ok=True)
                    made.add(path.parent)
                path.write_bytes(data)
                rows.append(row)
            if progress is not None:
                progress(len(files))
    except BaseException:
        for ref in pending:
            ray.cancel(ref)
        raise
    return write_manifest(out, rows)


def render_database_on(cluster: str, out_dir, table=None, objects=None, poses: int = 4, *,
                       rig_factory: Callable | None = None, progress=None, tasks: int | None = None,
                       **kwargs) -> Path:
    """:func:`~jaxrecog.hardware.render_database` on the cluster, with its
    arguments: the same database in ``out_dir``.  The rig: ``rig_factory``
    (a picklable callable; called once here for the dry pass and once per
    task), else ``SyntheticRig(table, objects=, n_poses=poses, seed=seed)``
    as there.  ``tasks``: how many Ray tasks (default four per CPU)."""
    import functools

    from .hardware import SyntheticRig, render_database

    if rig_factory is None:
        rig_factory = functools.partial(SyntheticRig, table, objects=objects, n_poses=poses,
                                        seed=kwargs.get("seed", 0))
    probe = rig_factory()
    try:
        blocks = [(m, p) for m in range(probe.n_objects) for p in range(probe.n_poses)]
    finally:
        probe.close()
    random = bool(kwargs.get("test_per_view") or kwargs.get("calib_per_view"))
    return _on_cluster(cluster, render_database, out_dir, kwargs, blocks, rig_factory=rig_factory,
                       random_splits=random, progress=progress, tasks=tasks)


def render_turntable_on(cluster: str, out_dir, objects, *, progress=None, tasks: int | None = None,
                        **kwargs) -> Path:
    """:func:`~jaxrecog.hardware.render.turntable.render_turntable` on the cluster,
    with its arguments: the same database in ``out_dir``."""
    from .hardware.render.turntable import render_turntable

    kwargs = dict(kwargs, objects=list(objects))
    blocks = [(m, p) for m in range(len(objects)) for p in range(int(kwargs.get("poses", 4)))]
    random = bool(kwargs.get("test_per_view", 2) or kwargs.get("calib_per_view", 1))
    return _on_cluster(cluster, render_turntable, out_dir, kwargs, blocks, rig_factory=None,
                       random_splits=random, progress=progress, tasks=tasks)
