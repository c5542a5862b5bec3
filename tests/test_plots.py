"""Figures: files written (PNG + SVG), PNG pixel size = figsize x DPI, content
that depends on the data (the marked cell, the drawn occluders), bad input."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from jaxrecog import plots
from jaxrecog.augment import SHAPES
from jaxrecog.results import ObjectRow
from jaxrecog.thesis import TABLE_7_8, TABLES

pytest.importorskip("matplotlib")


def _png(path):
    with Image.open(path) as im:
        return np.asarray(im.convert("RGB")), im.size


def _check_pair(paths, size):
    png, svg = paths
    assert png.suffix == ".png" and svg.suffix == ".svg"
    assert png.stat().st_size > 1000 and svg.stat().st_size > 1000
    assert svg.read_text().lstrip().startswith("<?xml")
    arr, wh = _png(png)
    assert wh == size
    assert arr.std() > 5  # not a blank canvas
    return arr


def test_heatmap_size_and_marked_cell(tmp_path):
    positions = (32, 7)
    scores = np.linspace(0.0, 1.0, 224)
    scores[7 * 12 + 3] = 5.0  # the best cell: v1 = 12, v2 = 3
    arr = _check_pair(plots.score_heatmap(scores, positions, tmp_path / "h.png"), (500, 800))
    red = (arr[..., 0] > 200) & (arr[..., 1] < 60) & (arr[..., 2] < 60)
    assert red.sum() > 50  # the box around the chosen configuration
    # a different best cell moves the box
    scores2 = scores.copy()
    scores2[7 * 12 + 3] = 0.0
    scores2[0] = 5.0
    arr2, _ = _png(plots.score_heatmap(scores2, positions, tmp_path / "h2")[0])
    red2 = (arr2[..., 0] > 200) & (arr2[..., 1] < 60) & (arr2[..., 2] < 60)
    ys, ys2 = np.nonzero(red)[0], np.nonzero(red2)[0]
    assert np.median(ys2) < np.median(ys)  # row 0 is above row 12


def test_heatmap_single_camera_and_nonfinite(tmp_path):
    s = np.array([0.1, np.nan, 0.3, -np.inf])
    _check_pair(plots.score_heatmap(s, (4,), tmp_path / "one"), (500, 800))


def test_heatmap_rejects_mismatch(tmp_path):
    with pytest.raises(ValueError, match="positions"):
        plots.score_heatmap(np.zeros(10), (32, 7), tmp_path / "x")


def test_belief_lines(tmp_path):
    arr = _check_pair(plots.belief_lines(np.asarray(TABLE_7_8), tmp_path / "b", true_object=5,
                                         reference=np.asarray(TABLE_7_8)), (700, 450))
    assert arr.shape == (450, 700, 3)
    with pytest.raises(ValueError, match="steps, objects"):
        plots.belief_lines(np.zeros(8), tmp_path / "bad")


def test_eigenimages(tmp_path):
    H, W, K = 12, 16, 5
    rng = np.random.default_rng(0)
    basis = np.linalg.qr(rng.normal(size=(H * W, K)))[0]
    paths = plots.eigenimages(rng.random(H * W), basis, (H, W), tmp_path / "e", eigenvalues=np.arange(K, 0, -1.0), n=3)
    _check_pair(paths, (960, 282))  # 4 tiles in one row: 4 x 2.4 in by (2.3 * 3/4 + 0.6 + 0.5) in


def test_occlusion_examples_cover_the_levels(tmp_path):
    img = np.full((60, 80), 200, np.uint8)
    levels = (0.05, 0.25)
    arr = _check_pair(plots.occlusion_examples(img, tmp_path / "o", levels=levels),
                      (int(round(100 * (1.9 * 2 + 0.9))), int(round(100 * (1.55 * len(SHAPES) + 0.7)))))
    assert arr.shape[0] == 845
    with pytest.raises(ValueError, match="gray"):
        plots.occlusion_examples(np.zeros((4, 4, 3), np.uint8), tmp_path / "bad")


def _rows(rate, views):
    rows = [ObjectRow(str(m + 1), 10, rate[m], 0.9, views[m]) for m in range(len(rate))]
    return rows + [ObjectRow("Average", 10 * len(rate), float(np.mean(rate)), 0.9, float(np.mean(views)))]


def test_campaign_bars(tmp_path, saved_figures):
    rows = {"mi": _rows([100.0] * 8, [2.0] * 8), "crlb": _rows([90.0] * 8, [3.0] * 8),
            "random": _rows([50.0] * 8, [6.0] * 8)}
    thesis = {p: TABLES[("i", p)] for p in rows}
    _check_pair(plots.campaign_bars(rows, tmp_path / "c.svg", thesis=thesis), (900, 650))
    # the legend names the planners as the CLI spells them
    assert sorted(saved_figures[0]["legend"]) == ["crlb", "mi", "random", "thesis (published)"]
    with pytest.raises(ValueError, match="no campaign"):
        plots.campaign_bars({}, tmp_path / "none")


def test_titles_wrap_at_commas_and_keep_short_phrases_whole():
    t = "Belief per step: object 5, pose 2, MI-CLASS, case iii (occluded), every 8th position"
    lines = plots.wrap_title(t, 62).split("\n")
    assert lines == ["Belief per step: object 5, pose 2, MI-CLASS,", "case iii (occluded), every 8th position"]
    assert plots.wrap_title("short", 62) == "short"
    long = plots.wrap_title("a " * 50, 20).split("\n")  # one part longer than the width: spaces
    assert all(len(line) <= 20 for line in long)


def _same_png(a, b) -> bool:
    return np.array_equal(_png(a[0])[0], _png(b[0])[0])


def test_case_bars_mark_the_thesis_where_it_has_numbers(tmp_path):
    """The thesis lookup of a report (variants map to the thesis's planner; a
    single-camera case has the MI average only; a strided table has none), and
    its bars are exactly campaign_bars with those markers and the case's title."""
    import math

    from jaxrecog.campaigns import CASES, CaseReport, Settings

    rows = {"mi": _rows([100.0] * 8, [2.0] * 8), "crlb-det": _rows([90.0] * 8, [3.0] * 8),
            "random": _rows([50.0] * 8, [6.0] * 8)}
    full = CaseReport(CASES["i"], Settings(), rows, {}, {})
    thesis = {"mi": TABLES[("i", "mi")], "crlb-det": TABLES[("i", "crlb")], "random": TABLES[("i", "random")]}
    assert {p: full.thesis_table(p) for p in rows} == thesis
    single = CaseReport(CASES["single-occluded"], Settings(), rows, {}, {})
    t = single.thesis_table("mi")
    assert t.average == (66.6, 0.74, 5.8) and len(t.rate) == 8 and all(math.isnan(x) for x in t.rate)
    assert single.reference("mi") == [None] * 8 + [(66.6, 0.74, 5.8)]
    assert single.thesis_table("crlb-det") is None and single.thesis_table("random") is None
    strided = CaseReport(CASES["i"], Settings(stride=8), rows, {}, {})
    assert all(strided.thesis_table(p) is None for p in rows)

    assert _same_png(plots.case_bars(full, tmp_path / "full"),
                     plots.campaign_bars(rows, tmp_path / "ref_full", thesis=thesis,
                                         title="Case (i): 100 trials per object, markers: thesis"))
    assert _same_png(plots.case_bars(strided, tmp_path / "s8", title="Database x"),
                     plots.campaign_bars(rows, tmp_path / "ref_s8", thesis={},
                                         title="Database x, every 8th position: 100 trials per object"))
    assert not _same_png(plots.case_bars(full, tmp_path / "full"), plots.case_bars(strided, tmp_path / "s8b"))


