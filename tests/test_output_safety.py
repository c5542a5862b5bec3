"""What jaxrecog writes and reads, at the edges: outputs only as regular files
in folders that exist, one writer per output, bounded text reads, model files
and images checked before they are inflated or decoded, ``--problems-out``
never in a database folder, a full stdout is an error, settings-file values
checked as flags are, ``recognize --plot`` checked before the trial.

Each test is a case a user (or a fault-injection run as root) hit: ``train --out
/dev/null`` replaced the device with a regular file, two ``train --out m.npz``
at once both exited 0 with one model lost, ``--config /dev/zero`` grew to
23.5 GB, a 12 MB model file inflated to 4.5 GB before its checksum failed.
"""

from __future__ import annotations

import contextlib
import io
import os
import stat
import struct
import time
import zipfile
import zlib
from pathlib import Path

import numpy as np
import pytest
from clirun import one_error_line, run_cli

from jaxrecog import cli

run = run_cli


# -- outputs: regular files in folders that exist ------------------------------------------

@pytest.fixture
def fifo(tmp_path):
    p = tmp_path / "pipe"
    os.mkfifo(p)
    return p


def test_an_output_must_be_a_regular_file_in_an_existing_folder(tmp_path, fifo):
    from jaxrecog._files import check_output_file, check_output_folder, write_text

    for target, words in (("/dev/null", "it is a character device, not a regular file"),
                          ("/dev/full", "it is a character device, not a regular file"),
                          (fifo, "it is a FIFO (named pipe), not a regular file"),
                          (tmp_path, "it is a folder"),
                          (tmp_path / "no" / "m.npz", f"folder {tmp_path / 'no'} does not exist (create it first)")):
        with pytest.raises(OSError) as e:
            check_output_file(target, "model file")
        assert str(e.value) == f"cannot write model file {target}: {words}"
    assert check_output_file(tmp_path / "new.npz") == tmp_path / "new.npz"
    assert write_text(tmp_path / "a.txt", "x\n").read_text() == "x\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "pipe"]  # no temporary file left
    assert check_output_folder(tmp_path / "out" / "iii") == tmp_path / "out" / "iii"   # a folder: made with parents
    for bad in (tmp_path / "a.txt", tmp_path / "a.txt" / "x"):
        with pytest.raises(OSError) as e:
            check_output_folder(bad, "database folder")
        assert str(e.value) == f"cannot write database folder {bad}: {tmp_path / 'a.txt'} exists and is not a folder"


def test_saving_a_model_over_a_device_or_into_a_missing_folder_is_refused(tmp_path, fifo):
    """save_model renamed its temporary file over any non-folder (as root,
    /dev/null became a regular file) and created --out's missing folders.  A
    FIFO of the test's own stands for the device: on code without the check,
    this test must not replace the machine's /dev/null."""
    from builders import random_sensor_model

    from jaxrecog import save_model

    model = random_sensor_model(positions=(2,), n_objects=2, n_poses=1)
    for target in (fifo, tmp_path / "missing" / "m.npz"):
        with pytest.raises(OSError, match=f"cannot write model file {target}"):
            save_model(target, model)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    assert not (tmp_path / "missing").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pipe"]


@pytest.mark.parametrize("out", ["/dev/null", "/dev/full", "missing/m.npz"])
def test_train_refuses_a_device_or_a_missing_folder_before_anything(tmp_path, out):
    p = run("train", tmp_path / "no-db", "--out", out, cwd=tmp_path)
    assert p.returncode == 1
    one_error_line(p, f"cannot write model file {out}")
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode) and not (tmp_path / "missing").exists()


# -- one writer per output -------------------------------------------------------------------

def test_a_second_train_into_the_same_model_file_is_refused(tmp_path):
    """Two ``train --out m.npz`` at once both trained and exited 0; one model was lost."""
    from jaxrecog._lock import file_lock

    with file_lock(tmp_path / "m.npz", what="jaxrecog train"):
        p = run("train", tmp_path / "no-db", "--out", tmp_path / "m.npz")
        assert (tmp_path / ".m.npz.lock").exists()
    assert p.returncode == 1
    one_error_line(p, f"{tmp_path / 'm.npz'} is being written by another jaxrecog train (PID {os.getpid()}",
                   "wait for it to end or choose another file")
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # the lock is gone with its holder


