"""A trial store is read back only as the trials of the run it was written
for: its header names the run (settings, planner, digests of the model and
the data) and every record is checked against the run's limits.  Before,
a second record of one trial, ``steps: 1000`` (max 7), ``correct: true`` for
a wrong answer, or a store of a ``--threshold 0.5`` run renamed to the
default run's name were all read and changed the tables."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from jaxrecog.campaigns import Settings
from jaxrecog.campaigns.stores import campaign_store, database_sha256, file_sha256, model_sha256
from jaxrecog.results import TrialResult, TrialStore
from jaxrecog.trial_checks import store_header

LIMITS = {"max_steps": 7, "p_threshold": 0.95, "min_views": 1, "n_objects": 2, "n_poses": 3, "positions": [3],
          "trials_per_object": 4}
HEADER = store_header({"planner": "mi", "settings": {"p_threshold": 0.95}, "model_sha256": "ab"}, LIMITS)


def _trial(trial=0, obj=0, pose=1, predicted=None, steps=2, p=0.97, stopped=True):
    predicted = obj if predicted is None else predicted
    return TrialResult(trial, obj, pose, predicted, pose, p, steps, stopped, ((0.0,),) * steps, ((1,),) * steps)


def _write(path, *lines) -> None:
    path.write_text("".join((line if isinstance(line, str) else json.dumps(line)) + "\n" for line in lines))


def _record(**change) -> dict:
    d = json.loads(_trial().to_json())
    d.update(change)
    return d


def test_a_store_writes_its_header_first_and_reads_back_its_trials(tmp_path):
    store = TrialStore(tmp_path / "t.jsonl", header=HEADER)
    store.extend([_trial(0), _trial(5, obj=1, steps=7, p=0.5, stopped=False)])
    store.append(_trial(1))
    first, *rest = store.path.read_text().splitlines()
    assert json.loads(first) == HEADER and len(rest) == 3
    assert sorted(TrialStore(store.path, header=HEADER).load()) == [0, 1, 5]
    assert sorted(TrialStore(store.path).load()) == [0, 1, 5]   # read without a run: its own header's limits


@pytest.mark.parametrize("record, needle", [
    (_record(steps=1000, configurations=[[1]] * 1000, occluded_fraction=[[0.0]] * 1000),
     "steps = 1000 exceeds max_steps = 7"),
    (_record(predicted_object=1), r"correct = true, but it predicted object 1 pose 1 for object 0 pose 1"),
    (_record(object=5, predicted_object=5), "object = 5, but the model has 2"),
    (_record(trial=6), "trial 6 is not one of object 0's"),
    (_record(exit_prob=0.6), r"stopped on the threshold at exit_prob = 0.6 < p_threshold = 0.95"),
    (_record(stopped=False), "ended below the threshold after 2 of max_steps = 7"),
    (_record(configurations=[[1], [3]]), r"configuration \[3\] of step 2 is not one of positions \[3\]"),
    (_record(steps=3), "configurations has 2 entries for 3 steps"),
])
def test_a_record_outside_the_runs_limits_is_refused_naming_file_and_line(tmp_path, record, needle):
    path = tmp_path / "t.jsonl"
    _write(path, HEADER, _trial(1).to_json(), record)
    with pytest.raises(ValueError, match=rf"^{path}: line 3 \(trial \d+\): {needle}.*move the file away") as e:
        TrialStore(path, header=HEADER).load()
    assert "\n" not in str(e.value)
    assert path.read_text().count("\n") == 3   # refused, not cut


def test_a_second_record_of_one_trial_is_refused(tmp_path):
    path = tmp_path / "t.jsonl"
    _write(path, HEADER, _trial(0).to_json(), _trial(1).to_json(), _trial(0, predicted=1).to_json())
    with pytest.raises(ValueError, match=rf"^{path}: line 4 records trial 0 again \(first on line 2\)"):
        TrialStore(path, header=HEADER).load()
    # without a header too: "correct" checked and one record per trial, whatever the run
    _write(path, _trial(0).to_json(), _trial(0).to_json())
    with pytest.raises(ValueError, match="line 2 records trial 0 again"):
        TrialStore(path).load()
    _write(path, _record(predicted_object=1))
    with pytest.raises(ValueError, match="line 1 .trial 0.: correct = true, but"):
        TrialStore(path).load()


def test_another_runs_store_under_this_runs_name_is_refused(tmp_path):
    """A ``--threshold 0.5`` run's store renamed to the default run's name."""
    half = store_header({"planner": "mi", "settings": {"p_threshold": 0.5}, "model_sha256": "ab"},
                        LIMITS | {"p_threshold": 0.5})
    path = tmp_path / "t.jsonl"
    TrialStore(path, header=half).append(_trial(0, p=0.6))
    with pytest.raises(ValueError, match=rf"^{path}: line 1 \(the store's header\) records limits.p_threshold = 0.5, "
                                         r"this run has 0.95: the trials of another run"):
        TrialStore(path, header=HEADER).load()
    # a store written before headers (or by hand) cannot be checked against the run: refused too
    _write(path, _trial(0).to_json())
    with pytest.raises(ValueError, match="line 1 is a trial record, not the store's header"):
        TrialStore(path, header=HEADER).load()


def test_campaign_stores_are_keyed_by_settings_model_and_data(tmp_path, moving_model):
    db, model = moving_model
    settings = Settings(workdir=tmp_path, trials_per_object=4)
    a = campaign_store(settings, "s", "mi", model, {"database_sha256": database_sha256(db)})
    a.append(dataclasses.replace(_trial(0, pose=1), configurations=((1,), (2,))))
    assert sorted(campaign_store(settings, "s", "mi", model, {"database_sha256": database_sha256(db)}).load()) == [0]
    redrawn = dataclasses.replace(db, images=255 - db.images)   # re-rendered in place: same manifest
    assert redrawn.manifest_sha256 == db.manifest_sha256 and database_sha256(redrawn) != database_sha256(db)
    for other, content in [(dataclasses.replace(settings, p_threshold=0.5), database_sha256(db)),
                           (settings, database_sha256(redrawn))]:
        with pytest.raises(ValueError, match="the store's header.* records "):
            campaign_store(other, "s", "mi", model, {"database_sha256": content}).load()
    import equinox as eqx

    nudged = eqx.tree_at(lambda m: m.cameras[0].likelihood.mu, model, model.cameras[0].likelihood.mu * 1.001)
    assert model_sha256(nudged) != model_sha256(model) == model_sha256(model)
    f = tmp_path / "bytes.bin"
    f.write_bytes(np.arange(3_000_000, dtype=np.uint8).tobytes())
    import hashlib

    assert file_sha256(f) == hashlib.sha256(f.read_bytes()).hexdigest()
