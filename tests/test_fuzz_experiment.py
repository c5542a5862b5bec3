"""Fuzzed experiment TOML files: whatever an experiment file holds,
``jaxrecog experiment FILE`` either gets through the settings validation (to
where the campaign would start: stubbed here, no campaign runs) or stops with
a one-line :class:`UsageError` or :class:`ValueError` (a problem list keeps
the project's rule: a head line, at most ten problems, a pointer), never
another exception type and never a traceback.

Files are generated from the Settings fields, the file's own keys (``case``,
``planners``, ``rig``, ``model``, a ``[settings]`` table) and stray keys,
with values of every TOML type (huge and negative integers, NaN and inf,
odd strings, arrays, tables), plus raw text mutations of a valid file.  The
run-time type checker is off (as for a user); each crash the fuzzer found is
pinned with ``@example``.
"""

from __future__ import annotations

import json
import math
import re

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from jaxrecog import campaigns as ex
from jaxrecog.cli import main
from jaxrecog.cli._common import UsageError
from jaxrecog.modelfile import ModelFileError

FUZZ = settings(max_examples=150, deadline=3000, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])

FIELDS = list(ex.Settings.FIELDS)
FILE_KEYS = ["case", "planners", "rig", "model"]


class Reached(Exception):
    """The settings were validated: the campaign would start here."""


@pytest.fixture(scope="module")
def stubbed(tmp_path_factory):
    """The campaign entry points raise :class:`Reached`; a tiny model file for 'model'."""
    from builders import random_sensor_model

    from jaxrecog import save_model

    root = tmp_path_factory.mktemp("fuzzexp")
    save_model(root / "m.npz", random_sensor_model(positions=(2,), n_objects=2, n_poses=1))

    def reached(*a, **k):
        raise Reached

    with pytest.MonkeyPatch.context() as mp:
        for name in ("run_case", "run_dataset", "prepare", "run_trace"):
            mp.setattr(ex, name, reached)
        yield root


def _key(k: str) -> str:
    return k if re.fullmatch(r"[A-Za-z0-9_-]+", k) else json.dumps(k)


def _value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v == math.inf else "-inf" if v == -math.inf else repr(v))
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_key(k)} = {_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(v)


def toml_text(entries: dict, table: dict | None = None) -> str:
    lines = [f"{_key(k)} = {_value(v)}" for k, v in entries.items()]
    if table is not None:
        lines += ["[settings]", *(f"{_key(k)} = {_value(v)}" for k, v in table.items())]
    return "\n".join(lines) + "\n"


_STRINGS = st.sampled_from(["", "i", "iii", "mi", "random", "gaussian-diag", "student-t", "uniform", "sticky",
                            "dataset:", "dataset:/nonexistent", "synthetic", "x" * 300, "é\u202e", "a\nb", "0",
                            "nan", "1e9", "../m.npz"]) | st.text(max_size=12)
_SCALARS = (st.integers(-3, 40) | st.sampled_from([0, -1, 2**31, 2**63 - 1, -(2**63)]) | st.booleans()
            | st.floats(allow_nan=True, allow_infinity=True) | _STRINGS)
_VALUES = st.recursive(_SCALARS, lambda inner: st.lists(inner, max_size=4)
                       | st.dictionaries(st.sampled_from(["nu", "rank", "x", ""]) | st.text(max_size=4), inner,
                                         max_size=3), max_leaves=6)


@st.composite
def experiment_files(draw, model_path: str) -> str:
    keys = st.sampled_from(FIELDS + FILE_KEYS) | st.text(min_size=1, max_size=8)
    entries = draw(st.dictionaries(keys, _VALUES, max_size=6))
    if draw(st.booleans()):  # mostly files that get past the case check
        entries.setdefault("case", draw(st.sampled_from(["i", "ii", "iii", "single-clean", "jitter"])))
    if draw(st.integers(0, 4)) == 0:  # a database campaign
        entries.pop("case", None)
        entries["rig"] = draw(st.sampled_from([f"dataset:{model_path}", "dataset:/nonexistent", "dataset:"]))
        entries["model"] = draw(st.sampled_from([model_path, "/nonexistent.npz"]) | _VALUES)
    table = draw(st.none() | st.dictionaries(keys, _VALUES, max_size=3))
    return toml_text(entries, table)


def _experiment(root, text: str | bytes) -> None:
    path = root / "e.toml"
    (path.write_bytes if isinstance(text, bytes) else path.write_text)(text)
    try:
        main(["experiment", str(path), "--out", str(root / "out"), "--debug"])
    except Reached:
        return
    except (UsageError, ValueError, ModelFileError) as e:
        lines = str(e).splitlines()
        assert 1 <= len(lines) <= 12 and lines[0].strip(), str(e)
        assert len(lines) == 1 or re.search(r"\d+ problems|problems\b|\(known", lines[0]), str(e)
        assert all(len(l) <= 1200 and l.isprintable() for l in lines), str(e)
        return
    # an exit code without an exception: argparse's own usage error (2)


_FOUND = [  # what the fuzzer found (each a TypeError deep in the run before)
    {"case": "iii", "planners": 3},                 # 'int' object is not iterable
    {"case": "iii", "samples": [1]},                # '<=' not supported between 'int' and 'list'
    {"case": "iii", "blur_sigma": [[0.0]]},         # float() argument must be ... not 'list'
    {"case": "iii", "workdir": [1]},                # expected str, bytes or os.PathLike object, not list
    {"case": "iii", "seed": 2**63 - 1 + 0, "samples": 0},
    {"case": "iii", "p_threshold": math.nan},
]


@pytest.mark.parametrize("entries", _FOUND)
def test_what_the_fuzzer_found(stubbed, unchecked, entries):
    path = stubbed / "e.toml"
    path.write_text(toml_text(entries))
    with unchecked(), pytest.raises((UsageError, ValueError)) as e:
        main(["experiment", str(path), "--out", str(stubbed / "out"), "--debug"])
    assert len(str(e.value).splitlines()) == 1, str(e.value)


@FUZZ
@given(data=st.data())
@example(data=None)
def test_generated_experiment_files(stubbed, unchecked, data):
    if data is None:  # the plain valid file reaches the campaign
        text = toml_text({"case": "iii", "trials_per_object": 2, "samples": 64})
        path = stubbed / "e.toml"
        path.write_text(text)
        with pytest.raises(Reached):
            main(["experiment", str(path), "--out", str(stubbed / "out"), "--debug"])
        return
    with unchecked():
        _experiment(stubbed, data.draw(experiment_files(str(stubbed / "m.npz"))))


_VALID = toml_text({"case": "iii", "planners": ["mi", "random"], "trials_per_object": 2, "samples": 64,
                    "likelihood": "student-t", "likelihood_options": {"nu": 5.0}, "blur_sigma": [0.0, 1.0]})
_TOKENS = ["", "=", "[", "]", "{", "}", '"', "\n", "nan", "inf", "-1", "99999999999999999999", "[settings]",
           "true", "0x10", "1e400", "\x00", "\\", ",", "#"]


@FUZZ
@given(ops=st.lists(st.tuples(st.integers(0, len(_VALID)), st.sampled_from(_TOKENS) | st.text(max_size=4),
                              st.integers(0, 6)), min_size=1, max_size=4))
def test_mutated_experiment_files(stubbed, unchecked, ops):
    text = _VALID
    for i, tok, cut in ops:
        text = text[:i] + tok + text[i + cut:]
    with unchecked():
        _experiment(stubbed, text.encode("utf-8", "surrogatepass"))
