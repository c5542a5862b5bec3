"""Fuzzed rig files: whatever a rig TOML holds, :func:`load_config` either
returns a :class:`RigConfig` or raises :class:`ConfigError` -- never another
exception -- with one line that starts with the file's name; nothing hangs
(every example has a deadline).

Random text and bytes, and random mutations (a value replaced by one of another
type or out of range, a key dropped or added, a table replaced by a scalar) of two
valid files: the simulated example and a hardware rig.  Like the manifest and
model-file fuzzers of ``test_fuzz_loaders.py``; each crash the fuzzer found is
pinned with ``@example``.
"""

from __future__ import annotations

import datetime
import json
import math
import tomllib

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from jaxrecog.hardware.physical.config import ConfigError, RigConfig, load_config

FUZZ = settings(max_examples=120, deadline=2000, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])

with open("examples/simulated_rig.toml", "rb") as f:
    SIMULATED = tomllib.load(f)
HARDWARE = {
    "kind": "hardware", "image_shape": [120, 160], "n_poses": 4,
    "controller": {"host": "192.168.0.20", "port": 5005, "timeout_s": 0.25, "retries": 5, "max_motion_s": 600.0,
                   "protocol_version": 2},
    "ptu": [{"port": "/dev/ttyUSB0", "baudrate": 9600, "timeout_s": 0.5, "pan_zero_deg": -22.5, "tilt_zero_deg": -45.0,
             "pan_sign": 1, "speed_deg_s": 50.0, "driver": "ptu-d46", "reconnect_s": 10.0, "homing_timeout_s": 30.0},
            {"port": "/dev/ttyUSB1", "pan_zero_deg": -90.0, "pan_sign": -1, "tilt_range_deg": [-46.6, 31.1]}],
    "camera": [{"source": 0, "kind": "video", "retries": 3, "black_level": 0, "reconnect_s": 5.0}, {"source": 1}],
    "table": {"camera1": [[0, 30], [45, 30], [90, 45]], "camera2": [-60, 0, 60],
              "workspace": {"object_xyz": [0.0, 0.0, 0.1], "cam1_z": 0.7, "tilt1_range_deg": [10, 89]}},
    "motion": {"gantry_m_s": 0.25, "track_m_s": 0.25, "ptu_deg_s": 300.0},
}


def toml_value(v) -> str:
    """A TOML value (inline tables and arrays), written independently of the loader."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        r = repr(v)
        return r if any(c in r for c in ".en") else r + ".0"
    if isinstance(v, str):
        return json.dumps(v)  # \uXXXX escapes are TOML escapes too
    if isinstance(v, (datetime.date, datetime.time)):
        return v.isoformat()
    if isinstance(v, list):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{json.dumps(str(k))} = {toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(type(v))


def to_toml(d: dict) -> str:
    return "".join(f"{json.dumps(str(k))} = {toml_value(v)}\n" for k, v in d.items())


def test_the_writer_round_trips_both_files():
    for d in (SIMULATED, HARDWARE):
        assert tomllib.loads(to_toml(d)) == d


def check(path, text: str | bytes) -> None:
    if isinstance(text, str):
        path.write_text(text, encoding="utf-8", errors="surrogatepass")
    else:
        path.write_bytes(text)
    try:
        cfg = load_config(path)
    except ConfigError as e:
        msg = str(e)
        assert msg.startswith(f"{path}: "), msg
        assert "\n" not in msg and "\r" not in msg and len(msg) <= 700 and msg.isprintable(), msg
    else:
        assert isinstance(cfg, RigConfig)


@FUZZ
@given(raw=st.binary(max_size=300))
@example(raw=b"\xff\xfe")  # not UTF-8 (tomllib raised UnicodeDecodeError)
@example(raw=b"a = " + b"[" * 2000)  # nested past the recursion limit
def test_random_bytes_as_a_rig_file(tmp_path, raw):
    check(tmp_path / "rig.toml", raw)


@FUZZ
@given(text=st.text(alphabet=st.sampled_from(list('[]{}="\',.#\n kindptucamerotlsimfauxyz0123456789-+_e')),
                    max_size=200))
def test_random_text_as_a_rig_file(tmp_path, text):
    check(tmp_path / "rig.toml", text)


VALUES = st.one_of(
    st.none(),  # (drop the key)
    st.booleans(),
    st.integers(-2**63, 2**63 - 1),
    st.sampled_from([0, 1, -1, 2, 3, 65535, 65536, 2**31, 10**9]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, 1e-300, 1e300, -1.0, 0.5, 89.9, 90.0, 180.0, 400.0]),
    st.text(max_size=12),
    st.sampled_from(["", "hardware", "simulated", "video", "sequence", "ptu-d46", "this:Nope", "/dev/ttyUSB0",
                     "inf", "rig.key"]),
    st.just(datetime.date(2026, 12, 3)),
    st.lists(st.floats(allow_nan=True, allow_infinity=True) | st.integers(-10**6, 10**6), max_size=4),
    st.lists(st.lists(st.integers(-400, 400), max_size=3), max_size=3),
    st.dictionaries(st.sampled_from(["port", "x", "camera1", "timeout_s"]), st.integers(-5, 5), max_size=2),
    st.just([{}]),
    st.just([[]]),
)


def _paths(d, prefix=()):
    """Every (path to a container, key) in a parsed TOML document."""
    items = d.items() if isinstance(d, dict) else enumerate(d)
    for k, v in items:
        yield prefix, k
        if isinstance(v, (dict, list)):
            yield from _paths(v, prefix + (k,))


def _mutate(doc, data):
    doc = json.loads(json.dumps(doc))
    for _ in range(data.draw(st.integers(1, 3), label="mutations")):
        paths = list(_paths(doc))
        if not paths:
            break
        where, key = data.draw(st.sampled_from(paths), label="at")
        parent = doc
        for k in where:
            parent = parent[k]
        if isinstance(parent, dict) and data.draw(st.booleans(), label="new key"):
            key = data.draw(st.sampled_from(["colour", "key", "port", "faults", "workspace", "ptu"]), label="name")
        value = data.draw(VALUES, label="value")
        if value is None:
            if isinstance(parent, dict):
                parent.pop(key, None)
            elif len(parent) > 1:
                parent.pop(key)
        else:
            parent[key] = value
    return doc


@FUZZ
@given(base=st.sampled_from(["simulated", "hardware"]), data=st.data())
def test_mutated_rig_files(tmp_path, base, data):
    doc = _mutate(SIMULATED if base == "simulated" else HARDWARE, data)
    check(tmp_path / "rig.toml", to_toml(doc))


@pytest.mark.parametrize("doc", [SIMULATED, HARDWARE], ids=["simulated", "hardware"])
def test_the_valid_files_still_load(tmp_path, doc):
    path = tmp_path / "rig.toml"
    path.write_text(to_toml(doc))
    cfg = load_config(path)
    assert cfg.kind == doc["kind"] and cfg.table.positions[0] == len(doc["table"]["camera1"])
