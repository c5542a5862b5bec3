"""The campaign that ``test_soak`` kills and resumes: run here in the test and,
to be killed with SIGKILL, as ``python tests/soak_campaign.py MODEL STORE``
(this module imports only what the campaign needs, so a restart is cheap)."""

from __future__ import annotations

import sys
import time

import jax.random as jr
from builders import moving_database  # tests/ is this script's folder: first on sys.path

from jaxrecog.campaign import plan_trials, run_campaign
from jaxrecog.hardware import DatasetRig
from jaxrecog.modelfile import load_model
from jaxrecog.planners import make_planner
from jaxrecog.recognizer import Recognizer
from jaxrecog.results import TrialResult, TrialStore

TRIALS_PER_OBJECT = 16


class SlowRig(DatasetRig):
    """A capture takes 2 ms, as a camera's would: the kills land mid-campaign."""

    def capture(self):
        time.sleep(0.002)
        return super().capture()


def campaign(model_path, store_path=None) -> list[TrialResult]:
    """Random-planner campaign on :func:`builders.moving_database`'s
    test split, every seed fixed, resumable from ``store_path``."""
    model = load_model(model_path)
    rec = Recognizer(model, make_planner("random", model, key=jr.PRNGKey(0)), p_threshold=0.99)
    specs = plan_trials(model.n_objects, model.n_poses, rec.positions, TRIALS_PER_OBJECT, seed=3)
    return run_campaign(rec, SlowRig(moving_database(), split="test"), specs, key=jr.PRNGKey(1), batch=4,
                        seed=2, store=None if store_path is None else TrialStore(store_path))


if __name__ == "__main__":
    campaign(sys.argv[1], sys.argv[2])
