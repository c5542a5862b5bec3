"""The ``jaxrecog`` command: every subcommand on a tiny database and model,
exit codes (0 / 1 runtime / 2 usage), files written, PNG sizes, TOML settings,
and docs/cli.md in step with --help."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from builders import write_synthetic_database
from clirun import one_error_line, run_cli
from PIL import Image

from jaxrecog import cli
from jaxrecog.modelfile import save_model
from jaxrecog.train import train_model

ROOT = Path(__file__).resolve().parent.parent


run = run_cli  # jaxrecog ARGS in this process (tests/clirun.py)


def test_the_installed_command_runs(tiny):
    """The real entry point (``python -m jaxrecog.cli``) in a fresh process:
    exit codes and the one error line, once, the way a shell sees them."""
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    ok = subprocess.run([sys.executable, "-m", "jaxrecog.cli", "inspect", str(tiny["model"])],
                        capture_output=True, text=True, timeout=120, env=env)
    assert ok.returncode == 0, ok.stderr
    assert ok.stdout.strip()
    bad = subprocess.run([sys.executable, "-m", "jaxrecog.cli", "inspect", str(tiny["root"] / "nope.npz")],
                         capture_output=True, text=True, timeout=120, env=env)
    assert bad.returncode == 1
    one_error_line(bad, "nope.npz")


def png_size(path) -> tuple[int, int]:
    assert Path(path).stat().st_size > 1000
    with Image.open(path) as im:
        return im.size


# -- usage errors -----------------------------------------------------------

@pytest.mark.parametrize("argv,needle", [
    ([], "required"),
    (["train"], "DATABASE"),
    (["plan", "m.npz", "--planner", "best"], "invalid choice"),
    (["recognize", "m.npz", "--threshold", "2"], "probability"),
    (["recognize", "m.npz", "--start", "a,b"], "positions like"),
    (["render", "--out", "x", "--stride", "0"], "positive"),
    (["nosuchcommand"], "invalid choice"),
])
def test_bad_arguments_exit_2(argv, needle, capsys):
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert needle in err and "usage:" in err


def test_help_of_every_subcommand(capsys):
    for name in cli.COMMANDS:
        assert cli.main([name, "--help"]) == 0
        out = capsys.readouterr().out
        assert out.startswith(f"usage: jaxrecog {name}")
        # every option has a help text
        parser = cli.subparsers(cli.build_parser())[name]
        for a in parser._actions:
            assert a.help, (name, a.dest)


def test_subcommands_are_the_public_modules_of_the_package():
    """A new subcommand is one new module in jaxrecog/cli/: found, not listed;
    --help keeps the workflow order (each module's ORDER)."""
    import importlib

    modules = sorted(p.stem for p in Path(cli.__file__).parent.glob("[!_]*.py"))
    assert sorted(cli.COMMANDS) == modules
    order = {name: importlib.import_module(f"jaxrecog.cli.{name}").ORDER for name in modules}
    assert list(cli.COMMANDS) == sorted(modules, key=order.__getitem__)
    # the workflow's order, whatever commands are added between
    workflow = ["render", "train", "inspect", "plan", "recognize", "experiment"]
    assert [c for c in cli.COMMANDS if c in workflow] == workflow
    assert list(cli.subparsers(cli.build_parser())) == list(cli.COMMANDS)


def test_missing_model_exit_1_one_line(tmp_path):
    p = run("inspect", tmp_path / "nope.npz")
    assert p.returncode == 1
    one_error_line(p, "nope.npz")
    p = run("plan", tmp_path / "nope.npz")
    assert p.returncode == 1
    one_error_line(p, "nope.npz")


def test_corrupt_model_exit_1_and_debug_traceback(tmp_path):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"PK\x03\x04 this is not a model" * 10)
    p = run("inspect", bad)
    assert p.returncode == 1
    one_error_line(p, "bad.npz")
    p = run("--debug", "inspect", bad)
    assert p.returncode == 1 and "Traceback" in p.stderr


# -- subcommands on the tiny model ---------------------------------------------

@pytest.mark.slow
def test_inspect_model_and_database(tiny, tmp_path, saved_figures):
    p = run("inspect", tiny["model"], "--plot-dir", tmp_path, "--camera", 1, "--position", 1)
    assert p.returncode == 0, p.stderr
    assert "2 objects x 2 poses" in p.stdout and "kind DB2" in p.stdout
    assert png_size(tmp_path / "eigenimages.png") == (960, 282)  # mean + K=3 eigenimages in one row
    (fig,) = saved_figures  # the camera and position as given (0-based), the eigenimages numbered as basis[:, k]
    assert fig["titles"][0].startswith("Camera 1, position 1: ")
    assert [t.split("\n")[0] for t in fig["titles"][1:5]] == ["mean image", "eigenimage 0", "eigenimage 1",
                                                              "eigenimage 2"]
    assert (tmp_path / "eigenimages.svg").is_file()
    p = run("inspect", tiny["db"], "--plot-dir", tmp_path)
    assert p.returncode == 0, p.stderr
    assert "splits: train 20, test 20, calib 0" in p.stdout and "positions (3, 2)" in p.stdout
    assert png_size(tmp_path / "occlusion_examples.png") == (1040, 845)
    p = run("inspect", tiny["model"], "--plot-dir", tmp_path, "--camera", 2)
    assert p.returncode == 2 and "no camera 2" in p.stderr


