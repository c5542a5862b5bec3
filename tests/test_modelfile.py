"""Model file: bit-exact round trip, one clear error per failure, crash-safe save."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import zipfile

import numpy as np
import pytest
from builders import make_database

from jaxrecog.modelfile import (
    FORMAT_VERSION, ModelFileContentError, ModelFileCorruptError, ModelFileMissingError,
    ModelFileTruncatedError, ModelFileVersionError, load_model, load_model_meta, save_model,
)
from jaxrecog.train import train_model


@pytest.fixture(scope="module")
def models():
    db = make_database(positions=(2, 1), n_objects=2, n_poses=2, image_shape=(16, 20))
    diag, info = train_model(db, kind="DB2", n_components=2, samples_per_image=5, return_info=True)
    full = train_model(db, kind="DB1", n_components=3, samples_per_image=6, covariance="full")
    return diag, full, info


def _leaves(m):
    return [np.asarray(getattr(c, f)) for c in m.cameras
            for f in ("mean_image", "basis", "eigenvalues", "mu", "var", "chol")
            if getattr(c, f) is not None]


@pytest.mark.parametrize("which", [0, 1])
def test_round_trip_bit_exact(tmp_path, models, which):
    m, info = models[which], models[2]
    p = save_model(tmp_path / "m.npz", m, training=info.params, manifest_sha256=info.manifest_sha256)
    got = load_model(p)
    a, b = _leaves(m), _leaves(got)
    assert len(a) == len(b)
    for x, y in zip(a, b):
        assert x.dtype == y.dtype == np.float32 and x.tobytes() == y.tobytes()
    assert (got.levels, got.image_shape, got.covariance, got.n_objects, got.n_poses) == \
        (m.levels, m.image_shape, m.covariance, m.n_objects, m.n_poses)
    meta = load_model_meta(p)
    assert meta["manifest_sha256"] == info.manifest_sha256 and meta["training"]["kind"] == "DB2"
    assert meta["format_version"] == FORMAT_VERSION
    assert [f for f in os.listdir(tmp_path)] == ["m.npz"]       # no temp left behind


def _rewrite(src, dst, change):
    with np.load(src) as z:
        d = {k: z[k] for k in z.files}
    change(d)
    with open(dst, "wb") as f:
        np.savez(f, **d)


def test_errors_each_their_own(tmp_path, models):
    m = models[0]
    good = save_model(tmp_path / "good.npz", m)
    raw = good.read_bytes()
    with pytest.raises(ModelFileMissingError, match="no such file"):
        load_model(tmp_path / "absent.npz")
    (tmp_path / "trunc.npz").write_bytes(raw[: len(raw) // 2])
    with pytest.raises(ModelFileTruncatedError, match="truncated"):
        load_model(tmp_path / "trunc.npz")
    (tmp_path / "junk.npz").write_bytes(b"hello, not a model" * 10)
    with pytest.raises(ModelFileCorruptError, match="not a model file"):
        load_model(tmp_path / "junk.npz")
    flipped = bytearray(raw)
    with zipfile.ZipFile(good) as z:
        info = z.getinfo("camera0.mu.npy")
    mid = info.header_offset + 30 + len(info.filename) + info.file_size // 2 + 64
    flipped[mid] ^= 0xFF
    (tmp_path / "flip.npz").write_bytes(bytes(flipped))
    with pytest.raises(ModelFileCorruptError, match="damaged|checksum"):
        load_model(tmp_path / "flip.npz")

    def version(d):
        d["format_version"] = np.array(FORMAT_VERSION + 1)
    _rewrite(good, tmp_path / "v.npz", version)
    with pytest.raises(ModelFileVersionError, match=f"format version {FORMAT_VERSION + 1}"):
        load_model(tmp_path / "v.npz")

    def nan_with_valid_hash(d):
        from jaxrecog.modelfile import _content_hash
        d["camera0.mu"] = d["camera0.mu"].copy()
        d["camera0.mu"][0, 0, 0, 0] = np.nan
        meta = json.loads(bytes(d["meta"]).decode())
        meta["content_sha256"] = _content_hash({k: v for k, v in d.items() if "." in k})
        d["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    _rewrite(good, tmp_path / "nan.npz", nan_with_valid_hash)
    with pytest.raises(ModelFileContentError, match="camera0.mu contains NaN"):
        load_model(tmp_path / "nan.npz")

    def wrong_dtype(d):
        from jaxrecog.modelfile import _content_hash
        d["camera1.var"] = d["camera1.var"].astype(np.float64)
        meta = json.loads(bytes(d["meta"]).decode())
        meta["content_sha256"] = _content_hash({k: v for k, v in d.items() if "." in k})
        d["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    _rewrite(good, tmp_path / "dt.npz", wrong_dtype)
    with pytest.raises(ModelFileContentError, match="camera1.var has dtype float64"):
        load_model(tmp_path / "dt.npz")

    def wrong_shape(d):
        from jaxrecog.modelfile import _content_hash
        V, C, L, K = d["camera0.mu"].shape
        d["camera0.mu"] = d["camera0.mu"].reshape(V, C * L, K)     # same values, wrong layout
        meta = json.loads(bytes(d["meta"]).decode())
        meta["content_sha256"] = _content_hash({k: v for k, v in d.items() if "." in k})
        d["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    _rewrite(good, tmp_path / "sh.npz", wrong_shape)
    V, C, L, K = np.asarray(m.cameras[0].mu).shape
    with pytest.raises(ModelFileContentError,
                       match=rf"camera0.mu has shape \({V}, {C * L}, {K}\), "
                             rf"expected \({V}, {C}, {L}, {K}\)"):
        load_model(tmp_path / "sh.npz")
    for f in ("trunc", "junk", "flip", "v", "nan", "dt", "sh"):
        with pytest.raises(Exception) as e:
            load_model(tmp_path / f"{f}.npz")
        assert "\n" not in str(e.value) and str(tmp_path) in str(e.value)


_WRITER = textwrap.dedent("""
    import os, sys, time
    import numpy as np
    import jax.numpy as jnp
    from jaxrecog.kernels import gaussian
    from jaxrecog.sensor_model import CameraModel, SensorModel
    from jaxrecog.modelfile import save_model
    V, C, L, K, H, W = 4, 8, 2, 30, 120, 160
    r = np.random.default_rng(1)
    f = lambda *s: jnp.asarray(r.random(s, dtype=np.float32) + 0.5)
    cam = CameraModel(f(V, H * W), f(V, H * W, K), f(V, K), gaussian(f(V, C, L, K), f(V, C, L, K)))
    m = SensorModel((cam,), 4, 2, (0.0, 0.1), (H, W), "diag")
    real_fsync = os.fsync
    def stall(fd):           # the data is written; stop right before the rename
        print("writing", flush=True)
        time.sleep(60)
    os.fsync = stall
    save_model(sys.argv[1], m)
