"""The settings of a campaign run: everything that defines it (defaults: the
thesis protocol), with the checks that give one clear line per bad value.

The field names are the configuration dialect of ``jaxrecog experiment``
(experiment files, ``--config`` tables, ``--print-config``,
:data:`jaxrecog._config.OPTION_FIELDS`).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

from .._fieldtypes import check_settings
from ..augment import AugmentParams
from ..kernels import DEFAULT_LIKELIHOOD, likelihood_class, likelihood_names
from ..motion import check_weight
from ..planners import DEFAULT_MIN_PER_STRATUM
from ..kernels.adaptive_scale import scale_grid
from ..recipes import THESIS, Recipe
from ..recognizer import check_min_views
from ..scene import CAPTURE_NOISE

__all__ = ["Settings"]


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
            worker processes (:func:`~jaxrecog.campaigns.rigs.capture_pool`); 0 = in this process (the
            default).  The results are the same; on a rendered rig the
            captures are most of a campaign's time.
        off_grid_deg, off_grid_eye, off_grid_light: off-grid captures
            (:class:`~jaxrecog.hardware.synthetic.OffGrid`): the bound of each
            trial's object yaw offset (degrees), the per-capture eye offset and
            light jitter; ``None`` = the case's (``Case.off_grid``: 0 for the
            thesis cases, :data:`~jaxrecog.campaigns.cases.JITTER` for ``jitter``); each finite, >= 0.
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
            their own file names and cache keys (:func:`~jaxrecog.campaigns.preparation.prepare`).
        view_jitter, view_jitter_deg: render this many views *near* each
            training view (the object turned up to ±``view_jitter_deg``
            degrees, :func:`~jaxrecog.hardware.render_db.jitter_offsets`) into
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
        check_settings(self)  # every field's type (and plain ranges) first: one line naming it
        object.__setattr__(self, "workdir", Path(self.workdir))
        self._check_training()
        self._check_view_jitter()
        object.__setattr__(self, "motion_cost", check_weight(self.motion_cost))
        for k, lo in (("devices", 1), ("render_workers", 0), ("stride", 1)):
            v = getattr(self, k)
            if isinstance(v, bool) or not isinstance(v, int) or v < lo:
                raise ValueError(f"{k} must be an integer >= {lo}, got {v!r}")
        check_min_views(self.min_views, self.max_steps)
        scale_grid(self.adaptive_scale)   # a ValueError for a bad value, before anything runs
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
        from ..hardware.render_db import jitter_offsets

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
        return AugmentParams(samples_per_image=self.samples_per_image, max_rotation=float(self.max_rotation),
                             max_scale=float(self.max_scale), blur_sigma=self.blur_sigma,
                             gain_amplitude=float(self.gain_amplitude), gain_cells=int(self.gain_cells),
                             occluder_gray=self.occluder_gray, max_shift=int(self.max_shift))


    @property
    def recipe(self) -> Recipe:
        """The recipe parts of these settings (:data:`~jaxrecog.recipes.TRAIN_FIELDS`
        a campaign trains with, :data:`~jaxrecog.recipes.STOP_FIELDS`) as a
        :class:`~jaxrecog.recipes.Recipe`: the thesis's with these parts."""
        return THESIS.replace(likelihood=self.likelihood, likelihood_options=self.likelihood_options,
                              interpolate=self.interpolate, interpolation=self.interpolation,
                              max_shift=self.max_shift, p_threshold=self.p_threshold, min_views=self.min_views,
                              exclude_visited=self.exclude_visited_positions, adaptive_scale=self.adaptive_scale)
