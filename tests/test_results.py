import json

import pytest

from jaxrecog.metrics import campaign_metrics
from jaxrecog.results import TrialResult, TrialStore, summarize, table_markdown, wilson_interval


def _trial(i, obj, ok=True, steps=2, p=0.97, stopped=True):
    return TrialResult(i, obj, 1, obj if ok else (obj + 1) % 3, 1, p, steps, stopped, ((0.1, 0.0),) * steps, ((0, 1),) * steps)


def test_summary_rows_match_hand_computation():
    rs = [_trial(0, 0), _trial(1, 0, ok=False, steps=4, p=0.5), _trial(2, 1, steps=1), _trial(3, 2, steps=3)]
    rows = summarize(rs, 3)
    assert [r.label for r in rows] == ["0", "1", "2", "Average"]  # objects 0-based, as the manifest and the CLI
    assert rows[0].rate == 50.0 and rows[0].views == 3.0 and rows[0].exit_prob == pytest.approx(0.735)
    assert rows[1].rate == 100.0 and rows[1].views == 1.0
    assert rows[3].rate == pytest.approx((50 + 100 + 100) / 3)
    md = table_markdown(rows, "demo", reference=[(100, 0.9, 2.0)] * 4)
    assert "| Average | 4 | 83.3 [" in md
    assert "| 100.0 / 0.90 / 2.0 |" in md


def test_confident_errors_count_wrong_trials_stopped_on_the_threshold_only():
    rs = [_trial(0, 0, ok=False, p=0.99), _trial(1, 0), _trial(2, 0, ok=False, p=0.6, stopped=False),
          _trial(3, 0), _trial(4, 1, steps=1)]
    rows = summarize(rs, 2)
    assert rows[0].confident_errors == 25.0  # 1 of 4: the step-limit miss is an error, not a confident one
    assert rows[0].rate == 50.0
    assert rows[1].confident_errors == 0.0
    assert rows[2].confident_errors == pytest.approx(12.5)  # mean over objects, as the rate
    md = table_markdown(rows)
    assert "Confident errors (%) [95 % CI]" in md.splitlines()[0]
    # 2 of 4 right: Wilson [15.0, 85.0] %; 1 of 4 confidently wrong: [4.6, 69.9] %
    assert "| 0 | 4 | 50.0 [15.0, 85.0] | 0.88 | 2.00 | 25.0 [4.6, 69.9] |" in md


@pytest.mark.parametrize("k,n", [(0, 1), (0, 20), (1, 20), (10, 20), (19, 20), (20, 20), (785, 800), (3, 7)])
def test_wilson_interval_matches_scipy(k, n):
    """The Wilson score interval against scipy's binomtest (the textbook form)."""
    from scipy.stats import binomtest

    ref = binomtest(k, n).proportion_ci(confidence_level=0.95, method="wilson")
    assert wilson_interval(k, n) == pytest.approx((ref.low, ref.high), abs=1e-12)
    ref90 = binomtest(k, n).proportion_ci(confidence_level=0.9, method="wilson")
    assert wilson_interval(k, n, 0.9) == pytest.approx((ref90.low, ref90.high), abs=1e-12)


def test_wilson_interval_edges():
    lo, hi = wilson_interval(0, 0)
    assert lo != lo and hi != hi  # no trials: no interval
    assert wilson_interval(20, 20) == (pytest.approx(0.8389, abs=1e-4), 1.0)  # a clean sweep still has a low end
    for bad in [(3, 2), (-1, 2)]:
        with pytest.raises(ValueError, match="successes"):
            wilson_interval(*bad)
    with pytest.raises(ValueError, match="confidence"):
        wilson_interval(1, 2, 1.0)


def test_every_rate_of_a_table_and_of_the_metrics_carries_its_interval():
    """Per object and pooled (the average row), rate and confident errors, in
    the rows, the Markdown and campaign_metrics."""
    rs = [_trial(0, 0, ok=False, p=0.99), _trial(1, 0), _trial(2, 1), _trial(3, 1, ok=False, stopped=False)]
    rows = summarize(rs, 3)
    assert rows[0].rate_ci == pytest.approx(tuple(100 * x for x in wilson_interval(1, 2)))
    assert rows[-1].rate_ci == pytest.approx(tuple(100 * x for x in wilson_interval(2, 4)))
    assert rows[-1].confident_errors_ci == pytest.approx(tuple(100 * x for x in wilson_interval(1, 4)))
    assert rows[2].trials == 0 and rows[2].rate_ci[0] != rows[2].rate_ci[0]
    md = table_markdown(rows)
    body = [line for line in md.splitlines()[2:] if not line.startswith("| 2 |")]
    assert all(line.count("[") == 2 for line in body), md
    m = campaign_metrics(rs)
    assert m["recognition_rate_ci"] == pytest.approx([100 * x for x in wilson_interval(2, 4)])
    assert m["confident_error_pct_of_trials_ci"] == pytest.approx([100 * x for x in wilson_interval(1, 4)])
    assert m["confident_error_rate_ci"] == pytest.approx([100 * x for x in wilson_interval(1, 3)])


