"""Fuzzed trial-store reader: whatever a store's bytes, :meth:`TrialStore.load`
returns trials that keep the run's limits or raises one ``ValueError`` of one
printable line naming the file, and nothing else escapes (in the style of
``tests/test_fuzz_loaders.py``; a few examples each, no JAX)."""

from __future__ import annotations

import json

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from jaxrecog.results import TrialResult, TrialStore
from jaxrecog.trial_checks import record_problem, store_header

FUZZ = settings(max_examples=20, deadline=2000, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])

LIMITS = {"max_steps": 7, "p_threshold": 0.95, "min_views": 1, "n_objects": 2, "n_poses": 3, "positions": [3, 2],
          "trials_per_object": 4}
HEADER = store_header({"planner": "mi", "settings": {"seed": 0}, "model_sha256": "ab"}, LIMITS)
GOOD = [TrialResult(t, t // 4, 1, t // 4, 1, 0.97, 2, True, ((0.0, 0.1),) * 2, ((1, 0), (2, 1))) for t in (0, 1, 5)]

_scalar = st.none() | st.booleans() | st.integers(-2**70, 2**70) | st.floats() | st.text(max_size=8)
_json = (_scalar | st.lists(_scalar | st.lists(_scalar, max_size=3), max_size=9)
         | st.dictionaries(st.text(max_size=6), _scalar, max_size=3))
_FIELDS = ["trial", "object", "pose", "predicted_object", "predicted_pose", "exit_prob", "steps", "stopped",
           "occluded_fraction", "configurations", "object_probs", "invalid_steps", "travel_s", "yaw_offset", "correct"]


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzzstore")


def _load(path, raw: bytes, header) -> None:
    path.write_bytes(raw)
    try:
        got = TrialStore(path, header=header).load()
    except ValueError as e:
        text = str(e)
        assert text.startswith(f"{path}: ") and "\n" not in text and text.isprintable() and len(text) < 1500, text
    else:   # what is read back keeps the limits: never a record the run could not have made
        for rec in got.values():
            assert isinstance(rec, TrialResult) and record_problem({}, rec, LIMITS if header else None) is None


@FUZZ
@given(raw=st.binary(max_size=400), with_header=st.booleans())
def test_random_bytes_as_a_store(folder, raw, with_header):
    _load(folder / "random.jsonl", raw, HEADER if with_header else None)


@FUZZ
@example(line=0, field="trial", value={"\ud7fc": False}, with_header=True, cut=0)  # a key printed unescaped
@given(line=st.integers(0, 3), field=st.sampled_from(_FIELDS), value=_json, with_header=st.booleans(),
       cut=st.integers(0, 40))
def test_a_mutated_field_of_a_valid_store(folder, line, field, value, with_header, cut):
    lines = [json.loads(json.dumps(HEADER))] + [json.loads(r.to_json()) for r in GOOD]
    target = lines[line] if line else lines[0].setdefault("limits", {})
    target[field] = value
    text = "".join(json.dumps(x) + "\n" for x in lines).encode()
    _load(folder / "mutated.jsonl", text[:len(text) - cut], HEADER if with_header else None)
