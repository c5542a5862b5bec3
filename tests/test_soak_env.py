"""The env soak on the synthetic rig, short: ``tests/soak_env.py``
for 80 steps with a random agent and 80 with the MI policy (the hand-run
figures, 10,000 steps each, are in docs/results.md).  No NaN in any reward,
belief or feature; resident memory flat after the warm-up; one pybullet
client per live env, none left after ``close``."""

from __future__ import annotations

import pytest
from soak_env import pybullet_clients, soak, train

STEPS = 80


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    return train(tmp_path_factory.mktemp("soak-env") / "db")


@pytest.mark.parametrize("policy", ["random", "mi"])
def test_env_soak_on_the_synthetic_rig(model, policy):
    before = pybullet_clients()
    r = soak(model, policy, STEPS)
    print(r)
    assert r["nan_steps"] == 0
    assert r["episodes"] >= 10
    if policy == "mi":
        assert 0 < r["declared"] < r["episodes"]   # both ends: declared and run to max_steps
    c = r["pybullet_clients"]
    assert c["while_live"] == c["before"] + 1 and c["at_resets"] == [c["before"] + 1]
    assert c["after_close"] == c["before"] == before
    assert r["rss_growth_after_warmup"] < 0.05, r["rss_mb"]