def test_train_writes_a_loadable_model_and_config_file(tiny, tmp_path):
    cfg = tmp_path / "settings.toml"
    cfg.write_text('[global]\nquiet = true\n\n[train]\nkind = "DB1"\ncomponents = 2\nsamples = 4\n')
    out = tmp_path / "m1.npz"
    p = run("--config", cfg, "train", tiny["db"], "--out", out, "--components", 3)
    assert p.returncode == 0, p.stderr
    from jaxrecog.modelfile import load_model, load_model_meta

    m = load_model(out)
    meta = load_model_meta(out)["training"]
    assert meta["kind"] == "DB1" and meta["samples_per_image"] == 4  # from the file
    assert m.cameras[0].basis.shape[-1] == 3  # the command line wins over the file
    assert len(m.levels) == 1
    cfg.write_text("[train]\nkindd = 'DB1'\n")
    p = run("--config", cfg, "train", tiny["db"], "--out", out)
    assert p.returncode == 2 and "kindd" in p.stderr
    p = run("--config", tmp_path / "absent.toml", "train", tiny["db"], "--out", out)
    assert p.returncode == 2 and "absent.toml" in p.stderr


def test_train_capture_augmentation_in_the_model_file_and_inspect(tiny, tmp_path):
    out = tmp_path / "cap.npz"
    p = run("-q", "train", tiny["db"], "--out", out, "--kind", "DB1", "--components", 3, "--samples", 4,
            "--rotation", 4, "--scale", 0.05, "--blur", "0.5,1.5", "--gain", 0.1, "--gain-cells", 4,
            "--occluder-gray", "30,220", "--max-shift", 2)
    assert p.returncode == 0, p.stderr
    from jaxrecog.modelfile import load_model_meta

    aug = load_model_meta(out)["training"]["augment"]
    assert aug["max_rotation"] == 4.0 and aug["max_scale"] == 0.05 and aug["gain_amplitude"] == 0.1
    assert list(aug["blur_sigma"]) == [0.5, 1.5] and aug["gain_cells"] == 4
    assert list(aug["occluder_gray"]) == [30.0, 220.0] and aug["max_shift"] == 2
    p = run("inspect", out)
    assert p.returncode == 0, p.stderr
    assert "max_shift 2;" in p.stdout, p.stdout
    assert ("capture rotation +-4 deg, scale +-0.05, blur sigma 0.5..1.5 px, gain +-0.1 (4x4 grid); "
            "occluders gray 30..220" in p.stdout), p.stdout
    p = run("inspect", tiny["model"])  # trained without: says so
    assert "noise_sigma 4.0, brightness_sigma 8.0, max_shift 3; capture off" in p.stdout, p.stdout
    cfg = tmp_path / "cap.toml"
    cfg.write_text("[train]\nblur = 1.0\nrotation = 2\n")  # TOML numbers, not strings
    p = run("-q", "--config", cfg, "train", tiny["db"], "--out", out, "--kind", "DB1", "--components", 3,
            "--samples", 4)
    assert p.returncode == 0, p.stderr
    aug = load_model_meta(out)["training"]["augment"]
    assert list(aug["blur_sigma"]) == [0.0, 1.0] and aug["max_rotation"] == 2.0
    for bad, needle in ((["--rotation", "-1"], "--rotation"), (["--blur", "2,1"], "--blur"),
                        (["--scale", "1"], "--scale"), (["--gain-cells", "1"], "--gain-cells"),
                        (["--occluder-gray", "200,100"], "--occluder-gray"), (["--occluder-gray", "0,300"], "--occluder-gray"),
                        (["--max-shift", "-1"], "--max-shift")):
        p = run("train", tiny["db"], "--out", out, *bad)
        assert p.returncode == 2 and needle in p.stderr, p.stderr


