"""The campaigns' synthetic rigs: the thesis table thinned by
``Settings.stride``, one rig with the settings' capture noise and off-grid
amounts, a pool of identical rigs for the lockstep slots, and that pool in
this process, spread over worker processes or on a Ray cluster (as are the
renders of a campaign's database: :func:`renderer`).
"""

from __future__ import annotations

import functools

from .cases import off_grid
from .settings import Settings

__all__ = ["rig_table", "make_rig", "rig_pool", "capture_pool", "rig_tag", "renderer"]


def rig_table(settings: Settings):
    """The thesis table (:func:`~jaxrecog.hardware.geometry.positions.default_table`)
    with every ``settings.stride``-th position of each camera."""
    from ..hardware.geometry.positions import CameraTable, default_table

    table = default_table()
    if settings.stride == 1:
        return table
    return CameraTable(table.workspace, tuple(v[:: settings.stride] for v in table.views))


def make_rig(settings: Settings, cameras: tuple[int, ...] | None = None, *, seed: int = 0,
             clean_counts: dict | None = None):
    """The synthetic rig with the thesis table (every ``settings.stride``-th
    position; or a subset of its cameras).  ``clean_counts``: a dict shared
    by identical rigs (:class:`~jaxrecog.hardware.SyntheticRig`)."""
    from ..hardware import Noise, SyntheticRig
    from ..hardware.geometry.positions import CameraTable

    table = rig_table(settings)
    if cameras is not None:
        table = CameraTable(table.workspace, tuple(table.views[i] for i in cameras))
    b, p, s = settings.capture_noise
    return SyntheticRig(table, noise=Noise(brightness=b, pixel=p, max_shift=int(s)), seed=seed,
                        off_grid=off_grid(settings), clean_counts=clean_counts)


def rig_pool(settings: Settings, cameras: tuple[int, ...] | None = None, *, seed: int = 0) -> list:
    """``settings.batch`` identical synthetic rigs, one per lockstep slot of the
    trial driver, so each trial's scene (object, pose, boards) is set up once
    instead of at every step (a reset with boards costs ~5 ms; a rig ~50 ms
    to build).  Captures are reseeded per (trial, step), so the results do not
    depend on the pool.  The rigs share one cache of unoccluded pixel counts
    (the denominator of the occluded fraction: one render fewer per occluded
    capture of a scene and view any rig has seen)."""
    shared: dict = {}
    return [make_rig(settings, cameras, seed=seed, clean_counts=shared) for _ in range(max(1, settings.batch))]


def capture_pool(settings: Settings, cameras: tuple[int, ...] | None = None, *, seed: int = 0, memo=None):
    """:func:`rig_pool`'s rigs as a :class:`~jaxrecog.hardware.rigs.rig_pool.RigPool`
    for the trial driver: in this process (``settings.render_workers == 0``)
    or spread over that many worker processes, which render side by side
    (the results are the same), or in Ray actors (``settings.cluster``).
    ``memo``: a :class:`~jaxrecog.hardware.rigs.capture_memo.CaptureMemo` that
    keeps the captures, so that a later campaign of the same trials on alike
    rigs (another planner, another case of the same scenes) renders only what
    it has not seen (the same captures); not on a cluster, whose actors run
    whole trials beside their rigs (the captures never come here).  Close the
    pool when done (it is a context manager)."""
    from ..hardware.rigs.rig_pool import LocalRigs, ProcessRigs

    factory = functools.partial(make_rig, settings, cameras, seed=seed, clean_counts={})
    if settings.cluster:
        from ..ray_rigs import RayRigs

        pool = RayRigs(factory, max(1, settings.batch), settings.render_workers, cluster=settings.cluster)
    elif settings.render_workers:
        pool = ProcessRigs(factory, max(1, settings.batch), settings.render_workers)
    else:
        pool = LocalRigs(rig_pool(settings, cameras, seed=seed))
    if memo is None or settings.cluster:
        return pool
    from ..hardware.rigs.capture_memo import MemoRigs

    return MemoRigs(pool, memo, rig_tag(settings, cameras, seed))


def rig_tag(settings: Settings, cameras: tuple[int, ...] | None, seed: int) -> tuple:
    """What :func:`make_rig` builds its rig from: pools of equal tags render alike."""
    return (settings.stride, cameras, tuple(settings.capture_noise), off_grid(settings), seed)


def renderer(settings: Settings, local, name: str):
    """``local`` (a render function), or with ``settings.cluster`` its Ray
    form, :mod:`jaxrecog.ray_render`'s ``name``, on that cluster (the same files)."""
    if not settings.cluster:
        return local
    from .. import ray_render

    return functools.partial(getattr(ray_render, name), settings.cluster)
