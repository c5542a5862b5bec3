"""The hand-held rig (``--rig handheld:DEVICE --layout FILE``): a person is told
where to put one camera, presses Enter, and the trial goes on as on any rig.
The camera here is an image sequence holding the views the planner asks for
(taken from the tiny database's test images), so the trial must come out
exactly as the same trial replayed from the database."""

from __future__ import annotations

import csv
import io
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from builders import recorded_steps
from clirun import one_error_line, run_cli

from jaxrecog.hardware import LayoutError, load_layout
from jaxrecog.hardware.physical.handheld import draw_layout, instruction

ROOT = Path(__file__).resolve().parent.parent
LAYOUT = ROOT / "examples" / "handheld_layout.toml"
TRIAL = ["--object", 1, "--pose", 0, "--min-views", 2, "--max-steps", 3]


def _table(text: str) -> list[str]:
    """The steps table and result of ``recognize``'s text (the lines after the header line)."""
    lines = text.splitlines()
    start = next(i for i, l in enumerate(lines) if l.startswith("step  config"))
    return [l for l in lines[start:] if not l.startswith("wrote")]


def _frames(tiny, configs, folder: Path, object: int = 1, pose: int = 0) -> str:
    """The database's test image of every (step, camera) view, in capture order, as ``folder/%03d.png``."""
    with open(tiny["db"] / "manifest.csv", newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["split"] == "test"]
    folder.mkdir()
    k = 0
    for config in configs:
        for camera, v in enumerate(config):
            (row,) = [r for r in rows if (int(r["camera"]), int(r["position"]), int(r["object"]), int(r["pose"]))
                      == (camera, v, object, pose)]
            shutil.copy(tiny["db"] / row["path"], folder / f"{k:03d}.png")
            k += 1
    return str(folder / "%03d.png")


def test_a_handheld_trial_from_an_image_sequence(tiny, tmp_path, monkeypatch):
    replay = run_cli("recognize", tiny["model"], "--rig", f"dataset:{tiny['db']}", *TRIAL)
    assert replay.returncode == 0, replay.stderr
    configs = [tuple(int(v) for v in line.split()[1].split(",")) for line in _table(replay.stdout)[2:-1]]
    assert len(configs) >= 2
    frames = _frames(tiny, configs, tmp_path / "frames")
    monkeypatch.setattr("sys.stdin", io.StringIO("\n" * (2 * len(configs))))  # the person presses Enter
    picture, rrd = tmp_path / "next.png", tmp_path / "handheld.rrd"
    p = run_cli("recognize", tiny["model"], "--rig", f"handheld:{frames}", "--layout", LAYOUT, *TRIAL,
                "--layout-picture", picture, "--rerun-save", rrd)
    assert p.returncode == 0, p.stderr
    layout = load_layout(LAYOUT)
    said = [l.split("press Enter to capture ")[-1] for l in p.stdout.splitlines() if "put the camera at" in l]
    assert said == [instruction(layout, s, i, v) for s, c in enumerate(configs) for i, v in enumerate(c)]
    assert said[0].startswith(f"step 1, camera 1 of 2 'high': put the camera at ") and "tilt 45 deg, 0.4 m" in said[0]
    assert f"\n> {said[0]}\n" in (ROOT / "docs" / "live.md").read_text()  # the page shows what a trial prints
    # the same recognizer, planner and stop rule as on the replayed database: the same steps and result
    assert _table(p.stdout) == _table(replay.stdout)
    assert "result: object 1, pose 0" in p.stdout and "-- correct" in p.stdout
    assert cv2.imread(str(picture)).shape == (480, 480, 3)
    found = recorded_steps(rrd)
    steps = list(range(1, len(configs) + 1))
    for stream in [("/camera/0/image", "Image:buffer"), ("/belief/objects", "BarChart:values"),
                   ("/rig/object", "Points3D:positions"), ("/rig/camera1", "Transform3D:translation")]:
        assert found[stream] == steps, stream