def test_train_bad_database_and_calibrate(tiny, tmp_path):
    p = run("train", tmp_path / "nodb", "--out", tmp_path / "m.npz")
    assert p.returncode == 1
    one_error_line(p, "nodb")
    # the tiny database has no 'calib' rows: a clear one-line usage error before training, no model written
    p = run("train", tiny["db"], "--out", tmp_path / "c.npz", "--samples", 4, "--components", 2, "--calibrate")
    assert p.returncode == 2
    assert "--calibrate (recipe robust) needs a 'calib' split" in p.stderr.strip().splitlines()[-1]
    assert not (tmp_path / "c.npz").exists()

    # the same database with its test rows relabelled 'calib': calibrated, saved, reported
    from jaxrecog.database import ImageDatabase, load_database, write_database
    from jaxrecog.modelfile import load_model

    db = load_database(tiny["db"])
    split = np.where(np.asarray(db.split) == "test", "calib", np.asarray(db.split))
    write_database(tmp_path / "cdb", ImageDatabase.from_arrays(db.images, db.camera, db.position, db.object, db.pose, split))
    p = run("train", tmp_path / "cdb", "--out", tmp_path / "c.npz", "--samples", 4, "--components", 2, "--calibrate")
    assert p.returncode == 0, p.stderr
    model = load_model(tmp_path / "c.npz")
    assert all(c.calibration is not None and np.all(np.asarray(c.calibration) >= 1.0) for c in model.cameras)
    p = run("inspect", tmp_path / "c.npz")
    assert p.returncode == 0 and "calibration" in p.stdout
    # the factors per camera and position, as stored (one row: fitted per position, all levels alike)
    for i, cam in enumerate(model.cameras):
        f = np.asarray(cam.calibration, dtype=float)
        assert np.all(f == f[:, :1])
        assert f"  camera {i} variance factors, positions 0..{f.shape[0] - 1}:" in p.stdout
        assert "    all levels: " + " ".join(f"{x:.3g}" for x in f[:, 0]) in p.stdout.splitlines()


@pytest.mark.slow
def test_plan_uniform_and_after_images(tiny, tmp_path, saved_figures):
    p = run("plan", tiny["model"], "--planner", "mi", "--samples", 64, "--plot", tmp_path / "h.png", "--top", 4)
    assert p.returncode == 0, p.stderr
    lines = p.stdout.splitlines()
    assert "6 configurations (uniform belief)" in lines[0]
    ranks = [l.split() for l in lines if l.strip()[:1].isdigit()]
    assert [int(r[0]) for r in ranks] == [1, 2, 3, 4]
    scores = [float(r[3]) for r in ranks]
    assert scores == sorted(scores, reverse=True)
    best = lines[0].split("best: (")[1].split(")")[0]
    assert ranks[0][1] == best
    assert png_size(tmp_path / "h.png") == (500, 800)
    # the heat map numbers cameras and positions as the CLI does (0-based): its chosen box is the best config
    (fig,) = saved_figures
    assert (fig["ylabels"][0], fig["xlabels"][0]) == ("camera 0 position", "camera 1 position")
    assert fig["yticks"][0] == ["0", "1", "2"] and fig["xticks"][0] == ["0", "1"]
    assert fig["legend"] == [f"chosen ({best})"]
    # images at a configuration: one per camera, the model's size
    db = tiny["db"]
    imgs = [db / "train/c0/v01/m1_p0.png", db / "train/c1/v00/m1_p0.png"]
    rows = [l.split(",") for l in (db / "manifest.csv").read_text().splitlines()[1:]]
    paths = {(int(r[1]), int(r[2]), int(r[3]), int(r[4]), r[5]): r[0] for r in rows}
    imgs = [db / paths[(0, 1, 1, 0, "test")], db / paths[(1, 0, 1, 0, "test")]]
    p = run("plan", tiny["model"], "--samples", 64, "--images", *imgs, "--at", "1,0")
    assert p.returncode == 0, p.stderr
    assert "best (object, pose) = (1, 0)" in p.stdout
    p = run("plan", tiny["model"], "--images", imgs[0], "--at", "1")
    assert p.returncode == 2 and "2 camera(s)" in p.stderr
    p = run("plan", tiny["model"], "--images", imgs[0], tmp_path / "no.png", "--at", "1,0")
    assert p.returncode == 1
    one_error_line(p, "no.png")


@pytest.mark.slow
def test_recognize_dataset_rig(tiny, tmp_path, saved_figures):
    p = run("recognize", tiny["model"], "--rig", f"dataset:{tiny['db']}", "--object", 1, "--pose", 1,
            "--samples", 64, "--start", "0,0", "--plot", tmp_path / "b.png")
    assert p.returncode == 0, p.stderr
    assert "step" in p.stdout and "result: object 1, pose 1" in p.stdout and "correct" in p.stdout
    assert png_size(tmp_path / "b.png") == (700, 450)
    # the belief plot numbers the objects as --object and the printed table do (0-based)
    (fig,) = saved_figures
    assert fig["titles"][0].startswith("Belief per step: object 1, pose 1,")
    assert fig["legend"] == ["object 0", "object 1 (true)"]
    p = run("recognize", tiny["model"], "--rig", "dataset:", "--samples", 64)
    assert p.returncode == 2
    p = run("recognize", tiny["model"], "--rig", "nonsense", "--samples", 64)
    assert p.returncode == 2 and "synthetic" in p.stderr
    p = run("recognize", tiny["model"], "--object", 7)
    assert p.returncode == 2 and "2 objects" in p.stderr


