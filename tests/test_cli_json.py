"""``--json`` on ``plan``, ``recognize``, ``inspect`` and ``experiment`` (issue
31): one JSON document on stdout with the keys docs/cli.md documents, no NaN;
and the small frictions of the command: a closed pipe, round-off scores, the
default ``--components`` on a small database."""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from clirun import one_error_line, run_cli

from jaxrecog import cli
from jaxrecog.cli._json import SCHEMAS, check, clean, dumps
from jaxrecog.results import wilson_interval

ROOT = Path(__file__).resolve().parent.parent

run = run_cli  # jaxrecog ARGS in this process (tests/clirun.py)


def _no_constants(name: str):
    raise AssertionError(f"{name} is not JSON")


def parse(p) -> dict:
    """The run's stdout as the one JSON document it must be (NaN / Infinity refused)."""
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout, parse_constant=_no_constants)


def documented_paths(command: str) -> set[str]:
    """The key paths of ``command``'s table in docs/cli.md ("JSON output")."""
    text = (ROOT / "docs/cli.md").read_text()
    section = text.split(f"### jaxrecog {command} --json\n", 1)[1].split("\n### ", 1)[0]
    return set(re.findall(r"^\| `([^`]+)` \|", section, flags=re.M))


def emitted_paths(doc, documented: set[str], prefix: str = "") -> set[str]:
    """The key paths of a document, down to the documented leaves (an object
    the docs describe as a whole, such as ``model.training``, is one path)."""
    out = set()
    for k, v in doc.items():
        path = prefix + k
        out.add(path)
        inner = [v] if isinstance(v, dict) else [x for x in v if isinstance(x, dict)] if isinstance(v, list) else []
        sub = f"{path}[]." if isinstance(v, list) else f"{path}."
        if any(d.startswith(sub) for d in documented):
            for x in inner:
                out |= emitted_paths(x, documented, sub)
    return out


def assert_documented(command: str, *docs: dict) -> None:
    """Each document has the keys and types of ``SCHEMAS[command]``, and together
    they emit exactly the key paths docs/cli.md lists for the command."""
    documented = documented_paths(command)
    for doc in docs:
        assert check(doc, SCHEMAS[command]) == []
        assert doc["command"] == command and doc["schema_version"] == 1
    emitted = set().union(*(emitted_paths(d, documented) for d in docs))
    assert emitted == documented, (sorted(emitted - documented), sorted(documented - emitted))


def test_json_values_are_json():
    """NaN and infinities are null, NumPy values plain numbers; allow_nan=False never sees a NaN."""
    doc = {"a": float("nan"), "b": [np.float32(1.5), np.inf, -np.inf], "c": np.arange(3), "d": (Path("x"), None),
           "e": np.bool_(True), "f": {"g": np.float64("nan")}}
    assert json.loads(dumps(doc)) == {"a": None, "b": [1.5, None, None], "c": [0, 1, 2], "d": ["x", None],
                                      "e": True, "f": {"g": None}}
    with pytest.raises(TypeError, match="object"):
        clean({"x": object()})


def test_check_finds_missing_undocumented_and_mistyped_keys():
    fields = SCHEMAS["plan"]["best"].fields
    good = {"rank": 1, "config": [0, 1], "index": 1, "score": None}
    assert check(good, fields) == []
    assert check({**good, "extra": 1}, fields) == ["extra: not documented"]
    assert check({k: v for k, v in good.items() if k != "index"}, fields) == ["index: missing"]
    assert check({**good, "rank": "1"}, fields)[0].startswith("rank: str")
    assert check({**good, "config": [0, 1.5]}, fields) == ["config[1]: float, documented as integer"]


