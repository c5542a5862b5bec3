"""Rendering and training for the campaigns: the synthetic training database
and the DB1 / DB2 models of a :class:`~jaxrecog.campaigns.Settings`, each
cached in the work folder under the names of :mod:`.naming` and reused while
its training parameters and its database's manifest hash match.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Sequence

from ..database import load_database
from ..modelfile import ModelFileError, load_model_meta, save_model
from ..train import train_model
from .naming import database_dir, model_path, params_match, training_params
from .rigs import renderer, rig_table
from .settings import Settings

__all__ = ["Prepared", "prepare", "progress_bar", "cached_model_is_fresh", "train_for"]


@dataclasses.dataclass(frozen=True)
class Prepared:
    database: Path
    models: dict[str, Path]  # "DB1" / "DB2" -> model file


def progress_bar(total: int, desc: str, enabled: bool):
    """A ``tqdm`` bar of ``total`` items (images to render, positions to
    train, trials to run: the unit follows ``desc``), off unless ``enabled``."""
    from tqdm.auto import tqdm

    unit = "img" if desc.startswith("render") else "position" if desc.startswith("train") else "trial"
    return tqdm(total=total, desc=desc, unit=unit, disable=not enabled, dynamic_ncols=True)


def cached_model_is_fresh(path: Path, db, want: dict) -> bool:
    """``path`` exists, reads, was trained on ``db`` (``load_db()`` or the
    database itself; its manifest hash) and with the parameters ``want``
    (:func:`~.naming.params_match`): the cache check of :func:`prepare` and
    :func:`~jaxrecog.campaigns.prepare_turntable`."""
    if not path.exists():
        return False
    try:
        meta = load_model_meta(path)
    except ModelFileError:
        return False
    db = db() if callable(db) else db
    params = (meta.get("training") or {}).get("params") or {}
    return meta.get("manifest_sha256") == db.manifest_sha256 and params_match(params, want)


def train_for(settings: Settings, db, kind: str, progress: bool):
    """``train_model`` of ``db`` with the training fields of ``settings`` (K,
    samples, seed, likelihood and options, capture augmentation, view jitter),
    with a progress bar; returns ``(model, info)``."""
    with progress_bar(int(sum(db.positions)), f"train {kind}", progress) as bar:
        return train_model(db, kind=kind, n_components=settings.n_components,
                           samples_per_image=settings.samples_per_image, seed=settings.seed,
                           likelihood=settings.likelihood, likelihood_options=dict(settings.likelihood_options),
                           augment=settings.augment_params(), view_jitter=bool(settings.view_jitter),
                           interpolate=settings.interpolate, interpolation=settings.interpolation,
                           progress=lambda done, total: bar.update(done - bar.n), return_info=True)


def prepare(settings: Settings, *, progress: bool = False, databases: Sequence[str] = ("DB1", "DB2")) -> Prepared:
    """Render the training database (once) and train the requested models
    (cached by their training parameters and the manifest's hash).  Each
    ``settings.stride`` has its own database folder and model files, so a
    small run never reuses a full-size cache or the other way round."""
    from ..hardware import render_database

    jitter = settings.view_jitter
    db_dir = database_dir(settings)
    manifest = db_dir / "manifest.csv"
    if not manifest.exists():
        table = rig_table(settings)
        n_images = sum(table.positions) * 8 * 4 * (1 + jitter)
        with progress_bar(n_images, "render database", progress) as bar:
            render = renderer(settings, render_database, "render_database_on")
            render(db_dir, table, progress=bar.update, jitter_per_view=jitter, jitter_yaw_deg=settings.view_jitter_deg)
    loaded = []  # the database, read once and only when needed

    def db():
        if not loaded:
            loaded.append(load_database(db_dir))
        return loaded[0]

    models = {}
    for kind in databases:
        path = model_path(settings, kind)
        if not cached_model_is_fresh(path, db, training_params(settings, kind)):
            model, info = train_for(settings, db(), kind, progress)
            save_model(path, model, training=info.to_dict(), manifest_sha256=db().manifest_sha256)
        models[kind] = path
    return Prepared(db_dir, models)
