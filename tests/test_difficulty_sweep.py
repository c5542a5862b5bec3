"""scripts/difficulty_sweep.py --quick, in-process, from the session's rendered
stride-8 database (the small models are trained in the test's work folder)."""

from __future__ import annotations

import json

from clirun import script


def _script():
    return script("difficulty_sweep")


def test_quick_sweep_writes_tables_and_figures(tmp_path, strided_workdir):
    mod = _script()
    work = strided_workdir(tmp_path / "work")
    out = tmp_path / "out"
    # --batch 4: 4 rigs a pool instead of 16 (each ~0.1 s to build) for the 8 trials a point; the results
    # do not depend on the batch (captures are reseeded per trial and step): 30.8 -> 20.3 s
    assert mod.main(["--quick", "--quiet", "--batch", "4", "--out", str(out), "--workdir", str(work)]) == 0
    summary = json.loads((out / "difficulty_sweep.json").read_text())
    assert summary["positions"] == [4, 1]
    combos = {(db, cams, p) for db in ("DB1", "DB2") for cams in ("1 camera", "2 cameras")
              for p in ("mi-class-pairwise", "random")}
    off = summary["off_grid"]
    assert {(r["database"], r["cameras"], r["planner"]) for r in off} == combos
    assert sorted({r["angle"] for r in off}) == list(mod.QUICK_ANGLES)
    assert all(r["trials"] == 8 and 0 <= r["rate"] <= 100 and 1 <= r["views"] <= 7 for r in off)
    occ = summary["occlusion"]
    assert len(occ) == len(combos) * len(mod.OCCLUSION_BINS)
    # the bins partition the trials at or below the last edge, the same for every planner and model
    for db, cams, p in combos:
        rows = [r for r in occ if (r["database"], r["cameras"], r["planner"]) == (db, cams, p)]
        above = [r for r in summary["occlusion_above_last_bin"] if (r["database"], r["cameras"], r["planner"]) == (db, cams, p)]
        assert sum(r["trials"] for r in rows) + above[0]["trials"] == 8
        for r in rows:
            assert r["trials"] == 0 or r["bin"][0] <= r["mean_fraction"] <= r["bin"][1]
            assert (r["trials"] == 0) == (r["rate"] is None)  # an empty bin: null, strict JSON
    md = (out / "difficulty_sweep.md").read_text()
    assert "Off-grid angle" in md and "Occlusion" in md and "mi-class-pairwise" in md
    for name in ("difficulty_occlusion.png", "difficulty_off_grid.png"):
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_bad_arguments_are_errors(tmp_path, capsys):
    mod = _script()
    assert mod.main(["--quick", "--axes", "nope", "--out", str(tmp_path)]) == 2
    assert mod.main(["--quick", "--angles", "-5", "--out", str(tmp_path)]) == 2
    assert "difficulty_sweep: error" in capsys.readouterr().err
