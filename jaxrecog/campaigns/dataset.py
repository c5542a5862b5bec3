"""A campaign on a stored image database with a trained model file: the
thesis cases' protocol (every object, random pose and start per trial, each
planner on the same trials) on any database in the folder + ``manifest.csv``
format, whose ``test`` split a :class:`~jaxrecog.hardware.DatasetRig`
replays, with as many cameras and positions as the model has.
"""

from __future__ import annotations

import functools
from typing import Callable, Sequence

import numpy as np

from ..campaign import plan_trials
from ..counts import check_counts
from ..database import load_database
from ..modelfile import load_model, load_model_meta
from ..planners import DEFAULT_PLANNER
from ..problems import problem_message
from ..recipes import recipe_from_meta
from ..results import TrialResult
from .cases import Case
from .naming import run_id
from .reports import CaseReport
from .run import compare_planners
from .settings import Settings
from .stores import database_sha256

__all__ = ["DATASET_PLANNERS", "dataset_planners", "run_dataset"]

#: Planners of :func:`run_dataset` when none are given: the model's recipe's
#: planner (:data:`~jaxrecog.planners.DEFAULT_PLANNER` for a thesis-recipe or
#: older model file) against the random baseline.
DATASET_PLANNERS = (DEFAULT_PLANNER, "random")


def dataset_planners(model_path) -> tuple[str, ...]:
    """``(the model's recipe's planner, "random")``: what :func:`run_dataset` compares by default."""
    return tuple(dict.fromkeys((recipe_from_meta(load_model_meta(model_path)).planner, "random")))


def _check_database_fits(db, model, folder, model_path) -> None:
    """One clear error before any trial when the database's test split cannot
    serve every (camera, position, object, pose) the model's campaign visits."""
    check_counts(model, db, model_name=str(model_path), other_name=f"database {folder}")
    positions = tuple(int(p) for p in model.positions)
    test = np.asarray(db.split) == "test"
    have = set(zip(*(np.asarray(getattr(db, f))[test].tolist() for f in ("camera", "position", "object", "pose"))))
    need = [(c, v, m, p) for c, n in enumerate(positions) for v in range(n)
            for m in range(model.n_objects) for p in range(model.n_poses)]
    missing = [k for k in need if k not in have]
    if missing:
        raise ValueError(problem_message(
            f"database {folder}: {len(missing)} of {len(need)} views have no 'test' image to replay",
            [f"camera {c}, position {v}, object {m}, pose {p}" for c, v, m, p in missing], counted=True))


def run_dataset(
    folder,
    model_path,
    settings: Settings,
    planners: Sequence[str] | None = None,
    *,
    progress: bool = False,
    on_result: Callable[[str, TrialResult], None] | None = None,
    live=None,
) -> CaseReport:
    """A campaign on a stored image database with a trained model file.

    A :class:`~jaxrecog.hardware.DatasetRig` replays the database's ``test``
    split; for every object of the model, ``settings.trials_per_object``
    trials with a random pose and a random initial configuration
    (:func:`~jaxrecog.campaign.plan_trials`), each planner on the same trials
    (default :func:`dataset_planners`: the model's recipe's and random).
    The model file fixes the cameras and positions (any number of each);
    the database must have a test image of every view.  Finished trials are
    kept in ``workdir/trials`` (named by the settings, the model's and the
    database's digests: its manifest and pixels,
    :func:`~jaxrecog.campaigns.stores.database_sha256`), so an interrupted
    campaign resumes and a database re-rendered in place starts afresh.  ``stride``,
    ``capture_noise`` and the training settings do not apply (stored images,
    a given model); ``stride`` must stay 1.  ``live``: the live view's
    observer factory (:func:`~jaxrecog.campaigns.run.compare_planners`).
    """
    from ..hardware import DatasetRig

    if settings.stride != 1:
        raise ValueError("stride selects positions of the synthetic rig; a database campaign uses the "
                         "database's own positions (leave stride at 1)")
    model = load_model(model_path)
    db = load_database(folder)
    _check_database_fits(db, model, folder, model_path)
    rig = DatasetRig(db, seed=settings.seed)
    pool = rig
    if settings.cluster:
        from ..ray_rigs import RayRigs

        pool = RayRigs(functools.partial(DatasetRig, db, seed=settings.seed), max(1, settings.batch),
                       settings.render_workers, cluster=settings.cluster)
    default = dataset_planners(model_path)   # reads the recipe: one newer than this code is refused here
    planners = tuple(planners or default)
    case = Case("dataset", f"Image database {folder} ({model.n_objects} objects x {model.n_poses} poses, "
                           f"positions {tuple(int(p) for p in model.positions)}), model {model_path}",
                str(folder), False, None, planners)
    specs = plan_trials(model.n_objects, model.n_poses, rig.positions, settings.trials_per_object, seed=settings.seed)
    rid = run_id(settings, model_path)
    data = database_sha256(db)   # the pixels, not only the manifest: a database re-rendered in place is another
    try:
        return compare_planners(case, model, pool, specs, settings, planners,
                                lambda planner: f"dataset-{planner}-{rid}-{data[:10]}", progress=progress,
                                on_result=on_result, probe=rig, live=live, content={"database_sha256": data})
    finally:
        if pool is not rig:
            pool.close()
