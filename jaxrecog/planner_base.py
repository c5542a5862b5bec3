"""The planner interface (:class:`Planner`) and the view-stability weight
shared by the stable planners (:mod:`jaxrecog.planners`,
:mod:`jaxrecog.pruned_planner`)."""

from __future__ import annotations

import math
from typing import ClassVar

import equinox as eqx
from jaxtyping import Array, Float, PRNGKeyArray

from . import kernels as K

__all__ = ["Planner", "stability_weight"]


class Planner(eqx.Module):
    """Scores all configurations; higher is better.

    ``revisits`` (a class attribute, not a field): whether the recognizer
    takes the planner's argmax as it is, even a configuration already visited
    (true for :class:`FixedPlanner`, which never moves); otherwise visited
    configurations are excluded while unvisited ones remain.
    """

    revisits: ClassVar[bool] = False
    n_configs: int = eqx.field(static=True)

    def scores(self, prior: K.PredictedBelief, key: PRNGKeyArray) -> Float[Array, " A"]:
        raise NotImplementedError

    def with_transition(self, kind: str, rho: float) -> "Planner":
        """This planner for a recognizer whose level transition is ``kind`` /
        ``rho`` (the recognizer calls it before scoring).  A one-step planner
        never predicts past the prior it is given: itself.  A planner that
        looks further ahead (:class:`LookaheadMIPlanner`) needs the transition
        between its steps to be the recognizer's."""
        del kind, rho
        return self


def stability_weight(model, stability: float | None) -> float:
    """The weight of the expected view instability in ``mi-class-pairwise-stable``:
    ``stability``, or where ``None`` the model's fitted one (``SensorModel.stability``),
    1 for a model without one; a ``ValueError`` unless a finite number >= 0."""
    if stability is None:
        stability = 1.0 if getattr(model, "stability", None) is None else model.stability
    if isinstance(stability, bool) or not isinstance(stability, (int, float)) or not 0.0 <= stability < math.inf:
        raise ValueError(f"stability must be a finite number >= 0, got {stability!r}")
    return float(stability)
