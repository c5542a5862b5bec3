"""Fuzzed ``--config`` settings files: whatever the file holds (any table, key
and TOML value; raw byte mutations of a valid file, invalid UTF-8 included),
``jaxrecog --config FILE COMMAND`` either takes the settings (and goes on to
the command, which stops at its missing input) or stops with exit code 2 and
one ``error:`` line naming the file, never a traceback and never another
exception.  The fuzzer's finds are pinned with ``@example``.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import re

from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from jaxrecog.cli import main

FUZZ = settings(max_examples=12, deadline=3000, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])

TABLES = ["global", "recognize", "plan", "inspect", "train"]
KEYS = ["quiet", "debug", "max_steps", "object", "pose", "threshold", "planner", "start", "samples", "seed",
        "plot", "occluders", "noise", "cameras", "objects", "min_views", "motion_cost", "kind", "components"]


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
    return "{" + ", ".join(f"{_key(k)} = {_value(x)}" for k, x in v.items()) + "}"


_SCALARS = (st.integers(-3, 40) | st.sampled_from([0, -1, 2**63 - 1]) | st.booleans()
            | st.floats(allow_nan=True, allow_infinity=True)
            | st.sampled_from(["", "mi", "random", "3,2", "x" * 300, "a\nb", "random:2", "nan"]) | st.text(max_size=8))
_VALUES = st.recursive(_SCALARS, lambda inner: st.lists(inner, max_size=3)
                       | st.dictionaries(st.text(max_size=4), inner, max_size=2), max_leaves=5)


@st.composite
def settings_files(draw) -> str:
    tables = draw(st.dictionaries(st.sampled_from(TABLES) | st.text(min_size=1, max_size=6),
                                  st.dictionaries(st.sampled_from(KEYS) | st.text(min_size=1, max_size=6), _VALUES,
                                                  max_size=4), max_size=3))
    return "".join(f"[{_key(t)}]\n" + "".join(f"{_key(k)} = {_value(v)}\n" for k, v in kv.items())
                   for t, kv in tables.items())


def _run(path, data: bytes) -> None:
    path.write_bytes(data)
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        code = main(["--config", str(path), "recognize", str(path.with_name("absent.npz"))])
    lines = err.getvalue().splitlines()
    assert "Traceback" not in err.getvalue()
    errors = [l for l in lines if "error:" in l]
    assert code in (1, 2) and len(errors) == 1, err.getvalue()
    if code == 2 and "absent.npz" not in errors[0]:  # the settings file's own problem: named
        assert str(path) in errors[0] or "settings file" in errors[0], errors[0]
    assert all(l.isprintable() and len(l) <= 1200 for l in lines), err.getvalue()


@FUZZ
@given(text=settings_files())
@example(text="[recognize]\nmax_steps = 0\n")
@example(text="[recognize]\nstart = [[1]]\n")
@example(text="[recognize]\nobjects = {a = 1}\n")
@example(text="[global]\nquiet = 3\n[recognize]\nplot = 1\n")
def test_generated_settings_files(tmp_path_factory, text):
    _run(tmp_path_factory.mktemp("cfg") / "c.toml", text.encode("utf-8", "surrogatepass"))


_VALID = b'[global]\nquiet = true\n\n[recognize]\nmax_steps = 3\nplanner = "random"\nstart = [1, 0]\n'
_TOKENS = [b"", b"=", b"[", b"]", b'"', b"\n", b"\xff", b"\xc3", b"\x00", b"nan", b"-1", b"1e400", b"[[", b"{"]


@FUZZ
@given(ops=st.lists(st.tuples(st.integers(0, len(_VALID)), st.sampled_from(_TOKENS) | st.binary(max_size=3),
                              st.integers(0, 4)), min_size=1, max_size=4))
@example(ops=[(20, b"\xff", 0)])
def test_mutated_settings_files(tmp_path_factory, ops):
    data = _VALID
    for i, tok, cut in ops:
        data = data[:i] + tok + data[i + cut:]
    _run(tmp_path_factory.mktemp("cfg") / "c.toml", data)
