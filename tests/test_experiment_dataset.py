"""``jaxrecog experiment --rig dataset:FOLDER --model MODEL.NPZ``: a campaign on
a stored image database, through the real command: tables,
files, plots, recognition above chance on a database whose objects can only
be told apart by moving, TOML experiment files, and the exit codes."""

from __future__ import annotations

import dataclasses
import glob
import json
from pathlib import Path

import pytest
from builders import moving_database, write_synthetic_database
from clirun import one_error_line, run_cli
from PIL import Image

from jaxrecog import cli
from jaxrecog.database import write_database
from jaxrecog.modelfile import save_model
from jaxrecog.train import train_model


run = run_cli  # jaxrecog ARGS in this process (tests/clirun.py)


@pytest.fixture(scope="module")
def moving(tmp_path_factory):
    """The one-camera database of :func:`builders.moving_database`
    (3 positions, 2 objects x 3 poses; the objects differ at position 2 only)
    on disk, and its DB1 model."""
    root = tmp_path_factory.mktemp("moving")
    write_database(root / "db", moving_database())
    model, info = train_model(root / "db", kind="DB1", n_components=2, samples_per_image=30, return_info=True)
    path = save_model(root / "model.npz", model, training=info.to_dict(), manifest_sha256=info.manifest_sha256)
    return {"root": root, "db": root / "db", "model": Path(path)}


def _png_size(path) -> tuple[int, int]:
    assert Path(path).stat().st_size > 1000
    with Image.open(path) as im:
        return im.size


@pytest.mark.slow
def test_campaign_on_an_image_database(moving, tmp_path, saved_figures):
    out = tmp_path / "out"
    trials = 6
    p = run("--quiet", "experiment", "--rig", f"dataset:{moving['db']}", "--model", moving["model"],
            "--planners", "mi", "random", "--trials", trials, "--samples", 64, "--out", out)
    assert p.returncode == 0, p.stderr
    text = p.stdout
    # the thesis-shaped table per planner: per-object rows and the average, no thesis column
    assert f"### Image database {moving['db']} (2 objects x 3 poses, positions (3,))" in text
    for planner in ("mi", "random"):  # as the CLI spells them
        assert f"**{planner} — {trials} trials per object" in text
    assert text.count("| Average | 12 |") == 2 and text.count("| 1 | 6 |") == 2 and "Thesis" not in text
    # one numbering: the table's rows and the bars' ticks are the manifest's objects (0-based, as --object)
    objects = sorted({int(r.split(",")[3]) for r in (moving["db"] / "manifest.csv").read_text().splitlines()[1:]})
    assert objects == [0, 1] and text.count("| 0 | 6 |") == 2
    (bars,) = saved_figures
    assert bars["xticks"][1] == ["0", "1", "Average"] and bars["xlabels"][1] == "object"
    # files: tables and the campaign bars, their paths printed
    for name in ("case_dataset.md", "case_dataset.json", "campaign_dataset.png", "campaign_dataset.svg"):
        assert (out / name).is_file() and str(out / name) in text
    assert _png_size(out / "campaign_dataset.png") == (900, 650)
    js = json.loads((out / "case_dataset.json").read_text())
    assert js["case"]["name"] == "dataset" and js["case"]["database"] == str(moving["db"])
    assert set(js["tables"]) == {"mi", "random"}
    mi_avg = js["tables"]["mi"][-1]
    assert mi_avg["label"] == "Average" and mi_avg["trials"] == 2 * trials
    # far above chance: 1 in 6 (object, pose) classes
    assert mi_avg["rate"] >= 90.0
    assert js["tables"]["random"][-1]["rate"] > 50.0
    # per-trial records (resumable store): random poses and starts, every object
    records = {}
    for planner in ("mi", "random"):
        (path,) = glob.glob(str(out / "work" / "trials" / f"dataset-{planner}-*.jsonl"))
        header, *lines = Path(path).read_text().splitlines()
        assert json.loads(header)["run"]["planner"] == planner   # what the trials depend on, then the trials
        records[planner] = [json.loads(line) for line in lines]
        assert len(records[planner]) == 2 * trials
    mi = records["mi"]
    assert {r["object"] for r in mi} == {0, 1} and len({r["pose"] for r in mi}) > 1
    starts = [r["configurations"][0][0] for r in mi]
    assert len(set(starts)) > 1 and sum(s != 2 for s in starts) >= 3
    # the objects differ only at position 2: every correct answer saw it ...
    for r in mi + records["random"]:
        if r["correct"]:
            assert [2] in r["configurations"], r
    # ... and MI moves there straight from positions 0 and 1
    for r in mi:
        if r["configurations"][0] != [2]:
            assert r["configurations"][1] == [2], r

    # the same campaign from an experiment TOML file: resumes from the stored trials
    toml = tmp_path / "db.toml"
    toml.write_text(f'rig = "dataset:{moving["db"]}"\nmodel = "{moving["model"]}"\nplanners = ["mi"]\n'
                    f"[settings]\ntrials_per_object = {trials}\nsamples = 64\n")
    q = run("--quiet", "experiment", toml, "--out", out)
    assert q.returncode == 0, q.stderr
    mi_table = text[text.index("**mi —"):text.index("**random —")].split("\n", 1)[1]
    assert mi_table.strip() in q.stdout and "**random" not in q.stdout
    # --json: the same table as one document (the stored trials again), the keys of docs/cli.md
    from jaxrecog.cli._json import SCHEMAS, check

    q = run("--quiet", "experiment", toml, "--out", out, "--json")
    assert q.returncode == 0, q.stderr
    doc = json.loads(q.stdout)
    assert check(doc, SCHEMAS["experiment"]) == []
    assert (doc["case"], doc["rig"], doc["model"]) == ("dataset", f"dataset:{moving['db']}", str(moving["model"]))
    (mi_doc,) = doc["planners"]
    as_json = {k: None if v != v else v for k, v in js["tables"]["mi"][-1].items()}  # NaN (no travel) is null
    assert mi_doc["planner"] == "mi" and mi_doc["rows"][-1] == {**as_json, "thesis": None}
    assert mi_doc["rows"][-1]["travel_s"] is None
    assert str(out / "case_dataset.json") in doc["written"] and doc["settings"]["trials_per_object"] == trials


