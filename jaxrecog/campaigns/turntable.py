"""The turntable campaign (not in the thesis): a rendered set of many random
objects whose test views lie halfway between the training views, its model
trained and calibrated, then the database campaign on its test split."""

from __future__ import annotations

import json
import time
from typing import Sequence

from ..database import load_database
from ..modelfile import save_model
from ..recipes import AUTO
from .dataset import run_dataset
from .naming import training_params, turntable_dir, turntable_model_path
from .preparation import Prepared, cached_model_is_fresh, progress_bar, train_for
from .rigs import renderer
from .reports import CaseReport
from .settings import Settings

__all__ = ["TURNTABLE_PLANNERS", "prepare_turntable", "run_turntable"]

#: Planners of :func:`run_turntable` when none are given.
TURNTABLE_PLANNERS = ("mi-class-pairwise", "random")


def prepare_turntable(settings: Settings, n_objects: int = 50, cameras: int = 1, occluded: bool = False, *,
                      poses: int = 4, step_deg: int = 20, test_per_view: int = 2, calib_per_view: int = 1,
                      object_seed: int = 0, kind: str | None = None, progress: bool = False) -> Prepared:
    """Render a turntable set (:func:`jaxrecog.hardware.render.turntable.render_turntable`:
    ``n_objects`` random_urdfs meshes, ``360 / step_deg`` positions per camera,
    test views halfway between training views, with a board in front of every
    test view when ``occluded``) into ``workdir/turntable-...`` and train its
    model (``kind``: DB1 for a clean set, DB2 for an occluded one; K, samples
    and seed from ``settings``), calibrated on the set's ``calib`` split, as
    ``jaxrecog train --calibrate`` does, and with the recipe's ``stability =
    auto`` (robust) the planner's stability weight fitted on the same split
    (:func:`jaxrecog.stability_fit.fit_stability`).  Both are cached (the model by its
    training parameters and the manifest's hash).  ``Prepared.models`` has
    one entry, ``"turntable"``."""
    from ..calibration import calibrate_model
    from ..calibration_data import features_from_database
    from ..hardware.render.random_objects import random_objects
    from ..hardware.render.turntable import render_turntable
    from ..stability_fit import with_stability

    kind = kind or ("DB2" if occluded else "DB1")
    jitter = settings.view_jitter
    if jitter and not settings.view_jitter_deg < step_deg / 2:
        raise ValueError(f"view_jitter_deg = {settings.view_jitter_deg:g}: the turntable's jitter views must lie "
                         f"closer to their training view than the test views ({step_deg / 2:g} degrees off)")
    db_dir = turntable_dir(settings, n_objects, cameras, occluded, poses, step_deg, object_seed)
    manifest = db_dir / "manifest.csv"
    if not manifest.exists():
        objects = random_objects(n_objects, seed=object_seed)
        total = cameras * (360 // step_deg) * n_objects * poses * (1 + test_per_view + calib_per_view)
        t0 = time.perf_counter()
        with progress_bar(total, f"render {db_dir.name}", progress) as bar:
            render = renderer(settings, render_turntable, "render_turntable_on")
            render(db_dir, objects, cameras=cameras, step_deg=step_deg, poses=poses,
                   test_per_view=test_per_view, calib_per_view=calib_per_view, occluders=occluded,
                   jitter_per_view=jitter, jitter_offset=settings.view_jitter_deg if jitter else None,
                   seed=settings.seed, progress=bar.update)
        (db_dir / "rig.json").write_text(json.dumps(
            {"turntable": True, "objects": f"random:{n_objects}", "object_seed": object_seed, "cameras": cameras,
             "poses": poses, "step_deg": step_deg, "positions": [360 // step_deg] * cameras,
             "per_view": {"test": test_per_view, "calib": calib_per_view}, "test_occluders": occluded,
             "names": [o.name for o in objects], "seed": settings.seed,
             "seconds": round(time.perf_counter() - t0, 1), "images": total}, indent=2) + "\n")
    db = load_database(db_dir)
    recipe = settings.recipe
    path = turntable_model_path(settings, db_dir, kind)
    if recipe.calib_pool:   # its own file: a cache key with fewer keys must not match it
        path = path.with_name(path.stem + "-pool" + path.suffix)
    # the planner's weight: the recipe's number, or (robust: auto) fitted on the calib split with the
    # recipe's adaptive scale; both in the cache key, so a cached model never lends its weight to another
    weight_key = {"stability": recipe.stability,
                  **({"stability_max_scale": recipe.adaptive_scale} if recipe.stability == AUTO else {}),
                  **({"calib_pool": True} if recipe.calib_pool else {})}   # pooled factors: another model
    params = dict(training_params(settings, kind), calibrated=True, **weight_key)
    if not cached_model_is_fresh(path, db, params):
        model, info = train_for(settings, db, kind, progress)
        t0 = time.perf_counter()
        model, cal = calibrate_model(model, db, pool=recipe.calib_pool)
        training = info.to_dict()
        training["params"] = dict(training["params"], calibrated=True, **weight_key)
        training["calibration_seconds"] = time.perf_counter() - t0
        model, fit = with_stability(model, recipe,
                                    features_from_database(model, db, "calib") if recipe.stability == AUTO else None)
        if fit is not None:
            training["stability_fit"] = fit.to_dict()
        save_model(path, model, training=training, manifest_sha256=db.manifest_sha256, calibration=cal.to_dict(),
                   recipe=recipe.replace(stability=model.stability, calibrate=True).to_dict())
    return Prepared(db_dir, {"turntable": path})


def run_turntable(settings: Settings, n_objects: int = 50, cameras: int = 1, occluded: bool = False,
                  planners: Sequence[str] | None = None, *, progress: bool = False,
                  prepared: Prepared | None = None, **turntable) -> CaseReport:
    """The turntable campaign: :func:`prepare_turntable` (cached), then
    :func:`~jaxrecog.campaigns.run_dataset` on its test split with the
    calibrated model (each planner on the same trials; resumable).
    ``turntable``: more :func:`prepare_turntable` options (poses, step_deg, ...)."""
    prepared = prepared or prepare_turntable(settings, n_objects, cameras, occluded, progress=progress, **turntable)
    return run_dataset(prepared.database, prepared.models["turntable"], settings,
                       planners=tuple(planners or TURNTABLE_PLANNERS), progress=progress)
