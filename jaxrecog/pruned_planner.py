"""``mi-class-pairwise-stable`` on the belief's live classes: the default
planner for models with many classes.

The stable planner (:class:`~jaxrecog.planners.StableViewMIPlanner`) holds
divergence tables ``[V_i, C, L_i, C', L_i']``: on the thesis layout (32 and 7
positions, 6 levels) 5.7 GB and 63 ms a step at C = 512 classes, 20 GB at
1024, and a belief on two classes costs more than a uniform one.
:class:`PrunedStableViewMIPlanner` scores the same

    score(a) = I_D^tau(c; g | a) - stability * sum_i E_{c ~ P(c)} d_i[v_i, c]

with the pairwise term over the live classes of the tempered belief
(:mod:`~jaxrecog.kernels.pruned_mi`: the top-B classes holding all but
``mass`` of it, B from fixed buckets, their divergences computed in the
step; within :func:`~jaxrecog.kernels.pruning_bound` of the full sum) and the
instability term over every class (exact: ``[V_i, C]`` per camera).  It holds
the model's likelihoods and, up to
:data:`~jaxrecog.kernels.pruned_mi.UNIFORM_TABLE_MAX` classes, the first
step's belief-free values: memory linear in C.

Option ``prune`` of the registry entry: ``"auto"`` (default) this planner
from :data:`PRUNE_MIN_CLASSES` classes on and the table planner below (the
thesis's and the campaigns' models: unchanged, bit for bit); ``True`` this
planner at the default mass; a number, this planner with that mass; ``False``
the table planner.
"""

from __future__ import annotations

import math

import equinox as eqx
from jaxtyping import Array, Float

from . import kernels as K
from .kernels import pruned_mi as _pruned
from .kernels import tempered_mi as _tempered_mi
from .planner_base import Planner, stability_weight

__all__ = ["PrunedStableViewMIPlanner", "PRUNE_MIN_CLASSES", "prune_mass"]

#: From this many classes on ``mi-class-pairwise-stable`` scores the live
#: classes alone (``prune="auto"``): its tables would hold 1.2 GB per
#: divergence array on the thesis layout, a step would take ~20-60 ms.
PRUNE_MIN_CLASSES = 256


def prune_mass(prune, n_classes: int) -> float | None:
    """The belief mass the live set may leave out for option ``prune``
    (module docstring), ``None`` for the table planner; a ``ValueError`` for
    anything but ``"auto"``, a bool or a number in [0, 1)."""
    if prune == "auto":
        return _pruned.DEFAULT_PRUNE_MASS if n_classes >= PRUNE_MIN_CLASSES else None
    if isinstance(prune, bool):
        return _pruned.DEFAULT_PRUNE_MASS if prune else None
    if isinstance(prune, (int, float)) and 0.0 <= prune < 1.0:
        return float(prune)
    raise ValueError(f"prune must be 'auto', true, false or the belief mass to leave out, in [0, 1); got {prune!r}")


class PrunedStableViewMIPlanner(Planner):
    """The stable planner's score with the pairwise MI over the live classes
    (module docstring).  ``temper`` and ``stability`` as
    :class:`~jaxrecog.planners.StableViewMIPlanner`; ``mass`` the belief mass
    the live set may leave out; ``buckets`` its sizes (one compiled branch each)."""

    tables: K.PrunedTables
    instability: tuple[Float[Array, "_V C"], ...]
    target: str = eqx.field(static=True, default="class")
    divergence: str = eqx.field(static=True, default="bhattacharyya")
    temper: float = eqx.field(static=True, default=1.0)
    stability: float = eqx.field(static=True, default=1.0)
    mass: float = eqx.field(static=True, default=_pruned.DEFAULT_PRUNE_MASS)
    buckets: tuple[int, ...] = eqx.field(static=True, default=_pruned.PRUNE_BUCKETS)

    @classmethod
    def from_model(cls, model, *, target: str = "class", divergence: str = "bhattacharyya", temper: float = 1.0,
                   stability: float | None = None, mass: float = _pruned.DEFAULT_PRUNE_MASS,
                   buckets: tuple[int, ...] = _pruned.PRUNE_BUCKETS,
                   uniform_table: bool | None = None) -> "PrunedStableViewMIPlanner":
        """The likelihoods, the instabilities and (``uniform_table``, default up
        to ``UNIFORM_TABLE_MAX`` classes) the first step's belief-free values."""
        if target not in ("state", "class"):
            raise ValueError(f"target must be 'state' or 'class', got {target!r}")
        stability = stability_weight(model, stability)
        temper = _tempered_mi.check_temper(temper)
        mass = _pruned.check_mass(mass)
        _pruned.live_buckets(model.likelihoods[0].n_classes, buckets)  # checks them
        tables = K.pruned_tables(model.likelihoods, kind=divergence, uniform=uniform_table)
        inst = tuple(K.view_stability.view_instability(lik) for lik in model.likelihoods)
        return cls(math.prod(model.positions), tables, inst, target, divergence, temper, stability, mass,
                   tuple(int(b) for b in buckets))

    def scores(self, prior, key):
        del key  # deterministic
        mi = K.pruned_pairwise_mutual_information(self.tables, _tempered_mi.tempered_belief(prior, self.temper),
                                                  kind=self.divergence, target=self.target, mass=self.mass,
                                                  buckets=self.buckets)
        if self.stability == 0.0:
            return mi
        return mi - self.stability * K.view_stability.expected_instability(self.instability, prior.log_pc)
