"""Planner Monte Carlo size: samples per state stratum, with a floor."""

from __future__ import annotations

from types import SimpleNamespace

import jax.random as jr
import pytest

from jaxrecog import train_model
from jaxrecog.experiments import Settings
from jaxrecog.planners import make_planner, samples_per_stratum
from jaxrecog.testing import moving_database


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
def test_make_planner_builds_tables_with_the_floor(name):
    db = moving_database()
    model = train_model(db, kind="DB1", n_components=2, samples_per_image=10)
    strata = model.n_objects * model.n_poses
    p = make_planner(name, model, key=jr.PRNGKey(0), samples=strata, min_per_stratum=3)
    assert p.tables.ld_self[0].shape[3] == 3
    p1 = make_planner(name, model, key=jr.PRNGKey(0), samples=strata)
    assert p1.tables.ld_self[0].shape[3] == 1
    # planners without tables accept (and ignore) the option
    assert make_planner("random", model, key=jr.PRNGKey(0), min_per_stratum=3).n_configs == p.n_configs