def test_recognize_on_a_database_without_test_rows_is_one_plain_line(tiny, tmp_path):
    """Nothing to replay: one line that says what to add, no exception class name."""
    db = write_synthetic_database(tmp_path / "db", positions=(3, 2), n_objects=2, n_poses=2, image_shape=(30, 40))
    p = run("recognize", tiny["model"], "--rig", f"dataset:{db}", "--object", 0, "--pose", 0)
    assert p.returncode == 1
    line = one_error_line(p, f"--rig dataset:{db}", "no 'test' rows", "--test-per-view")
    assert "RigError" not in line


def test_render_a_one_camera_layout(tmp_path):
    """The synthetic rig with camera 0 only, every 8th position (4 positions).
    Render, train and recognize on the synthetic rig, and a model refused by
    a rig of other positions: README's tutorial (tests/test_readme_tutorial.py)."""
    layout = ["--cameras", 1, "--stride", 8, "--objects", 2, "--poses", 2]
    p = run("render", "--out", tmp_path / "db", *layout)
    assert p.returncode == 0, p.stderr
    assert json.loads((tmp_path / "db/rig.json").read_text())["positions"] == [4]
    assert len((tmp_path / "db/manifest.csv").read_text().splitlines()) == 1 + 4 * 2 * 2


# -- experiment and demo, with the campaign replaced by a stub ---------------------

def test_experiment_case_and_toml(fake_experiments, tmp_path, capsys):
    out = tmp_path / "exp"
    assert cli.main(["--quiet", "experiment", "i", "--out", str(out), "--trials", "3", "--planners", "mi",
                     "random", "--trace"]) == 0
    name, settings, planners = fake_experiments["run_case"]
    assert name == "i" and planners == ["mi", "random"] and settings.trials_per_object == 3
    assert settings.workdir == out / "work"
    text = capsys.readouterr().out
    assert "Case (i)" in text and str(out / "campaign_i.png") in text
    assert png_size(out / "campaign_i.png") == (900, 650)
    assert png_size(out / "belief_trace.png") == (700, 450)
    assert json.loads((out / "case_i.json").read_text())["tables"]["mi"][0]["trials"] == 3
    toml = tmp_path / "e.toml"
    toml.write_text('case = "iii"\nplanners = ["crlb"]\n[settings]\nsamples = 99\nseed = 4\n')
    assert cli.main(["experiment", str(toml), "--out", str(out), "--seed", "5"]) == 0
    name, settings, planners = fake_experiments["run_case"]
    assert (name, planners, settings.samples, settings.seed) == ("iii", ["crlb"], 99, 5)
    # --stride reaches the Settings (a thinned table: no thesis markers, cached apart)
    assert cli.main(["--quiet", "experiment", "i", "--out", str(out), "--stride", "8", "--planners", "mi"]) == 0
    assert fake_experiments["run_case"][1].stride == 8
    toml.write_text('case = "i"\n[settings]\nstride = 4\n')
    assert cli.main(["--quiet", "experiment", str(toml), "--out", str(out)]) == 0
    assert fake_experiments["run_case"][1].stride == 4
    # the planner's sample floor: default 8, overridable
    assert fake_experiments["run_case"][1].min_per_stratum == 8
    assert cli.main(["--quiet", "experiment", "i", "--out", str(out), "--min-per-stratum", "2"]) == 0
    assert fake_experiments["run_case"][1].min_per_stratum == 2
    toml.write_text('case = "iii"\nbogus = 1\n')
    assert cli.main(["experiment", str(toml), "--out", str(out)]) == 2
    assert "bogus" in capsys.readouterr().err
    assert cli.main(["experiment", "iv", "--out", str(out)]) == 2


def test_demo_quick_is_the_smoke_sizes_unless_given():
    """``demo --quick``: every 8th position, 2 trials per object; a size given wins."""
    from jaxrecog.cli import build_parser, demo

    def sizes(*argv):
        return demo.demo_sizes(build_parser().parse_args(["demo", *argv]))

    assert sizes() == (1, 10) and sizes("--quick") == (8, 2)
    assert sizes("--quick", "--stride", "4") == (4, 2) and sizes("--quick", "--trials", "5") == (8, 5)