def test_rate_bars_carry_the_rows_wilson_interval(tmp_path):
    """The error bar of each bar is its row's 95 % Wilson interval (NaN: none)."""
    from jaxrecog.results import TrialResult, summarize, wilson_interval

    res = [TrialResult(i, i % 2, 0, i % 2 if i < 5 else 0, 0, 0.99, 1, True) for i in range(8)]
    rows = summarize(res, 2)
    lo, hi = plots.rate_interval(rows, ["0", "1", "Average", "9"])
    k0 = sum(r.correct for r in res if r.object == 0)
    assert (lo[0], hi[0]) == pytest.approx(tuple(100 * x for x in wilson_interval(k0, 4)))
    assert (lo[2], hi[2]) == pytest.approx(tuple(100 * x for x in wilson_interval(sum(r.correct for r in res), 8)))
    assert np.isnan(lo[3]) and np.isnan(hi[3])
    plots.campaign_bars({"mi-class": rows}, tmp_path / "ci")  # draws with the bars


def test_belief_groups_keep_the_true_object_and_lump_the_flat_ones():
    P = np.asarray(TABLE_7_8)
    assert plots.belief_groups(P, 5) == ([0, 1, 3, 4, 5], [2, 6, 7])
    assert plots.belief_groups(P, 6) == ([0, 1, 3, 4, 5, 6], [2, 7])  # the true object always drawn
    flat_one = np.array([[0.5, 0.5], [0.001, 0.999]])
    assert plots.belief_groups(flat_one, 1) == ([0, 1], [])  # one object alone hides nothing: its own line
    assert plots.step_labels(3, [(1, 2)]) == ["0\nprior", "1\n(1,2)", "2"]


