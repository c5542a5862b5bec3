"""Planner Monte Carlo size: samples per state stratum, with a floor."""

from __future__ import annotations

from types import SimpleNamespace

import jax.numpy as jnp
import jax.random as jr
import pytest

from jaxrecog.campaigns import Settings
from jaxrecog.planners import DEFAULT_MIN_PER_STRATUM, PLANNERS, make_planner, planner_names, planner_spec, planners_markdown, samples_per_stratum


def _sizes(objects=8, poses=4, levels=6, cameras=2):
    return SimpleNamespace(n_objects=objects, n_poses=poses, levels=tuple(range(levels)), cameras=(None,) * cameras)


def test_samples_per_stratum_rounds_up_and_floors():
    db2 = _sizes()  # thesis DB2: 32 classes x 6 x 6 levels = 1152 strata
    assert samples_per_stratum(db2, 1024) == 1
    assert samples_per_stratum(db2, 1153) == 2
    assert samples_per_stratum(db2, 1024, min_per_stratum=8) == 8
    assert samples_per_stratum(db2, 8 * 1152 + 1, min_per_stratum=8) == 9
    db1 = _sizes(levels=1)  # 32 strata: the floor does not bind
    assert samples_per_stratum(db1, 1024, min_per_stratum=8) == 32
    single = _sizes(cameras=1)
    assert samples_per_stratum(single, 1024) == 6
    for bad in ((0, 1), (1024, 0)):
        with pytest.raises(ValueError, match="must be >= 1"):
            samples_per_stratum(db2, *bad)


def test_campaign_default_floor_is_eight():
    assert Settings().min_per_stratum == 8


@pytest.mark.parametrize("name", ["mi", "mi-class", "crlb"])
def test_make_planner_builds_tables_with_the_floor(name, moving_model):
    _, model = moving_model
    strata = model.n_objects * model.n_poses
    p = make_planner(name, model, key=jr.PRNGKey(0), samples=strata, min_per_stratum=3)
    assert p.tables.ld_self[0].shape[3] == 3
    p1 = make_planner(name, model, key=jr.PRNGKey(0), samples=strata, min_per_stratum=1)
    assert p1.tables.ld_self[0].shape[3] == 1
    # the default floor is the campaigns' (one definition, DEFAULT_MIN_PER_STRATUM = 8)
    p8 = make_planner(name, model, key=jr.PRNGKey(0), samples=strata)
    assert p8.tables.ld_self[0].shape[3] == DEFAULT_MIN_PER_STRATUM == 8
    # planners without tables accept (and ignore) the option
    assert make_planner("random", model, key=jr.PRNGKey(0), min_per_stratum=3).n_configs == p.n_configs


# -- the registry: one mapping feeds make_planner, the CLI, the docs and the thesis lookup


def test_registry_names_are_the_choices_and_every_entry_builds(getkey, moving_model):
    _, model = moving_model
    assert planner_names() == tuple(PLANNERS)
    assert {"mi", "mi-class", "crlb", "crlb-det", "crlb-eig", "random", "fixed"} <= set(PLANNERS)
    prior_free = {"random", "fixed"}
    for name, spec in PLANNERS.items():
        p = make_planner(name, model, key=getkey(), samples=8, min_per_stratum=1)
        assert p.n_configs == 3  # the moving database: one camera, 3 positions
        assert spec.description and "\n" not in spec.description
        assert (name in prior_free) == (not hasattr(p, "tables"))


def test_registry_thesis_keys_name_real_thesis_tables():
    from jaxrecog.thesis import TABLES

    columns = {planner for (_, planner) in TABLES}
    for name, spec in PLANNERS.items():
        assert spec.thesis is None or spec.thesis in columns, name
    assert planner_spec("mi-class").thesis == "mi" and planner_spec("crlb-det").thesis == "crlb"
    assert planner_spec("fixed").thesis is None


def test_aliases_and_unknown_names():
    assert planner_spec("mi-state") is PLANNERS["mi"]
    assert planner_spec("crlb-trace") is PLANNERS["crlb"]
    with pytest.raises(ValueError, match="unknown planner 'nope'; choose one of mi, mi-class"):
        planner_spec("nope")


def test_a_new_planner_is_one_registry_entry(getkey, monkeypatch, moving_model):
    """Registering an entry is all it takes for make_planner to build it."""
    from jaxrecog import planners as P

    _, model = moving_model
    entry = P.PlannerSpec(lambda m, *, key, samples, min_per_stratum: P.FixedPlanner(P._n_configs(m), 2), None, "test")
    monkeypatch.setitem(P.PLANNERS, "always-three", entry)
    assert "always-three" in planner_names()
    p = make_planner("always-three", model, key=getkey())
    assert int(jnp.argmax(p.scores(None, getkey()))) == 2


def test_planners_doc_is_generated_from_the_registry():
    from pathlib import Path

    doc = Path(__file__).resolve().parents[1] / "docs" / "planners.md"
    assert doc.read_text() == planners_markdown(), "docs/planners.md is stale: run scripts/gen_cli_docs.py"
    for name in PLANNERS:
        assert f"`{name}`" in doc.read_text()