@pytest.mark.slow
def test_plan_json(tiny, tmp_path):
    p = run("plan", tiny["model"], "--samples", 64, "--top", 3, "--json", "--plot", tmp_path / "h.png")
    doc = parse(p)
    assert doc["belief"] == "uniform" and doc["images"] is None and doc["configurations"] == 6
    assert [r["rank"] for r in doc["ranking"]] == [1, 2, 3] and doc["best"] == doc["ranking"][0]
    scores = [r["score"] for r in doc["ranking"]]
    assert scores == sorted(scores, reverse=True)
    assert doc["written"] == [str(tmp_path / "h.png"), str(tmp_path / "h.svg")]
    assert doc["positions"] == [3, 2] and doc["planner"] == "mi-class-pairwise"  # the model's recipe's
    # the text form prints the same ranking
    text = run("plan", tiny["model"], "--samples", 64, "--top", 3)
    rows = [l.split() for l in text.stdout.splitlines() if l.strip()[:1].isdigit()]
    assert [(int(r[0]), r[1], int(r[2])) for r in rows] == [
        (r["rank"], ",".join(map(str, r["config"])), r["index"]) for r in doc["ranking"]]
    # after images: the decision they give
    rows = [l.split(",") for l in (tiny["db"] / "manifest.csv").read_text().splitlines()[1:]]
    paths = {(int(r[1]), int(r[2]), int(r[3]), int(r[4]), r[5]): r[0] for r in rows}
    imgs = [tiny["db"] / paths[(0, 1, 1, 0, "test")], tiny["db"] / paths[(1, 0, 1, 0, "test")]]
    after = parse(run("plan", tiny["model"], "--samples", 64, "--images", *imgs, "--at", "1,0", "--json"))
    assert after["belief"] == "images"
    assert after["images"] == {**after["images"], "at": [1, 0], "used": True, "object": 1, "pose": 0,
                               "paths": [str(i) for i in imgs]}
    assert_documented("plan", doc, after)


@pytest.mark.slow
def test_recognize_json(tiny):
    argv = ["recognize", tiny["model"], "--rig", f"dataset:{tiny['db']}", "--object", 1, "--pose", 1,
            "--samples", 64, "--start", "0,0"]
    doc = parse(run(*argv, "--json"))
    assert_documented("recognize", doc)
    steps = doc["steps"]
    assert [s["step"] for s in steps] == list(range(1, len(steps) + 1)) and steps[0]["config"] == [0, 0]
    assert doc["start"] == [0, 0] and steps[-1]["stop"] and steps[-1]["next"] is None
    assert all(s["next"] is not None and s["next"] == t["config"] for s, t in zip(steps, steps[1:]))
    for s in steps:
        probs = [b["probability"] for b in s["belief"]]
        assert len(probs) == 4 and probs == sorted(probs, reverse=True)  # 2 x 2 states, all listed
        assert (s["belief"][0]["object"], s["belief"][0]["pose"]) == (s["object"], s["pose"])
        assert probs[0] == pytest.approx(s["probability"], abs=1e-6)
        assert sum(s["object_probabilities"]) == pytest.approx(1.0, abs=1e-5)
    r = doc["result"]
    assert (r["object"], r["pose"], r["correct"], r["steps"]) == (1, 1, True, len(steps))
    assert r["travel_s"] is None  # a replayed database has no geometry
    # the text form says the same
    text = run(*argv).stdout
    assert f"result: object 1, pose 1 with P = {r['probability']:.3f} after {len(steps)} step(s) -- correct" in text


