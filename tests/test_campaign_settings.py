"""``campaigns.Settings`` is a recipe and the run's options, while
every setting keeps its flat name: the configuration dialect, ``--print-config``,
the reports' JSON and the run ids read the same 36 names as before, and
``cluster`` (where a campaign runs) after ``render_workers``."""

from __future__ import annotations

import dataclasses

import pytest

from jaxrecog.campaigns import Settings
from jaxrecog.recipes import ROBUST, THESIS

#: the flat names, in the order main's flat Settings declared them (the dialect's order), and ``cluster``
MAIN_FIELDS = (
    "workdir", "trials_per_object", "seed", "samples", "min_per_stratum", "batch", "n_components",
    "samples_per_image", "p_threshold", "max_steps", "capture_noise", "transition", "stride", "min_views",
    "exclude_visited_positions", "adaptive_scale", "shared_view", "motion_cost", "devices", "render_workers",
    "cluster", "off_grid_deg", "off_grid_eye", "off_grid_light", "likelihood", "likelihood_options", "max_rotation",
    "max_scale", "blur_sigma", "gain_amplitude", "gain_cells", "occluder_gray", "max_shift", "view_jitter",
    "view_jitter_deg", "interpolate", "interpolation",
)


def test_the_flat_names_are_mains_in_mains_order():
    assert Settings.FIELDS == MAIN_FIELDS
    assert tuple(Settings().flat()) == MAIN_FIELDS
    assert {f.name for f in dataclasses.fields(Settings)} == set(MAIN_FIELDS) - {
        "p_threshold", "min_views", "exclude_visited_positions", "adaptive_scale", "likelihood",
        "likelihood_options", "max_shift", "interpolate", "interpolation", "occluder_gray"} | {"recipe"}


def test_the_recipe_parts_live_in_the_recipe():
    s = Settings(p_threshold=0.9, exclude_visited_positions=True, likelihood="gaussian-lowrank",
                 likelihood_options={"rank": 2}, trials_per_object=3)
    assert s.recipe == THESIS.replace(p_threshold=0.9, exclude_visited=True, likelihood="gaussian-lowrank",
                                      likelihood_options=(("rank", 2),))
    assert (s.p_threshold, s.exclude_visited_positions, s.likelihood_options) == (0.9, True, (("rank", 2),))
    assert Settings().recipe == THESIS and Settings().flat()["likelihood"] == "gaussian-diag"


def test_a_recipe_gives_the_defaults_and_flat_names_override_them():
    s = Settings(recipe=ROBUST, p_threshold=0.9)
    assert s.recipe.name == "robust" and s.p_threshold == 0.9
    assert (s.likelihood, s.interpolate, s.interpolation, s.min_views, s.adaptive_scale) == (
        "view-mixture-lowrank", 2, "flow", 2, 32.0)
    assert s.exclude_visited_positions and s.recipe.planner == ROBUST.planner
    assert s.occluder_gray == (0.0, 255.0) and Settings().occluder_gray == (0.0, 0.0)    # robust: gray occluders
    assert Settings(recipe=ROBUST, occluder_gray=[0, 0]).recipe.occluder_gray == (0.0, 0.0)


def test_replace_keeps_the_recipe_and_changes_a_flat_name():
    s = Settings(recipe=ROBUST, trials_per_object=2)
    t = dataclasses.replace(s, min_views=3, off_grid_deg=4)
    assert t.recipe == ROBUST.replace(min_views=3, likelihood_options=s.likelihood_options)
    assert (t.min_views, t.off_grid_deg, t.trials_per_object) == (3, 4.0, 2)
    assert dataclasses.replace(t) == t and hash(dataclasses.replace(t)) == hash(t)


def test_bad_input_names_the_flat_setting():
    with pytest.raises(ValueError, match=r"^p_threshold must be a probability in \(0, 1\], got 2$"):
        Settings(p_threshold=2)
    with pytest.raises(ValueError, match="^min_views must be an integer"):
        Settings(min_views=0)
    with pytest.raises(TypeError, match="unexpected keyword argument 'exclude_visited'"):
        Settings(exclude_visited=True)  # the recipe's name of the part is not a setting
    with pytest.raises(TypeError):
        Settings("out/work")  # noqa: the recipe and every setting are keywords


def test_a_trial_count_past_the_maximum_is_refused_before_any_spec_is_drawn():
    """``--trials 1000000000`` drew every trial's spec up front (gigabytes, no
    trial started); now the count is refused at once, naming the maximum."""
    import time

    from jaxrecog.campaign import MAX_TRIALS, plan_trials

    with pytest.raises(ValueError, match=rf"^trials_per_object must be in \[1, {MAX_TRIALS}\].*got 1000000000$"):
        Settings(trials_per_object=1_000_000_000)
    assert Settings(trials_per_object=MAX_TRIALS).trials_per_object == MAX_TRIALS
    t0 = time.perf_counter()
    with pytest.raises(ValueError, match=rf"8 objects x 12501 trials per object: a campaign runs 1 to {MAX_TRIALS}"):
        plan_trials(8, 4, (4, 1), MAX_TRIALS // 8 + 1)
    assert time.perf_counter() - t0 < 0.5   # refused before drawing
    assert len(plan_trials(2, 4, (4, 1), 3)) == 6
