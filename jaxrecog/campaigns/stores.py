"""A campaign's trial stores, keyed by the content their trials depend on.

A store (``workdir/trials/NAME.jsonl``, :class:`~jaxrecog.results.TrialStore`)
opens with a header (:func:`~jaxrecog.trial_checks.store_header`) that
records the run's settings (all but where files go and how the work is
spread, :data:`~jaxrecog.campaigns.naming.RUN_ID_IGNORED`), the planner, the
digest of the model's arrays (:func:`model_sha256`) and, for a campaign on an
image database, the digest of its manifest and pixels
(:func:`database_sha256`), and the limits every record must keep.  A store
whose header is not the run's is refused with one line (another run's trials
under this run's name); so is a record outside the limits.  The file names
are digests too (:func:`~jaxrecog.campaigns.naming.run_id`; a database
campaign's name ends with its data digest), so a changed model or a database
re-rendered in place starts a store of its own.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import Mapping

import jax
import numpy as np

from ..results import TrialStore
from ..trial_checks import store_header
from .naming import RUN_ID_IGNORED
from .settings import Settings

__all__ = ["file_sha256", "database_sha256", "model_sha256", "campaign_store"]

_CHUNK = 1 << 20


def file_sha256(path: str | os.PathLike) -> str:
    """The sha256 of a file's bytes, read in 1 MiB pieces."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(_CHUNK):
            h.update(chunk)
    return h.hexdigest()


def database_sha256(db) -> str:
    """The digest of what a campaign on ``db`` replays: its manifest (every
    row's file, camera, position, object, pose and split) and its decoded
    pixels, all rows (:class:`~jaxrecog.database.ImageDatabase`), hashed
    from memory row by row.  A database re-rendered in place (the same
    manifest text, new images) gets another digest; the same pixels in
    another image format, the same one."""
    h = hashlib.sha256(f"{db.manifest_sha256}|{db.images.shape}|{db.images.dtype}".encode())
    images = np.ascontiguousarray(db.images)
    for row in images.reshape(len(images), -1):
        h.update(row)
    return h.hexdigest()


def model_sha256(model) -> str:
    """The digest of a sensor model's content: every array (dtype, shape,
    bytes) and its sizes, levels and stability — what its trials depend on,
    whether it came from a file or was calibrated in memory."""
    h = hashlib.sha256(repr((model.n_objects, model.n_poses, tuple(model.levels), tuple(model.image_shape),
                             model.stability, model.likelihood_kinds, model.positions)).encode())
    for leaf in jax.tree.leaves(model):
        if hasattr(leaf, "dtype") and hasattr(leaf, "shape"):
            x = np.ascontiguousarray(np.asarray(leaf))
            h.update(f"{x.dtype}{x.shape}".encode())
            h.update(x.reshape(-1).view(np.uint8))
    return h.hexdigest()


def campaign_store(settings: Settings, name: str, planner: str, model, content: Mapping[str, str] | None = None
                   ) -> TrialStore:
    """The store ``workdir/trials/<name>.jsonl`` of ``planner``'s trials of a
    campaign with ``settings`` and ``model`` (``content``: digests of further
    data the trials depend on, e.g. ``{"database_sha256": ...}``; a
    ``model_sha256`` there saves hashing the model again), with the header it
    must have."""
    fields = {k: v for k, v in settings.flat().items() if k not in RUN_ID_IGNORED}
    content = dict(content or {})
    run = {"planner": planner, "settings": fields,
           "model_sha256": content.pop("model_sha256", None) or model_sha256(model), **content}
    limits = {"max_steps": settings.max_steps, "p_threshold": settings.p_threshold,
              "min_views": settings.min_views, "n_objects": model.n_objects, "n_poses": model.n_poses,
              "positions": [int(v) for v in model.positions], "trials_per_object": settings.trials_per_object}
    return TrialStore(Path(settings.workdir) / "trials" / f"{name}.jsonl", header=store_header(run, limits))
