"""Image database loader: round trip and every validation problem, by row."""

from __future__ import annotations

import csv

import cv2
import numpy as np
import pytest
from builders import make_database

from jaxrecog.database import DatabaseError, ImageDatabase, NonGrayImageWarning, load_database, write_database


@pytest.fixture
def folder(tmp_path):
    db = make_database(positions=(2, 1), n_objects=2, n_poses=2, image_shape=(24, 32), n_test=1)
    write_database(tmp_path, db)
    return tmp_path, db


def _rows(folder):
    with open(folder / "manifest.csv", newline="") as f:
        return list(csv.reader(f))


def _write(folder, rows):
    with open(folder / "manifest.csv", "w", newline="") as f:
        csv.writer(f).writerows(rows)


def test_round_trip(folder):
    root, db = folder
    got = load_database(root)
    np.testing.assert_array_equal(got.images, db.images)
    np.testing.assert_array_equal(got.class_index, db.object * db.n_poses + db.pose)
    assert got.positions == (2, 1) and got.n_classes == 4 and got.image_shape == (24, 32)
    assert got.manifest_sha256 == db.manifest_sha256
    tr = got.train_images(0)
    assert tr.shape == (2, 4, 24, 32)
    # slot [v, c] holds the train image of that position and class
    i = int(np.flatnonzero((got.split == "train") & (got.camera == 0) & (got.position == 1)
                           & (got.object == 1) & (got.pose == 0))[0])
    np.testing.assert_array_equal(tr[1, 2], got.images[i])


def test_every_problem_reported_with_row(folder):
    root, _ = folder
    rows = _rows(root)
    rows[2][0] = "nope/missing.png"                      # row 2: missing file
    rows[3] = list(rows[1])                              # row 3: duplicate of row 1
    rows[4][1] = "x"                                     # row 4: camera not an integer
    rows[5][5] = "validate"                              # row 5: bad split
    big = np.full((30, 32), 100, np.uint8)
    cv2.imwrite(str(root / rows[6][0]), big)             # row 6: other size
    _write(root, rows)
    with pytest.raises(DatabaseError) as e:
        load_database(root)
    msg = str(e.value)
    for needle in ("row 2: missing file 'nope/missing.png'", "row 3: duplicate of row 1",
                   "row 4: camera 'x' is not an integer", "row 5: split 'validate'",
                   "row 6: image", "30x32"):
        assert needle in msg, msg
    assert len(e.value.problems) == 6  # duplicate path + duplicate train entry for row 3


def test_header_unknown_and_missing_columns(folder):
    root, _ = folder
    rows = _rows(root)
    rows[0] = ["path", "camera", "position", "object", "angle", "split"]
    _write(root, rows)
    with pytest.raises(DatabaseError) as e:
        load_database(root)
    assert "unknown column 'angle'" in str(e.value)
    assert "missing column(s) pose" in str(e.value)


def test_missing_manifest(tmp_path):
    with pytest.raises(DatabaseError, match="no manifest.csv"):
        load_database(tmp_path)


def test_colour_image_converted_with_warning(folder):
    root, db = folder
    rows = _rows(root)
    gray = cv2.imread(str(root / rows[1][0]), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(root / rows[1][0]), cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR))
    with pytest.warns(NonGrayImageWarning, match="rows 1"):
        got = load_database(root)
    np.testing.assert_array_equal(got.images[0], gray)


def test_missing_train_image_named(folder):
    root, _ = folder
    rows = _rows(root)
    keep = [rows[0]] + [r for r in rows[1:] if not (r[1:5] == ["0", "1", "1", "0"] and r[5] == "train")]
    _write(root, keep)
    db = load_database(root)
    with pytest.raises(DatabaseError, match="camera 0 position 1: no train image of object 1 pose 0"):
        db.train_images(0)


def test_any_sizes():
    db = make_database(positions=(1, 2, 3), n_objects=1, n_poses=3, image_shape=(16, 20))
    assert db.n_cameras == 3 and db.positions == (1, 2, 3) and db.n_classes == 3
    assert db.train_images(2).shape == (3, 3, 16, 20)


# ---- long problem lists ----------------------------------------------------------------

def _break_every_row(root):
    rows = _rows(root)
    for r in rows[1:]:
        r[5] = "validate"  # one problem per row
    _write(root, rows)
    return len(rows) - 1