def test_the_picture_rings_the_next_position():
    layout = load_layout(LAYOUT)
    img = draw_layout(layout, 1, 1)  # camera 2 'low' at 'left': pan 90 -> the picture's left
    red = np.argwhere((img[:, :, 2] > 200) & (img[:, :, 1] < 60) & (img[:, :, 0] < 60))
    assert red.size and red[:, 1].mean() < img.shape[1] / 3 and abs(red[:, 0].mean() - 240) < 30


@pytest.mark.parametrize("text, needle", [
    ('[[cameras]]\nname = "a"\nzoom = 2\npositions = [{name = "p", pan_deg = 0, tilt_deg = 0}]\n',
     "unknown key 'zoom' in camera 1 (expected: name, positions)"),
    ('[[cameras]]\npositions = [{name = "p", pan_deg = 0, tilt = 30}]\n',
     "unknown key 'tilt' in camera 1 position 1 (expected: name, note, pan_deg, tilt_deg)"),
    ('[[cameras]]\npositions = [{name = "p", pan_deg = 0}]\n', "camera 1 position 1 needs 'tilt_deg'"),
    ('[[cameras]]\npositions = [{name = "p", pan_deg = 0, tilt_deg = 120}]\n', "tilt_deg = 120 is not a number in"),
    ('cameras = 3\n', "needs one [[cameras]] entry per camera"),
    ('[[cameras]\n', "layout "),
])
def test_a_bad_layout_is_one_line(text, needle, tmp_path):
    path = tmp_path / "layout.toml"
    path.write_text(text)
    with pytest.raises(LayoutError) as e:
        load_layout(path)
    assert needle in str(e.value) and str(path) in str(e.value) and "\n" not in str(e.value)


def test_handheld_failures_are_one_line(tiny, tmp_path, monkeypatch):
    bad = tmp_path / "layout.toml"
    bad.write_text(LAYOUT.read_text().replace('distance_m = 0.4', 'distance_m = 0.4\nunits = "cm"'))
    frames = tmp_path / "frames"
    frames.mkdir()
    shutil.copy(next((tiny["db"] / "cam0").rglob("*test*.png")), frames / "000.png")  # one frame only
    rig = ["recognize", tiny["model"], "--start", "0,0"]
    p = run_cli(*rig, "--rig", f"handheld:{frames}/%03d.png", "--layout", bad)
    assert p.returncode == 1 and one_error_line(p, "unknown key 'units' in the top level")
    # the camera gives its one frame for camera 1, then nothing for camera 2
    p = run_cli(*rig, "--rig", f"handheld:{frames}/%03d.png", "--layout", LAYOUT, "--no-wait")
    assert p.returncode == 1
    one_error_line(p, "the hand-held camera returned no image for step 1, camera 2")
    p = run_cli(*rig, "--rig", f"handheld:{tmp_path}/nothing.avi", "--layout", LAYOUT, "--no-wait")
    assert p.returncode == 1 and one_error_line(p, "hand-held camera: ", "could not open")
    one_camera = tmp_path / "one.toml"  # the model has two cameras (3 and 2 positions)
    one_camera.write_text(LAYOUT.read_text().split("[[cameras]]\nname = \"low\"")[0])
    p = run_cli(*rig, "--rig", f"handheld:{frames}/%03d.png", "--layout", one_camera, "--no-wait")
    assert p.returncode == 1 and one_error_line(p, "does not match model")
    monkeypatch.setattr("sys.stdin", io.StringIO(""))  # no one at the keyboard
    p = run_cli(*rig, "--rig", f"handheld:{frames}/%03d.png", "--layout", LAYOUT)
    assert p.returncode == 1 and one_error_line(p, "stdin closed while waiting for Enter (--no-wait")
    for args, needle in [(["--rig", "handheld:0"], "needs --layout"),
                         (["--rig", f"dataset:{tiny['db']}", "--no-wait"], "go with --rig handheld:DEVICE"),
                         (["--rig", "handheld:", "--layout", LAYOUT], "needs a device")]:
        p = run_cli(*rig, *args)
        assert p.returncode == 2 and needle in p.stderr, p.stderr