@pytest.mark.slow
def test_demo_writes_every_plot(fake_experiments, tiny, tmp_path, capsys):
    out = tmp_path / "demo"
    assert cli.main(["demo", "--out", str(out), "--trials", "3"]) == 0
    assert fake_experiments["prepare"].stride == 1
    text = capsys.readouterr().out
    sizes = {"campaign_iii": (900, 650), "belief_trace": (700, 450), "mi_scores": (500, 800),
             "eigenimages": (960, 282), "occlusion_examples": (1040, 845)}
    for stem, size in sizes.items():
        assert str(out / f"{stem}.png") in text
        assert png_size(out / f"{stem}.png") == size
        assert (out / f"{stem}.svg").is_file()
    assert "| Average |" in text
    assert fake_experiments["run_case"][0] == "iii"
    # the prepared models' summaries, before the campaign's table
    assert text.index("DB2 model:\nmodel file " + str(tiny["model"])) < text.index("| Average |")
    assert "2 objects x 2 poses" in text and "kind DB2" in text


# -- bench -------------------------------------------------------------------

def test_bench_merges_json_and_reports_failures(tmp_path):
    bench = tmp_path / "benchmarks"
    bench.mkdir()
    (bench / "bench_fast.py").write_text(
        "import argparse, json\nap = argparse.ArgumentParser(); ap.add_argument('--out')\n"
        "a = ap.parse_args(); open(a.out, 'w').write(json.dumps({'median_s': 0.25, 'n': 3, 'cpus': 2, 'step_ms': {'median': 0.5}}))\n")
    p = run("bench", "--benchmarks", bench, "--out", tmp_path / "out")
    assert p.returncode == 0, p.stderr
    merged = json.loads((tmp_path / "out/bench.json").read_text())
    assert merged == {"fast": {"median_s": 0.25, "n": 3, "cpus": 2, "step_ms": {"median": 0.5}}}
    assert "median_s=0.25, step_ms.median=0.5" in p.stdout  # timing leaves at any depth
    assert "cpus" not in p.stdout and "n=3" not in p.stdout
    (bench / "bench_broken.py").write_text("raise SystemExit('boom')\n")
    p = run("bench", "--benchmarks", bench, "--out", tmp_path / "out")
    assert p.returncode == 1
    one_error_line(p, "broken")
    assert json.loads((tmp_path / "out/bench.json").read_text())["broken"]["error"] == "boom"
    p = run("bench", "--benchmarks", tmp_path / "empty", "--out", tmp_path / "out")
    assert p.returncode == 1
    one_error_line(p, "no benchmark scripts")


# -- progress and docs -----------------------------------------------------------

def test_progress_quiet_off_a_terminal():
    import io

    from jaxrecog import _progress as progress

    class TTY(io.StringIO):
        def isatty(self):
            return True

    progress.set_quiet(False)
    assert not progress.enabled(io.StringIO())
    assert progress.enabled(TTY())
    s = TTY()
    with progress.bar(10, "work", "img", stream=s) as b:
        b.update(4)
        b.set(10, 10)
    assert "work" in s.getvalue() and "10/10" in s.getvalue()
    progress.set_quiet(True)
    try:
        assert not progress.enabled(TTY())
    finally:
        progress.set_quiet(False)


def test_cli_docs_up_to_date():
    p = subprocess.run([sys.executable, str(ROOT / "scripts/gen_cli_docs.py"), "--check"], capture_output=True,
                       text=True)
    assert p.returncode == 0, p.stderr


def test_method_doc_names_exist():
    """Every ``file`` + ``function`` pair in docs/method.md names real code."""
    import ast
    import re

    text = (ROOT / "docs/method.md").read_text()
    checked = 0
    for line in text.splitlines():
        if not line.startswith("|"):
            continue
        code = line.rstrip("|").split("|")[-1]
        current = None
        for tok in re.findall(r"`([^`]+)`", code):
            if tok.endswith(".py"):
                current = ROOT / tok
                assert current.is_file(), tok
                tree = ast.parse(current.read_text())
                defs = {n.name for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.ClassDef))}
                defs |= {t.id for n in tree.body if isinstance(n, (ast.Assign, ast.AnnAssign))
                         for t in (n.targets if isinstance(n, ast.Assign) else [n.target])
                         if isinstance(t, ast.Name)}
            elif current is not None and re.fullmatch(r"[A-Za-z_][\w.]*", tok):
                for part in tok.split("."):
                    assert part in defs, f"{tok} not defined in {current.name}"
                checked += 1
    assert checked > 30