def test_a_long_problem_list_shows_the_count_and_ten_lines_and_writes_nothing(tmp_path):
    db = make_database(positions=(3, 2), n_objects=2, n_poses=2, image_shape=(12, 16), n_test=1)
    write_database(tmp_path, db)
    n = _break_every_row(tmp_path)
    assert n > 10
    before = sorted(p.name for p in tmp_path.iterdir())
    with pytest.raises(DatabaseError) as e:
        load_database(tmp_path)
    lines = str(e.value).splitlines()
    assert lines[0] == f"invalid image database {tmp_path}: {n} problems"
    assert [l.strip() for l in lines[1:11]] == [f"row {r}: split 'validate' is not one of train, test, calib, jitter"
                                                for r in range(1, 11)]
    assert lines[11].strip() == (f"... {n - 10} more (run with --debug to see all, or --problems-out FILE "
                                 "to write them to a file)") and len(lines) == 12
    assert e.value.full_list is None and len(e.value.problems) == n
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # reading wrote nothing into the folder


def test_a_read_only_command_never_writes_through_a_link_in_the_database(tmp_path, capsys):
    """A symlink is not followed: ``ln -s ~/victim.txt DB/manifest-errors.txt;
    jaxrecog inspect DB`` used to overwrite victim.txt."""
    from jaxrecog import cli

    db_dir, victim = tmp_path / "db", tmp_path / "victim.txt"
    db = make_database(positions=(3, 2), n_objects=2, n_poses=2, image_shape=(12, 16), n_test=1)
    write_database(db_dir, db)
    _break_every_row(db_dir)
    victim.write_text("precious\n")
    (db_dir / "manifest-errors.txt").symlink_to(victim)
    before = sorted(p.name for p in db_dir.iterdir())
    assert cli.main(["inspect", str(db_dir)]) == 1
    assert victim.read_text() == "precious\n"
    assert sorted(p.name for p in db_dir.iterdir()) == before
    assert "--problems-out FILE" in capsys.readouterr().err.splitlines()[-1]


def test_problems_out_writes_the_whole_list_to_a_new_file_only(tmp_path, capsys):
    from jaxrecog import cli

    db_dir = tmp_path / "db"
    db = make_database(positions=(3, 2), n_objects=2, n_poses=2, image_shape=(12, 16), n_test=1)
    write_database(db_dir, db)
    n = _break_every_row(db_dir)
    out = tmp_path / "problems.txt"
    assert cli.main(["inspect", str(db_dir), "--problems-out", str(out)]) == 1
    err = capsys.readouterr().err.splitlines()
    assert err[-1] == f"jaxrecog: all {n} problems written to {out}"
    written = out.read_text().splitlines()
    assert written[0] == f"invalid image database {db_dir}: {n} problems" and len(written) == n + 1
    assert written[1] == "row 1: split 'validate' is not one of train, test, calib, jitter"
    # an existing file, or a link to one, is never overwritten
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    link = tmp_path / "link.txt"
    link.symlink_to(victim)
    for target in (out, victim, link):
        before = target.read_text()
        assert cli.main(["inspect", str(db_dir), "--problems-out", str(target)]) == 1
        assert capsys.readouterr().err.splitlines()[-1] == (f"jaxrecog: --problems-out {target} exists; not "
                                                             "overwritten (the list was not written)")
        assert target.read_text() == before
    # a missing folder: refused before the command runs (no folder is made for it)
    assert cli.main(["inspect", str(db_dir), "--problems-out", str(tmp_path / "no" / "such.txt")]) == 2
    assert capsys.readouterr().err.splitlines()[-1] == (
        f"jaxrecog inspect: error: cannot write --problems-out file {tmp_path / 'no' / 'such.txt'}: folder "
        f"{tmp_path / 'no'} does not exist (create it first)")


def test_a_problem_list_message_is_the_same_with_or_without_a_folder():
    from jaxrecog.dbformat import database_error

    err = database_error("db", [f"row {r}: bad" for r in range(1, 13)])
    assert err.full_list is None
    assert str(err).splitlines()[-1].strip() == ("... 2 more (run with --debug to see all, or --problems-out FILE "
                                                 "to write them to a file)")
    # ten or fewer problems: nothing left out
    few = database_error("db", ["row 1: bad", "row 2: worse"])
    assert str(few).splitlines() == ["invalid image database db: 2 problems", "  row 1: bad", "  row 2: worse"]