""")


def test_killed_writer_leaves_old_file(tmp_path, models):
    target = tmp_path / "model.npz"
    save_model(target, models[0])
    before = target.read_bytes()
    proc = subprocess.Popen([sys.executable, "-c", _WRITER, str(target)],
                            stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "writing"
        temps = [p for p in os.listdir(tmp_path) if p.endswith(".tmp")]
        assert len(temps) == 1 and (tmp_path / temps[0]).stat().st_size > 5_000_000
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
        proc.stdout.close()
    assert proc.returncode == -signal.SIGKILL
    assert target.read_bytes() == before
    got = load_model(target)
    for x, y in zip(_leaves(models[0]), _leaves(got)):
        assert x.tobytes() == y.tobytes()


# ---- litter, modes and an unwritable target ---------------------------------------------

def test_the_next_save_removes_a_killed_writers_temp_and_keeps_a_live_ones(tmp_path, models):
    """SIGKILL during a model write left a hidden 19 MB ``.m.npz.*.tmp`` for good."""
    target = tmp_path / "model.npz"
    save_model(target, models[0])
    proc = subprocess.Popen([sys.executable, "-c", _WRITER, str(target)], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "writing"
        temps = sorted(p for p in os.listdir(tmp_path) if p.endswith(".tmp"))
        assert len(temps) == 1 and temps[0].startswith(".model.npz.") and f"-{proc.pid}." in temps[0]
        save_model(target, models[1])             # the writer is alive: its file stays
        assert sorted(p for p in os.listdir(tmp_path) if p.endswith(".tmp")) == temps
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
        proc.stdout.close()
    other = tmp_path / ".other.npz.x-1.abcd.tmp"  # another model's temp is not ours to remove
    other.write_bytes(b"x")
    save_model(target, models[0])
    assert sorted(p for p in os.listdir(tmp_path) if p.endswith(".tmp")) == [other.name]
    got = load_model(target)
    assert [x.tobytes() for x in _leaves(got)] == [x.tobytes() for x in _leaves(models[0])]


def test_an_older_writers_temp_goes_once_it_is_an_hour_old(tmp_path, models):
    target = tmp_path / "m.npz"
    old, young = tmp_path / ".m.npz.a1b2c3d4.tmp", tmp_path / ".m.npz.e5f6g7h8.tmp"   # tempfile.mkstemp names
    for p in (old, young):
        p.write_bytes(b"x" * 100)
    os.utime(old, (0, 0))
    save_model(target, models[0])
    assert not old.exists() and young.exists()


@pytest.mark.parametrize("umask,mode", [(0o022, 0o644), (0o077, 0o600), (0o002, 0o664)])
def test_a_new_model_file_has_the_mode_the_umask_gives(tmp_path, models, umask, mode):
    """Model files were always 0600 whatever the umask."""
    old = os.umask(umask)
    try:
        save_model(tmp_path / "m.npz", models[0])
    finally:
        os.umask(old)
    assert (tmp_path / "m.npz").stat().st_mode & 0o777 == mode


def test_a_model_written_over_an_existing_file_keeps_its_mode(tmp_path, models):
    target = tmp_path / "m.npz"
    save_model(target, models[0])
    os.chmod(target, 0o640)
    save_model(target, models[1])
    assert target.stat().st_mode & 0o777 == 0o640


def test_check_writable_says_so_before_training_and_leaves_nothing(tmp_path):
    from jaxrecog.modelfile import check_writable

    (tmp_path / "afile").write_text("x")
    with pytest.raises(NotADirectoryError, match=r"^cannot write model file .*afile/m.npz: .*afile is not a folder$"):
        check_writable(tmp_path / "afile" / "m.npz")
    with pytest.raises(IsADirectoryError, match="it is a folder"):
        check_writable(tmp_path)
    with pytest.raises(FileNotFoundError, match=r"^cannot write model file .*new/deeper/m.npz: folder .*new/deeper "
                                                r"does not exist \(create it first\)$"):
        check_writable(tmp_path / "new" / "deeper" / "m.npz")   # no folder is made behind the user's back
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]
    if os.geteuid() != 0:  # root writes anywhere
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o555)
        try:
            with pytest.raises(PermissionError, match=r"folder .*ro is not writable \(Permission denied\)"):
                check_writable(ro / "m.npz")
        finally:
            ro.chmod(0o755)


def test_train_refuses_an_unwritable_out_before_training(tmp_path, monkeypatch, capsys):
    """An unwritable ``train --out`` was reported only after training."""
    from jaxrecog import cli, write_database
    from jaxrecog.cli import train as train_cmd

    write_database(tmp_path / "db", make_database(positions=(2,), n_objects=2, n_poses=1, image_shape=(8, 10)))
    (tmp_path / "afile").write_text("x")

    def no_training(*a, **k):
        raise AssertionError("trained before checking --out")

    monkeypatch.setattr(train_cmd, "train_model", no_training)
    assert cli.main(["train", str(tmp_path / "db"), "--out", str(tmp_path / "afile" / "m.npz")]) == 1
    assert capsys.readouterr().err.splitlines() == [
        f"jaxrecog: error: cannot write model file {tmp_path / 'afile' / 'm.npz'}: {tmp_path / 'afile'} is not a folder"]


def test_a_model_that_cannot_explain_any_capture_is_refused_on_load(tmp_path, models):
    """A file whose basis is 1e30 (finite, checksum valid) loaded, and every
    trial ended at the uniform belief, WRONG.  Now its arrays are checked
    for what a trained model has: an orthonormal basis, a unit mean, bounded
    feature means and positive variances; one line names the file and array."""
    import equinox as eqx
    import jax.numpy as jnp

    m = models[0]
    for name, change, needle in [
        ("basis", lambda c: c.basis * 1e30,
         r"camera0.basis at position 0 is not orthonormal \(vector 0 has length inf, not 1\)"),
        ("mean", lambda c: c.mean_image * 5, "camera0.mean_image has norm"),
        ("mu", lambda c: c.likelihood.mu + 1e20, "camera0.mu reaches 1e\\+20"),
    ]:
        field = {"basis": lambda c: c.basis, "mean": lambda c: c.mean_image, "mu": lambda c: c.likelihood.mu}[name]
        broken = eqx.tree_at(lambda mm: field(mm.cameras[0]), m, jnp.asarray(change(m.cameras[0]), jnp.float32))
        path = save_model(tmp_path / f"{name}.npz", broken)
        with pytest.raises(ModelFileContentError, match=f"^model file {path}: {needle}") as e:
            load_model(path)
        assert "\n" not in str(e.value)
    load_model(save_model(tmp_path / "ok.npz", m))   # the model as trained loads
