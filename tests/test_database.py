"""Image database loader: round trip and every validation problem, by row."""

from __future__ import annotations

import csv

import cv2
import numpy as np
import pytest

from jaxrecog.database import DatabaseError, NonGrayImageWarning, load_database, write_database
from jaxrecog.testing import make_database


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
