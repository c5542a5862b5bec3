"""scripts/photo_bench.py --quick, in-process: the real-photo benchmark's CI
form (one grid, two objects, small models; it checks the pipeline, not the
numbers of docs/results.md)."""

from __future__ import annotations

import json

from clirun import script


def test_quick_benchmark_writes_its_table_json_and_figure(tmp_path):
    mod = script("photo_bench")
    out = tmp_path / "out"
    assert mod.main(["--quick", "--out", str(out)]) == 0
    summary = json.loads((out / "photo_bench.json").read_text())
    rows = summary["rows"]
    # every recipe, each with its own planner (from the model file) and random, on the same trials
    assert [(r["variant"], r["planner"]) for r in rows] == [
        ("recipe robust", "mi-class-pairwise-stable"), ("recipe robust", "random"),
        ("recipe thesis", "mi-class-pairwise"), ("recipe thesis", "random")]
    for r in rows:
        assert (r["grid"], r["offset"], r["trials"]) == (40, 20.0, 2 * 3)
        assert 0 <= r["confident_error_pct_of_trials"] <= 100 - r["recognition_rate"] + 1e-9
        assert 0.0 <= r["ece"] <= 1.0 and 0.0 < r["mean_exit_prob"] <= 1.0
    # the stop rule came from each model's recipe
    robust = [r for r in rows if r["variant"] == "recipe robust"]
    thesis = [r for r in rows if r["variant"] == "recipe thesis"]
    assert all((r["min_views"], r["exclude_visited"]) == (2, True) and r["mean_views"] >= 2 for r in robust)
    assert all((r["min_views"], r["exclude_visited"]) == (1, False) for r in thesis)
    # the robust model's planner weight was fitted on the calib split (a number); the thesis's 1
    assert all(r["stability"] in (0.0, 1.0) for r in robust) and all(r["stability"] == 1.0 for r in thesis)
    md = (out / "photo_bench.md").read_text().splitlines()
    assert md[0] == mod.HEADER.splitlines()[0] and len(md) == 2 + len(rows)
    # both rates of every row with their 95 % Wilson interval, in the table and the JSON
    assert all(line.count(" [") == 2 for line in md[2:]), md
    assert all(r["recognition_rate_ci"][0] <= r["recognition_rate"] <= r["recognition_rate_ci"][1] for r in rows)
    assert (out / "photo_bench_confident_errors.png").stat().st_size > 10_000