def test_a_second_render_into_the_same_folder_is_refused(tmp_path):
    from jaxrecog._lock import folder_lock

    with folder_lock(tmp_path / "db", what="jaxrecog render"):
        p = run("render", "--out", tmp_path / "db", "--stride", 8, "--objects", 1, "--poses", 1)
    assert p.returncode == 1
    one_error_line(p, f"{tmp_path / 'db'} is in use by another jaxrecog render (PID {os.getpid()}")
    (tmp_path / "x").write_text("a file")
    p = run("render", "--out", tmp_path / "x" / "db")
    assert p.returncode == 1
    one_error_line(p, f"cannot write database folder {tmp_path / 'x' / 'db'}: {tmp_path / 'x'} exists and is not a folder")


# -- settings files: bounded, regular, UTF-8 -------------------------------------------------

def test_a_settings_file_is_read_bounded_and_as_utf8(tmp_path, fifo):
    t0 = time.perf_counter()
    for path, words in (("/dev/zero", "settings file /dev/zero is a character device, not a regular file"),
                        (fifo, f"settings file {fifo} is a FIFO (named pipe), not a regular file")):
        p = run("--config", path, "recipes")
        assert p.returncode == 2, p.stderr
        assert p.stderr.splitlines()[-1] == f"jaxrecog: error: {words}"
    assert time.perf_counter() - t0 < 5   # /dev/zero was read until memory ran out
    bad = tmp_path / "latin1.toml"
    bad.write_bytes(b"[train]\nkind = \"DB\xe9\"\n")
    p = run("--config", bad, "recipes")
    assert p.returncode == 2 and "Traceback" not in p.stderr
    assert p.stderr.splitlines()[-1] == f"jaxrecog: error: settings file {bad} is not UTF-8 text (byte 0xe9 at offset 18)"
    big = tmp_path / "big.toml"
    big.write_text("#" * (1 << 20) + "\n")
    p = run("--config", big, "recipes")
    assert p.returncode == 2
    assert p.stderr.splitlines()[-1] == (f"jaxrecog: error: settings file {big} is {(1 << 20) + 1} bytes, more than "
                                         f"the {1 << 20} a settings file may have")
    exp = tmp_path / "e.toml"
    exp.write_bytes(b"case = \"iii\xff\"\n")
    p = run("experiment", exp)
    assert p.returncode == 2 and "experiment file" in p.stderr and "not UTF-8" in p.stderr
    from jaxrecog._files import read_text

    with pytest.raises(OSError, match="is not UTF-8 text"):
        read_text(bad)


@pytest.mark.parametrize("line,words", [
    ("max_steps = 0", "[recognize] max_steps = 0: expected a positive integer, got '0' (as --max-steps)"),
    ("object = -1", "[recognize] object = -1: expected an integer >= 0, got '-1' (as --object)"),
    ("threshold = 2", "[recognize] threshold = 2: expected a probability in (0, 1], got '2' (as --threshold)"),
    ('planner = "best"', "[recognize] planner = 'best': invalid choice 'best' (choose from"),
    ("occluders = 1", "[recognize] occluders = 1: expected true or false (as --occluders)"),
])
def test_settings_file_values_are_checked_as_flags_are(tmp_path, line, words):
    """``max_steps = 0`` in a --config file skipped the check --max-steps 0 gets,
    and failed later with an unrelated message."""
    cfg = tmp_path / "c.toml"
    cfg.write_text(f"[recognize]\n{line}\n")
    p = run("--config", cfg, "recognize", tmp_path / "m.npz")
    assert p.returncode == 2, p.stderr
    last = p.stderr.splitlines()[-1]
    assert last.startswith(f"jaxrecog: error: settings file {cfg}: {words}"), last


