"""``Settings.stride``: the thesis campaigns end to end on a thinned table
(every 8th position: 4 x 1 configurations, 160 rendered images), for real —
``jaxrecog demo`` and ``scripts/reproduce_thesis.py`` train, run a campaign
and write their tables and plots; each stride has its own caches.  Both start
from the session's one rendered strided database (``strided_workdir``,
rendered by the same ``prepare`` they call), so it is rendered once, not twice."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from clirun import run_cli, run_script
from PIL import Image

from jaxrecog.campaigns import CaseReport, Settings, make_rig, results_dir, rig_table



def png_size(path) -> tuple[int, int]:
    assert Path(path).stat().st_size > 1000
    with Image.open(path) as im:
        return im.size


def test_stride_thins_the_table_and_names_the_caches(tmp_path, unchecked):
    assert rig_table(Settings()).positions == (32, 7)
    assert rig_table(Settings(stride=8)).positions == (4, 1)
    assert rig_table(Settings(stride=4)).positions == (8, 2)  # as `jaxrecog render --stride 4`
    with make_rig(Settings(stride=8), (0,)) as rig:
        assert rig.positions == (4,)
    assert results_dir(Settings(workdir=tmp_path)) == tmp_path / "results"
    assert results_dir(Settings(workdir=tmp_path, stride=8)) == tmp_path / "results-stride8"
    for bad in (0, -1, 1.5, True):
        with unchecked(), pytest.raises(ValueError, match="stride"):  # 1.5: the guard, not the checker
            Settings(stride=bad)
    # a strided table is not the thesis's rig: no thesis numbers beside its tables
    from jaxrecog.campaigns import CASES

    assert CaseReport(CASES["i"], Settings(), {}, {}, {}).reference("mi") is not None
    assert CaseReport(CASES["i"], Settings(stride=8), {}, {}, {}).reference("mi") is None


def _assert_small_database(work: Path) -> None:
    manifest = work / "database-stride8" / "manifest.csv"
    assert len(manifest.read_text().splitlines()) == 1 + (4 + 1) * 8 * 4
    assert not (work / "database").exists()  # the full table's cache is neither made nor used


@pytest.mark.slow
def test_demo_on_a_strided_table(tmp_path, strided_workdir):
    out = tmp_path / "demo"
    strided_workdir(out / "work")
    p = run_cli("--quiet", "demo", "--stride", "8", "--trials", "1", "--planners", "mi-class", "--out", out)
    assert p.returncode == 0, p.stderr
    text = p.stdout
    assert "positions (4, 1), 8 objects x 4 poses" in text
    assert "training: kind DB2, K 12, samples_per_image 30" in text
    assert "### Case (iii)" in text and "**mi-class — 1 trials per object" in text
    assert "| Average | 8 |" in text and "Thesis" not in text
    sizes = {"campaign_iii": (900, 650), "belief_trace": (700, 450), "mi_scores": (500, 800),
             "eigenimages": (960, 515), "occlusion_examples": (1040, 845)}
    for stem, size in sizes.items():
        assert str(out / f"{stem}.png") in text
        assert png_size(out / f"{stem}.png") == size
        assert (out / f"{stem}.svg").is_file()
    js = json.loads((out / "case_iii.json").read_text())
    assert js["settings"]["stride"] == 8 and js["tables"]["mi-class"][-1]["trials"] == 8
    work = out / "work"
    _assert_small_database(work)
    assert sorted(x.name for x in work.glob("model-*.npz")) == [
        "model-db1-stride8-K12-S30-seed0.npz", "model-db2-stride8-K12-S30-seed0.npz"]


@pytest.mark.slow
def test_reproduce_thesis_script_on_a_strided_table(tmp_path, strided_workdir):
    work = strided_workdir(tmp_path / "thesis")
    p = run_script("reproduce_thesis", "--case", "i", "--trials", "1", "--stride", "8", "--batch", "4", "--workdir", work, "--quiet")
    assert p.returncode == 0, p.stderr
    text = p.stdout
    assert "### Case (i)" in text and "Thesis" not in text
    for planner in ("mi", "mi-class", "crlb", "random"):  # case (i)'s planners, as the CLI spells them,, each on the same 8 trials
        assert f"**{planner} — 1 trials per object" in text
    assert text.count("| Average | 8 |") == 4
    md = work / "results-stride8" / "case-i.md"
    assert f"wrote {md}" in text and md.read_text().strip() in text
    js = json.loads((work / "results-stride8" / "case-i.json").read_text())
    assert js["settings"]["stride"] == 8 and set(js["tables"]) == {"mi", "mi-class", "crlb", "random"}
    avg = js["tables"]["mi"][-1]
    assert avg["label"] == "Average" and avg["rate"] > 100 / 32  # above chance (32 classes)
    _assert_small_database(work)
    assert not (work / "results").exists()
    # case (i) needs the DB1 model only
    assert [x.name for x in work.glob("model-*.npz")] == ["model-db1-stride8-K20-S100-seed0.npz"]
    assert len(list((work / "trials").glob("case-i-*.jsonl"))) == 4
    q = run_script("reproduce_thesis", "--case", "iv")
    assert q.returncode == 2 and "'iv'" in q.stderr and "Traceback" not in q.stderr


def test_reproduce_thesis_takes_a_recipe():
    """``--recipe`` (default thesis: the settings the script always built);
    ``robust`` brings its training and stop rule, and --likelihood overrides
    only the family."""
    from clirun import script

    from jaxrecog.kernels import DEFAULT_LIKELIHOOD
    from jaxrecog.recipes import ROBUST

    mod = script("reproduce_thesis")
    parse = mod.build_parser().parse_args
    thesis = mod._settings(parse(["--workdir", "w"]))
    assert thesis.flat() == Settings(workdir="w", likelihood=DEFAULT_LIKELIHOOD, likelihood_options={}).flat()
    assert thesis.recipe.name == "thesis"
    robust = mod._settings(parse(["--workdir", "w", "--recipe", "robust"]))
    assert robust.recipe.name == "robust" and robust.likelihood == ROBUST.likelihood
    assert (robust.p_threshold, robust.min_views, robust.adaptive_scale) == (0.99, 2, 32.0)
    diag = mod._settings(parse(["--workdir", "w", "--recipe", "robust", "--likelihood", "view-mixture"]))
    assert diag.likelihood == "view-mixture" and diag.min_views == 2
    with pytest.raises(ValueError, match="interpolated views are mixture components"):  # a part that contradicts
        mod._settings(parse(["--workdir", "w", "--recipe", "robust", "--likelihood", "gaussian-diag"]))
    with pytest.raises(SystemExit):
        parse(["--recipe", "fast"])
