"""Every error that lists problems follows one rule: the
count, the first ten one per line, and where the rest are
(:func:`jaxrecog.problems.problem_message`)."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest

from jaxrecog._config import ConfigFileError, section
from jaxrecog.problems import DEBUG_HINT


def _shape(msg: str, n: int) -> list[str]:
    lines = msg.splitlines()
    assert lines[0].endswith(f"{n} problems"), msg
    assert len(lines) == 12 and lines[-1].strip().startswith(f"... {n - 10} more"), msg
    return [l.strip() for l in lines[1:11]]


def test_a_settings_table_with_many_unknown_options():
    table = {f"opt-{i:02d}": i for i in range(14)} | {"kind": "DB1"}
    with pytest.raises(ConfigFileError) as e:
        section({"train": table}, "train", {"kind"}, "s.toml")
    # each problem names its table
    assert _shape(str(e.value), 14) == [f"[train]: unknown key 'opt-{i:02d}'" for i in range(10)]
    assert DEBUG_HINT in str(e.value)
    assert section({"train": {"kind": "DB1"}}, "train", {"kind"}, "s.toml") == {"kind": "DB1"}


def test_a_model_file_with_many_unexpected_arrays(tmp_path):
    from jaxrecog import train_model
    from jaxrecog.modelfile import ModelFileContentError, _content_hash, load_model, save_model
    from builders import make_database

    path = save_model(tmp_path / "m.npz", train_model(make_database(positions=(2,), n_objects=1, n_poses=2,
                                                                    image_shape=(8, 8)),
                                                      n_components=1, samples_per_image=2))
    with np.load(path) as npz:
        entries = {k: npz[k] for k in npz.files}
    for i in range(12):
        entries[f"extra{i:02d}"] = np.zeros(1, np.float32)
    meta = json.loads(bytes(entries["meta"]).decode())
    meta["content_sha256"] = _content_hash({k: v for k, v in entries.items() if k not in ("meta", "format_version")})
    entries["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    buf = io.BytesIO()
    np.savez(buf, **entries)
    path.write_bytes(buf.getvalue())
    with pytest.raises(ModelFileContentError) as e:
        load_model(path)
    assert str(path) in str(e.value).splitlines()[0]
    assert _shape(str(e.value), 12) == [f"extra{i:02d}" for i in range(10)]
