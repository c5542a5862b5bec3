"""The live view (:mod:`jaxrecog.liveview`): a recorded trial holds one entry per
step of every stream, read back with rerun's own reader; without rerun, one
line naming the extra; the occlusion estimate is the belief's expected level."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from builders import recorded_steps
from clirun import one_error_line, run_cli

from jaxrecog.kernels.belief import Belief
from jaxrecog.liveview import INSTALL_HINT, LiveViewError, RerunRecorder, occlusion_estimates

#: the streams every step logs for a two-camera model (entity, component)
STREAMS = [("/camera/0/image", "Image:buffer"), ("/camera/1/image", "Image:buffer"),
           ("/belief/objects", "BarChart:values"), ("/belief/poses", "Tensor:data"),
           ("/occlusion/camera0", "Scalars:scalars"), ("/occlusion/camera1", "Scalars:scalars"),
           ("/planner/scores", "Tensor:data"), ("/log", "TextLog:text")]
#: and from the rig's geometry: the object and each camera in 3-D
RIG_STREAMS = [("/rig/object", "Points3D:positions"), ("/rig/camera0", "Transform3D:translation"),
               ("/rig/camera0", "Pinhole:image_from_camera"), ("/rig/camera1", "Transform3D:translation")]


def test_the_occlusion_estimate_is_the_beliefs_expected_level():
    """sum_c P(c) sum_k P_i(k | c) level_k, per camera."""
    pc = np.array([0.25, 0.75])
    pk0 = np.array([[1.0, 0.0], [0.5, 0.5]])  # camera 0: class 1 half at level 0.2
    pk1 = np.array([[0.0, 1.0], [0.0, 1.0]])  # camera 1: surely at level 0.2
    belief = Belief(np.log(pc), (np.log(np.maximum(pk0, 1e-300)), np.log(np.maximum(pk1, 1e-300))))
    np.testing.assert_allclose(occlusion_estimates(belief, (0.0, 0.2)), [0.75 * 0.5 * 0.2, 0.2], atol=1e-12)


def test_a_recorded_trial_holds_one_entry_per_step_of_each_stream(tiny, tmp_path):
    rrd = tmp_path / "trial.rrd"
    p = run_cli("recognize", tiny["model"], "--rig", f"dataset:{tiny['db']}", "--object", 1, "--min-views", 3,
                "--max-steps", 3, "--rerun-save", rrd)
    assert p.returncode == 0, p.stderr
    assert f"wrote {rrd}" in p.stdout and "after 3 step(s)" in p.stdout
    found = recorded_steps(rrd)
    for stream in STREAMS:
        assert found.get(stream) == [1, 2, 3], (stream, found.get(stream))
    # a replayed database has no geometry: no 3-D view, and no true occluded fraction
    assert not [k for k in found if k[0].startswith(("/rig", "/occlusion/camera0/true"))]


@pytest.mark.parametrize("command", ["recognize", "experiment"])
def test_without_rerun_the_live_view_is_one_line_naming_the_extra(command, tiny, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "rerun", None)  # `import rerun` raises ImportError, as when not installed
    with pytest.raises(LiveViewError, match=r"pip install 'jaxrecog\[rerun\]'"):
        RerunRecorder(object(), save=tmp_path / "x.rrd")
    args = {"recognize": ["recognize", tiny["model"], "--rig", f"dataset:{tiny['db']}"],
            "experiment": ["experiment", "--rig", f"dataset:{tiny['db']}", "--model", tiny["model"],
                           "--out", tmp_path / "out"]}[command]
    p = run_cli(*args, "--rerun-save", tmp_path / "x.rrd")
    assert p.returncode == 1
    assert one_error_line(p, INSTALL_HINT).endswith(f"rerun SDK, which is not installed: {INSTALL_HINT}")
    assert not (tmp_path / "x.rrd").exists() and not (tmp_path / "out" / "config.toml").exists()


@pytest.mark.slow
def test_the_live_view_of_a_campaign_has_each_planners_trials(tiny, tmp_path):
    """``experiment --rerun-save``: every trial's steps, under the planner's path."""
    rrd = tmp_path / "campaign.rrd"
    p = run_cli("--quiet", "experiment", "--rig", f"dataset:{tiny['db']}", "--model", tiny["model"],
                "--trials", 1, "--planners", "random", "--samples", 64, "--out", tmp_path / "out",
                "--rerun-save", rrd, "--json")
    assert p.returncode == 0, p.stderr
    import json

    doc = json.loads(p.stdout)
    assert str(rrd) in doc["written"]
    found = recorded_steps(rrd)
    # two trials (one per object): each step of each once, every stream alike
    steps = found[("/random/camera/0/image", "Image:buffer")]
    assert steps and steps.count(1) == 2
    for entity, component in STREAMS:
        assert found[(f"/random{entity}", component)] == steps


def test_the_geometry_comes_from_the_rigs_table_or_layout():
    """The 3-D view's object and eyes: a rig's table (synthetic), a rig file's
    table (hardware), a layout (hand-held); none for a replayed database."""
    from types import SimpleNamespace

    from jaxrecog.hardware import load_layout
    from jaxrecog.hardware.geometry.positions import default_table
    from jaxrecog.liveview import _look_at, rig_geometry

    table = default_table()
    for rig in (SimpleNamespace(table=table), SimpleNamespace(config=SimpleNamespace(table=table))):
        g = rig_geometry(rig)
        assert [e.shape for e in g.eyes] == [(32, 3), (7, 3)] and g.object_xyz == table.workspace.object_xyz
        np.testing.assert_allclose(g.eyes[1][3], table.views[1][3].eye)
    layout = load_layout(Path(__file__).resolve().parent.parent / "examples" / "handheld_layout.toml")
    g = rig_geometry(SimpleNamespace(geometry=layout.geometry()))
    np.testing.assert_allclose(g.eyes[0][1], [0.0, 0.4 * np.cos(np.pi / 4), 0.4 * np.sin(np.pi / 4)])  # 'front'
    assert rig_geometry(SimpleNamespace()) is None
    eye, target = np.array([0.3, -0.2, 0.5]), np.array([0.0, 0.0, 0.1])
    r = _look_at(eye, target)  # the camera's z axis points at the object, upright, a rotation
    np.testing.assert_allclose(r[:, 2], (target - eye) / np.linalg.norm(target - eye))
    np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) > 0 and r[2, 1] < 0  # image y (down) points down in the world


def test_the_live_view_module_imports_rerun_only_when_a_recorder_is_made():
    """No ``import rerun`` at module level of :mod:`jaxrecog.liveview` (the core
    imports without the extra; ``import jaxrecog`` loading no rerun is
    tests/test_boundaries.py's)."""
    import ast

    import jaxrecog.liveview as live

    tree = ast.parse(Path(live.__file__).read_text())
    top = [n for n in tree.body if isinstance(n, (ast.Import, ast.ImportFrom))]
    names = {a.name for n in top if isinstance(n, ast.Import) for a in n.names}
    names |= {n.module for n in top if isinstance(n, ast.ImportFrom) and n.module}
    assert not {n for n in names if n.split(".")[0] == "rerun"}, names


def test_a_viewer_without_a_display_is_one_line(tiny, tmp_path, monkeypatch):
    """``--rerun`` on a machine without a display says so (and how to record
    instead) before the trial, rather than failing to reach the viewer after it."""
    monkeypatch.setattr(sys, "platform", "linux")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    p = run_cli("recognize", tiny["model"], "--rig", f"dataset:{tiny['db']}", "--rerun")
    assert p.returncode == 1
    one_error_line(p, "no display here for a viewer", "--rerun-save FILE.rrd")