@pytest.mark.slow
def test_recognize_on_a_rig_from_toml(tiny, tmp_path):
    """examples/simulated_rig.toml: PTU and controller simulators + rendered images
    (32 x 7 positions); a wrong-sized model is refused with one line."""
    toml = ROOT / "examples/simulated_rig.toml"
    p = run("recognize", tiny["model"], "--rig", toml, "--samples", 32)
    assert p.returncode == 1
    one_error_line(p, "positions (32, 7)", "model.npz")
    db = write_synthetic_database(tmp_path / "db", positions=(32, 7), n_objects=2, n_poses=4,
                                  image_shape=(120, 160))
    db = db if db.is_dir() else db.parent
    model = train_model(db, kind="DB1", n_components=3, samples_per_image=4)
    save_model(tmp_path / "m.npz", model)
    p = run("recognize", tmp_path / "m.npz", "--rig", toml, "--object", 1, "--pose", 2, "--samples", 32,
            "--max-steps", 2)
    assert p.returncode == 0, p.stderr
    steps = [l.split() for l in p.stdout.splitlines() if l.strip()[:1].isdigit()]
    assert [int(s[0]) for s in steps] == list(range(1, len(steps) + 1)) and 1 <= len(steps) <= 2
    assert steps[-1][-1] == "stop" and "result: object" in p.stdout
    p = run("recognize", tmp_path / "m.npz", "--rig", tmp_path / "none.toml")
    assert p.returncode == 1
    one_error_line(p, "none.toml")


def test_bad_toml_files_are_usage_errors_naming_the_file(tmp_path):
    bad = tmp_path / "broken.toml"
    bad.write_text("case = [unclosed\n")
    p = run("experiment", bad)
    assert p.returncode == 2 and "experiment file" in p.stderr and "broken.toml" in p.stderr
    assert "not valid TOML" in p.stderr and "Traceback" not in p.stderr
    p = run("--config", bad, "inspect", tmp_path)
    assert p.returncode == 2 and "settings file" in p.stderr and "broken.toml" in p.stderr
    p = run("--config", tmp_path / "absent.toml", "inspect", tmp_path)
    assert p.returncode == 2 and "absent.toml" in p.stderr and "not found" in p.stderr


# -- images the belief cannot use: one line and exit 1, or a warning with --skip-invalid ----

BAD_IMAGES = {  # kind -> (image of the tiny model's 30x40, written as; words of the reason)
    "black": (lambda: np.zeros((30, 40), np.uint8), "png", "all-black"),
    "constant": (lambda: np.full((30, 40), 7, np.uint8), "png", "constant image (every pixel 7)"),
    "nan": (lambda: np.where(np.eye(30, 40, dtype=bool), np.nan, 50.0).astype(np.float32), "tiff",
            "30 pixel(s) are NaN"),
    "wrong size": (lambda: np.random.default_rng(0).integers(1, 255, (20, 30), dtype=np.uint8), "png",
                   "is 20x30, the model expects 30x40"),
}


def _test_image(tiny, camera, position, obj=1, pose=0):
    rows = [l.split(",") for l in (tiny["db"] / "manifest.csv").read_text().splitlines()[1:]]
    paths = {(int(r[1]), int(r[2]), int(r[3]), int(r[4]), r[5]): r[0] for r in rows}
    return tiny["db"] / paths[(camera, position, obj, pose, "test")]


def _bad_image(kind, folder) -> Path:
    make, ext, _ = BAD_IMAGES[kind]
    path = Path(folder) / f"{kind.replace(' ', '_')}.{ext}"
    assert cv2.imwrite(str(path), make())
    return path


@pytest.mark.parametrize("kind", list(BAD_IMAGES))
def test_plan_rejects_an_image_the_belief_cannot_use(tiny, tmp_path, kind):
    """`plan --images black.png ...` used to exit 0 and print the uniform prior as if the image had counted."""
    bad = _bad_image(kind, tmp_path)
    p = run("plan", tiny["model"], "--samples", 64, "--images", _test_image(tiny, 0, 1), bad, "--at", "1,0")
    assert p.returncode == 1, p.stdout
    line = one_error_line(p, str(bad), BAD_IMAGES[kind][2], "--skip-invalid")
    assert "camera" not in line and p.stdout == ""


@pytest.mark.slow
def test_plan_skip_invalid_warns_and_scores_the_unchanged_belief(tiny, tmp_path):
    bad = _bad_image("black", tmp_path)
    good = _test_image(tiny, 0, 1)
    p = run("plan", tiny["model"], "--samples", 64, "--images", good, bad, "--at", "1,0", "--skip-invalid")
    assert p.returncode == 0, p.stderr
    warnings = [l for l in p.stderr.splitlines() if l.startswith("jaxrecog: warning:")]
    assert len(warnings) == 1 and str(bad) in warnings[0] and "all-black" in warnings[0]
    # 2 objects x 2 poses: the belief is still the uniform prior
    assert "after the images at 1,0 (not used): best (object, pose) = (0, 0), P = 0.250" in p.stdout
    p = run("plan", tiny["model"], "--samples", 64, "--images", good, _test_image(tiny, 1, 0), "--at", "1,0",
            "--skip-invalid")
    assert p.returncode == 0 and "warning" not in p.stderr and "(not used)" not in p.stdout
    assert "best (object, pose) = (1, 0)" in p.stdout