@pytest.mark.slow
def test_inspect_json(tiny, tmp_path):
    model = parse(run("inspect", tiny["model"], "--json", "--plot-dir", tmp_path))
    db = parse(run("inspect", tiny["db"], "--json"))
    assert model["kind"] == "model" and model["database"] is None and db["kind"] == "database" and db["model"] is None
    m = model["model"]
    assert (m["objects"], m["poses"], m["classes"], m["positions"], m["components"]) == (2, 2, 4, [3, 2], 3)
    assert m["image_shape"] == [30, 40] and m["training"]["kind"] == "DB2" and m["training"]["K"] == 3
    assert m["recipe"]["name"] == "thesis" and m["recipe"]["recorded"] is True  # save_model's default
    assert [c["camera"] for c in m["per_camera"]] == [0, 1] and m["per_camera"][0]["eigenspaces"] == 3
    assert m["per_camera"][0]["variance_factors"] is None
    assert model["written"] == [str(tmp_path / "eigenimages.png"), str(tmp_path / "eigenimages.svg")]
    d = db["database"]
    assert d["splits"] == {"train": 20, "test": 20, "calib": 0} and d["positions"] == [3, 2] and d["images"] == 40
    # a calibrated model: its variance factors per camera, [position][level]
    from jaxrecog.calibration import calibrate_model
    from jaxrecog.database import ImageDatabase, load_database
    from jaxrecog.modelfile import load_model, save_model
    from jaxrecog.recipes import get_recipe

    full = load_database(tiny["db"])
    split = np.where(np.asarray(full.split) == "test", "calib", np.asarray(full.split))
    calib = ImageDatabase.from_arrays(full.images, full.camera, full.position, full.object, full.pose, split)
    cal_model, _ = calibrate_model(load_model(tiny["model"]), calib)
    save_model(tmp_path / "cal.npz", cal_model, recipe=get_recipe("robust").to_dict())
    cal = parse(run("inspect", tmp_path / "cal.npz", "--json"))
    factors = cal["model"]["per_camera"][1]["variance_factors"]  # camera 1: [2 positions][levels]
    assert np.asarray(factors).shape == (2, len(m["levels"])) and np.all(np.asarray(factors) >= 1.0)
    assert not cal["model"]["training"] and cal["model"]["recipe"] == {**get_recipe("robust").to_dict(),
                                                                          "recorded": True}
    assert_documented("inspect", model, db, cal)


def test_experiment_json(fake_experiments, tmp_path):
    """A thesis case (the campaign stubbed): its tables per planner, NaN (no travel recorded) as null."""
    out = tmp_path / "exp"
    p = run("--quiet", "experiment", "i", "--out", out, "--trials", 3, "--planners", "mi", "random", "--json")
    doc = parse(p)
    assert_documented("experiment", doc)
    assert (doc["case"], doc["rig"], doc["model"], doc["out"]) == ("i", "synthetic", None, str(out))
    assert [x["planner"] for x in doc["planners"]] == ["mi", "random"]
    rows = doc["planners"][0]["rows"]
    assert [r["label"] for r in rows] == ["0", "1", "Average"] and rows[-1]["trials"] == 6
    assert rows[-1]["travel_s"] is None and rows[0]["rate"] == pytest.approx(2 / 3 * 100)
    # every rate with its 95 % Wilson interval (2 of 3 right: [20.8, 93.9] %)
    assert rows[0]["rate_ci"] == pytest.approx([100 * x for x in wilson_interval(2, 3)])
    assert all(len(r["rate_ci"]) == 2 and len(r["confident_errors_ci"]) == 2 for r in rows)
    assert doc["settings"]["trials_per_object"] == 3 and doc["settings"]["workdir"] == str(out / "work")
    assert str(out / "case_i.json") in doc["written"] and str(out / "campaign_i.png") in doc["written"]
    assert all(Path(f).is_file() for f in doc["written"])


def test_json_errors_keep_the_one_line_and_print_nothing(tiny, tmp_path):
    p = run("plan", tmp_path / "nope.npz", "--json")
    assert p.returncode == 1 and p.stdout == ""
    one_error_line(p, "nope.npz")
    p = run("recognize", tiny["model"], "--object", 7, "--json")
    assert p.returncode == 2 and p.stdout == "" and "2 objects" in p.stderr
    p = run("inspect", tmp_path / "nodb", "--json")
    assert p.returncode == 1 and p.stdout == ""


def test_json_in_a_settings_file(tiny, tmp_path):
    cfg = tmp_path / "s.toml"
    cfg.write_text("[inspect]\njson = true\n")
    doc = parse(run("--config", cfg, "inspect", tiny["db"]))
    assert doc["kind"] == "database"


# -- small frictions --------------------------------------------------------------------


class _ClosedPipe(io.StringIO):
    """A stdout whose reader went away: every write and flush raises EPIPE."""

    def write(self, s):
        raise BrokenPipeError(32, "Broken pipe")

    def flush(self):
        raise BrokenPipeError(32, "Broken pipe")


