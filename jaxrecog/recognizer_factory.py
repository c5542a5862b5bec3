"""The one place a :class:`~jaxrecog.recognizer.Recognizer` is assembled from
a model, a planner, a recipe's stop rule and a run's options: the campaigns,
``jaxrecog recognize`` / ``plan`` and the environment's planner policies all
build theirs here, so a new recognizer option is wired once.
"""

from __future__ import annotations

import jax.random as jr
from jaxtyping import PRNGKeyArray

from .motion import MotionCost
from .planners import DEFAULT_MIN_PER_STRATUM, Planner, make_planner
from .recipes import AUTO, THESIS, Recipe
from .recognizer import Recognizer

__all__ = ["make_recognizer", "MotionCostWithoutGeometry"]


class MotionCostWithoutGeometry(ValueError):
    """A motion cost λ > 0 asked of a rig without travel times (no geometry)."""


def make_recognizer(model, planner: str | Planner | None = None, *, recipe: Recipe = THESIS,
                    key: PRNGKeyArray | None = None, samples: int = 1024,
                    min_per_stratum: int = DEFAULT_MIN_PER_STRATUM, max_steps: int = 7,
                    transition: str = "uniform", rho: float = 0.9, shared_view: bool = False,
                    travel=None, motion_cost: float = 0.0) -> Recognizer:
    """The recognizer of ``model`` with ``planner`` and ``recipe``'s stop rule.

    Args:
        model: the :class:`~jaxrecog.sensor_model.SensorModel`.
        planner: a :class:`~jaxrecog.planners.Planner`, or a registry name
            built with :func:`~jaxrecog.planners.make_planner` (tables drawn
            from ``key``, default ``PRNGKey(0)``; ``samples`` and
            ``min_per_stratum`` the Monte Carlo sizes); ``None``: the
            recipe's planner.  ``mi-class-pairwise-stable`` takes the
            model's fitted weight (``SensorModel.stability``), else the
            recipe's ``stability`` when it is a number, else 1.
        recipe: the stop rule (:data:`~jaxrecog.recipes.STOP_FIELDS`:
            ``p_threshold``, ``min_views``, ``exclude_visited``,
            ``adaptive_scale``); default the thesis's, the recognizer's own
            defaults.  Its training parts are the model's business, not read here.
        max_steps, transition, rho, shared_view: the run's options
            (:class:`~jaxrecog.recognizer.Recognizer`).
        travel: per-camera travel-time tables of the rig
            (:func:`jaxrecog.motion.rig_travel_times`): the motion cost uses
            them and every result records its travel time; ``None`` (a rig
            without a geometry) allows only ``motion_cost = 0``
            (:class:`MotionCostWithoutGeometry` otherwise, before any planner
            table is drawn).
        motion_cost: λ >= 0, score units per second of rig motion.
    """
    if travel is None and motion_cost > 0:
        raise MotionCostWithoutGeometry(f"motion_cost = {motion_cost} needs the rig's travel times (its geometry); "
                                        "this rig has none (a replayed image database)")
    if planner is None or isinstance(planner, str):
        name = recipe.planner if planner is None else planner
        options = {}
        if (name == "mi-class-pairwise-stable" and getattr(model, "stability", None) is None
                and recipe.stability != AUTO):
            options["stability"] = float(recipe.stability)   # a model without its own weight: the recipe's
        planner = make_planner(name, model, key=jr.PRNGKey(0) if key is None else key, samples=samples,
                               min_per_stratum=min_per_stratum, **options)
    motion = None if travel is None else MotionCost(travel, motion_cost)
    return Recognizer(model, planner, p_threshold=recipe.p_threshold, max_steps=max_steps,
                      min_views=recipe.min_views, transition=transition, rho=rho,
                      exclude_visited_positions=recipe.exclude_visited, motion=motion,
                      shared_view=shared_view, adaptive_scale=recipe.adaptive_scale)