def test_one_problem_is_one_line_and_odd_text_stays_on_its_line():
    from jaxrecog.problems import LINE_CAP, problem_message

    assert problem_message("model m", ["no such file"]) == "model m: no such file"
    msg = problem_message("h", ["a\nb\r\x00c", "x" * 10_000])
    assert msg.splitlines() == ["h: 2 problems", "  a b c", "  " + "x" * (LINE_CAP - 3) + "..."]


def test_the_cli_prints_ten_problems_one_per_line_and_debug_prints_all(tmp_path, capsys):
    from jaxrecog import cli

    db = make_database(positions=(3, 2), n_objects=2, n_poses=2, image_shape=(12, 16), n_test=1)
    write_database(tmp_path, db)
    n = _break_every_row(tmp_path)
    assert cli.main(["inspect", str(tmp_path)]) == 1
    err = capsys.readouterr().err.splitlines()
    assert err[0] == f"jaxrecog: error: invalid image database {tmp_path}: {n} problems"
    assert len(err) == 12 and err[1] == "  row 1: split 'validate' is not one of train, test, calib, jitter"
    assert "--problems-out FILE" in err[-1]
    with pytest.raises(DatabaseError):
        cli.main(["inspect", str(tmp_path), "--debug"])
    err = capsys.readouterr().err.splitlines()
    assert err == [f"row {r}: split 'validate' is not one of train, test, calib, jitter" for r in range(1, n + 1)]


# ---- turntable data ---------------------------------------------------------------------

def test_one_file_for_several_views_loads_with_a_note(folder):
    from jaxrecog.database import notes

    root, db = folder
    rows = _rows(root)
    # a turntable: the photo of (position 0, pose 1) is also the view of (position 1, pose 0)
    a = next(i for i, r in enumerate(rows) if r[1:] == ["0", "0", "0", "1", "train"])
    b = next(i for i, r in enumerate(rows) if r[1:] == ["0", "1", "0", "0", "train"])
    rows[b][0] = rows[a][0]
    _write(root, rows)
    got = load_database(root)
    assert got.paths[a - 1] == got.paths[b - 1]
    np.testing.assert_array_equal(got.images[a - 1], got.images[b - 1])
    assert got.n_rows == db.n_rows
    assert notes(got) == ["  1 image file(s) are used by more than one row (turntable views: one photo "
                          "serves several (pose, position) rows)"]
    assert notes(db) == []


def test_inspect_shows_the_turntable_note(folder, capsys):
    from jaxrecog import cli

    root, _ = folder
    rows = _rows(root)
    rows[2][0] = rows[1][0]  # rows 1 and 2 differ in their view, not their file
    assert rows[1][1:] != rows[2][1:]
    _write(root, rows)
    assert cli.main(["inspect", str(root)]) == 0
    assert "1 image file(s) are used by more than one row (turntable views" in capsys.readouterr().out


def test_a_truly_duplicated_row_is_still_an_error(folder):
    root, _ = folder
    rows = _rows(root)
    test_row = next(i for i, r in enumerate(rows) if r[5] == "test")
    rows.append(list(rows[test_row]))  # same path, camera, position, object, pose and split
    _write(root, rows)
    with pytest.raises(DatabaseError) as e:
        load_database(root)
    assert e.value.problems == [f"row {len(rows) - 1}: duplicate of row {test_row} (same path "
                                f"'{rows[test_row][0]}', camera, position, object, pose and split)"]


def test_the_same_file_as_two_train_images_of_one_view_is_an_error(folder):
    root, _ = folder
    rows = _rows(root)
    rows.append([rows[2][0], *rows[1][1:]])  # another file claims row 1's train view
    _write(root, rows)
    with pytest.raises(DatabaseError, match=f"row {len(rows) - 1}: duplicate train entry"):
        load_database(root)


# ---- one format for the loader, the renderer and the dataset rig (jaxrecog/dbformat.py) -----

def test_the_renderer_and_the_loader_share_one_format(tmp_path):
    from jaxrecog import database
    from jaxrecog import dbformat
    from jaxrecog.hardware.render import render_db

    assert render_db.MANIFEST_COLUMNS is dbformat.COLUMNS is database.COLUMNS
    assert database.DatabaseError is dbformat.DatabaseError
    db = make_database(positions=(2,), n_objects=1, n_poses=2, image_shape=(8, 8))
    write_database(tmp_path, db)
    from jaxrecog.hardware import DatasetRig

    rig = DatasetRig.from_folder(tmp_path, split="train")
    assert rig.positions == (2,) and rig.image_shape == (8, 8)


