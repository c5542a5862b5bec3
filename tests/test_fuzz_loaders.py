"""Fuzzed loaders: whatever bytes arrive, the manifest loader
raises only :class:`DatabaseError` and the model-file loader only a
:class:`ModelFileError` subclass, each with a short message whose problems are
one line each, and nothing hangs (every example has a deadline).

Random bytes, random mutations of a valid manifest / model file, truncations,
bit flips, and field mutations of a model file whose checksum is recomputed
(so the mutation reaches the checks behind the checksum).  Each crash the
fuzzer found is pinned with ``@example``.
"""

from __future__ import annotations

import io
import json
import shutil
import warnings
import zipfile

import numpy as np
import pytest
from builders import make_database
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from jaxrecog import train_model
from jaxrecog.database import DatabaseError, ImageDatabase, load_database, write_database
from jaxrecog.modelfile import ModelFileError, ModelFileVersionWarning, _content_hash, load_model, save_model
from jaxrecog.sensor_model import SensorModel

FUZZ = settings(max_examples=100, deadline=2000, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])


def _check_message(err: Exception) -> None:
    """Short, readable: a head line, at most 10 problems and a pointer, each one line."""
    lines = str(err).splitlines()
    assert 1 <= len(lines) <= 12, str(err)
    assert lines[0].strip(), str(err)
    assert all(len(l) <= 1000 and l.isprintable() for l in lines), str(err)
    for p in getattr(err, "problems", ()):
        assert "\n" not in p and "\r" not in p, p


# ---------------------------------------------------------------- manifests

@pytest.fixture(scope="module")
def db_folder(tmp_path_factory):
    root = tmp_path_factory.mktemp("fuzzdb")
    write_database(root, make_database(positions=(2, 1), n_objects=2, n_poses=2, image_shape=(8, 8), n_test=1))
    return root, (root / "manifest.csv").read_bytes()


def _load_manifest(root, raw: bytes) -> None:
    (root / "manifest.csv").write_bytes(raw)
    try:
        db = load_database(root)
    except DatabaseError as e:
        _check_message(e)
    else:
        assert isinstance(db, ImageDatabase) and db.n_rows >= 1


_HEADER = b"path,camera,position,object,pose,split\n"


@FUZZ
@given(raw=st.binary(max_size=600))
@example(raw=_HEADER + b"\n\n\n")  # blank rows only: ValueError from np.stack
@example(raw=_HEADER + b"a" * 300 + b".png,0,0,0,0,train\n")  # OSError: file name too long
@example(raw=_HEADER + b"cam0/pos000/obj0_pose0_train_0.png,0,0,0," + b"9" * 30 + b",train\n")  # OverflowError
@example(raw=_HEADER + b'"' + b"x" * 200_000 + b'",0,0,0,0,train\n')  # csv.Error: field larger than the limit
@example(raw=_HEADER + b"\x00.png,0,0,0,0,train\n")  # a NUL byte printed in the message
@example(raw=_HEADER + b'"a\nb.png",0,0,0,0,train\n')  # a quoted newline split a problem over two lines
def test_random_bytes_as_a_manifest(db_folder, raw):
    root, _ = db_folder
    _load_manifest(root, raw)


_TOKENS = ["", ",", '"', "\n", "\r\n", "\x00", "-1", "1e9", "99999999999999999999", "..", "/", "../x.png",
           "train", "test", "calib", "path", "camera", " ", "\ufeff", "é", "0x10", "1_0", "nan"]


@st.composite
def manifest_mutations(draw, valid: bytes):
    text = valid.decode()
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["insert", "delete", "replace", "dup_line", "drop_line", "field"]))
        i = draw(st.integers(0, len(text)))
        if op == "insert":
            text = text[:i] + draw(st.sampled_from(_TOKENS) | st.text(max_size=5)) + text[i:]
        elif op == "delete":
            text = text[:i] + text[i + draw(st.integers(1, 20)):]
        elif op == "replace":
            text = text[:i] + draw(st.sampled_from(_TOKENS)) + text[i + 1:]
        else:
            lines = text.split("\n")
            j = draw(st.integers(0, len(lines) - 1))
            if op == "dup_line":
                lines.insert(j, lines[j])
            elif op == "drop_line":
                del lines[j]
            else:
                fields = lines[j].split(",")
                k = draw(st.integers(0, len(fields) - 1))
                fields[k] = draw(st.sampled_from(_TOKENS) | st.text(max_size=8))
                lines[j] = ",".join(fields)
            text = "\n".join(lines)
    return text.encode("utf-8", "surrogatepass")


@FUZZ
@given(data=st.data())
def test_mutated_manifests(db_folder, data):
    root, valid = db_folder
    _load_manifest(root, data.draw(manifest_mutations(valid)))


def test_the_valid_manifest_still_loads(db_folder):
    root, valid = db_folder
    (root / "manifest.csv").write_bytes(valid)
    assert load_database(root).n_rows == 24


# ---------------------------------------------------------------- model files

@pytest.fixture(scope="module")
def model_file(tmp_path_factory):
    db = make_database(positions=(2,), n_objects=2, n_poses=2, image_shape=(8, 8))
    model = train_model(db, kind="DB1", n_components=2, samples_per_image=4)
    path = tmp_path_factory.mktemp("fuzzmodel") / "model.npz"
    save_model(path, model, manifest_sha256=db.manifest_sha256)
    return path, path.read_bytes()