def test_belief_trace_draws_table_7_8_beside_the_trial_it_traces(tmp_path):
    import types

    probs = np.asarray(TABLE_7_8[1:])
    res = types.SimpleNamespace(object=5, pose=2, object_probs=probs)
    title = "Belief per step: object 5, pose 2, mi, case iii (occluded)"
    with_ref = plots.belief_trace(res, tmp_path / "t", planner="mi", case="iii", occluded=True, thesis_rig=True)
    assert _same_png(with_ref, plots.belief_lines(np.asarray(TABLE_7_8), tmp_path / "r", true_object=5,
                                                  reference=np.asarray(TABLE_7_8), title=title))
    # on a strided table the thesis's trace does not apply
    plain = plots.belief_trace(res, tmp_path / "s", planner="mi", case="iii", occluded=True, thesis_rig=False)
    assert _same_png(plain, plots.belief_lines(np.asarray(TABLE_7_8), tmp_path / "p", true_object=5, title=title))
    assert not _same_png(with_ref, plain)


def test_the_trace_names_objects_and_cameras_as_the_cli_does(tmp_path, saved_figures):
    """One numbering: the traced trial of object 5 (the thesis's
    object 6 of Table 7.8) is object 5 in reproduce_thesis's table, its
    decision line and the belief plot's legend and title, and the cameras
    are 0 and 1; only the thesis's own number is named as the thesis's."""
    import types

    from clirun import script

    res = types.SimpleNamespace(object=5, pose=2, predicted_object=5, predicted_pose=2, exit_prob=0.99,
                                object_probs=np.asarray(TABLE_7_8[1:]), configurations=((0, 1), (2, 3)),
                                occluded_fraction=((0.1, 0.2), (0.0, 0.3)))
    md = script("reproduce_thesis").trace_markdown(res)
    rows = [line.split("|")[1].strip() for line in md.splitlines() if line.startswith("| Obj.")]
    assert rows == [f"Obj. {m}" for m in range(8)]
    assert "Decision: object 5, pose 2 (true object 5, pose 2)" in md
    assert "(camera 0, camera 1)" in md and "Thesis Table 7.8 (the thesis's object 6 = object 5" in md
    plots.belief_trace(res, tmp_path / "t", planner="mi", case="iii", occluded=True, thesis_rig=True)
    (fig,) = saved_figures
    assert fig["titles"][0].startswith("Belief per step: object 5, pose 2, mi")
    # objects 2, 6 and 7 never pass 1 % after the prior: one summed line, not three hidden at zero
    assert fig["legend"][:5] == [f"object {m}" + (" (true)" if m == 5 else "") for m in (0, 1, 3, 4, 5)]
    assert fig["legend"][5:] == ["others: 2, 6, 7\n(each \u2264 1 %, summed)", "thesis Table 7.8 (object 5)"]
    # each step names the configuration its image set was taken at
    assert fig["xticks"][0][:3] == ["0\nprior", "1\n(0,1)", "2\n(2,3)"]
