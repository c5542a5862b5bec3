"""The thesis's experiments (chapter 7) on the synthetic rig, and campaigns
on a stored image database.

``prepare`` renders the training database and trains the DB1 and DB2 sensor
models (cached in the work folder); ``run_case`` runs one case with several
planners on the *same* trials (same poses, initial configurations and
occluder layouts per trial) and returns the thesis-shaped tables.
Observations are rendered images with capture noise — never samples of the
Gaussian model under test.  ``Settings.stride`` thins the thesis's 32 x 7
table (every ``stride``-th position per camera) for quick runs; each stride
has its own cached database and models.

``run_dataset`` runs the same protocol (every object, random pose and start
per trial, planners on the same trials) on any image database in the folder
+ ``manifest.csv`` format with a trained model file: a
:class:`~jaxrecog.hardware.DatasetRig` replays its ``test`` split, with as
many cameras and positions as the model has.

Cases (DESIGN.md §4):

============== ======== =========== ======= ======================
name           database scene       cameras planners (default)
============== ======== =========== ======= ======================
i              DB1      clean       both    mi, mi-class, crlb, random
ii             DB1      occluders   both    mi, mi-class, crlb
iii            DB2      occluders   both    mi, mi-class, crlb
single-clean   DB1      clean       cam 0   mi, mi-class
single-occluded DB2     occluders   cam 0   mi, mi-class
jitter         DB1      clean,      both    mi-class, mi-class-pairwise, random
                        off-grid
jitter-occluded DB2     occluders,  both    mi-class, mi-class-pairwise, random
                        off-grid
============== ======== =========== ======= ======================

Off-grid cases (issue 18, item 4; not in the thesis): every trial's object
sits turned ``U(-20°, 20°)`` off its training pose (drawn per trial, the same
for every planner), and every capture moves each camera's eye and jitters the
light (:class:`~jaxrecog.hardware.render.synthetic.OffGrid`, :data:`JITTER`), so no
test image is a training view.  ``Settings.off_grid_deg`` /
``off_grid_eye`` / ``off_grid_light`` override a case's amounts (``None``:
the case's; 0 for the thesis cases).

``mi`` is the thesis's target I(s; g) over the full state (object, pose and
both occlusion levels); ``mi-class`` is I(c; g) with the levels marginalised
(DESIGN.md §3): with six levels per camera the state target is dominated by
the occlusion levels and can prefer views that reveal occlusion over views
that reveal identity.

Occluders: one cardboard board in front of every camera's *initial* view, so
that the first images of both cameras are occluded (thesis §7.2); the
recognizer has to move to see past them.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from pathlib import Path
from typing import Callable, Sequence

import jax.random as jr

from .campaign import TrialSpec, plan_trials, run_campaign
from .kernels import DEFAULT_LIKELIHOOD
from .problems import problem_message
from .planners import DEFAULT_MIN_PER_STRATUM, DEFAULT_PLANNER, make_planner, planner_spec
from .results import ObjectRow, TrialResult, TrialStore, summarize, table_json, table_markdown
from .thesis import ThesisTable, published

__all__ = [
    "CAPTURE_NOISE", "Case", "CASES", "JITTER", "case_settings", "off_grid", "DATASET_PLANNERS", "Settings", "Prepared", "CaseReport", "prepare", "make_rig",
    "model_path",
    "capture_pool", "rig_pool", "rig_table",
    "results_dir", "run_case", "run_dataset", "run_trace",
]


@dataclasses.dataclass(frozen=True)
class Case:
    name: str
    title: str
    database: str  # "DB1" | "DB2"; for run_dataset: the database folder
    occluded: bool
    cameras: tuple[int, ...] | None  # None = all cameras
    planners: tuple[str, ...]
    #: (yaw bound in degrees, eye offset, light jitter) of the captures
    #: (:class:`~jaxrecog.hardware.render.synthetic.OffGrid`); zeros = on the grid
    off_grid: tuple[float, float, float] = (0.0, 0.0, 0.0)


#: The off-grid amounts of the ``jitter`` cases: object yaw within ±20° of the
#: training pose (per trial; the table's poses are 90° apart and camera 1's
#: positions ~11° apart in azimuth), eye offset 0.04 (rms 4 % of the eye-object
#: distance, ~2.3° of viewing direction) and light jitter 0.2 per capture: twice
#: :class:`~jaxrecog.hardware.render.synthetic.Perturb`'s defaults (0.02, 0.1) for eye
#: and light, as the yaw is ~7x its 3°.  ``scripts/difficulty_sweep.py`` scales
#: all three with the angle A: (A, 0.002 A, 0.01 A).
JITTER: tuple[float, float, float] = (20.0, 0.04, 0.2)

CASES: dict[str, Case] = {
    c.name: c
    for c in (
        Case("i", "Case (i): non-occluded objects, DB1 model", "DB1", False, None, ("mi", "mi-class", "crlb", "random")),
        Case("ii", "Case (ii): occluded objects, no occlusion model (DB1)", "DB1", True, None, ("mi", "mi-class", "crlb")),
        Case("iii", "Case (iii): occluded objects, occlusion model (DB2)", "DB2", True, None, ("mi", "mi-class", "crlb")),
        Case("single-clean", "Single camera (camera 0), non-occluded, DB1", "DB1", False, (0,), ("mi", "mi-class")),
        Case("single-occluded", "Single camera (camera 0), occluded, DB2", "DB2", True, (0,), ("mi", "mi-class")),
        Case("jitter", "Off-grid captures (yaw ±20°, eye and light jitter), non-occluded objects, DB1", "DB1", False,
             None, ("mi-class", "mi-class-pairwise", "random"), JITTER),
        Case("jitter-occluded", "Off-grid captures (yaw ±20°, eye and light jitter), occluded objects, DB2", "DB2",
             True, None, ("mi-class", "mi-class-pairwise", "random"), JITTER),
    )
}


#: (brightness sd, pixel sd, max shift px) of every synthetic capture the
#: recognizer is tested on: campaign captures (``Settings.capture_noise``),
#: ``jaxrecog recognize --rig synthetic`` and the test split of ``jaxrecog render``.
CAPTURE_NOISE: tuple[float, float, int] = (0.05, 2.0, 2)


@dataclasses.dataclass(frozen=True)
class Settings:
    """Everything that defines a run (defaults: the thesis protocol).

    Attributes:
        workdir: where the database, models, trials and tables go.
        trials_per_object: thesis: ~100.
        seed: seeds trials, occluders, training and the planners' tables.
        samples: Monte Carlo samples per configuration for MI / CRLB.
        min_per_stratum: at least this many samples per state stratum
            (c, k_1, k_2): with DB2's 1152 strata, 1024 samples alone would
            give one draw per stratum, too few for the planner to see a
            sticker view (:func:`jaxrecog.planners.samples_per_stratum`).
        batch: trials run in lockstep: each step of a batch is one jitted call
            (a ``lax.map`` over the trials, :func:`~jaxrecog.campaign.batched_step`).
        n_components: eigenspace dimension K.
        samples_per_image: augmented samples per training image.
        p_threshold, max_steps: stop rule (thesis: 0.95, 7).
        capture_noise: (brightness sd, pixel sd, max shift px) of every capture.
        transition: "uniform" (thesis) or "sticky".
        stride: keep every ``stride``-th position of each camera of the thesis
            table (``views[::stride]``, as ``jaxrecog render --stride``): 1 =
            the full 32 x 7 table; 8 = (4, 1) positions, a database of 160
            images that renders and trains in seconds (tests, smoke runs).
            The database and model files of each stride are cached apart.
        min_views: never stop on P_th before this many image sets
            (:class:`~jaxrecog.recognizer.Recognizer`; a departure from the
            thesis, which stops at the first step that reaches P_th; default 1).
        exclude_visited_positions: never send a camera back to a position it
            already used (:class:`~jaxrecog.recognizer.Recognizer`; a departure
            from the thesis, off by default).
        shared_view: keep a view mixture's component (the object's turn) in
            the belief, one per trial for every camera and step
            (:class:`~jaxrecog.recognizer.Recognizer`,
            :mod:`jaxrecog.kernels.shared_latent`; not in the thesis, off by
            default; needs a view-mixture likelihood).
        motion_cost: λ >= 0 of motion-cost-aware planning, score units per
            second (nats/s for MI): each configuration's score is lowered by
            λ times the seconds the rig needs to move there
            (:mod:`jaxrecog.motion`; not in the thesis; 0 = off).  Every
            campaign on a rig with a geometry (the synthetic cases) reports
            the travel time per trial, whatever λ.
        devices: shard each lockstep batch over this many devices
            (:func:`jaxrecog.driver.trial_mesh`; the batch is rounded up to a
            multiple); the results are the same as on one device.
        render_workers: render the synthetic rig's captures in this many
            worker processes (:func:`capture_pool`); 0 = in this process (the
            default).  The results are the same; on a rendered rig the
            captures are most of a campaign's time.
        off_grid_deg, off_grid_eye, off_grid_light: off-grid captures
            (:class:`~jaxrecog.hardware.render.synthetic.OffGrid`): the bound of each
            trial's object yaw offset (degrees), the per-capture eye offset and
            light jitter; ``None`` = the case's (``Case.off_grid``: 0 for the
            thesis cases, :data:`JITTER` for ``jitter``); each finite, >= 0.
        likelihood: the sensor-model family ``prepare`` trains (a name of
            :data:`jaxrecog.kernels.LIKELIHOODS`; default ``gaussian-diag``,
            the thesis's and ``train_model``'s default).
        likelihood_options: the family's fit options (e.g. ``(("nu", "auto"),)``,
            ``(("rank", 4),)``): a dict or pairs, kept as sorted pairs so the
            settings stay hashable.
        max_rotation, max_scale, blur_sigma, gain_amplitude, gain_cells: the
            capture augmentation of training
            (:class:`~jaxrecog.augment.AugmentParams`; off by default).
        occluder_gray: ``(lo, hi)``: DB2's training occluders get a gray
            level drawn from ``U(lo, hi)`` (0..255) instead of black (the
            thesis's; ``(0, 0)``, the default).
        max_shift: training samples are shifted by up to this many pixels
            in x and y (:class:`~jaxrecog.augment.AugmentParams`; default 3;
            the thesis gives no number).  The synthetic rig's captures shift
            by up to 2 (``capture_noise``).
            Anything but the defaults of these eight fields gives the models
            their own file names and cache keys (:func:`prepare`).
        view_jitter, view_jitter_deg: render this many views *near* each
            training view (the object turned up to ±``view_jitter_deg``
            degrees, :func:`~jaxrecog.hardware.render.render_db.jitter_offsets`) into
            the database's ``jitter`` split and train on them as extra base
            images of their view (``train_model(view_jitter=True)``): the
            neighbouring views of the turn-table between the training poses.
            0 = off (the thesis).  Not in the thesis; its own database folder
            (``database...-vjNxD``) and model files.
        interpolate: interpolated views per side toward each neighbouring
            position (``train_model(interpolate=)``, a view-mixture
            ``likelihood``; 0 = off, the thesis); its own model files.
    """

    workdir: Path | str = Path("out/experiments")  # a str becomes a Path (__post_init__)
    trials_per_object: int = 100
    seed: int = 0
    samples: int = 1024
    min_per_stratum: int = DEFAULT_MIN_PER_STRATUM
    batch: int = 16
    n_components: int = 20
    samples_per_image: int = 100
    p_threshold: float = 0.95
    max_steps: int = 7
    capture_noise: tuple[float, float, int] = CAPTURE_NOISE
    transition: str = "uniform"
    stride: int = 1
    min_views: int = 1
    exclude_visited_positions: bool = False
    adaptive_scale: float = 1.0
    shared_view: bool = False
    motion_cost: float = 0.0
    devices: int = 1
    render_workers: int = 0
    off_grid_deg: float | None = None
    off_grid_eye: float | None = None
    off_grid_light: float | None = None
    likelihood: str = DEFAULT_LIKELIHOOD
    # a dict or pairs (an experiment file's table) become sorted pairs (__post_init__)
    likelihood_options: tuple[tuple[str, object], ...] | dict[str, object] = ()
    max_rotation: float = 0.0
    max_scale: float = 0.0
    blur_sigma: tuple[float, float] | list[float] | float = (0.0, 0.0)  # one number: (0, sigma)
    gain_amplitude: float = 0.0
    gain_cells: int = 3
    occluder_gray: tuple[float, float] | list[float] = (0.0, 0.0)
    max_shift: int = 3
    view_jitter: int = 0
    view_jitter_deg: float = 10.0
    interpolate: int = 0
    interpolation: str = "linear"

    def __post_init__(self):
        from ._fieldtypes import check_settings

        check_settings(self)  # every field's type (and plain ranges) first: one line naming it
        object.__setattr__(self, "workdir", Path(self.workdir))
        self._check_training()
        self._check_view_jitter()
        from .motion import check_weight

        object.__setattr__(self, "motion_cost", check_weight(self.motion_cost))
        for k, lo in (("devices", 1), ("render_workers", 0), ("stride", 1)):
            v = getattr(self, k)
            if isinstance(v, bool) or not isinstance(v, int) or v < lo:
                raise ValueError(f"{k} must be an integer >= {lo}, got {v!r}")
        from .recognizer import check_min_views

        check_min_views(self.min_views, self.max_steps)
        if self.trials_per_object < 1:
            raise ValueError("trials_per_object must be >= 1")
        for k in ("off_grid_deg", "off_grid_eye", "off_grid_light"):
            v = getattr(self, k)
            if v is None:
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 <= v < math.inf:
                raise ValueError(f"{k} must be a finite number >= 0 (or None: the case's), got {v!r}")
            object.__setattr__(self, k, float(v))

    def _check_view_jitter(self) -> None:
        from .hardware.render.render_db import jitter_offsets

        try:
            jitter_offsets(self.view_jitter, self.view_jitter_deg)
        except ValueError as e:
            msg = str(e).replace("jitter_per_view", "view_jitter").replace("jitter_yaw_deg", "view_jitter_deg")
            raise ValueError(msg) from None
        object.__setattr__(self, "view_jitter_deg", float(self.view_jitter_deg))

    def _check_training(self) -> None:
        """Normalise and check the likelihood and augmentation fields: the
        registry name of the family, its options as sorted pairs (every name
        one the family's ``fit`` takes), the blur range as a float pair, and
        the augmentation accepted by :class:`~jaxrecog.augment.AugmentParams`."""
        from .kernels import likelihood_class, likelihood_names

        try:
            family = likelihood_class(self.likelihood)
        except ValueError as e:
            raise ValueError(f"likelihood: {e}") from None
        name = next(n for n in likelihood_names() if likelihood_class(n) is family)
        object.__setattr__(self, "likelihood", name)
        opts = self.likelihood_options
        opts = dict(opts.items() if hasattr(opts, "items") else opts)
        bad = sorted(set(opts) - set(family.fit_options))
        if bad:
            raise ValueError(f"likelihood_options: {name!r} has no option {', '.join(map(repr, bad))} "
                             f"(it takes: {', '.join(family.fit_options) or 'none'})")
        opts = family.with_defaults(**opts)   # a changed default changes the cache key
        object.__setattr__(self, "likelihood_options", tuple(sorted(opts.items())))
        if isinstance(self.interpolate, bool) or not isinstance(self.interpolate, int) or self.interpolate < 0:
            raise ValueError(f"interpolate must be an integer >= 0, got {self.interpolate!r}")
        if self.interpolation not in ("linear", "flow"):
            raise ValueError(f"interpolation must be 'linear' or 'flow', got {self.interpolation!r}")
        if self.interpolate and not family.view_components:
            raise ValueError(f"interpolate = {self.interpolate}: interpolated views are mixture components; "
                             f"likelihood {name!r} has none (use view-mixture or view-mixture-lowrank)")
        blur = self.blur_sigma
        blur = (0.0, float(blur)) if isinstance(blur, (int, float)) else tuple(float(x) for x in blur)
        object.__setattr__(self, "blur_sigma", blur)
        object.__setattr__(self, "occluder_gray", tuple(float(x) for x in self.occluder_gray))
        self.augment_params()  # raises on a bad augmentation

    def augment_params(self):
        """The :class:`~jaxrecog.augment.AugmentParams` of training (its
        defaults but the capture fields; ``samples_per_image`` is
        ``train_model``'s)."""
        from .augment import AugmentParams

        return AugmentParams(samples_per_image=self.samples_per_image, max_rotation=float(self.max_rotation),
                             max_scale=float(self.max_scale), blur_sigma=self.blur_sigma,
                             gain_amplitude=float(self.gain_amplitude), gain_cells=int(self.gain_cells),
                             occluder_gray=self.occluder_gray, max_shift=int(self.max_shift))


_OFF_GRID_FIELDS = ("off_grid_deg", "off_grid_eye", "off_grid_light")


def case_settings(case: "Case", settings: Settings) -> Settings:
    """``settings`` with the off-grid amounts it leaves at ``None`` taken from
    the case (``Case.off_grid``), so the run id and the reports name the
    amounts the campaign ran with."""
    fill = {k: float(v) for k, v in zip(_OFF_GRID_FIELDS, case.off_grid) if getattr(settings, k) is None}
    return dataclasses.replace(settings, **fill) if fill else settings


def off_grid(settings: Settings):
    """The :class:`~jaxrecog.hardware.render.synthetic.OffGrid` of ``settings``
    (``None`` amounts count as 0), or ``None`` when all are 0 (on the grid)."""
    from .hardware.render.synthetic import OffGrid

    og = OffGrid(*(getattr(settings, k) or 0.0 for k in _OFF_GRID_FIELDS))
    return None if og.off else og


@dataclasses.dataclass(frozen=True)
class Prepared:
    database: Path
    models: dict[str, Path]  # "DB1" / "DB2" -> model file


def _progress_bar(total: int, desc: str, enabled: bool):
    from tqdm.auto import tqdm

    unit = "img" if desc.startswith("render") else "position" if desc.startswith("train") else "trial"
    return tqdm(total=total, desc=desc, unit=unit, disable=not enabled, dynamic_ncols=True)


#: Settings fields of the likelihood and the capture augmentation, and their
#: defaults: models trained with these keep the file names and cache keys
#: they had before the fields existed.
_AUGMENT_FIELDS = ("max_rotation", "max_scale", "blur_sigma", "gain_amplitude", "gain_cells", "occluder_gray",
                   "max_shift")
_LATER_AUGMENT_FIELDS = ("occluder_gray", "max_shift")
_TRAINING_FIELDS = ("likelihood", "likelihood_options", *_AUGMENT_FIELDS, "view_jitter", "view_jitter_deg",
                    "interpolate", "interpolation")


def _training_defaults() -> dict:
    return {f.name: f.default for f in dataclasses.fields(Settings) if f.name in _TRAINING_FIELDS}


def _training_extra(settings: Settings) -> dict:
    """The likelihood / augmentation fields of ``settings`` that differ from
    the defaults (``{}`` for the thesis's training)."""
    defaults = _training_defaults()
    return {k: getattr(settings, k) for k in _TRAINING_FIELDS if getattr(settings, k) != defaults[k]}


def _training_params(settings: Settings, kind: str) -> dict:
    """The training parameters a cached model file must match to be reused
    (compared with the file's ``training.params``; a dict value is compared
    key by key, lists for tuples).  The default likelihood and augmentation
    add nothing, so the key of a default model is what it always was."""
    params = {"kind": kind, "K": settings.n_components, "samples_per_image": settings.samples_per_image,
              "seed": settings.seed}
    extra = _training_extra(settings)
    if extra:
        from .kernels import likelihood_class

        params["likelihood"] = likelihood_class(settings.likelihood).kind
        params["likelihood_options"] = {k: v for k, v in settings.likelihood_options}
        aug = dataclasses.asdict(settings.augment_params())
        # a field added later counts only when set: model files from before it stay valid
        params["augment"] = {k: (list(aug[k]) if isinstance(aug[k], tuple) else aug[k])
                             for k in _AUGMENT_FIELDS if k in extra or k not in _LATER_AUGMENT_FIELDS}
        if settings.interpolate:   # a linear model's key is what it was before 'interpolation' existed
            params["interpolate"] = {"points_per_side": settings.interpolate,
                                     **({} if settings.interpolation == "linear" else
                                        {"interpolation": settings.interpolation})}
    return params


def _params_match(have, want) -> bool:
    """``have`` (a model file's training params) agrees with ``want``: dicts
    key by key (keys of ``want`` only), tuples as lists."""
    if isinstance(want, dict):
        return isinstance(have, dict) and all(_params_match(have.get(k), v) for k, v in want.items())
    if isinstance(want, tuple):
        want = list(want)
    return have == want


def _model_tag(settings: Settings) -> str:
    """File-name suffix of a model trained with a non-default likelihood or
    augmentation: ``-<likelihood>-<digest of the fields>`` ("" for the
    defaults, so existing model files stay valid)."""
    import hashlib

    extra = _training_extra(settings)
    if not extra:
        return ""
    digest = hashlib.sha256(json.dumps(extra, sort_keys=True, default=str).encode()).hexdigest()[:8]
    return f"-{settings.likelihood}-{digest}"


def model_path(settings: Settings, kind: str) -> Path:
    """The cached model file of ``kind`` ("DB1" / "DB2") under ``settings``."""
    return settings.workdir / (f"model-{kind.lower()}{_stride_tag(settings)}-K{settings.n_components}"
                               f"-S{settings.samples_per_image}-seed{settings.seed}{_model_tag(settings)}.npz")


def _run_id(settings: Settings, model_path: Path | str) -> str:
    """A short digest of everything that changes a campaign's results besides
    the planner: the settings (but the work folder and batch size) and the
    model file's bytes.  Trial stores are named by it, so a resumed campaign
    never mixes trials run under other settings or another model."""
    import hashlib

    fields = {k: v for k, v in dataclasses.asdict(settings).items() if k not in ("workdir", "batch", "devices", "render_workers")}
    # added later: off keeps the digests of earlier runs
    for k in ("exclude_visited_positions", "shared_view", "motion_cost", *_OFF_GRID_FIELDS):
        if not fields[k]:
            del fields[k]
    if fields["adaptive_scale"] == 1.0:
        del fields["adaptive_scale"]
    if fields["min_views"] == 1:
        del fields["min_views"]
    defaults = _training_defaults()
    for k in _TRAINING_FIELDS:
        if getattr(settings, k) == defaults[k]:
            del fields[k]
    h = hashlib.sha256(json.dumps(fields, sort_keys=True, default=str).encode())
    h.update(hashlib.sha256(Path(model_path).read_bytes()).digest())
    return h.hexdigest()[:10]


def rig_table(settings: Settings):
    """The thesis table (:func:`~jaxrecog.hardware.geometry.positions.default_table`)
    with every ``settings.stride``-th position of each camera."""
    from .hardware.geometry.positions import CameraTable, default_table

    table = default_table()
    if settings.stride == 1:
        return table
    return CameraTable(table.workspace, tuple(v[:: settings.stride] for v in table.views))


def _stride_tag(settings: Settings) -> str:
    """File-name suffix of a strided table's cache ("" for the full table,
    so existing full-size work folders stay valid)."""
    return "" if settings.stride == 1 else f"-stride{settings.stride}"


def _cached_model_is_fresh(path: Path, db, want: dict) -> bool:
    """``path`` exists, reads, was trained on ``db`` (``load_db()`` or the
    database itself; its manifest hash) and with the parameters ``want``
    (:func:`_params_match`): the cache check of :func:`prepare` and
    :func:`prepare_turntable`."""
    from .modelfile import ModelFileError, load_model_meta

    if not path.exists():
        return False
    try:
        meta = load_model_meta(path)
    except ModelFileError:
        return False
    db = db() if callable(db) else db
    params = (meta.get("training") or {}).get("params") or {}
    return meta.get("manifest_sha256") == db.manifest_sha256 and _params_match(params, want)


def _train(settings: Settings, db, kind: str, progress: bool):
    """``train_model`` of ``db`` with the training fields of ``settings`` (K,
    samples, seed, likelihood and options, capture augmentation, view jitter),
    with a progress bar; returns ``(model, info)``."""
    from .train import train_model

    with _progress_bar(int(sum(db.positions)), f"train {kind}", progress) as bar:
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
    from .database import load_database
    from .hardware import render_database
    from .modelfile import save_model

    work = settings.workdir
    tag = _stride_tag(settings)
    jitter = settings.view_jitter
    db_dir = work / (f"database{tag}" + (f"-vj{jitter}x{settings.view_jitter_deg:g}" if jitter else ""))
    manifest = db_dir / "manifest.csv"
    if not manifest.exists():
        table = rig_table(settings)
        n_images = sum(table.positions) * 8 * 4 * (1 + jitter)
        with _progress_bar(n_images, "render database", progress) as bar:
            render_database(db_dir, table, progress=bar.update, jitter_per_view=jitter,
                            jitter_yaw_deg=settings.view_jitter_deg)
    loaded = []  # the database, read once and only when needed

    def db():
        if not loaded:
            loaded.append(load_database(db_dir))
        return loaded[0]

    models = {}
    for kind in databases:
        path = model_path(settings, kind)
        if not _cached_model_is_fresh(path, db, _training_params(settings, kind)):
            model, info = _train(settings, db(), kind, progress)
            save_model(path, model, training=info.to_dict(), manifest_sha256=db().manifest_sha256)
        models[kind] = path
    return Prepared(db_dir, models)


def make_rig(settings: Settings, cameras: tuple[int, ...] | None = None, *, seed: int = 0,
             clean_counts: dict | None = None):
    """The synthetic rig with the thesis table (every ``settings.stride``-th
    position; or a subset of its cameras).  ``clean_counts``: a dict shared
    by identical rigs (:class:`~jaxrecog.hardware.SyntheticRig`)."""
    from .hardware import Noise, SyntheticRig
    from .hardware.geometry.positions import CameraTable

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


def capture_pool(settings: Settings, cameras: tuple[int, ...] | None = None, *, seed: int = 0):
    """:func:`rig_pool`'s rigs as a :class:`~jaxrecog.hardware.rigs.rig_pool.RigPool`
    for the trial driver: in this process (``settings.render_workers == 0``)
    or spread over that many worker processes, which render side by side
    (the results are the same).  Close it when done (it is a context manager)."""
    import functools

    from .hardware.rigs.rig_pool import LocalRigs, ProcessRigs

    if settings.render_workers:
        factory = functools.partial(make_rig, settings, cameras, seed=seed, clean_counts={})
        return ProcessRigs(factory, max(1, settings.batch), settings.render_workers)
    return LocalRigs(rig_pool(settings, cameras, seed=seed))


# the campaigns' board ranges (OCCLUDER_SIZE / OCCLUDER_OFFSET) live with the boards


def occluder_factory(rig, size: tuple[float, float] | None = None, offset: tuple[float, float] | None = None):
    """Cardboard for one trial (thesis §7.2): a board in front of each camera's
    *initial* view, so both first images are occluded, plus one board per
    camera facing a random other position, so moving is not a guaranteed
    escape.  ``size`` / ``offset``: the boards' half-size and offset ranges
    (:func:`~jaxrecog.hardware.random_occluders`; default the campaign's,
    ``OCCLUDER_SIZE`` / ``OCCLUDER_OFFSET`` of :mod:`jaxrecog.hardware.render.occluders`)."""
    from .hardware import OccluderLayout, random_occluders
    from .hardware.render.occluders import OCCLUDER_OFFSET, OCCLUDER_SIZE
    from .hardware.geometry.positions import CameraTable

    size = OCCLUDER_SIZE if size is None else size
    offset = OCCLUDER_OFFSET if offset is None else offset

    def factory(rng, initial):
        first = CameraTable(rig.table.workspace, tuple((views[v],) for views, v in zip(rig.table.views, initial)))
        a = random_occluders(rng, first, radius=rig.radius, size=size, offset=offset)
        b = random_occluders(rng, rig.table, radius=rig.radius, size=size, offset=offset)
        return OccluderLayout(a.boards + b.boards)

    return factory


def case_trials(case: Case, settings: Settings, rig, n_objects: int, n_poses: int, objects=None) -> list[TrialSpec]:
    return plan_trials(
        n_objects,
        n_poses,
        rig.positions,
        settings.trials_per_object,
        seed=settings.seed,
        objects=objects,
        occluders=occluder_factory(rig) if case.occluded else None,
        yaw_deg=case_settings(case, settings).off_grid_deg or 0.0,
    )


def make_recognizer(model, planner_name: str, settings: Settings, travel=None):
    """The campaign's recognizer.  ``travel``: per-camera travel-time tables
    of the rig (:func:`jaxrecog.motion.rig_travel_times`) — the motion cost
    ``settings.motion_cost`` uses them and every result records its travel
    time; ``None`` (a rig without a geometry) allows only ``motion_cost = 0``."""
    from .motion import MotionCost
    from .recognizer import Recognizer

    if travel is None and settings.motion_cost > 0:
        raise ValueError(f"motion_cost = {settings.motion_cost} needs the rig's travel times (its geometry); "
                         "this rig has none (a replayed image database)")
    planner = make_planner(planner_name, model, key=jr.PRNGKey(settings.seed), samples=settings.samples,
                           min_per_stratum=settings.min_per_stratum)
    motion = None if travel is None else MotionCost(travel, settings.motion_cost)
    return Recognizer(model, planner, p_threshold=settings.p_threshold, max_steps=settings.max_steps,
                      min_views=settings.min_views, transition=settings.transition,
                      exclude_visited_positions=settings.exclude_visited_positions, motion=motion,
                      shared_view=settings.shared_view, adaptive_scale=settings.adaptive_scale)


def case_model(prepared: Prepared, case: Case):
    from .modelfile import load_model
    from .recognizer import restrict_cameras

    model = load_model(prepared.models[case.database])
    return restrict_cameras(model, case.cameras) if case.cameras is not None else model


def results_dir(settings: Settings) -> Path:
    """Where :meth:`CaseReport.write` puts tables by default:
    ``workdir/results`` (``workdir/results-strideN`` for a strided table)."""
    return settings.workdir / f"results{_stride_tag(settings)}"


@dataclasses.dataclass
class CaseReport:
    case: Case
    settings: Settings
    rows: dict[str, list[ObjectRow]]
    results: dict[str, list[TrialResult]]
    seconds: dict[str, float]

    def thesis_table(self, planner: str) -> ThesisTable | None:
        """The thesis's published table for this case and planner
        (:func:`~jaxrecog.thesis.published`), if any; none on a strided table
        (not the thesis's rig).  The planner's thesis column comes from the
        registry (``planners.PLANNERS``: ``mi-class`` is compared with the
        thesis's ``mi``, ``crlb-det`` with its ``crlb``)."""
        if self.settings.stride != 1:
            return None
        n_objects = sum(r.label != "Average" for r in next(iter(self.rows.values()), []))
        return published(self.case.name, planner_spec(planner).thesis, n_objects)

    def reference(self, planner: str):
        """The thesis's (rate, exit, views) rows for this case and planner
        (``None`` per object where the thesis gives only the average), or
        ``None`` (:meth:`thesis_table`)."""
        t = self.thesis_table(planner)
        if t is None:
            return None
        rows = [None if math.isnan(r) else (r, e, v) for r, e, v in zip(t.rate, t.exit_prob, t.views)]
        return rows + [t.average]

    def markdown(self) -> str:
        parts = [f"### {self.case.title}", ""]
        for planner, rows in self.rows.items():
            ref = self.reference(planner)
            n = self.settings.trials_per_object
            parts.append(table_markdown(rows, f"{planner.upper()} — {n} trials per object, {self.seconds[planner]:.0f} s", reference=ref))
        return "\n".join(parts)

    def to_json(self) -> dict:
        return {
            "case": dataclasses.asdict(self.case),
            "settings": {k: (str(v) if isinstance(v, Path) else v) for k, v in dataclasses.asdict(self.settings).items()},
            "tables": {p: table_json(r) for p, r in self.rows.items()},
            "seconds": self.seconds,
        }

    def write(self, folder: Path | None = None) -> tuple[Path, Path]:
        folder = Path(folder or results_dir(self.settings))
        folder.mkdir(parents=True, exist_ok=True)
        md = folder / f"case-{self.case.name}.md"
        js = folder / f"case-{self.case.name}.json"
        md.write_text(self.markdown())
        js.write_text(json.dumps(self.to_json(), indent=1))
        return md, js


def _campaign(
    case: Case,
    model,
    rig,  # one Rig, one per lockstep slot, or a RigPool
    specs: Sequence[TrialSpec],
    settings: Settings,
    planners: Sequence[str],
    store_name: Callable[[str], str],
    *,
    progress: bool,
    on_result: Callable[[str, TrialResult], None] | None,
    probe,
) -> CaseReport:
    """Each planner on the same trials (``specs``) on ``rig``; finished trials
    go to ``workdir/trials/<store_name(planner)>.jsonl`` (resumable).
    ``probe``: a rig of the same table, whose geometry gives the travel times."""
    from .motion import rig_travel_times

    rows, results, seconds = {}, {}, {}
    travel = rig_travel_times(probe)
    for planner in planners:
        rec = make_recognizer(model, planner, settings, travel)
        store = TrialStore(settings.workdir / "trials" / f"{store_name(planner)}.jsonl")
        t0 = time.perf_counter()
        with _progress_bar(len(specs), f"{case.name} {planner}" if case.name == "dataset" else f"case {case.name} {planner}", progress) as bar:
            already = len(store.load())
            bar.update(min(already, len(specs)))
            res = run_campaign(rec, rig, specs, key=jr.PRNGKey(settings.seed + 1), batch=settings.batch, seed=settings.seed, store=store, progress=bar.update,
                               devices=settings.devices)
        seconds[planner] = time.perf_counter() - t0
        results[planner] = res
        rows[planner] = summarize(res, model.n_objects)
        if on_result is not None:
            for r in res:
                on_result(planner, r)
    return CaseReport(case, settings, rows, results, seconds)


def run_case(
    name: str,
    settings: Settings,
    planners: Sequence[str] | None = None,
    *,
    progress: bool = False,
    prepared: Prepared | None = None,
    on_result: Callable[[str, TrialResult], None] | None = None,
) -> CaseReport:
    """Run one thesis case with each planner on the same trials (resumable:
    finished trials are kept in ``workdir/trials``)."""
    if name not in CASES:
        raise ValueError(f"unknown case {name!r}; choose one of {', '.join(CASES)}")
    case = CASES[name]
    settings = case_settings(case, settings)
    prepared = prepared or prepare(settings, progress=progress, databases=(case.database,))
    model = case_model(prepared, case)
    probe = make_rig(settings, case.cameras, seed=settings.seed)  # the table and geometry, here
    specs = case_trials(case, settings, probe, model.n_objects, model.n_poses)
    run_id = _run_id(settings, prepared.models[case.database])
    with capture_pool(settings, case.cameras, seed=settings.seed) as rigs:
        return _campaign(case, model, rigs, specs, settings, list(planners or case.planners),
                         lambda planner: f"case-{name}-{planner}-{run_id}", progress=progress,
                         on_result=on_result, probe=probe)


#: Planners of :func:`run_dataset` when none are given: the model's recipe's
#: planner (:data:`~jaxrecog.planners.DEFAULT_PLANNER` for a thesis-recipe or
#: older model file) against the random baseline.
DATASET_PLANNERS = (DEFAULT_PLANNER, "random")


def dataset_planners(model_path) -> tuple[str, ...]:
    """``(the model's recipe's planner, "random")``: what :func:`run_dataset` compares by default."""
    from .modelfile import load_model_meta
    from .recipes import recipe_from_meta

    return tuple(dict.fromkeys((recipe_from_meta(load_model_meta(model_path)).planner, "random")))


def _check_database_fits(db, model, folder, model_path) -> None:
    """One clear error before any trial when the database's test split cannot
    serve every (camera, position, object, pose) the model's campaign visits."""
    import numpy as np

    from .counts import check_counts

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
    manifest's hashes), so an interrupted campaign resumes.  ``stride``,
    ``capture_noise`` and the training settings do not apply (stored images,
    a given model); ``stride`` must stay 1.
    """
    from .database import load_database
    from .hardware import DatasetRig
    from .modelfile import load_model

    if settings.stride != 1:
        raise ValueError("stride selects positions of the synthetic rig; a database campaign uses the "
                         "database's own positions (leave stride at 1)")
    model = load_model(model_path)
    db = load_database(folder)
    _check_database_fits(db, model, folder, model_path)
    rig = DatasetRig(db, seed=settings.seed)
    planners = tuple(planners or dataset_planners(model_path))
    case = Case("dataset", f"Image database {folder} ({model.n_objects} objects x {model.n_poses} poses, "
                           f"positions {tuple(int(p) for p in model.positions)}), model {model_path}",
                str(folder), False, None, planners)
    specs = plan_trials(model.n_objects, model.n_poses, rig.positions, settings.trials_per_object, seed=settings.seed)
    run_id = _run_id(settings, model_path)
    db_id = db.manifest_sha256[:10]
    return _campaign(case, model, rig, specs, settings, planners,
                     lambda planner: f"dataset-{planner}-{run_id}-{db_id}", progress=progress, on_result=on_result,
                     probe=rig)


def run_trace(settings: Settings, *, object: int = 5, planner: str = "mi", case: str = "iii", trial: int = 0, prepared: Prepared | None = None) -> TrialResult:
    """Replay one trial of a case's campaign with its per-step object
    probabilities, like thesis Table 7.8 (default: object 6 = index 5, its
    first trial, occluded, case iii).  Same scene, start, noise and keys as in
    :func:`run_case` with the same settings."""
    c = CASES[case]
    settings = case_settings(c, settings)
    prepared = prepared or prepare(settings, databases=(c.database,))
    model = case_model(prepared, c)
    rig = make_rig(settings, c.cameras, seed=settings.seed)
    if not 0 <= trial < settings.trials_per_object:
        raise ValueError(f"trial must be in [0, {settings.trials_per_object}), got {trial}")
    (spec,) = [s for s in case_trials(c, settings, rig, model.n_objects, model.n_poses, objects=[object])
               if s.trial == object * settings.trials_per_object + trial]
    from .motion import rig_travel_times

    rec = make_recognizer(model, planner, settings, rig_travel_times(rig))
    (res,) = run_campaign(rec, rig, [spec], key=jr.PRNGKey(settings.seed + 1), batch=1, seed=settings.seed, trace=True)
    return res


# ---------------------------------------------------------------- turntable set (issue 18, item 4)

#: Planners of :func:`run_turntable` when none are given.
TURNTABLE_PLANNERS = ("mi-class-pairwise", "random")


def _turntable_name(n_objects: int, cameras: int, occluded: bool, poses: int, step_deg: int, object_seed: int) -> str:
    return (f"turntable-n{n_objects}-c{cameras}-p{poses}-s{step_deg}{'-occ' if occluded else ''}"
            f"{f'-o{object_seed}' if object_seed else ''}")


def prepare_turntable(settings: Settings, n_objects: int = 50, cameras: int = 1, occluded: bool = False, *,
                      poses: int = 4, step_deg: int = 20, test_per_view: int = 2, calib_per_view: int = 1,
                      object_seed: int = 0, kind: str | None = None, progress: bool = False) -> Prepared:
    """Render a turntable set (:func:`jaxrecog.hardware.render.turntable.render_turntable`:
    ``n_objects`` random_urdfs meshes, ``360 / step_deg`` positions per camera,
    test views halfway between training views, with a board in front of every
    test view when ``occluded``) into ``workdir/turntable-...`` and train its
    model (``kind``: DB1 for a clean set, DB2 for an occluded one; K, samples
    and seed from ``settings``), calibrated on the set's ``calib`` split, as
    ``jaxrecog train --calibrate`` does.  Both are cached (the model by its
    training parameters and the manifest's hash).  ``Prepared.models`` has
    one entry, ``"turntable"``."""
    from .calibration import calibrate_model
    from .database import load_database
    from .hardware.render.random_objects import random_objects
    from .hardware.render.turntable import render_turntable
    from .modelfile import save_model

    kind = kind or ("DB2" if occluded else "DB1")
    jitter = settings.view_jitter
    if jitter and not settings.view_jitter_deg < step_deg / 2:
        raise ValueError(f"view_jitter_deg = {settings.view_jitter_deg:g}: the turntable's jitter views must lie "
                         f"closer to their training view than the test views ({step_deg / 2:g} degrees off)")
    name = _turntable_name(n_objects, cameras, occluded, poses, step_deg, object_seed) + (
        f"-vj{jitter}x{settings.view_jitter_deg:g}" if jitter else "")
    db_dir = settings.workdir / name
    manifest = db_dir / "manifest.csv"
    if not manifest.exists():
        objects = random_objects(n_objects, seed=object_seed)
        total = cameras * (360 // step_deg) * n_objects * poses * (1 + test_per_view + calib_per_view)
        t0 = time.perf_counter()
        with _progress_bar(total, f"render {name}", progress) as bar:
            render_turntable(db_dir, objects, cameras=cameras, step_deg=step_deg, poses=poses,
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
    path = db_dir / (f"model-{kind.lower()}-K{settings.n_components}-S{settings.samples_per_image}-seed{settings.seed}"
                     f"{_model_tag(settings)}-cal.npz")
    if not _cached_model_is_fresh(path, db, dict(_training_params(settings, kind), calibrated=True)):
        model, info = _train(settings, db, kind, progress)
        t0 = time.perf_counter()
        model, cal = calibrate_model(model, db)
        training = info.to_dict()
        training["params"] = dict(training["params"], calibrated=True)
        training["calibration_seconds"] = time.perf_counter() - t0
        save_model(path, model, training=training, manifest_sha256=db.manifest_sha256, calibration=cal.to_dict())
    return Prepared(db_dir, {"turntable": path})


def run_turntable(settings: Settings, n_objects: int = 50, cameras: int = 1, occluded: bool = False,
                  planners: Sequence[str] | None = None, *, progress: bool = False,
                  prepared: Prepared | None = None, **turntable) -> CaseReport:
    """The turntable campaign: :func:`prepare_turntable` (cached), then
    :func:`run_dataset` on its test split with the calibrated model (each
    planner on the same trials; resumable).  ``turntable``: more
    :func:`prepare_turntable` options (poses, step_deg, ...)."""
    prepared = prepared or prepare_turntable(settings, n_objects, cameras, occluded, progress=progress, **turntable)
    return run_dataset(prepared.database, prepared.models["turntable"], settings,
                       planners=tuple(planners or TURNTABLE_PLANNERS), progress=progress)


__all__ += ["TURNTABLE_PLANNERS", "prepare_turntable", "run_turntable"]