def _load_model_bytes(path, raw: bytes) -> None:
    path.write_bytes(raw)
    try:
        with warnings.catch_warnings():  # a mutated format_version 1 loads, with a warning
            warnings.simplefilter("ignore", ModelFileVersionWarning)
            model = load_model(path)
    except ModelFileError as e:
        _check_message(e)
        assert str(path) in str(e).splitlines()[0]
    else:
        assert isinstance(model, SensorModel)


@FUZZ
@given(raw=st.binary(max_size=400))
@example(raw=b"PK\x03\x04")
@example(raw=b"PK\x03\x04" + b"\x00" * 100)
def test_random_bytes_as_a_model_file(model_file, raw):
    path, _ = model_file
    _load_model_bytes(path.with_name("random.npz"), raw)


@FUZZ
@given(cut=st.none() | st.integers(0, 10**5), flips=st.lists(st.tuples(st.integers(0, 10**5), st.integers(0, 7)),
                                                           max_size=8))
@example(cut=None, flips=[(3475, 1)])  # a flipped name in the zip directory: 3 kB of binary in the message
def test_truncated_and_bit_flipped_model_files(model_file, cut, flips):
    path, valid = model_file
    raw = bytearray(valid if cut is None else valid[: cut % len(valid)])
    for i, bit in flips:
        if raw:
            raw[i % len(raw)] ^= 1 << bit
    _load_model_bytes(path.with_name("damaged.npz"), bytes(raw))


_JSON = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**70), 2**70) | st.floats(allow_nan=False) | st.text(max_size=6),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=4),
    max_leaves=8,
)


_ARRAYS = [f"camera0.{f}" for f in ("mean_image", "basis", "eigenvalues", "mu", "var")]
_VERSIONS = [np.array(1), np.array(4), np.array([], np.int64), np.array("2"), np.array([2, 2]),
             np.array(2.5), np.array(2**40)]
_CHANGES = ["nan", "neg", "float64", "int32", "bool", "flat", "empty", "huge"]
_META_KEYS = ["n_cameras", "positions", "n_objects", "n_poses", "levels", "image_shape", "covariance",
              "likelihoods", "n_components", "calibrated", "content_sha256", "format_version"]

_OPS = st.lists(st.one_of(
    st.tuples(st.just("meta"), st.sampled_from(_META_KEYS),
              _JSON | st.sampled_from([0, -1, 10**9, [], [0], ["x"], "full", "diag", "Infinity"])),
    st.tuples(st.just("meta_whole"), _JSON),
    st.tuples(st.just("version"), st.integers(0, len(_VERSIONS) - 1)),
    st.tuples(st.just("array"), st.sampled_from(_ARRAYS), st.sampled_from(_CHANGES), st.integers(0, 10**6)),
    st.tuples(st.just("drop"), st.sampled_from(_ARRAYS)),
    st.tuples(st.just("add"), st.sampled_from(["camera0.mu", "camera1.var", "camera0.calibration", "x"])),
), min_size=1, max_size=3)


def _mutate(entries: dict[str, np.ndarray], ops, rehash: bool) -> bytes:
    """Apply the field mutations ``ops`` to a model file's entries; with
    ``rehash`` the content checksum is made to match the changed arrays."""
    out = dict(entries)
    meta = json.loads(bytes(out["meta"]).decode())
    for op, *args in ops:
        if op == "meta" and isinstance(meta, dict):
            key, value = args
            meta[key] = float("inf") if value == "Infinity" else value
        elif op == "meta_whole":
            meta = args[0]
        elif op == "version":
            out["format_version"] = _VERSIONS[args[0]]
        elif op == "drop":
            out.pop(args[0], None)
        elif op == "add":
            out[args[0]] = entries["camera0.var"]
        elif op == "array" and args[0] in out:
            key, change, i = args
            x = out[key]
            if change == "nan":
                x = x.copy()
                x.flat[i % x.size] = np.nan
            elif change == "neg":
                x = -np.abs(x)
            elif change in ("float64", "int32", "bool"):
                x = x.astype(change)
            elif change == "flat":
                x = x.reshape(-1)
            elif change == "empty":
                x = np.zeros((0,), np.float32)
            else:
                x = np.full_like(x, 3e38)
            out[key] = x
    if rehash and isinstance(meta, dict):
        meta["content_sha256"] = _content_hash({k: v for k, v in out.items() if k not in ("meta", "format_version")})
    out["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    buf = io.BytesIO()
    np.savez(buf, **out)
    return buf.getvalue()


@FUZZ
@given(ops=_OPS, rehash=st.booleans())
@example(ops=[("meta", "n_cameras", 0), ("version", 2)], rehash=False)  # empty format_version: IndexError
@example(ops=[("meta", "n_cameras", "Infinity")], rehash=True)  # int(inf): OverflowError
@example(ops=[("meta_whole", None)], rehash=False)  # metadata not an object: TypeError
def test_field_mutations_of_a_model_file(model_file, ops, rehash):
    path, valid = model_file
    with np.load(io.BytesIO(valid)) as npz:
        entries = {k: npz[k] for k in npz.files}
    _load_model_bytes(path.with_name("mutated.npz"), _mutate(entries, ops, rehash))


def test_the_valid_model_file_still_loads(model_file, tmp_path):
    path, valid = model_file
    shutil.copy(path, tmp_path / "copy.npz")
    assert isinstance(load_model(tmp_path / "copy.npz"), SensorModel)
    with zipfile.ZipFile(path) as z:
        assert "meta.npy" in z.namelist()