def test_unreported_thesis_value_is_a_dash_not_nan():
    rows = summarize([_trial(0, 0)], 1)
    md = table_markdown(rows, reference=[(97.8, float("nan"), 5.1)] * 2)
    assert "97.8 \u2014 5.1" not in md and "| 97.8 / \u2014 / 5.1 |" in md and "nan" not in md


def test_store_resumes_and_drops_torn_line(tmp_path):
    store = TrialStore(tmp_path / "t.jsonl")
    for i in range(3):
        store.append(_trial(i, i % 3))
    with open(store.path, "ab") as f:
        f.write(b'{"trial": 3, "obj')  # a writer died here
    loaded = store.load()
    assert sorted(loaded) == [0, 1, 2]
    assert loaded[1] == _trial(1, 1)
    store.append(_trial(3, 0))
    again = store.load()
    assert sorted(again) == [0, 1, 2, 3]
    lines = store.path.read_text().splitlines()
    assert all(json.loads(line)["trial"] == k for k, line in enumerate(lines))


def test_store_refuses_a_corrupt_middle_line(tmp_path):
    store = TrialStore(tmp_path / "t.jsonl")
    store.append(_trial(0, 0))
    with open(store.path, "ab") as f:
        f.write(b"not json\n")
    store.append(_trial(2, 2))
    before = store.path.read_bytes()
    with pytest.raises(ValueError, match="line 2"):
        store.load()
    assert store.path.read_bytes() == before  # nothing truncated


@pytest.mark.parametrize("field,value,why", [
    ("exit_prob", "high", "exit_prob = \"high\" is not a probability (a number in 0..1)"),
    ("exit_prob", 7, "exit_prob = 7 is not a probability (a number in 0..1)"),
    ("steps", 2.5, "steps = 2.5 is not a non-negative integer"),
    ("stopped", "yes", "stopped = \"yes\" is not true or false"),
    ("configurations", [[0, "a"]], "configurations = [[0, \"a\"]] is not a list of lists of integers"),
    ("predicted_pose", None, "predicted_pose = null is not a non-negative integer"),
])
def test_a_damaged_record_is_refused_on_load_naming_file_line_and_field(tmp_path, field, value, why):
    """``"exit_prob": "high"`` ran every remaining trial, then failed with a bare TypeError."""
    store = TrialStore(tmp_path / "t.jsonl")
    store.append(_trial(0, 0))
    rec = json.loads(_trial(1, 1).to_json())
    rec[field] = value
    with open(store.path, "a") as f:
        f.write(json.dumps(rec) + "\n")
    with pytest.raises(ValueError) as e:
        store.load()
    assert str(e.value) == (f"{store.path}: line 2 is not a trial record ({why}); move the file away to start "
                            "afresh")


def test_a_record_that_is_not_an_object_or_lacks_a_field_is_refused(tmp_path):
    store = TrialStore(tmp_path / "t.jsonl")
    store.path.write_text("[1, 2]\n")
    with pytest.raises(ValueError, match=r"line 1 is not a trial record \(a JSON object expected, got list\)"):
        store.load()
    rec = json.loads(_trial(0, 0).to_json())
    del rec["exit_prob"], rec["steps"]
    store.path.write_text(json.dumps(rec) + "\n")
    with pytest.raises(ValueError, match=r"line 1 is not a trial record \(missing field\(s\) exit_prob, steps\)"):
        store.load()
    # a record as the store writes it (and one of an older store: no travel_s) loads
    ok = json.loads(_trial(0, 0).to_json())
    del ok["travel_s"]
    store.path.write_text(_trial(1, 1).to_json() + "\n" + json.dumps(ok) + "\n")
    assert sorted(store.load()) == [0, 1]


def test_a_campaign_with_a_damaged_store_fails_before_running_a_trial(tmp_path, unchecked):
    from jaxrecog.campaign import run_campaign

    store = TrialStore(tmp_path / "t.jsonl")
    rec = json.loads(_trial(0, 0).to_json())
    rec["exit_prob"] = "high"
    store.path.write_text(json.dumps(rec) + "\n")

    class NoRig:
        def __getattr__(self, name):
            raise AssertionError(f"the rig was used ({name}) before the store was read")

    class NoRecognizer(NoRig):
        pass

    with unchecked(), pytest.raises(ValueError, match="line 1 is not a trial record"):
        run_campaign(NoRecognizer(), NoRig(), [], key=None, store=store)


def test_a_case_reports_metrics_rows_carry_both_intervals(tmp_path):
    """CaseReport.metrics_table (the turntable and rig-recipe summaries): rate
    and confident errors each with the 95 % Wilson interval of its counts."""
    from jaxrecog.campaigns import CASES, CaseReport, Settings

    rs = [_trial(0, 0, ok=False, p=0.99), _trial(1, 0), _trial(2, 1), _trial(3, 1)]
    report = CaseReport(CASES["iii"], Settings(workdir=tmp_path), {"mi": summarize(rs, 2)}, {"mi": rs}, {"mi": 3.0})
    lines, metrics = report.metrics_table()
    assert "[95 % CI]" in lines[0] and metrics["mi"]["recognition_rate_ci"] == pytest.approx(
        [100 * x for x in wilson_interval(3, 4)])
    assert lines[2].startswith("| mi | 4 | 75.0 [30.1, 95.4] | 2.00 | 25.0 [4.6, 69.9] |"), lines[2]