def test_a_closed_stdout_ends_quietly(tiny):
    err = io.StringIO()
    with contextlib.redirect_stdout(_ClosedPipe()), contextlib.redirect_stderr(err):
        code = cli.main(["recipes"])
    assert code == cli.BROKEN_PIPE and err.getvalue() == ""
    with contextlib.redirect_stdout(_ClosedPipe()), contextlib.redirect_stderr(err):
        code = cli.main(["inspect", str(tiny["db"]), "--json"])
    assert code == cli.BROKEN_PIPE and err.getvalue() == ""


def test_a_broken_pipe_elsewhere_is_still_an_error(monkeypatch, capsys):
    """A broken pipe that is not stdout's (a rig's connection) is reported as any failure."""

    def broken(args):
        raise BrokenPipeError(32, "Broken pipe")

    monkeypatch.setitem(cli.COMMANDS, "recipes", broken)
    assert cli.main(["recipes"]) == 1
    assert "jaxrecog: error: [Errno 32] Broken pipe" in capsys.readouterr().err


@pytest.mark.slow
def test_a_pipe_into_head_ends_quietly():
    """The real command with its reader gone before it writes (``jaxrecog recipes | head -0``):
    no error line, no traceback, no complaint at exit; the exit code of a Unix tool ended by SIGPIPE."""
    env = dict(os.environ, JAX_PLATFORMS="cpu", PYTHONPATH=str(ROOT))
    with subprocess.Popen([sys.executable, "-m", "jaxrecog.cli", "recipes"], stdout=subprocess.PIPE,
                          stderr=subprocess.PIPE, env=env, cwd=ROOT) as proc:
        proc.stdout.close()  # long before the command has imported jax and printed
        err = proc.stderr.read().decode()
        code = proc.wait(timeout=120)
    assert code == cli.BROKEN_PIPE and err == "", err


def test_round_off_scores_print_as_zero():
    """An MI of -2.2e-08 next to scores of order 1 is 0 (text and --json); a small
    score that is the scale (a CRLB in small units) is kept."""
    from jaxrecog.cli import plan

    shown = plan.shown_scores(np.array([0.5, -2.2e-8, 0.1, -np.inf, np.nan]))
    assert shown[1] == 0.0 and not np.signbit(shown[1]) and list(shown[[0, 2]]) == [0.5, 0.1]
    assert shown[3] == -np.inf and np.isnan(shown[4])
    assert list(plan.shown_scores(np.array([-1e-5, -2e-5, 1.5e-12]))) == [-1e-5, -2e-5, 0.0]
    ranking = plan._ranking(np.array([0.5, -2.2e-8, 0.1, 0.3, 0.2, -np.inf]), (3, 2), 6)
    doc = {"images": None, "planner": "mi", "configurations": 6, "best": ranking[0], "ranking": ranking,
           "written": []}
    text = plan._text(doc)
    assert "e-08" not in text and [l.split()[-1] for l in text.splitlines()[3:]] == [
        "0.5", "0.3", "0.2", "0.1", "0", "-inf"]
    assert [r["score"] for r in clean(ranking)] == [0.5, 0.3, 0.2, 0.1, 0.0, None]


def test_default_components_fit_a_small_database(tiny, tmp_path):
    """The tiny database has 4 training images per position (rank 3): the default K = 20
    becomes 3 with one line on stderr; an explicit --components above 3 is refused, naming the flag."""
    fast = ["--recipe", "thesis", "--kind", "DB1", "--samples", 4]
    p = run("-q", "train", tiny["db"], "--out", tmp_path / "m.npz", *fast)
    assert p.returncode == 0, p.stderr
    notes = [l for l in p.stderr.splitlines() if "component" in l]
    assert notes == ["jaxrecog: K = 3 components, the database's smallest eigenspace rank (the default "
                     "--components 20 is more than the data holds)"], p.stderr
    assert "(K=3," in p.stdout
    p = run("train", tiny["db"], "--out", tmp_path / "m5.npz", *fast, "--components", 5)
    assert p.returncode == 2 and not (tmp_path / "m5.npz").exists()
    assert ("jaxrecog train: error: --components 5: the database's smallest eigenspace rank is 3"
            in p.stderr.splitlines()[-1]), p.stderr
    p = run("-q", "train", tiny["db"], "--out", tmp_path / "m3.npz", *fast, "--components", 3)
    assert p.returncode == 0 and "component" not in p.stderr
