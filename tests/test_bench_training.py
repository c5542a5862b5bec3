"""benchmarks/bench_training.py on a tiny database: one row per likelihood,
each trained in its own child process, with the ratio against the diagonal
Gaussian of the same run; an unknown family is a usage error; the objects
scaling mode's rows and per-class ratios."""

from __future__ import annotations

import json

import pytest

from clirun import script

TINY = ["--positions", "2,1", "--objects", "2", "--poses", "2", "--height", "12", "--width", "16",
        "--samples", "4", "--components", "2", "--kind", "DB1"]


def _bench():
    return script("bench_training", "benchmarks")


def test_one_row_per_likelihood_with_ratios(tmp_path, capsys):
    out = tmp_path / "t.json"
    assert _bench().main([*TINY, "--likelihoods", "gaussian-diag", "student-t", "--out", str(out)]) == 0
    rows = json.loads(out.read_text())["rows"]
    assert [r["likelihood"] for r in rows] == ["gaussian-diag", "student-t"]
    assert rows[0]["ratio_vs_diag"] == 1.0 and rows[1]["ratio_vs_diag"] > 0
    assert all(r["wall_s"] > 0 and r["peak_rss_mb"] > 0 and r["sizes"]["positions"] == [2, 1] for r in rows)
    assert "student-t" in capsys.readouterr().out


def test_unknown_likelihood_is_an_error(tmp_path, capsys):
    assert _bench().main([*TINY, "--likelihoods", "nope", "--out", str(tmp_path / "t.json")]) == 2
    assert "unknown likelihood" in capsys.readouterr().err


def test_view_mixtures_train_on_jitter_images(tmp_path):
    """A view mixture trains on ``--view-jitter`` extra images per view (one
    component each); the thesis's Gaussian of the same run on none."""
    out = tmp_path / "t.json"
    assert _bench().main([*TINY, "--view-jitter", "2", "--likelihoods", "gaussian-diag", "view-mixture-lowrank",
                          "--out", str(out)]) == 0
    rows = {(r["likelihood"], r["occluded_jitter"]): r for r in json.loads(out.read_text())["rows"]}
    assert list(rows) == [("gaussian-diag", None), ("view-mixture-lowrank", "sampled"),
                          ("view-mixture-lowrank", "translated")]
    diag = rows["gaussian-diag", None]["sizes"]
    assert diag["view_jitter_images_per_view"] == 0
    mix = rows["view-mixture-lowrank", "sampled"]["sizes"]
    assert mix["view_jitter_images_per_view"] == 2
    assert mix["augmented_samples"] == 3 * diag["augmented_samples"]
    # DB1 has one level: translating occluded components samples the same
    assert rows["view-mixture-lowrank", "translated"]["sizes"]["augmented_samples"] == mix["augmented_samples"]


def test_translated_view_mixtures_sample_jitter_images_at_level_0(tmp_path):
    out = tmp_path / "t.json"
    db2 = ["--height", "30", "--width", "40", "--kind", "DB2"]   # occluders need a larger image
    assert _bench().main([*TINY, *db2, "--view-jitter", "2", "--likelihoods", "view-mixture",
                          "--occluded-jitter", "translated", "--out", str(out)]) == 0
    (row,) = json.loads(out.read_text())["rows"]
    assert row["occluded_jitter"] == "translated"
    # 6 levels of each of the 2*1 + 1 = 3 positions x 4 classes, plus 2 jitter images at level 0
    assert row["sizes"]["augmented_samples"] == 3 * 4 * 4 * (6 + 2)


def test_objects_scaling_rows_and_per_class_ratios(tmp_path, capsys):
    """``--scale-objects``: one row per size of a turntable-shaped database
    (one camera, one train and one calib view per position and class), each
    cost per class against the smallest size's; training alone here
    (``--no-calibrate``: calibration compiles per size) and in this process."""
    out = tmp_path / "s.json"
    tiny = ["--positions", "2", "--poses", "2", "--height", "12", "--width", "16", "--samples", "4",
            "--components", "2"]
    assert _bench().main([*tiny, "--scale-objects", "2", "4", "--in-process", "--no-calibrate",
                          "--out", str(out)]) == 0
    res = json.loads(out.read_text())
    rows = res["rows"]
    assert res["benchmark"] == "training-objects" and [r["objects"] for r in rows] == [2, 4]
    assert [r["classes"] for r in rows] == [4, 8]
    assert [r["sizes"]["train_images"] for r in rows] == [8, 16] == [r["sizes"]["calib_images"] for r in rows]
    assert rows[0]["sizes"]["kind"] == "DB1" and rows[0]["sizes"]["positions"] == [2]
    for r in rows:
        assert r["train_wall_s"] > 0 and r["peak_rss_mb"] > 0 and r["calibrate_wall_s"] is None
        q = r["per_class_vs_smallest"]
        assert q["calibrate_cpu_s"] is None
        want = (r["train_wall_s"] / 8) / (rows[0]["train_wall_s"] / 4) if r is rows[1] else 1.0
        assert q["train_wall_s"] == pytest.approx(want, rel=1e-12)
    assert "per class vs smallest" in capsys.readouterr().out
    assert _bench().main(["--scale-objects", "0", "--out", str(out)]) == 2


def test_per_class_ratios_say_how_costs_grow():
    rows = [{"classes": 40, **dict.fromkeys(_bench()._SCALED, 10.0)},
            {"classes": 200, **dict.fromkeys(_bench()._SCALED, 50.0), "calibrate_cpu_s": 250.0}]
    _bench().per_class_ratios(rows[::-1])   # the smallest is the base, in any order
    assert rows[0]["per_class_vs_smallest"]["total_wall_s"] == 1.0
    assert rows[1]["per_class_vs_smallest"]["total_wall_s"] == 1.0     # linear
    assert rows[1]["per_class_vs_smallest"]["calibrate_cpu_s"] == 5.0  # quadratic