@pytest.mark.parametrize("argv,needle", [
    (["--rig", "dataset:DB"], "needs --model"),
    (["--model", "m.npz"], "--model is used with --rig dataset"),
    (["i", "--rig", "dataset:DB", "--model", "m.npz"], "leave out the case"),
    (["--rig", "dataset:", "--model", "m.npz"], "needs a folder"),
    (["--rig", "cameras.toml", "--model", "m.npz"], "expected 'synthetic' or 'dataset:FOLDER'"),
    (["--rig", "dataset:DB", "--model", "m.npz", "--trace"], "--trace"),
    (["--rig", "dataset:DB", "--model", "m.npz", "--stride", "2"], "--stride"),
    ([], "give a CASE"),
    (["--rig", "synthetic"], "give a CASE"),
])
def test_usage_errors_exit_2(argv, needle, tmp_path, capsys):
    assert cli.main(["experiment", *argv, "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert needle in err and "usage: jaxrecog experiment" in err
    assert not any(tmp_path.iterdir())  # nothing ran


def test_usage_errors_from_a_toml_file(tmp_path, capsys):
    toml = tmp_path / "e.toml"
    toml.write_text('rig = "dataset:DB"\n')
    assert cli.main(["experiment", str(toml), "--out", str(tmp_path / "o")]) == 2
    assert "needs --model" in capsys.readouterr().err
    toml.write_text('planners = ["mi"]\n')
    assert cli.main(["experiment", str(toml), "--out", str(tmp_path / "o")]) == 2
    assert "needs a 'case' key" in capsys.readouterr().err


def test_missing_model_is_usage_error(moving):
    p = run("experiment", "--rig", f"dataset:{moving['db']}")
    assert p.returncode == 2 and "needs --model" in p.stderr and "Traceback" not in p.stderr


@pytest.mark.slow
def test_runtime_failures_exit_1_with_one_line(moving, tmp_path):
    p = run("experiment", "--rig", f"dataset:{moving['db']}", "--model", tmp_path / "nope.npz", "--out", tmp_path)
    assert p.returncode == 1
    one_error_line(p, "nope.npz")
    p = run("experiment", "--rig", f"dataset:{tmp_path / 'nodb'}", "--model", moving["model"], "--out", tmp_path)
    assert p.returncode == 1
    one_error_line(p, "nodb")
    # a model of another layout: refused before any trial, naming both
    other = write_synthetic_database(tmp_path / "other", positions=(2, 2), n_objects=2, n_poses=3,
                                     image_shape=(24, 32))
    other = other if other.is_dir() else other.parent
    save_model(tmp_path / "other.npz", train_model(other, kind="DB1", n_components=2, samples_per_image=4))
    p = run("experiment", "--rig", f"dataset:{moving['db']}", "--model", tmp_path / "other.npz", "--out", tmp_path)
    assert p.returncode == 1
    one_error_line(p, "positions (3,)", "other.npz", "(2, 2)")
    # a database without a test image of every view
    db = moving_database()
    keep = ~((db.split == "test") & (db.position == 1) & (db.object == 1))
    from jaxrecog.database import ImageDatabase

    write_database(tmp_path / "gappy", ImageDatabase.from_arrays(
        db.images[keep], *(getattr(db, f)[keep] for f in ("camera", "position", "object", "pose", "split"))))
    p = run("experiment", "--rig", f"dataset:{tmp_path / 'gappy'}", "--model", moving["model"], "--out", tmp_path)
    assert p.returncode == 1
    one_error_line(p, "gappy", "3 of 18 views have no 'test' image")
    assert "\n  camera 0, position 1, object 1, pose 0\n" in p.stderr, p.stderr  # one view per line
    assert not (tmp_path / "case_dataset.md").exists()


def test_the_shipped_example_experiment_file_is_valid(tmp_path, monkeypatch):
    """examples/my_experiment.toml (named in the README) reads into the case,
    planners and Settings it says, with no unknown key."""
    from pathlib import Path

    from jaxrecog import cli
    from jaxrecog import campaigns as ex

    seen = {}

    class _Stop(Exception):
        pass

    def run_case(name, settings, planners=None, **kw):
        seen.update(name=name, settings=settings, planners=planners)
        raise _Stop

    monkeypatch.setattr(ex, "run_case", run_case)
    path = Path(__file__).resolve().parents[1] / "examples" / "my_experiment.toml"
    assert cli.main(["--quiet", "experiment", str(path), "--out", str(tmp_path / "o"),
                     "--workdir", str(tmp_path / "w")]) == 1          # _Stop: a runtime error, after parsing
    s = seen["settings"]
    assert seen["name"] == "ii" and list(seen["planners"]) == ["mi-class-pairwise", "random"]
    assert (s.trials_per_object, s.stride, s.n_components, s.samples_per_image, s.min_views,
            s.exclude_visited_positions) == (10, 4, 12, 30, 2, True)


def test_a_database_re_rendered_in_place_does_not_reuse_the_old_trials(moving, tmp_path):
    """The same manifest text with new images: the trial stores were keyed by
    the manifest and the old trials were reported as the new database's
    (78.75 % against 76.25 % fresh).  The stores are keyed by the pixels now."""
    import shutil

    import numpy as np

    from jaxrecog.campaigns import Settings, run_dataset
    from jaxrecog.database import load_database

    folder = tmp_path / "db"
    shutil.copytree(moving["db"], folder)
    settings = Settings(workdir=tmp_path / "work", trials_per_object=3, samples=16, batch=2)

    def campaign(workdir):
        report = run_dataset(folder, moving["model"], dataclasses.replace(settings, workdir=workdir), ("random",))
        return report.results["random"]

    before = campaign(tmp_path / "work")
    db = load_database(folder)
    for path, img in zip(db.paths, db.images):   # re-render: every image turned upside down, same names
        Image.fromarray(np.ascontiguousarray(img[::-1])).save(folder / path)
    assert load_database(folder).manifest_sha256 == db.manifest_sha256
    after = campaign(tmp_path / "work")
    fresh = campaign(tmp_path / "fresh")
    assert after == fresh and after != before
    assert len(list((tmp_path / "work" / "trials").glob("dataset-random-*.jsonl"))) == 2
