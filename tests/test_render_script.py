"""scripts/render_database.py: a smoke run on a small camera table
writes a database the foundation loader accepts, the contact sheet of 8 objects
x 4 poses and the look-alike table; the script starts as a program."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from jaxrecog import load_database

pytest.importorskip("pybullet")

from jaxrecog.hardware import SyntheticRig, contact_sheet  # noqa: E402
from jaxrecog.hardware.geometry.positions import CameraTable, default_table  # noqa: E402

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "render_database.py"


@pytest.fixture
def script(monkeypatch):
    """The script as a module whose rig sees 3 + 3 positions (not 32 + 7)."""
    spec = importlib.util.spec_from_file_location("render_database_script", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    t = default_table()
    small = CameraTable(t.workspace, (t.views[0][::11], t.views[1][::3]))
    monkeypatch.setattr(mod, "SyntheticRig", lambda seed=0: SyntheticRig(small, seed=seed))
    return mod, small


def test_script_writes_database_sheet_and_lookalike_table(tmp_path, script, capsys):
    mod, small = script
    png = tmp_path / "sheet.png"
    rc = mod.main([str(tmp_path / "db"), "--test-per-view", "1", "--test-occluders", "--seed", "3",
                   "--contact-sheet", str(png), "--sheet-views", "0:1,1:2", "--lookalike-table"])
    assert rc == 0
    out = capsys.readouterr().out
    assert f"wrote {2 * 6 * 32} images" in out
    db = load_database(tmp_path / "db")
    assert db.positions == (3, 3) and db.n_classes == 32 and db.image_shape == (120, 160)
    assert db.rows("train").size == 6 * 32 and db.rows("test").size == 6 * 32
    # the sheet on disk is the contact sheet of the two requested views
    import cv2

    sheet = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
    with SyntheticRig(small) as rig:
        np.testing.assert_array_equal(sheet, contact_sheet(rig, [(0, 1), (1, 2)]))
    assert "contact sheet (rows: objects 0-7; columns: poses 0-3 at [(0, 1), (1, 2)])" in out
    # the look-alike table: both pairs, every pose, distances as camera:position=d
    for a, b in ((4, 5), (6, 7)):
        assert f"objects {a}/{b} (thesis {a + 1}/{b + 1})" in out
    assert sum(line.startswith("  pose ") for line in out.splitlines()) == 2 * 4


def test_unwritable_contact_sheet_fails_with_status_1(tmp_path, script, capsys):
    mod, _ = script
    bad = tmp_path / "no_such_folder" / "sheet.png"
    assert mod.main([str(tmp_path / "db"), "--contact-sheet", str(bad), "--sheet-views", "0:0"]) == 1
    assert f"could not write {bad}" in capsys.readouterr().err


@pytest.mark.parametrize("views,match", [
    ("0:9,1:3", "camera 0 position 9 is not on the rig"),     # the default, beyond 3 + 3 positions
    ("2:0", "camera 2 position 0 is not on the rig"),
    ("0-1", "expected camera:position pairs"),
])
def test_bad_sheet_views_fail_before_rendering(tmp_path, script, capsys, views, match):
    mod, _ = script
    with pytest.raises(SystemExit) as e:
        mod.main([str(tmp_path / "db"), "--contact-sheet", str(tmp_path / "s.png"), "--sheet-views", views])
    assert e.value.code == 2 and match in capsys.readouterr().err
    assert not (tmp_path / "db").exists()


def test_script_runs_as_a_program():
    p = subprocess.run([sys.executable, str(SCRIPT), "--help"], capture_output=True, text=True,
                       timeout=120)
    assert p.returncode == 0, p.stderr
    assert "--contact-sheet" in p.stdout and "--lookalike-table" in p.stdout