def test_global_switches_in_a_settings_file_must_be_true_or_false(tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text('[global]\nquiet = "no"\n')   # was taken as quiet: a non-empty string is true
    p = run("--config", cfg, "recipes")
    assert p.returncode == 2
    assert p.stderr.splitlines()[-1] == (f"jaxrecog: error: settings file {cfg}: [global] quiet = 'no': expected "
                                         f"true or false (as --quiet)")


def test_settings_file_values_of_the_right_kind_still_work(tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text('[recognize]\nmax_steps = 3\nstart = [1, 0]\nthreshold = 0.9\nplanner = "random"\n'
                   'occluders = true\n')
    parser = cli.build_parser()
    cli._apply_config(parser, str(cfg))
    args = parser.parse_args(["recognize", "m.npz"])
    assert (args.max_steps, args.start, args.threshold, args.planner, args.occluders) == (3, (1, 0), 0.9, "random", True)


# -- model files and images: sizes checked before inflating or decoding ---------------------

def _npy_header(shape, dtype="<f4") -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": dtype, "fortran_order": False, "shape": shape})
    return buf.getvalue()


def test_a_model_member_declaring_a_huge_shape_is_refused_before_it_is_read(tmp_path):
    """An .npz member declaring shape (10**6, 10**6) gave MemoryError: 3.64 TiB, naming no file."""
    from jaxrecog.modelfile import ModelFileCorruptError, load_model

    path = tmp_path / "huge.npz"
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("format_version.npy", _npy_header((), "<i8") + struct.pack("<q", 4))
        z.writestr("camera0.basis.npy", _npy_header((10**6, 10**6)) + b"\0" * 64)
    with pytest.raises(ModelFileCorruptError) as e:
        load_model(path)
    assert str(e.value) == (f"model file {path}: array camera0.basis declares shape (1000000, 1000000) float32 "
                            f"(3.64 TiB) but the file holds 64 bytes of it")


def test_a_compressed_model_member_is_refused_by_its_declared_size(tmp_path, monkeypatch):
    """A 12 MB model file inflated to 4.5 GB (20 s) before 'checksum mismatch'."""
    from jaxrecog import modelfile
    from jaxrecog.modelfile import ModelFileCorruptError, load_model

    path = tmp_path / "bomb.npz"
    n = 48 << 20   # 48 MiB of zeros: about 48 kB deflated
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("format_version.npy", _npy_header((), "<i8") + struct.pack("<q", 4))
        z.writestr("camera0.basis.npy", _npy_header((n // 4,)) + bytes(n))
    inflated = []
    real = zlib.decompressobj
    monkeypatch.setattr(zlib, "decompressobj", lambda *a: inflated.append(1) or real(*a))
    with pytest.raises(ModelFileCorruptError) as e:
        load_model(path)
    msg = str(e.value)
    assert msg.startswith(f"model file {path}: its members declare 48.00 MiB in all, more than a ") and \
        msg.endswith("not a model file (a decompression bomb?)"), msg
    assert modelfile.MAX_INFLATION * path.stat().st_size < n and not inflated


def _png(width: int, height: int) -> bytes:
    """A PNG whose header says width x height (its pixel data is a stub: never decoded)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b"")


@pytest.mark.parametrize("row", [1, 3])
def test_a_huge_image_is_refused_by_its_header_naming_its_row(tmp_path, row):
    """A 20000 x 20000 PNG on row 1 gave MemoryError: 179 GiB, no row named."""
    from builders import write_synthetic_database

    from jaxrecog import load_database
    from jaxrecog.dbformat import DatabaseError

    db = write_synthetic_database(tmp_path / "db", positions=(2,), n_objects=2, n_poses=1, image_shape=(8, 10))
    db = db if db.is_dir() else db.parent
    name = (db / "manifest.csv").read_text().splitlines()[row].split(",")[0]
    (db / name).write_bytes(_png(20000, 20000))
    with pytest.raises(DatabaseError) as e:
        load_database(db)
    assert str(e.value).endswith(f"row {row}: image '{name}' is 20000x20000 pixels by its header, more than the "
                                 f"{1 << 25} an image may have (not decoded)"), str(e.value)


def test_a_manifest_is_read_bounded(tmp_path, monkeypatch):
    from jaxrecog import dbformat, load_database
    from jaxrecog.dbformat import DatabaseError

    (tmp_path / "db").mkdir()
    (tmp_path / "db" / "manifest.csv").write_text("path,camera,position,object,pose,split\n" * 100)
    monkeypatch.setattr(dbformat, "MAX_MANIFEST_BYTES", 1000)
    with pytest.raises(DatabaseError) as e:
        load_database(tmp_path / "db")
    assert str(e.value) == (f"invalid image database {tmp_path / 'db'}: manifest.csv {tmp_path / 'db' / 'manifest.csv'} "
                            f"is 3900 bytes, more than the 1000 a manifest.csv may have")


def test_image_sizes_come_from_the_headers_of_the_usual_formats(tmp_path):
    import cv2

    from jaxrecog._imagesize import image_size

    for ext in ("png", "jpg", "bmp", "pgm", "ppm", "tif"):
        f = tmp_path / f"i.{ext}"
        cv2.imwrite(str(f), np.zeros((30, 40, 3) if ext == "ppm" else (30, 40), np.uint8))
        assert image_size(f) == (40, 30), ext
    (tmp_path / "x.bin").write_bytes(b"not an image")
    assert image_size(tmp_path / "x.bin") is None


# -- --problems-out, stdout, recognize --plot ----------------------------------------------

def test_problems_out_in_a_database_folder_is_refused(tmp_path):
    db = tmp_path / "db"
    (db / "images").mkdir(parents=True)
    (db / "manifest.csv").write_text("path,camera,position,object,pose,split\n")
    for target in (db / "p.txt", db / "images" / "p.txt"):
        p = run("--problems-out", target, "inspect", db)
        assert p.returncode == 2
        assert p.stderr.splitlines()[-1] == (f"jaxrecog inspect: error: --problems-out {target} is in the image "
                                             f"database folder {db}: a command never writes into a database "
                                             f"folder; choose a file outside it")
    assert sorted(p.name for p in db.rglob("*")) == ["images", "manifest.csv"]
    p = run("--problems-out", "/dev/null", "inspect", db)
    assert p.returncode == 2 and "not a regular file" in p.stderr


@contextlib.contextmanager
def _stdout_on(path: str):
    with open(path, "w") as f, contextlib.redirect_stdout(f):
        yield


@pytest.mark.parametrize("argv", [["--help"], ["recipes"], ["train", "--help"]])
def test_output_that_stdout_cannot_take_is_an_error(argv, capsys):
    """``jaxrecog --help > /dev/full`` exited 0 (argparse dropped the failed write)."""
    with _stdout_on("/dev/full"):
        code = cli.main(argv)
    assert code == 1
    assert capsys.readouterr().err.splitlines() == [
        "jaxrecog: error: cannot write the output to standard output (No space left on device)"]


def test_recognize_checks_plot_before_the_trial(tmp_path):
    """--plot into a folder that cannot take it failed after the trial (on a real rig: a trial lost)."""
    (tmp_path / "afile").write_text("x")
    p = run("recognize", tmp_path / "absent.npz", "--plot", tmp_path / "afile" / "b.png")
    assert p.returncode == 1
    one_error_line(p, f"cannot write --plot file {tmp_path / 'afile' / 'b.png'}: {tmp_path / 'afile'} is not a folder")


@pytest.mark.slow
def test_recognize_prints_the_result_before_a_plot_that_fails(tiny, tmp_path, monkeypatch):
    from jaxrecog import plots

    def disk_full(*a, **k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(plots, "belief_lines", disk_full)
    p = run("recognize", tiny["model"], "--rig", f"dataset:{tiny['db']}", "--object", 1, "--pose", 1,
            "--samples", 64, "--start", "0,0", "--plot", tmp_path / "b.png")   # test_cli's trial: compiled once
    assert p.returncode == 1, p.stderr
    assert "result: object" in p.stdout
    one_error_line(p, f"--plot {tmp_path / 'b.png'} was not written", "the trial's result is printed above")
