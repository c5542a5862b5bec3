"""Cache naming: the names of a campaign's database folders, model files,
trial stores and result folders, and the training parameters a cached model
must match.

Every name here is part of the work folders on disk: a changed name orphans
existing caches and trial stores (tests/test_campaign_naming.py pins them).
Fields added to :class:`~jaxrecog.campaigns.Settings` after a name existed
count only when set, so the names of earlier runs stay what they were.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

from ..kernels import likelihood_class
from .settings import Settings

__all__ = ["AUGMENT_FIELDS", "TRAINING_FIELDS", "training_defaults", "training_extra", "training_params",
           "params_match", "model_tag", "stride_tag", "model_path", "database_dir", "run_id", "results_dir",
           "turntable_name", "turntable_dir", "turntable_model_path", "RUN_ID_IGNORED"]

#: Settings fields of the likelihood and the capture augmentation, and their
#: defaults: models trained with these keep the file names and cache keys
#: they had before the fields existed.
AUGMENT_FIELDS = ("max_rotation", "max_scale", "blur_sigma", "gain_amplitude", "gain_cells", "occluder_gray",
                  "max_shift")
#: augmentation fields added later: they enter a model's cache key only when set
_LATER_AUGMENT_FIELDS = ("occluder_gray", "max_shift")
TRAINING_FIELDS = ("likelihood", "likelihood_options", *AUGMENT_FIELDS, "view_jitter", "view_jitter_deg",
                   "interpolate", "interpolation")
#: Settings fields that never change a campaign's results (where files go, how
#: the work is spread): not in the run id
RUN_ID_IGNORED = ("workdir", "batch", "devices", "render_workers", "cluster")
#: fields added after the run id existed: left out while off (falsy), so the
#: digests of earlier runs stay valid
_LATER_RUN_FIELDS = ("exclude_visited_positions", "shared_view", "motion_cost", "off_grid_deg", "off_grid_eye",
                     "off_grid_light")
#: fields added later whose "off" value is not falsy: left out at that value
_LATER_RUN_DEFAULTS = {"adaptive_scale": 1.0, "min_views": 1}


def training_defaults() -> dict:
    """The default of every training field (:data:`TRAINING_FIELDS`)."""
    defaults = Settings.defaults()
    return {k: defaults[k] for k in TRAINING_FIELDS}


def training_extra(settings: Settings) -> dict:
    """The likelihood / augmentation fields of ``settings`` that differ from
    the defaults (``{}`` for the thesis's training)."""
    defaults = training_defaults()
    return {k: getattr(settings, k) for k in TRAINING_FIELDS if getattr(settings, k) != defaults[k]}


def training_params(settings: Settings, kind: str) -> dict:
    """The training parameters a cached model file must match to be reused
    (compared with the file's ``training.params``; a dict value is compared
    key by key, lists for tuples).  The default likelihood and augmentation
    add nothing, so the key of a default model is what it always was."""
    params = {"kind": kind, "K": settings.n_components, "samples_per_image": settings.samples_per_image,
              "seed": settings.seed}
    extra = training_extra(settings)
    if extra:
        params["likelihood"] = likelihood_class(settings.likelihood).kind
        params["likelihood_options"] = {k: v for k, v in settings.likelihood_options}
        aug = dataclasses.asdict(settings.augment_params())
        # a field added later counts only when set: model files from before it stay valid
        params["augment"] = {k: (list(aug[k]) if isinstance(aug[k], tuple) else aug[k])
                             for k in AUGMENT_FIELDS if k in extra or k not in _LATER_AUGMENT_FIELDS}
        if settings.interpolate:   # a linear model's key is what it was before 'interpolation' existed
            params["interpolate"] = {"points_per_side": settings.interpolate,
                                     **({} if settings.interpolation == "linear" else
                                        {"interpolation": settings.interpolation})}
    return params


def params_match(have, want) -> bool:
    """``have`` (a model file's training params) agrees with ``want``: dicts
    key by key (keys of ``want`` only), tuples as lists."""
    if isinstance(want, dict):
        return isinstance(have, dict) and all(params_match(have.get(k), v) for k, v in want.items())
    if isinstance(want, tuple):
        want = list(want)
    return have == want


def model_tag(settings: Settings) -> str:
    """File-name suffix of a model trained with a non-default likelihood or
    augmentation: ``-<likelihood>-<digest of the fields>`` ("" for the
    defaults, so existing model files stay valid)."""
    extra = training_extra(settings)
    if not extra:
        return ""
    digest = hashlib.sha256(json.dumps(extra, sort_keys=True, default=str).encode()).hexdigest()[:8]
    return f"-{settings.likelihood}-{digest}"


def stride_tag(settings: Settings) -> str:
    """File-name suffix of a strided table's cache ("" for the full table,
    so existing full-size work folders stay valid)."""
    return "" if settings.stride == 1 else f"-stride{settings.stride}"


def _jitter_tag(settings: Settings) -> str:
    """Folder suffix of a database with view-jitter rows ("" without)."""
    return f"-vj{settings.view_jitter}x{settings.view_jitter_deg:g}" if settings.view_jitter else ""


def database_dir(settings: Settings) -> Path:
    """The rendered training database of ``settings``'s table and view jitter."""
    return settings.workdir / f"database{stride_tag(settings)}{_jitter_tag(settings)}"


def model_path(settings: Settings, kind: str) -> Path:
    """The cached model file of ``kind`` ("DB1" / "DB2") under ``settings``."""
    return settings.workdir / (f"model-{kind.lower()}{stride_tag(settings)}-K{settings.n_components}"
                               f"-S{settings.samples_per_image}-seed{settings.seed}{model_tag(settings)}.npz")


def run_id(settings: Settings, model_path: Path | str) -> str:
    """A short digest of everything that changes a campaign's results besides
    the planner: the settings (but :data:`RUN_ID_IGNORED`) and the model
    file's bytes.  Trial stores are named by it, so a resumed campaign never
    mixes trials run under other settings or another model."""
    fields = {k: v for k, v in settings.flat().items() if k not in RUN_ID_IGNORED}
    for k in _LATER_RUN_FIELDS:
        if not fields[k]:
            del fields[k]
    for k, off in _LATER_RUN_DEFAULTS.items():
        if fields[k] == off:
            del fields[k]
    defaults = training_defaults()
    for k in TRAINING_FIELDS:
        if getattr(settings, k) == defaults[k]:
            del fields[k]
    h = hashlib.sha256(json.dumps(fields, sort_keys=True, default=str).encode())
    h.update(hashlib.sha256(Path(model_path).read_bytes()).digest())
    return h.hexdigest()[:10]


def results_dir(settings: Settings) -> Path:
    """Where :meth:`~jaxrecog.campaigns.CaseReport.write` puts tables by
    default: ``workdir/results`` (``workdir/results-strideN`` for a strided table)."""
    return settings.workdir / f"results{stride_tag(settings)}"


def turntable_name(n_objects: int, cameras: int, occluded: bool, poses: int, step_deg: int, object_seed: int) -> str:
    """The folder name of a rendered turntable set (without view jitter)."""
    return (f"turntable-n{n_objects}-c{cameras}-p{poses}-s{step_deg}{'-occ' if occluded else ''}"
            f"{f'-o{object_seed}' if object_seed else ''}")


def turntable_dir(settings: Settings, n_objects: int, cameras: int, occluded: bool, poses: int, step_deg: int,
                  object_seed: int) -> Path:
    """The turntable set's folder under ``settings.workdir`` (its view jitter's own)."""
    return settings.workdir / (turntable_name(n_objects, cameras, occluded, poses, step_deg, object_seed)
                               + _jitter_tag(settings))


def turntable_model_path(settings: Settings, db_dir: Path, kind: str) -> Path:
    """The calibrated model file of a turntable set in ``db_dir``."""
    return db_dir / (f"model-{kind.lower()}-K{settings.n_components}-S{settings.samples_per_image}"
                     f"-seed{settings.seed}{model_tag(settings)}-cal.npz")