def _database_with(tiny, folder, kind) -> Path:
    """The tiny database with camera 0's test images at position 0 replaced by
    a bad image (for "wrong size": every image at 20x30)."""
    from jaxrecog.database import ImageDatabase, load_database, write_database

    db = load_database(tiny["db"])
    images = np.asarray(db.images)
    if kind == "wrong size":
        images = np.stack([cv2.resize(im, (30, 20)) for im in images])
    else:
        hit = (np.asarray(db.camera) == 0) & (np.asarray(db.position) == 0) & (np.asarray(db.split) == "test")
        images = images.copy()
        images[hit] = BAD_IMAGES[kind][0]()
    out = write_database(folder, ImageDatabase.from_arrays(images, db.camera, db.position, db.object, db.pose,
                                                           db.split))
    return out if out.is_dir() else out.parent


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["black", "constant", "wrong size"])
def test_recognize_rejects_a_capture_the_belief_cannot_use(tiny, tmp_path, kind):
    db = _database_with(tiny, tmp_path / "db", kind)
    p = run("recognize", tiny["model"], "--rig", f"dataset:{db}", "--object", 1, "--pose", 1, "--start", "0,0",
            "--samples", 64)
    assert p.returncode == 1, p.stdout
    if kind == "wrong size":  # a whole database of another size: the one counts check, before any step
        assert p.stderr.splitlines() == [f"jaxrecog: error: rig dataset:{db} does not match model {tiny['model']}: "
                                         "images 20x30 vs the model's 30x40"]
    else:
        one_error_line(p, "image of camera 0 at position 0 (step 1)", BAD_IMAGES[kind][2], "--skip-invalid")
    assert "result:" not in p.stdout


@pytest.mark.slow
def test_recognize_skip_invalid_goes_on_without_the_image_set(tiny, tmp_path):
    db = _database_with(tiny, tmp_path / "db", "black")
    p = run("recognize", tiny["model"], "--rig", f"dataset:{db}", "--object", 1, "--pose", 1, "--start", "0,0",
            "--samples", 64, "--skip-invalid")
    assert p.returncode == 0, p.stderr
    warnings = [l for l in p.stderr.splitlines() if l.startswith("jaxrecog: warning:")]
    assert warnings and all("camera 0 at position 0" in w and "all-black" in w for w in warnings)
    steps = [l.split() for l in p.stdout.splitlines() if l.strip()[:1].isdigit()]
    assert steps[0][1] == "0,0" and steps[0][4] == "0.250"  # step 1 left the uniform belief as it was
    assert len(steps) >= 2 and "result: object" in p.stdout


def test_recognize_rejects_a_nan_capture(tiny, monkeypatch, capsys):
    """No CLI rig delivers NaN (they give 8-bit images), so a stub rig does: in process."""
    from jaxrecog.cli import recognize
    from jaxrecog.hardware import Capture, DatasetRig

    class NaNRig(DatasetRig):
        def capture(self):
            images = super().capture().images.astype(np.float32)
            return Capture(np.where(np.eye(30, 40, dtype=bool), np.nan, images), ())

    monkeypatch.setattr(recognize, "_make_rig", lambda args, model: NaNRig.from_folder(tiny["db"]))
    argv = ["recognize", str(tiny["model"]), "--samples", "16", "--start", "2,1", "--object", "1"]
    assert cli.main(argv) == 1
    err = capsys.readouterr().err
    assert err.count("jaxrecog: error:") == 1 and "Traceback" not in err
    assert "image of camera 0 at position 2 (step 1): 30 pixel(s) are NaN" in err