# ---- indices form dense ranges, checked before any array is sized ------------------------

def test_one_mistyped_index_names_its_row_at_once(folder):
    """Position 999999 in one row cost a minute and gigabytes (train), and a
    large object index too gave 'MemoryError ... 16.0 TiB' with no row named."""
    import resource
    import time

    root, _ = folder
    rows = _rows(root)
    rows[3][2] = "999999"       # row 3: position
    rows[5][3] = "1000000"      # row 5: object (below MAX_INDEX = 2**20)
    _write(root, rows)
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t0 = time.perf_counter()
    with pytest.raises(DatabaseError) as e:
        load_database(root)
    assert time.perf_counter() - t0 < 2.0   # was a minute
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss0 < 100_000  # KiB; was gigabytes
    cam = rows[3][1]
    assert e.value.problems == [
        f"row 3: camera {cam} position 999999 leaves a gap (no row has camera {cam} position "
        f"{2 if cam == '0' else 1}..999998; indices count 0, 1, 2, ... without gaps)",
        "row 5: object 1000000 leaves a gap (no row has object 2..999999; indices count 0, 1, 2, ... without gaps)",
    ]


def test_a_missing_index_in_the_middle_is_one_problem_naming_the_first_row_past_it(folder):
    root, _ = folder
    rows = _rows(root)
    # pose 1 -> 2 everywhere: poses 0 and 2, no pose 1
    for r in rows[1:]:
        if r[4] == "1":
            r[4] = "2"
    _write(root, rows)
    first = next(i for i, r in enumerate(rows[1:], start=1) if r[4] == "2")
    with pytest.raises(DatabaseError) as e:
        load_database(root)
    assert e.value.problems == [f"row {first}: pose 2 leaves a gap (no row has pose 1; indices count 0, 1, 2, "
                                "... without gaps)"]


def test_in_memory_databases_follow_the_same_rule():
    img = np.zeros((2, 4, 4), np.uint8)
    with pytest.raises(DatabaseError, match=r"row 2: camera 2 leaves a gap \(no row has camera 1;"):
        ImageDatabase.from_arrays(img, [0, 2], [0, 0], [0, 0], [0, 0], ["train", "train"])


def test_sparse_views_are_listed_without_sizing_their_product():
    """Dense indices whose combinations are few (object i only in pose i): the
    missing train views are named, the first 1000 and a count, without an
    array of positions x objects x poses."""
    n = 3000
    idx = np.arange(n)
    db = ImageDatabase.from_arrays(np.zeros((n, 2, 2), np.uint8), np.zeros(n, int), np.zeros(n, int), idx, idx,
                                   ["train"] * n)
    with pytest.raises(DatabaseError) as e:
        db.train_images(0)
    probs = e.value.problems
    assert len(probs) == 1001 and probs[0] == "camera 0 position 0: no train image of object 0 pose 1"
    assert probs[-1] == f"camera 0: {n * n - n - 1000} more of its 1 positions x {n * n} classes have no train image"


def test_a_colour_image_is_one_warning_line_at_the_cli(folder):
    """``jaxrecog inspect`` on a database with a colour image says so
    in one line, ``jaxrecog: warning: ...``, not Python's warning with its
    source line and category; the caller's warning display is restored."""
    import subprocess
    import sys
    import warnings

    from clirun import run_cli

    root, _ = folder
    rows = _rows(root)
    gray = cv2.imread(str(root / rows[1][0]), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(root / rows[1][0]), cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR))
    before = warnings.showwarning
    with warnings.catch_warnings():
        warnings.simplefilter("default", NonGrayImageWarning)
        p = run_cli("inspect", root)
    assert warnings.showwarning is before
    assert p.returncode == 0 and p.stderr.splitlines() == [
        f"jaxrecog: warning: {root}: 1 colour image(s) converted to gray (rows 1)"], p.stderr
    q = subprocess.run([sys.executable, "-m", "jaxrecog.cli", "inspect", str(root)], capture_output=True, text=True)
    assert q.returncode == 0 and "jaxrecog: warning:" in q.stderr and "NonGrayImageWarning" not in q.stderr, q.stderr
