"""A turntable image database: many objects, a camera on a circle, test views off the grid.

The layout of a real turntable photo set (one camera, the object turned
every ``step`` degrees), rendered with the synthetic rig.  Turntable angle
``v`` of camera ``i`` is an eye on a circle about the object centre, at
azimuth ``step * v`` degrees and the camera's elevation (camera 0: 30°,
camera 1 of a two-camera set: 60°), ``distance`` m from the centre, looking
at it (the scene's zoom rule frames every object alike).  The light stays
fixed in the world.

Poses are resting orientations, not yaws (a yaw is another turntable angle):
pose ``p`` turns the object about the horizontal x axis by ``90° p``
(:data:`~.random_objects.RESTING_ROTATIONS`) and sets it down on the table,
so pose 2 is pose 0 upside down.

Splits (all labelled with grid indices ``position = v``):

``train``
    clean renders at azimuth ``step * v`` (the grid).
``test``
    ``test_per_view`` renders at ``step * v + test_offset`` (default
    ``+step / 2``: halfway to the next grid view -- both neighbours are
    equally near, and the label is always the lower one, ``v``), with the
    light and camera-offset perturbations and capture noise of
    :data:`TURNTABLE_PERTURB`; with ``occluders`` each test image has its own
    cardboard board in front of its view (10..40 % of the object hidden).
``calib``
    ``calib_per_view`` renders ``calib_offset`` (default ``step / 4``) off
    the grid, the sign alternating with ``v + j``, same perturbations, no
    occluders: held-out views for ``train --calibrate``.
``jitter``
    ``jitter_per_view`` clean renders around each grid view, labelled with
    that view: offsets ``±jitter_offset * k / ceil(N / 2)``, k = 1..ceil(N/2)
    (N = 2: ±5° for a 20° grid), extra training samples of the view for
    ``train --view-jitter``.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ...dbformat import write_manifest
from ..geometry.kinematics import Workspace
from .occluders import OCCLUDER_OFFSET, OCCLUDER_SIZE, random_occluders
from ..geometry.positions import CameraTable, View
from .random_objects import RESTING_ROTATIONS, rested
from .render_db import alternating_offsets, image_sink
from .scene import Intrinsics, ObjectSpec
from .synthetic import Noise, Perturb, SyntheticRig

__all__ = ["ELEVATIONS", "TURNTABLE_PERTURB", "turntable_table", "turntable_rig", "render_turntable",
           "turntable_angles"]

#: Elevation (degrees) of camera 0 and of the second camera of a two-camera set.
ELEVATIONS = (30.0, 60.0)
DISTANCE = 0.8

#: Test and calib perturbations: camera offset 2 % of the distance, light
#: direction and coefficients 10 %, capture noise as every synthetic test
#: capture (jaxrecog.scene.CAPTURE_NOISE); no random yaw (the azimuth offset is set).
TURNTABLE_PERTURB = Perturb(yaw_deg=0.0, eye_offset=0.02, light=0.1, noise=Noise(brightness=0.05, pixel=2.0, max_shift=2))



def _eye(centre: Sequence[float], azimuth_deg: float, elevation_deg: float, distance: float) -> tuple[float, float, float]:
    a, e = math.radians(azimuth_deg), math.radians(elevation_deg)
    c = np.asarray(centre, dtype=float)
    return tuple(float(x) for x in c + distance * np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)]))


def turntable_table(azimuths: Sequence[Sequence[float]], elevations: Sequence[float] = ELEVATIONS, *,
                    distance: float = DISTANCE, workspace: Workspace | None = None) -> CameraTable:
    """A table whose camera ``i`` has one position per azimuth of ``azimuths[i]``
    (degrees), at elevation ``elevations[i]``, ``distance`` m from the object centre."""
    ws = workspace or Workspace()
    if len(elevations) < len(azimuths):
        raise ValueError(f"{len(azimuths)} cameras need {len(azimuths)} elevations, got {tuple(elevations)}")
    views = tuple(
        tuple(View(math.radians(a), math.radians(el), _eye(ws.object_xyz, a, el, distance)) for a in az)
        for az, el in zip(azimuths, elevations)
    )
    return CameraTable(ws, views)


def turntable_angles(n_positions: int, step_deg: float, *, test_per_view: int = 0, calib_per_view: int = 0,
                     jitter_per_view: int = 0, test_offset: float | None = None, calib_offset: float | None = None,
                     jitter_offset: float | None = None) -> dict[str, Callable[[int, int], float]]:
    """The azimuth (degrees) of image ``j`` of grid view ``v``, per split: ``{split: f(v, j)}``."""
    step = float(step_deg)
    t_off = step / 2 if test_offset is None else float(test_offset)
    c_off = step / 4 if calib_offset is None else float(calib_offset)
    j_off = step / 4 if jitter_offset is None else float(jitter_offset)
    # test / calib offsets of 0 are allowed: on-grid held-out views, the thesis
    # protocol's control; jitter on the grid would repeat the training views.
    if math.isclose(math.remainder(j_off, step), 0.0, abs_tol=1e-9):
        raise ValueError(f"jitter offset {j_off:g}° lies on the {step:g}° grid; it must be off the grid")
    jitter = alternating_offsets(jitter_per_view, j_off)
    out: dict[str, Callable[[int, int], float]] = {"train": lambda v, j: step * v}
    if test_per_view:
        out["test"] = lambda v, j: step * v + t_off
    if calib_per_view:
        out["calib"] = lambda v, j: step * v + (c_off if (v + j) % 2 == 0 else -c_off)
    if jitter_per_view:
        out["jitter"] = lambda v, j: step * v + jitter[j]
    return out


def turntable_rig(objects: Sequence[ObjectSpec], azimuths: Sequence[Sequence[float]], *, poses: int = 4,
                  elevations: Sequence[float] = ELEVATIONS, distance: float = DISTANCE,
                  intrinsics: Intrinsics = Intrinsics(), seed: int = 0) -> SyntheticRig:
    """A synthetic rig whose scene object ``m * poses + p`` is object ``m`` in
    resting orientation ``p`` (one "pose" of the rig, pose 0), with one
    table position per azimuth."""
    if not 1 <= int(poses) <= len(RESTING_ROTATIONS):
        raise ValueError(f"turntable poses must lie in 1..{len(RESTING_ROTATIONS)}, got {poses}")
    variants = [rested(o, RESTING_ROTATIONS[p]) for o in objects for p in range(int(poses))]
    table = turntable_table(azimuths, elevations, distance=distance)
    return SyntheticRig(table, objects=variants, n_poses=1, intrinsics=intrinsics, seed=seed)


def render_turntable(
    out_dir: str | os.PathLike,
    objects: Sequence[ObjectSpec],
    *,
    cameras: int = 1,
    step_deg: float = 20.0,
    poses: int = 4,
    test_per_view: int = 2,
    calib_per_view: int = 1,
    jitter_per_view: int = 0,
    test_offset: float | None = None,
    calib_offset: float | None = None,
    jitter_offset: float | None = None,
    occluders: bool = False,
    perturb: Perturb = TURNTABLE_PERTURB,
    elevations: Sequence[float] = ELEVATIONS,
    distance: float = DISTANCE,
    intrinsics: Intrinsics = Intrinsics(),
    seed: int = 0,
    progress: Callable[[int], object] | None = None,
    blocks=None,
) -> Path | None:
    """Render the turntable database (module doc) into ``out_dir`` and return
    the path of its ``manifest.csv``.  Positions per camera:
    ``round(360 / step_deg)`` (``step_deg`` must divide 360).  ``blocks``:
    only some (object, pose) blocks, written nowhere, as
    :func:`~.render_db.render_database`'s (a Ray task's share)."""
    n_pos = round(360.0 / float(step_deg))
    if n_pos < 1 or not math.isclose(n_pos * float(step_deg), 360.0):
        raise ValueError(f"step_deg must divide 360, got {step_deg}")
    if not 1 <= int(cameras) <= len(elevations):
        raise ValueError(f"cameras must lie in 1..{len(elevations)}, got {cameras}")
    for name, n in (("test_per_view", test_per_view), ("calib_per_view", calib_per_view),
                    ("jitter_per_view", jitter_per_view)):
        if int(n) < 0:
            raise ValueError(f"{name} must be >= 0, got {n}")
    counts = {"train": 1, "test": test_per_view, "calib": calib_per_view, "jitter": jitter_per_view}
    angles = turntable_angles(n_pos, step_deg, test_per_view=test_per_view, calib_per_view=calib_per_view,
                              jitter_per_view=jitter_per_view, test_offset=test_offset, calib_offset=calib_offset,
                              jitter_offset=jitter_offset)
    # one table position per distinct azimuth any split needs (rounded to 1e-6 degrees)
    need = sorted({round(f(v, j) % 360.0, 6) for s, f in angles.items() for v in range(n_pos) for j in range(counts[s])})
    index = {a: k for k, a in enumerate(need)}
    at = {s: (lambda v, j, f=f: index[round(f(v, j) % 360.0, 6)]) for s, f in angles.items()}
    n_cam = int(cameras)
    rig = turntable_rig(objects, [need] * n_cam, poses=poses, elevations=elevations, distance=distance,
                        intrinsics=intrinsics, seed=seed)
    out = Path(out_dir)
    rows: list[tuple] = []
    test_rng = np.random.default_rng([seed, 0x7E57])
    calib_rng = np.random.default_rng([seed, 0xCA1])
    emit = image_sink(out, rows, blocks)

    try:
        for s in angles if blocks is None else ():
            for i in range(n_cam):
                for v in range(n_pos):
                    (out / s / f"c{i}" / f"v{v:02d}").mkdir(parents=True, exist_ok=True)
        for m in range(len(objects)):
            for p in range(int(poses)):
                if blocks is not None and not blocks.start(m, p, rig, (test_rng, calib_rng, rig._rng)):
                    continue
                scene_obj = m * int(poses) + p
                rig.reset(scene_obj, 0)
                for i in range(n_cam):
                    for v in range(n_pos):
                        img, _ = rig.render_clean(i, at["train"](v, 0))
                        emit(f"train/c{i}/v{v:02d}/m{m}_p{p}.png", img, i, v, m, p, "train")
                        for j in range(jitter_per_view):
                            img, _ = rig.render_clean(i, at["jitter"](v, j))
                            emit(f"jitter/c{i}/v{v:02d}/m{m}_p{p}_{j}.png", img, i, v, m, p, "jitter")
                        if progress is not None:
                            progress(1 + jitter_per_view)
                for i in range(n_cam):
                    for v in range(n_pos):
                        for j in range(test_per_view):
                            if occluders:
                                k = at["test"](v, j)
                                one = CameraTable(rig.table.workspace, ((rig.table.views[i][k],),))
                                rig.reset(scene_obj, 0, random_occluders(test_rng, one, radius=rig.radius,
                                                                          size=OCCLUDER_SIZE, offset=OCCLUDER_OFFSET))
                            img, _ = rig.render_perturbed(i, at["test"](v, j), perturb, test_rng)
                            emit(f"test/c{i}/v{v:02d}/m{m}_p{p}_{j}.png", img, i, v, m, p, "test")
                        if occluders and test_per_view:
                            rig.reset(scene_obj, 0)
                        for j in range(calib_per_view):
                            img, _ = rig.render_perturbed(i, at["calib"](v, j), perturb, calib_rng)
                            emit(f"calib/c{i}/v{v:02d}/m{m}_p{p}_{j}.png", img, i, v, m, p, "calib")
                        if progress is not None:
                            progress(test_per_view + calib_per_view)
    finally:
        rig.close()
    return None if blocks is not None else write_manifest(out, rows)