def test_experiment_view_choice_and_devices_flags(fake_experiments, tmp_path, capsys):
    """--exclude-visited, --motion-cost and --devices reach the Settings; off by default; an
    experiment TOML may set them; bad values are usage errors (exit 2) with one clear line."""
    out = tmp_path / "exp"
    assert cli.main(["--quiet", "experiment", "i", "--out", str(out), "--planners", "mi"]) == 0
    s = fake_experiments["run_case"][1]
    assert (s.exclude_visited_positions, s.motion_cost, s.devices) == (False, 0.0, 1)
    assert cli.main(["--quiet", "experiment", "i", "--out", str(out), "--planners", "mi", "--exclude-visited",
                     "--motion-cost", "0.25", "--devices", "1"]) == 0
    s = fake_experiments["run_case"][1]
    assert (s.exclude_visited_positions, s.motion_cost, s.devices) == (True, 0.25, 1)
    toml = tmp_path / "e.toml"
    toml.write_text('case = "i"\n[settings]\nmotion_cost = 0.5\nexclude_visited_positions = true\n')
    assert cli.main(["--quiet", "experiment", str(toml), "--out", str(out)]) == 0
    s = fake_experiments["run_case"][1]
    assert (s.exclude_visited_positions, s.motion_cost) == (True, 0.5)
    assert not s.shared_view
    assert cli.main(["--quiet", "experiment", "i", "--out", str(out), "--planners", "mi", "--shared-view"]) == 0
    assert fake_experiments["run_case"][1].shared_view
    assert fake_experiments["run_case"][1].min_views == 1
    assert cli.main(["--quiet", "experiment", "i", "--out", str(out), "--planners", "mi", "--min-views", "2"]) == 0
    assert fake_experiments["run_case"][1].min_views == 2
    capsys.readouterr()
    assert cli.main(["experiment", "i", "--out", str(out), "--min-views", "0"]) == 2
    assert "--min-views" in capsys.readouterr().err
    assert cli.main(["experiment", "i", "--out", str(out), "--min-views", "8"]) == 2
    assert "min_views must be an integer in [1, max_steps = 7]" in capsys.readouterr().err
    capsys.readouterr()
    assert cli.main(["experiment", "i", "--out", str(out), "--motion-cost", "-1"]) == 2
    assert "motion cost" in capsys.readouterr().err
    import jax

    n = len(jax.devices())
    assert cli.main(["experiment", "i", "--out", str(out), "--devices", str(n + 3)]) == 2
    err = capsys.readouterr().err
    assert f"--devices {n + 3}" in err and f"{n} exist" in err
    # --render-workers reaches the Settings (0 = this process, the default); a database is not rendered
    assert fake_experiments["run_case"][1].render_workers == 0
    assert cli.main(["--quiet", "experiment", "i", "--out", str(out), "--planners", "mi", "--render-workers", "3"]) == 0
    assert fake_experiments["run_case"][1].render_workers == 3
    capsys.readouterr()
    assert cli.main(["experiment", "i", "--out", str(out), "--render-workers", "-1"]) == 2
    assert "--render-workers" in capsys.readouterr().err
    assert cli.main(["experiment", "--rig", f"dataset:{tmp_path}", "--model", str(tmp_path / "m.npz"),
                     "--out", str(out), "--render-workers", "2"]) == 2
    assert "a replayed database is not rendered" in capsys.readouterr().err


def test_recognize_view_choice_flags(tiny, capsys):
    rig = f"dataset:{tiny['db']}"
    assert cli.main(["--quiet", "recognize", str(tiny["model"]), "--rig", rig, "--samples", "64", "--start", "0,0",
                     "--exclude-visited"]) == 0
    assert "result: object" in capsys.readouterr().out
    # a replayed database has no geometry: no travel times to weigh
    assert cli.main(["recognize", str(tiny["model"]), "--rig", rig, "--samples", "64", "--motion-cost", "1"]) == 2
    assert "geometry" in capsys.readouterr().err
    assert cli.main(["--quiet", "recognize", str(tiny["model"]), "--rig", rig, "--samples", "64", "--start", "0,0",
                     "--min-views", "2"]) == 0
    assert "result: object" in capsys.readouterr().out
    assert cli.main(["recognize", str(tiny["model"]), "--rig", rig, "--samples", "64", "--min-views", "3",
                     "--max-steps", "2"]) == 2
    assert "--min-views 3 is above --max-steps 2" in capsys.readouterr().err
    # --shared-view needs a view-mixture model: one clear line, no traceback
    assert cli.main(["recognize", str(tiny["model"]), "--rig", rig, "--samples", "64", "--shared-view"]) != 0
    err = capsys.readouterr().err
    assert "no view components" in err and "Traceback" not in err


def test_default_planner_is_the_model_recipes_everywhere():
    """`recognize`, `plan` and a dataset campaign take the planner from the
    model's recipe (no parser default); every recipe names a registered
    planner, and the thesis recipe's is planners.DEFAULT_PLANNER."""
    from jaxrecog.campaigns import DATASET_PLANNERS
    from jaxrecog.planners import DEFAULT_PLANNER, PLANNERS
    from jaxrecog.recipes import RECIPES, THESIS

    assert DEFAULT_PLANNER in PLANNERS and DATASET_PLANNERS[0] == DEFAULT_PLANNER == THESIS.planner
    assert all(r.planner in PLANNERS for r in RECIPES.values())
    subs = cli.subparsers(cli.build_parser())
    for name in ("recognize", "plan", "train"):
        assert subs[name].get_default("planner") is None
