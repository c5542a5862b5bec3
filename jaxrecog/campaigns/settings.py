"""The settings of a campaign run: a recipe and the run's options.

:class:`Settings` holds the :class:`~jaxrecog.recipes.Recipe` a campaign
trains and stops by (its likelihood and fit options, interpolated views,
training shift range, and stop rule) and the options of the run (trials,
seeds, Monte Carlo sizes, work folder, table stride, capture augmentation,
rendered view jitter, off-grid amounts, devices, ...).

The configuration dialect of ``jaxrecog experiment`` stays flat: experiment
files, ``--config`` tables, ``--print-config`` and ``config.toml`` name every
setting by its flat name (:data:`FIELDS`, in this order), a recipe part as
well as a run option (``p_threshold``, ``likelihood``, ``trials_per_object``,
...; :data:`RECIPE_PARTS` maps the recipe parts' flat names to the recipe's).
``Settings(**flat)`` builds one, ``settings.p_threshold`` reads a part,
``dataclasses.replace(settings, p_threshold=0.9)`` changes one and
:meth:`Settings.flat` gives them all; ``Settings(recipe=r, **flat)`` starts
from the recipe ``r`` instead of the thesis's.  Every value is checked with
one clear line naming its flat name.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any, ClassVar

from .._fieldtypes import check_settings
from ..cluster import check_cluster
from ..augment import AugmentParams
from ..campaign import MAX_TRIALS
from ..kernels import likelihood_class, likelihood_names
from ..kernels.adaptive_scale import scale_grid
from ..motion import check_weight
from ..planners import DEFAULT_MIN_PER_STRATUM
from ..recipes import THESIS, Recipe
from ..recognizer import check_min_views
from ..scene import CAPTURE_NOISE

__all__ = ["Settings", "FIELDS", "RECIPE_PARTS"]

#: The recipe parts a Settings holds through its recipe: flat name -> the
#: :class:`~jaxrecog.recipes.Recipe` part (their names differ only for
#: ``exclude_visited_positions``), and each flat name's type as the dialect
#: checks it.  The recipe's ``view_jitter``, ``calibrate`` and ``planner`` are
#: not settings of a campaign: the rendered view jitter is the run option
#: ``view_jitter``, the synthetic cases train uncalibrated models, and a case
#: names its planners (a database campaign's default is the model's recipe's).
RECIPE_PARTS: dict[str, str] = {
    "p_threshold": "p_threshold",
    "min_views": "min_views",
    "exclude_visited_positions": "exclude_visited",
    "adaptive_scale": "adaptive_scale",
    "likelihood": "likelihood",
    "likelihood_options": "likelihood_options",
    "max_shift": "max_shift",
    "interpolate": "interpolate",
    "interpolation": "interpolation",
    "occluder_gray": "occluder_gray",
}
_PART_TYPES = {"p_threshold": "float", "min_views": "int", "exclude_visited_positions": "bool",
               "adaptive_scale": "float", "likelihood": "str",
               "likelihood_options": "tuple[tuple[str, object], ...] | dict[str, object]", "max_shift": "int",
               "interpolate": "int", "interpolation": "str", "occluder_gray": "tuple[float, float] | list[float]"}

#: Every setting's flat name, in the dialect's order (``--print-config``,
#: ``config.toml``, reports' JSON, the trial stores' run ids).
FIELDS: tuple[str, ...] = (
    "workdir", "trials_per_object", "seed", "samples", "min_per_stratum", "batch", "n_components",
    "samples_per_image", "p_threshold", "max_steps", "capture_noise", "transition", "stride", "min_views",
    "exclude_visited_positions", "adaptive_scale", "shared_view", "motion_cost", "devices", "render_workers",
    "cluster", "off_grid_deg", "off_grid_eye", "off_grid_light", "likelihood", "likelihood_options", "max_rotation",
    "max_scale", "blur_sigma", "gain_amplitude", "gain_cells", "occluder_gray", "max_shift", "view_jitter",
    "view_jitter_deg", "interpolate", "interpolation",
)


@dataclasses.dataclass(frozen=True, init=False)
class Settings:
    """Everything that defines a run (defaults: the thesis protocol): the
    ``recipe`` and the run's options (module doc).

    ``Settings(*, recipe=None, **flat)``: the recipe (default
    :data:`~jaxrecog.recipes.THESIS`) with the recipe parts given by their flat
    names overriding its own, and the run options (unknown names: a
    ``TypeError``; a bad value: a ``ValueError`` naming it).

    Attributes:
        recipe: the :class:`~jaxrecog.recipes.Recipe` the campaign trains and
            stops by; its parts read under their flat names below (marked
            *recipe*).  Its ``name`` is the recipe it started from (``thesis``
            unless given) with the parts given by flat name replaced.
        workdir: where the database, models, trials and tables go.
        trials_per_object: thesis: ~100; at most
            :data:`~jaxrecog.campaign.MAX_TRIALS` (so is the campaign's total).
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
        p_threshold, max_steps: stop rule (thesis: 0.95, 7); ``p_threshold``: *recipe*.
        capture_noise: (brightness sd, pixel sd, max shift px) of every capture.
        transition: "uniform" (thesis) or "sticky".
        stride: keep every ``stride``-th position of each camera of the thesis
            table (``views[::stride]``, as ``jaxrecog render --stride``): 1 =
            the full 32 x 7 table; 8 = (4, 1) positions, a database of 160
            images that renders and trains in seconds (tests, smoke runs).
            The database and model files of each stride are cached apart.
        min_views: never stop on P_th before this many image sets
            (:class:`~jaxrecog.recognizer.Recognizer`; a departure from the
            thesis, which stops at the first step that reaches P_th; default 1; *recipe*).
        exclude_visited_positions: never send a camera back to a position it
            already used (:class:`~jaxrecog.recognizer.Recognizer`; a departure
            from the thesis, off by default; *recipe* ``exclude_visited``).
        adaptive_scale: the largest per-capture variance factor of the
            adaptive scale (:mod:`jaxrecog.kernels.adaptive_scale`; 1 = off,
            the thesis; *recipe*).
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
            worker processes (:func:`~jaxrecog.campaigns.rigs.capture_pool`); 0 = in this process (the
            default).  The results are the same; on a rendered rig the
            captures are most of a campaign's time.  With ``cluster``: the
            number of Ray workers (0 = one per CPU of the cluster).
        cluster: run the campaign (and render its database) on Ray:
            ``"ray"`` (a local Ray instance) or ``"ray://HOST:PORT"`` (a
            running cluster; :mod:`jaxrecog.cluster`, ``docs/cluster.md``);
            ``None`` = this machine (the default).  The results are the same.
        off_grid_deg, off_grid_eye, off_grid_light: off-grid captures
            (:class:`~jaxrecog.hardware.render.synthetic.OffGrid`): the bound of each
            trial's object yaw offset (degrees), the per-capture eye offset and
            light jitter; ``None`` = the case's (``Case.off_grid``: 0 for the
            thesis cases, :data:`~jaxrecog.campaigns.cases.JITTER` for ``jitter``); each finite, >= 0.
        likelihood: the sensor-model family ``prepare`` trains (a name of
            :data:`jaxrecog.kernels.LIKELIHOODS`; default ``gaussian-diag``,
            the thesis's and ``train_model``'s default; *recipe*).
        likelihood_options: the family's fit options (e.g. ``(("nu", "auto"),)``,
            ``(("rank", 4),)``): a dict or pairs, kept as sorted pairs so the
            settings stay hashable (*recipe*).
        max_rotation, max_scale, blur_sigma, gain_amplitude, gain_cells: the
            capture augmentation of training
            (:class:`~jaxrecog.augment.AugmentParams`; off by default).
        occluder_gray: ``(lo, hi)``: DB2's training occluders get a gray
            level drawn from ``U(lo, hi)`` (0..255) instead of black (the
            thesis's; ``(0, 0)``, the default; *recipe*, robust ``(0, 255)``).
        max_shift: training samples are shifted by up to this many pixels
            in x and y (:class:`~jaxrecog.augment.AugmentParams`; default 3;
            the thesis gives no number; *recipe*).  The synthetic rig's captures shift
            by up to 2 (``capture_noise``).
            Anything but the defaults of these eight fields gives the models
            their own file names and cache keys (:func:`~jaxrecog.campaigns.preparation.prepare`).
        view_jitter, view_jitter_deg: render this many views *near* each
            training view (the object turned up to ±``view_jitter_deg``
            degrees, :func:`~jaxrecog.hardware.render.render_db.jitter_offsets`) into
            the database's ``jitter`` split and train on them as extra base
            images of their view (``train_model(view_jitter=True)``): the
            neighbouring views of the turn-table between the training poses.
            0 = off (the thesis).  Not in the thesis; its own database folder
            (``database...-vjNxD``) and model files.
        interpolate, interpolation: interpolated views per side toward each
            neighbouring position (``train_model(interpolate=)``, a
            view-mixture ``likelihood``; 0 = off, the thesis) and how they are
            made (``"linear"`` or ``"flow"``); its own model files (*recipe*).
    """

    FIELDS: ClassVar[tuple[str, ...]] = FIELDS

    recipe: Recipe = THESIS
    workdir: Path | str = Path("out/experiments")  # a str becomes a Path
    trials_per_object: int = 100
    seed: int = 0
    samples: int = 1024
    min_per_stratum: int = DEFAULT_MIN_PER_STRATUM
    batch: int = 16
    n_components: int = 20
    samples_per_image: int = 100
    max_steps: int = 7
    capture_noise: tuple[float, float, int] = CAPTURE_NOISE
    transition: str = "uniform"
    stride: int = 1
    shared_view: bool = False
    motion_cost: float = 0.0
    devices: int = 1
    render_workers: int = 0
    cluster: str | None = None
    off_grid_deg: float | None = None
    off_grid_eye: float | None = None
    off_grid_light: float | None = None
    max_rotation: float = 0.0
    max_scale: float = 0.0
    blur_sigma: tuple[float, float] | list[float] | float = (0.0, 0.0)  # one number: (0, sigma)
    gain_amplitude: float = 0.0
    gain_cells: int = 3
    view_jitter: int = 0
    view_jitter_deg: float = 10.0

    def __init__(self, *, recipe: Recipe | None = None, **values: Any):
        base = THESIS if recipe is None else recipe
        if not isinstance(base, Recipe):
            raise ValueError(f"recipe must be a jaxrecog.recipes.Recipe (e.g. get_recipe('robust')), "
                             f"got {type(base).__name__}")
        unknown = sorted(set(values) - set(FIELDS))
        if unknown:
            raise TypeError(f"Settings() got an unexpected keyword argument {unknown[0]!r}")
        flat = _check({name: values[name] if name in values else _default(name, base) for name in FIELDS})
        for f in dataclasses.fields(self):
            if f.name != "recipe":
                object.__setattr__(self, f.name, flat[f.name])
        object.__setattr__(self, "recipe", base.replace(**{part: flat[name] for name, part in RECIPE_PARTS.items()}))

    # the recipe parts under their flat names
    p_threshold = property(lambda self: self.recipe.p_threshold, doc="stop probability P_th (thesis: 0.95)")
    min_views = property(lambda self: self.recipe.min_views,
                         doc="never stop on P_th before this many image sets (1: the thesis)")
    exclude_visited_positions = property(lambda self: self.recipe.exclude_visited,
                                         doc="never send a camera back to a position it used (off: the thesis)")
    adaptive_scale = property(lambda self: self.recipe.adaptive_scale,
                              doc="the adaptive scale's largest variance factor (1 = off: the thesis)")
    likelihood = property(lambda self: self.recipe.likelihood, doc="the sensor-model family prepare trains")
    likelihood_options = property(lambda self: self.recipe.likelihood_options,
                                  doc="the family's fit options, sorted (name, value) pairs")
    max_shift = property(lambda self: self.recipe.max_shift, doc="training shifts in pixels")
    interpolate = property(lambda self: self.recipe.interpolate,
                           doc="interpolated views per side toward each neighbouring position")
    interpolation = property(lambda self: self.recipe.interpolation,
                             doc="how interpolated views are made: 'linear' or 'flow'")
    occluder_gray = property(lambda self: self.recipe.occluder_gray,
                             doc="DB2's training occluders' gray range ((0, 0): black, the thesis's)")

    @classmethod
    def defaults(cls) -> dict[str, Any]:
        """Every setting's default under its flat name (the thesis recipe's
        parts and the run options' defaults), in :data:`FIELDS` order."""
        return {name: _default(name, THESIS) for name in FIELDS}

    def flat(self) -> dict[str, Any]:
        """Every setting under its flat name, in :data:`FIELDS` order (what
        the dialect, the reports and the run ids read)."""
        return {name: getattr(self, name) for name in FIELDS}

    def augment_params(self) -> AugmentParams:
        """The :class:`~jaxrecog.augment.AugmentParams` of training (its
        defaults but the capture fields; ``samples_per_image`` is
        ``train_model``'s)."""
        return _augment_params(self.flat())


_RUN_FIELDS = {f.name: f for f in dataclasses.fields(Settings) if f.name != "recipe"}
assert set(FIELDS) == set(_RUN_FIELDS) | set(RECIPE_PARTS) and len(FIELDS) == len(_RUN_FIELDS) + len(RECIPE_PARTS), \
    "FIELDS must name every run option and recipe part once"
_TYPES = {name: _PART_TYPES[name] if name in RECIPE_PARTS else _RUN_FIELDS[name].type for name in FIELDS}


def _default(name: str, recipe: Recipe):
    """The value of setting ``name`` that no one gave: the recipe's part, or the run option's default."""
    return getattr(recipe, RECIPE_PARTS[name]) if name in RECIPE_PARTS else _RUN_FIELDS[name].default


def _check(flat: dict[str, Any]) -> dict[str, Any]:
    """The settings checked (one line naming the first bad one) and normalised:
    a Path for the work folder, the likelihood's registry name and its options
    as sorted pairs, float pairs, float off-grid amounts."""
    check_settings(flat, _TYPES)  # every value's type (and plain ranges) first
    flat["workdir"] = Path(flat["workdir"])
    flat["cluster"] = check_cluster(flat["cluster"])
    _check_training(flat)
    _check_view_jitter(flat)
    flat["motion_cost"] = check_weight(flat["motion_cost"])
    for k, lo in (("devices", 1), ("render_workers", 0), ("stride", 1)):
        v = flat[k]
        if isinstance(v, bool) or not isinstance(v, int) or v < lo:
            raise ValueError(f"{k} must be an integer >= {lo}, got {v!r}")
    check_min_views(flat["min_views"], flat["max_steps"])
    scale_grid(flat["adaptive_scale"])   # a ValueError for a bad value, before anything runs
    if not 1 <= flat["trials_per_object"] <= MAX_TRIALS:
        raise ValueError(f"trials_per_object must be in [1, {MAX_TRIALS}] (a campaign holds every trial's spec "
                         f"and result in memory), got {flat['trials_per_object']}")
    for k in ("off_grid_deg", "off_grid_eye", "off_grid_light"):
        v = flat[k]
        if v is None:
            continue
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 <= v < math.inf:
            raise ValueError(f"{k} must be a finite number >= 0 (or None: the case's), got {v!r}")
        flat[k] = float(v)
    return flat


def _check_view_jitter(flat: dict[str, Any]) -> None:
    from ..hardware.render.render_db import jitter_offsets

    try:
        jitter_offsets(flat["view_jitter"], flat["view_jitter_deg"])
    except ValueError as e:
        msg = str(e).replace("jitter_per_view", "view_jitter").replace("jitter_yaw_deg", "view_jitter_deg")
        raise ValueError(msg) from None
    flat["view_jitter_deg"] = float(flat["view_jitter_deg"])


def _check_training(flat: dict[str, Any]) -> None:
    """Normalise and check the likelihood and augmentation settings: the
    registry name of the family, its options as sorted pairs (every name
    one the family's ``fit`` takes), the blur range as a float pair, and
    the augmentation accepted by :class:`~jaxrecog.augment.AugmentParams`."""
    try:
        family = likelihood_class(flat["likelihood"])
    except ValueError as e:
        raise ValueError(f"likelihood: {e}") from None
    name = next(n for n in likelihood_names() if likelihood_class(n) is family)
    flat["likelihood"] = name
    opts = flat["likelihood_options"]
    opts = dict(opts.items() if hasattr(opts, "items") else opts)
    bad = sorted(set(opts) - set(family.fit_options))
    if bad:
        raise ValueError(f"likelihood_options: {name!r} has no option {', '.join(map(repr, bad))} "
                         f"(it takes: {', '.join(family.fit_options) or 'none'})")
    opts = family.with_defaults(**opts)   # a changed default changes the cache key
    flat["likelihood_options"] = tuple(sorted(opts.items()))
    interpolate = flat["interpolate"]
    if isinstance(interpolate, bool) or not isinstance(interpolate, int) or interpolate < 0:
        raise ValueError(f"interpolate must be an integer >= 0, got {interpolate!r}")
    if flat["interpolation"] not in ("linear", "flow"):
        raise ValueError(f"interpolation must be 'linear' or 'flow', got {flat['interpolation']!r}")
    if interpolate and not family.view_components:
        raise ValueError(f"interpolate = {interpolate}: interpolated views are mixture components; "
                         f"likelihood {name!r} has none (use view-mixture or view-mixture-lowrank)")
    blur = flat["blur_sigma"]
    flat["blur_sigma"] = (0.0, float(blur)) if isinstance(blur, (int, float)) else tuple(float(x) for x in blur)
    flat["occluder_gray"] = tuple(float(x) for x in flat["occluder_gray"])
    _augment_params(flat)  # raises on a bad augmentation


def _augment_params(flat: dict[str, Any]) -> AugmentParams:
    return AugmentParams(samples_per_image=flat["samples_per_image"], max_rotation=float(flat["max_rotation"]),
                         max_scale=float(flat["max_scale"]), blur_sigma=flat["blur_sigma"],
                         gain_amplitude=float(flat["gain_amplitude"]), gain_cells=int(flat["gain_cells"]),
                         occluder_gray=flat["occluder_gray"], max_shift=int(flat["max_shift"]))
