"""View planners: a planner is a value that scores every camera configuration.

Every planner maps the *predicted prior* of the next step (a
:class:`~jaxrecog.kernels.PredictedBelief`: level rows per candidate position,
``[V_i, C, L_i]``, from :func:`~jaxrecog.kernels.transition_per_position`) and
a key to ``[A]`` scores, higher = better, A = prod_i V_i (row-major).  The
recognizer takes the argmax; it never branches on the planner's kind.

- :class:`MIPlanner` — Mutual Information I(s; g | a) (thesis eq. 5.3-5.13),
  or I(c; g | a) with ``target="class"`` (see docs/design.md §3, "Target").
- :class:`PairwiseMIPlanner` — the deterministic pairwise-distance estimate of
  the same I(s; g | a) or I(c; g | a) (Kolchinsky & Tracey 2017; Bhattacharyya:
  a lower bound, KL: an upper bound), no samples (docs/design.md §7).
- :class:`LookaheadMIPlanner` — the two-step value of a first configuration:
  its pairwise MI plus the expected pairwise MI of the best second
  configuration after each sampled outcome (non-myopic, where the thesis
  plans one step ahead; :func:`~jaxrecog.kernels.lookahead_information`).
- :class:`CRLBPlanner` — minus a criterion of the Cramér-Rao bound J_g(a)^-1
  (eq. 5.14-5.28): trace (A-optimal, default), log-det (D) or the largest
  eigenvalue (E).
- :class:`PairwiseCRLBPlanner` — the same criterion on a deterministic
  pairwise-distance estimate of J_g(a) (no samples, no sampling noise;
  :func:`~jaxrecog.kernels.pairwise_fisher_information`).
- :class:`QMCCRLBPlanner` — the CRLB of the Monte Carlo J_g(a) on randomised
  scrambled-Sobol draws (quasi-Monte Carlo: less variance for as many draws;
  :func:`~jaxrecog.kernels.qmc_fisher_information`).
- :class:`RandomPlanner` — a uniformly random configuration.
- :class:`FixedPlanner` — one fixed configuration (the passive baseline).

The single-camera baseline is not a planner: it is a recognizer over a model
with camera 1 alone (:func:`jaxrecog.recognizer.restrict_cameras`), with any of
these planners.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Callable, ClassVar, NamedTuple

import equinox as eqx
import jax
import jax.random as jr
from jaxtyping import Array, Float, PRNGKeyArray

from . import kernels as K
from .kernels import tempered_mi as _tempered_mi
from .planner_base import Planner, stability_weight
from .pruned_planner import PRUNE_MIN_CLASSES, PRUNING_MARKDOWN, PrunedStableViewMIPlanner, prune_mass
from .table_cache import divergence_tables, sample_tables

__all__ = [
    "Planner",
    "MIPlanner",
    "PairwiseMIPlanner",
    "PrunedStableViewMIPlanner",
    "TemperedPairwiseMIPlanner",
    "StableViewMIPlanner",
    "LookaheadMIPlanner",
    "CRLBPlanner",
    "PairwiseCRLBPlanner",
    "QMCCRLBPlanner",
    "RandomPlanner",
    "FixedPlanner",
    "make_planner",
    "samples_per_stratum",
    "PLANNERS",
    "ALIASES",
    "PlannerSpec",
    "DEFAULT_MIN_PER_STRATUM",
    "DEFAULT_PLANNER",
    "DEFAULT_LOOKAHEAD_TOP_K",
    "planner_names",
    "planner_spec",
    "planners_markdown",
]


#: Monte Carlo floor of samples per state stratum used by campaigns, the CLI and
#: :func:`make_planner` (see :func:`samples_per_stratum` for why 8, not 1).
DEFAULT_MIN_PER_STRATUM = 8

#: The planner a recognizer uses when none is named (``jaxrecog recognize``,
#: ``jaxrecog plan``, a campaign on an image database): the pairwise-distance
#: I(c; g) with Bhattacharyya distances.  Measured (docs/results.md, "Planners
#: beyond the thesis"): case (iii), 800 trials, 95.75 % at 1.88 views against
#: 95.5 % / 1.89 for the Monte Carlo ``mi-class`` at J = 8 and 91.4 % / 2.42
#: for the thesis's state target ``mi``; argmax regret 0.0026 nats against a
#: J = 32 oracle where MI at J = 8 has 0.039; 1.5 ms per 224 configurations
#: against 72 ms.  Not the thesis's planner: the thesis cases keep ``mi``.
DEFAULT_PLANNER = "mi-class-pairwise"

#: First configurations the lookahead planners evaluate two steps deep by
#: default (the best by one-step score; fewer where the model has fewer).
DEFAULT_LOOKAHEAD_TOP_K = 8


def _n_configs(model) -> int:
    return math.prod(model.positions)


def samples_per_stratum(model, samples: int, min_per_stratum: int = 1) -> int:
    """J: ``samples`` per configuration rounded up to whole samples per state
    stratum (c, k_0, ...), and at least ``min_per_stratum`` (default 1: no floor;
    the planners use :data:`DEFAULT_MIN_PER_STRATUM`).

    The floor matters for occlusion models: with C = 32 and L = 6 levels on
    two cameras there are 1152 strata, so 1024 samples give J = 1 and each
    class is seen by camera i through only L_i draws (one per level).  The
    tables are drawn once and reused at every step, so one unlucky draw makes
    a view look useless for the whole campaign: at J = 1 the I(c; g) estimate
    of a sticker view ranges over -0.12 .. +0.36 nats across keys, while its
    value (J = 32) is +0.23 — the planner then never takes it.
    """
    if samples < 1 or min_per_stratum < 1:
        raise ValueError(f"samples and min_per_stratum must be >= 1, got {samples}, {min_per_stratum}")
    strata = model.n_objects * model.n_poses * len(model.levels) ** len(model.cameras)
    return max(int(min_per_stratum), math.ceil(samples / strata))


def _tables(model, key: PRNGKeyArray, samples: int, store: str, min_per_stratum: int) -> K.MITables:
    """The offline sample tables shared by MI and CRLB (J from :func:`samples_per_stratum`)."""
    j = samples_per_stratum(model, samples, min_per_stratum)
    return sample_tables(model.likelihoods, key=key, samples_per_stratum=j, store=store)


class MIPlanner(Planner):
    """Mutual Information over all configurations in one call (eq. 5.5, 5.10).

    ``levels="belief"`` uses the predicted level distribution of each camera
    (exact for both transitions); ``levels="uniform"`` uses the thesis's
    belief-free offline tables (P_i(k|c) = 1/L, eq. 3.9, 5.12-5.13) for every
    camera at every position and ignores the prior's level rows.  Under the
    uniform transition that is exact only for configurations where every
    camera moves: a camera that keeps its position keeps its levels, which the
    offline tables treat as re-drawn, so configurations with a staying camera
    are scored approximately; use ``levels="belief"`` for the exact value.
    """

    tables: K.MITables
    target: str = eqx.field(static=True, default="state")
    levels: str = eqx.field(static=True, default="belief")

    @classmethod
    def from_model(cls, model, *, key: PRNGKeyArray, samples: int = 1024, target: str = "state", levels: str = "belief",
                   min_per_stratum: int = DEFAULT_MIN_PER_STRATUM) -> "MIPlanner":
        """Build the offline sample tables: ``samples`` ≈ samples per configuration
        (rounded up to a whole number of samples per state stratum)."""
        tables = _tables(model, key, samples, "uniform" if levels == "uniform" else "full", min_per_stratum)
        return cls(_n_configs(model), tables, target, levels)

    def scores(self, prior, key):
        del key  # common random numbers live in the tables
        return K.mutual_information(self.tables, prior, target=self.target, levels=self.levels)


class PairwiseMIPlanner(Planner):
    """Pairwise-distance MI over all configurations, no Monte Carlo
    (:func:`~jaxrecog.kernels.pairwise_mutual_information`).

    ``divergence="bhattacharyya"`` scores a lower bound on I(s; g | a),
    ``"kl"`` an upper bound; ``target`` and ``levels`` as :class:`MIPlanner`.
    """

    tables: K.PairwiseTables
    target: str = eqx.field(static=True, default="state")
    levels: str = eqx.field(static=True, default="belief")

    @classmethod
    def from_model(cls, model, *, target: str = "state", divergence: str = "bhattacharyya",
                   levels: str = "belief") -> "PairwiseMIPlanner":
        """Build the divergence tables (belief-free, once per model; no key, no samples)."""
        if levels not in ("belief", "uniform"):
            raise ValueError(f"levels must be 'belief' or 'uniform', got {levels!r}")
        if target not in ("state", "class"):
            raise ValueError(f"target must be 'state' or 'class', got {target!r}")
        tables = divergence_tables(model.likelihoods, divergence)
        return cls(_n_configs(model), tables, target, levels)

    def scores(self, prior, key):
        del key  # deterministic
        return K.pairwise_mutual_information(self.tables, prior, target=self.target, levels=self.levels)


class TemperedPairwiseMIPlanner(PairwiseMIPlanner):
    """The pairwise-distance MI under the tempered class belief
    P_tau(c) ∝ P(c)^tau (:mod:`~jaxrecog.kernels.tempered_mi`):
    ``temper = 1`` is :class:`PairwiseMIPlanner`; ``temper = 0`` (default)
    scores I(c; g | a) under the uniform class prior, so the next view is the
    unvisited one the model separates classes best at over all class pairs,
    not the one where it predicts the present (often wrong, over-confident)
    top class farthest from its few competitors: on real photos between the
    training views that prediction is least reliable exactly where it is
    largest.  The level rows of the belief are used as they are."""

    temper: float = eqx.field(static=True, default=0.0)

    @classmethod
    def from_model(cls, model, *, target: str = "class", divergence: str = "bhattacharyya",
                   levels: str = "belief", temper: float = 0.0) -> "TemperedPairwiseMIPlanner":
        base = super().from_model(model, target=target, divergence=divergence, levels=levels)
        return dataclasses.replace(base, temper=_tempered_mi.check_temper(temper))

    def scores(self, prior, key):
        del key  # deterministic
        return _tempered_mi.tempered_pairwise_mutual_information(self.tables, prior, self.temper,
                                                                 target=self.target, levels=self.levels)


class StableViewMIPlanner(TemperedPairwiseMIPlanner):
    """The tempered pairwise MI minus ``stability`` times the expected view
    instability of the configuration under the class belief
    (:mod:`~jaxrecog.kernels.view_stability`)::

        score(a) = I_D^tau(c; g | a) - stability * sum_i E_{c ~ P(c)} d_i[v_i, c]

    ``temper`` defaults to 1 here (the belief itself): with the stability
    term the plain belief no longer chases the views where the model is worst
    (photos, 40° grid, diagonal mixture: 99.0 / 1.0 % in 2.18 views at 1,
    2.21 at 0), and on the synthetic rig's off-grid case it keeps the plain
    planner's rate (low-rank mixture: 96.0 / 0.0 % against 93.0 / 1.0 % at 0).

    ``d`` (mean 1 per camera) is large where a class's appearance changes
    fast between training views, so a capture there is modelled worst; with
    the adaptive scale such a capture weighs little and does not count
    toward the stop, so the planner prefers views the likely classes are
    stable at.  ``stability = 0`` is :class:`TemperedPairwiseMIPlanner`; a
    model without view components has ``d = 0`` (the same).  ``stability=None``: the
    model's weight fitted on held-out captures (``SensorModel.stability``,
    :mod:`jaxrecog.stability_fit`), 1 for a model without one."""

    temper: float = eqx.field(static=True, default=1.0)   # the belief itself (class docstring)
    instability: tuple[Float[Array, "_V C"], ...] = ()
    stability: float = eqx.field(static=True, default=1.0)

    @classmethod
    def from_model(cls, model, *, target: str = "class", divergence: str = "bhattacharyya",
                   levels: str = "belief", temper: float = 1.0, stability: float | None = None) -> "StableViewMIPlanner":
        stability = stability_weight(model, stability)
        base = TemperedPairwiseMIPlanner.from_model(model, target=target, divergence=divergence, levels=levels,
                                                    temper=temper)
        inst = tuple(K.view_stability.view_instability(lik) for lik in model.likelihoods)
        return cls(base.n_configs, base.tables, target=base.target, levels=base.levels, temper=base.temper,
                   instability=inst, stability=stability)

    def scores(self, prior, key):
        mi = super().scores(prior, key)
        if self.stability == 0.0:
            return mi
        return mi - self.stability * K.view_stability.expected_instability(self.instability, prior.log_pc)


class LookaheadMIPlanner(Planner):
    """Two-step lookahead on the pairwise-distance MI
    (:func:`~jaxrecog.kernels.lookahead_information`): for each of the ``top_k``
    configurations a_1 of largest one-step score,

        I_D(x; g_1 | a_1) + E_{g_1} [ max_{a_2 != a_1} I_D(x; g_2 | a_2, g_1, a_1) ]

    with I_D the Bhattacharyya pairwise estimate (``divergence``) of
    I(s; g) or I(c; g) (``target``), the outcomes g_1 a systematic sample of
    ``outcomes`` draws from the Monte Carlo tables (fresh offset and sample
    indices from the step's key, common to every a_1), the posterior after
    g_1 by Bayes' rule and the level transition ``transition`` / ``rho``
    between the steps (set to the recognizer's by :meth:`with_transition`).
    Configurations outside the ``top_k`` keep their one-step order below the
    evaluated ones.

    Attributes:
        tables: :class:`~jaxrecog.kernels.MITables` without ``ld_max`` /
            ``ld_exp`` (only ``ld`` is read: the outcomes' log-likelihoods).
        pairwise: the divergence tables of the one-step score.
    """

    tables: K.MITables
    pairwise: K.PairwiseTables
    target: str = eqx.field(static=True, default="state")
    top_k: int = eqx.field(static=True, default=8)
    outcomes: int = eqx.field(static=True, default=16)
    transition: str = eqx.field(static=True, default="uniform")
    rho: float = eqx.field(static=True, default=0.9)
    batch_size: int | None = eqx.field(static=True, default=32)

    def __check_init__(self):
        if self.target not in ("state", "class"):
            raise ValueError(f"target must be 'state' or 'class', got {self.target!r}")
        if not 1 <= int(self.top_k) <= self.n_configs:
            raise ValueError(f"top_k = {self.top_k}: a lookahead over more first configurations than exist "
                             f"(A = {self.n_configs}); need 1 <= top_k <= A")
        if int(self.outcomes) < 1:
            raise ValueError(f"outcomes must be >= 1, got {self.outcomes}")
        if self.transition not in ("uniform", "sticky"):
            raise ValueError(f"transition must be 'uniform' or 'sticky', got {self.transition!r}")

    @classmethod
    def from_model(cls, model, *, key: PRNGKeyArray, samples: int = 1024, target: str = "state", top_k: int | None = None,
                   outcomes: int = 16, divergence: str = "bhattacharyya", transition: str = "uniform", rho: float = 0.9,
                   batch_size: int | None = 32, min_per_stratum: int = DEFAULT_MIN_PER_STRATUM) -> "LookaheadMIPlanner":
        """The outcome tables (J from :func:`samples_per_stratum`) and the divergence tables.

        ``top_k``: first configurations looked at two steps deep, at most A
        (default ``min(DEFAULT_LOOKAHEAD_TOP_K, A)``); ``outcomes``: sampled
        g_1 per first configuration; ``batch_size``: one-step calls per chunk
        (memory), ``None`` for one vmap."""
        n = _n_configs(model)
        top_k = min(DEFAULT_LOOKAHEAD_TOP_K, n) if top_k is None else top_k
        if not 1 <= int(top_k) <= n:  # before building any table
            raise ValueError(f"top_k = {top_k}: a lookahead over more first configurations than exist "
                             f"(A = {n}); need 1 <= top_k <= A")
        tables = _tables(model, key, samples, "full", min_per_stratum)._replace(ld_max=None, ld_exp=None)
        pairwise = divergence_tables(model.likelihoods, divergence)
        return cls(n, tables, pairwise, target, int(top_k), int(outcomes), transition, float(rho), batch_size)

    def with_transition(self, kind, rho):
        if (kind, float(rho)) == (self.transition, self.rho):
            return self
        return dataclasses.replace(self, transition=kind, rho=float(rho))

    def scores(self, prior, key):
        ld = self.tables.ld[0]
        draws = K.lookahead_draws(key, self.outcomes, ld.shape[3], dtype=ld.dtype)
        score = functools.partial(K.pairwise_mutual_information, self.pairwise, target=self.target)
        return K.lookahead_information(self.tables, score, prior, draws=draws, top_k=self.top_k,
                                       transition=self.transition, rho=self.rho, batch_size=self.batch_size)


class CRLBPlanner(Planner):
    """Minus the chosen criterion of J_g(a)^-1 (eq. 5.25): smaller bound = better."""

    tables: K.MITables
    n_objects: int = eqx.field(static=True, default=1)
    n_poses: int = eqx.field(static=True, default=1)
    criterion: str = eqx.field(static=True, default="trace")
    sigma_s: float = eqx.field(static=True, default=K.DEFAULT_SIGMA_S)

    @classmethod
    def from_model(cls, model, *, key: PRNGKeyArray, samples: int = 1024, criterion: str = "trace", sigma_s: float = K.DEFAULT_SIGMA_S,
                   min_per_stratum: int = DEFAULT_MIN_PER_STRATUM) -> "CRLBPlanner":
        tables = _tables(model, key, samples, "full", min_per_stratum)
        return cls(_n_configs(model), tables, model.n_objects, model.n_poses, criterion, sigma_s)

    def scores(self, prior, key):
        fisher = K.fisher_information(
            self.tables, prior, key=key, n_objects=self.n_objects, n_poses=self.n_poses, sigma_s=self.sigma_s
        )
        return -K.crlb_criterion(fisher, kind=self.criterion)


class PairwiseCRLBPlanner(Planner):
    """Minus the chosen criterion of the pairwise-distance estimate of J_g(a)
    (:func:`~jaxrecog.kernels.pairwise_fisher_information`: (Sigma_0 - Sigma_g(a))
    / sigma_s^4 with pairwise posterior weights, deterministic, no key)."""

    tables: K.PairwiseFisherTables
    n_objects: int = eqx.field(static=True, default=1)
    n_poses: int = eqx.field(static=True, default=1)
    criterion: str = eqx.field(static=True, default="trace")

    @classmethod
    def from_model(cls, model, *, criterion: str = "trace", sigma_s: float = K.DEFAULT_SIGMA_S,
                   divergence: str = "bhattacharyya") -> "PairwiseCRLBPlanner":
        """Build the divergence tables (belief-free, once per model; no key, no samples)."""
        if criterion not in ("trace", "logdet", "maxeig"):
            raise ValueError(f"criterion must be 'trace', 'logdet' or 'maxeig', got {criterion!r}")
        tables = K.pairwise_fisher_tables(model.likelihoods, kind=divergence, sigma_s=sigma_s)
        return cls(_n_configs(model), tables, model.n_objects, model.n_poses, criterion)

    def scores(self, prior, key):
        del key  # deterministic
        fisher = K.pairwise_fisher_information(self.tables, prior, n_objects=self.n_objects, n_poses=self.n_poses)
        return -K.crlb_criterion(fisher, kind=self.criterion)


class QMCCRLBPlanner(Planner):
    """Minus the chosen criterion of the quasi-Monte Carlo J_g(a)
    (:func:`~jaxrecog.kernels.qmc_fisher_information`: the Monte Carlo kernel
    on scrambled Sobol points, the smoothing draws re-randomised from the key
    at every call)."""

    tables: K.QMCFisherTables
    n_objects: int = eqx.field(static=True, default=1)
    n_poses: int = eqx.field(static=True, default=1)
    criterion: str = eqx.field(static=True, default="trace")
    sigma_s: float = eqx.field(static=True, default=K.DEFAULT_SIGMA_S)

    @classmethod
    def from_model(cls, model, *, key: PRNGKeyArray, samples: int = 1024, criterion: str = "trace",
                   sigma_s: float = K.DEFAULT_SIGMA_S, min_per_stratum: int = DEFAULT_MIN_PER_STRATUM) -> "QMCCRLBPlanner":
        """J from :func:`samples_per_stratum`, rounded up to a power of 2 (Sobol
        points); the scrambling seed drawn from ``key``."""
        if criterion not in ("trace", "logdet", "maxeig"):
            raise ValueError(f"criterion must be 'trace', 'logdet' or 'maxeig', got {criterion!r}")
        j = samples_per_stratum(model, samples, min_per_stratum)
        j = 1 << (j - 1).bit_length()
        seed = int(jr.randint(key, (), 0, 2**31 - 1))
        tables = K.qmc_fisher_tables(model.likelihoods, seed=seed, samples_per_stratum=j)
        return cls(_n_configs(model), tables, model.n_objects, model.n_poses, criterion, sigma_s)

    def scores(self, prior, key):
        fisher = K.qmc_fisher_information(self.tables, prior, key=key, n_objects=self.n_objects,
                                          n_poses=self.n_poses, sigma_s=self.sigma_s)
        return -K.crlb_criterion(fisher, kind=self.criterion)


class RandomPlanner(Planner):
    """Uniformly random configuration (thesis Table 7.3's baseline)."""

    def scores(self, prior, key):
        return jr.uniform(key, (self.n_configs,))


class FixedPlanner(Planner):
    """Always the same configuration (passive recognition)."""

    revisits: ClassVar[bool] = True
    index: int = eqx.field(static=True, default=0)

    def scores(self, prior, key):
        return jax.nn.one_hot(self.index, self.n_configs)


def _sampled(cls, **fixed):
    """A registry builder for a Monte Carlo planner: ``cls.from_model`` with
    the key, the sample counts, the entry's ``fixed`` options and the user's."""
    def build(model, *, key, samples, min_per_stratum, **options):
        return cls.from_model(model, key=key, samples=samples, min_per_stratum=min_per_stratum, **fixed, **options)
    return build


def _deterministic(cls, **fixed):
    """A registry builder for a planner without samples (the key and sample counts are unused)."""
    def build(model, *, key, samples, min_per_stratum, **options):
        del key, samples, min_per_stratum  # deterministic: no samples
        return cls.from_model(model, **fixed, **options)
    return build


def _mi(target: str):
    return _sampled(MIPlanner, target=target)


def _pairwise(target: str, divergence: str):
    return _deterministic(PairwiseMIPlanner, target=target, divergence=divergence)


def _tempered(target: str):
    return _deterministic(TemperedPairwiseMIPlanner, target=target)


def _stable(target: str):
    """The stable planner's builder: on the live classes alone
    (:mod:`~jaxrecog.pruned_planner`, option ``prune``) or on the tables."""
    def build(model, *, key, samples, min_per_stratum, prune="auto", **options):
        del key, samples, min_per_stratum  # deterministic: no samples
        mass = prune_mass(prune, model.likelihoods[0].n_classes)
        if mass is None:
            return StableViewMIPlanner.from_model(model, target=target, **options)
        return PrunedStableViewMIPlanner.from_model(model, target=target, mass=mass, **options)
    return build


def _lookahead(target: str):
    return _sampled(LookaheadMIPlanner, target=target)


def _crlb(criterion: str):
    return _sampled(CRLBPlanner, criterion=criterion)


def _crlb_pairwise(criterion: str):
    return _deterministic(PairwiseCRLBPlanner, criterion=criterion)


def _crlb_qmc(criterion: str):
    return _sampled(QMCCRLBPlanner, criterion=criterion)


def _random(model, *, key, samples, min_per_stratum):
    return RandomPlanner(_n_configs(model))


def _fixed(model, *, key, samples, min_per_stratum, index: int = 0):
    return FixedPlanner(_n_configs(model), int(index))


class PlannerSpec(NamedTuple):
    """One entry of :data:`PLANNERS`.

    Attributes:
        build: ``build(model, *, key, samples, min_per_stratum, **options) -> Planner``.
        thesis: the planner column of the thesis's chapter-7 tables this planner
            is compared with (:data:`jaxrecog.thesis.TABLES` keys ``(case, thesis)``),
            or ``None``.
        description: one line for ``--help`` and ``docs/planners.md``.
    """

    build: Callable[..., Planner]
    thesis: str | None
    description: str


#: The planner registry: name -> :class:`PlannerSpec`.  It feeds
#: :func:`make_planner`, the CLI's ``--planner`` choices, ``docs/planners.md``
#: and the thesis lookup of the result tables.  A new planner is one entry here
#: plus its kernel.
PLANNERS: dict[str, PlannerSpec] = {
    "mi": PlannerSpec(_mi("state"), "mi", "Mutual Information I(s; g | a) over the full state (object, pose, levels), eq. 5.10"),
    "mi-class": PlannerSpec(_mi("class"), "mi", "Mutual Information I(c; g | a) about (object, pose), occlusion levels marginalised"),
    "mi-pairwise": PlannerSpec(_pairwise("state", "bhattacharyya"), "mi",
                               "pairwise-distance I(s; g | a), Bhattacharyya (a lower bound; deterministic, Kolchinsky & Tracey 2017)"),
    "mi-class-pairwise": PlannerSpec(_pairwise("class", "bhattacharyya"), "mi",
                                     "pairwise-distance I(c; g | a), Bhattacharyya (deterministic; levels marginalised)"),
    "mi-pairwise-kl": PlannerSpec(_pairwise("state", "kl"), "mi",
                                  "pairwise-distance I(s; g | a), KL (an upper bound; deterministic)"),
    "mi-class-pairwise-kl": PlannerSpec(_pairwise("class", "kl"), "mi",
                                        "pairwise-distance I(c; g | a), KL (deterministic; levels marginalised)"),
    "mi-class-pairwise-robust": PlannerSpec(_tempered("class"), "mi",
                                            "pairwise I(c; g | a) under the tempered class belief P(c)^tau (option temper, default 0: "
                                            "the uniform class prior; does not chase an over-confident belief)"),
    "mi-class-pairwise-stable": PlannerSpec(_stable("class"), "mi",
                                            "pairwise I(c; g | a) under P(c)^tau (option temper, default 1) minus option "
                                            "stability (default: the model's, fitted on held-out captures, else 1) times the expected "
                                            "view instability under the belief: prefers views the likely classes look alike "
                                            "at from either side (a view-mixture model's interpolated components); "
                                            f"from {PRUNE_MIN_CLASSES} classes (option prune) on the classes holding the belief's mass"),
    "mi-lookahead": PlannerSpec(_lookahead("state"), "mi",
                                "two-step lookahead: pairwise I(s; g_1 | a_1) + E max_a2 I(s; g_2 | a_2, g_1), top-k first moves (options top_k, outcomes)"),
    "mi-class-lookahead": PlannerSpec(_lookahead("class"), "mi",
                                      "two-step lookahead on the pairwise I(c; g): I(c; g_1 | a_1) + E max_a2 I(c; g_2 | a_2, g_1)"),
    "crlb": PlannerSpec(_crlb("trace"), "crlb", "Cramér-Rao bound, minimise trace(J_g^-1) (A-optimal), eq. 5.25"),
    "crlb-det": PlannerSpec(_crlb("logdet"), "crlb", "Cramér-Rao bound, minimise log det(J_g^-1) (D-optimal)"),
    "crlb-eig": PlannerSpec(_crlb("maxeig"), "crlb", "Cramér-Rao bound, minimise the largest eigenvalue of J_g^-1 (E-optimal)"),
    "crlb-pairwise": PlannerSpec(_crlb_pairwise("trace"), "crlb",
                                 "Cramér-Rao bound, trace(J_g^-1) of a deterministic pairwise-distance (Bhattacharyya) J_g (no samples)"),
    "crlb-qmc": PlannerSpec(_crlb_qmc("trace"), "crlb",
                            "Cramér-Rao bound, trace(J_g^-1) of the Monte Carlo J_g on randomised scrambled-Sobol draws (quasi-Monte Carlo)"),
    "random": PlannerSpec(_random, "random", "a uniformly random configuration (thesis Table 7.3)"),
    "fixed": PlannerSpec(_fixed, None, "one fixed configuration, option index (passive baseline)"),
}

#: Other spellings accepted by :func:`make_planner` (not listed as choices).
ALIASES = {"mi-state": "mi", "crlb-trace": "crlb"}


def planner_names() -> tuple[str, ...]:
    """The registered planner names, in registry order (the CLI's choices)."""
    return tuple(PLANNERS)


def planner_spec(name: str) -> PlannerSpec:
    """The registry entry of ``name`` (or of an alias); a ``ValueError`` naming
    the choices for an unknown name."""
    spec = PLANNERS.get(ALIASES.get(name, name))
    if spec is None:
        raise ValueError(f"unknown planner {name!r}; choose one of {', '.join(PLANNERS)}")
    return spec


def make_planner(name: str, model, *, key: PRNGKeyArray, samples: int = 1024,
                 min_per_stratum: int = DEFAULT_MIN_PER_STRATUM, **options) -> Planner:
    """Planner by registry name (:data:`PLANNERS`).  ``samples`` /
    ``min_per_stratum``: Monte Carlo size of the sampling planners (see
    :func:`samples_per_stratum`; planners without samples ignore them);
    ``options`` go to the entry's constructor (e.g. ``index`` for ``fixed``)."""
    return planner_spec(name).build(model, key=key, samples=samples, min_per_stratum=min_per_stratum, **options)


def planners_markdown() -> str:
    """The registry as the Markdown table of ``docs/planners.md``."""
    lines = [
        "# Planners",
        "",
        "Generated from `jaxrecog.planners.PLANNERS` by `scripts/gen_cli_docs.py`; a new planner",
        "is one registry entry in `jaxrecog/planners.py` plus its kernel.",
        "",
        "| name | compared with the thesis's | what it scores |",
        "|---|---|---|",
    ]
    for name, spec in PLANNERS.items():
        lines.append(f"| `{name}` | {spec.thesis or '—'} | {spec.description} |")
    lines += ["", "Aliases: " + ", ".join(f"`{a}` = `{n}`" for a, n in ALIASES.items()), "", PRUNING_MARKDOWN]
    return "\n".join(lines)
