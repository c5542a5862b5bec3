"""A third camera: the rig file of docs/hardware.md "A third camera" drives
the simulated hardware -- three PTU simulators, the controller simulator speaking
protocol version 3 -- through moves and captures; version 2 keeps the thesis rig's
two cameras."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from jaxrecog.hardware.devices.datagram import Move
from jaxrecog.hardware.geometry.kinematics import Gantry, Track, ptu_angles
from jaxrecog.hardware.physical.config import ConfigError, load_config
from jaxrecog.hardware.physical.hardware_rig import SimulatedHardwareRig
from jaxrecog.hardware.sim.controller_sim import LINEAR_RESOLUTION_M

H, W = 120, 160
DOC = Path(__file__).parents[1] / "docs" / "hardware.md"


class EyeRenderer:
    """An image whose first row carries the eye it was rendered at (float64 bytes)."""

    def reset(self, object, pose, occluders=None):
        pass

    def render_at(self, camera, eye):
        img = np.full((H, W), 128, np.uint8)
        img[0, :24] = np.frombuffer(np.asarray(eye, np.float64).tobytes(), np.uint8)
        img[1, 0] = camera
        return img, 0.0


def decode_eye(img):
    return tuple(np.frombuffer(img[0, :24].tobytes(), np.float64))


def doc_rig_file(tmp_path, extra: str = "") -> Path:
    """The TOML of docs/hardware.md's "A third camera" section (``extra`` lines appended)."""
    text = DOC.read_text(encoding="utf-8")
    block = text[text.index("## A third camera"):].split("```toml\n", 1)[1].split("```", 1)[0]
    path = tmp_path / "three.toml"
    path.write_text(block + extra)
    return path


def test_three_cameras_move_and_capture_on_the_simulated_hardware(tmp_path):
    cfg = load_config(doc_rig_file(tmp_path))
    table = cfg.table
    assert table.positions == (4, 3, 3) and cfg.controller.protocol_version == 4
    assert [type(c) for c in table.carriers] == [Gantry, Track, Track]
    configs = [(0, 0, 2), (3, 1, 0), (1, 2, 1)]
    with SimulatedHardwareRig(EyeRenderer(), cfg) as rig:
        rig.reset(1, 2)
        for cfg_ in configs:
            rig.move(cfg_)
            cap = rig.capture()  # (checks that every simulated PTU points at the object)
            assert len(cap.images) == 3
            for cam, img in enumerate(cap.images):
                assert img[1, 0] == cam
                assert decode_eye(img) == pytest.approx(table.views[cam][cfg_[cam]].eye, abs=LINEAR_RESOLUTION_M)
        executed = rig.controller_sim.executed[1:]  # the first is reset's
        assert [e.move for e in executed] == [
            Move(tuple((table.views[i][v].pan, table.views[i][v].tilt) for i, v in enumerate(c)), math.pi)
            for c in configs]
        assert [len(e.reply.reached) for e in executed] == [3, 3, 3]
        # camera 3 rides its own track, across the table from camera 2's
        assert rig.eyes[2][0] == -0.75 and rig.eyes[1][0] == 0.75
        for cam, sim in enumerate(rig.ptu_sims):
            pan, tilt = ptu_angles(rig.eyes[cam], table.workspace.object_xyz, rig.config.ptu(cam))
            assert sim.position() == (round(pan * 3600 / 185.1428), round(tilt * 3600 / 185.1428))


def test_protocol_version_2_cannot_drive_a_third_camera(tmp_path):
    with pytest.raises(ConfigError, match=r"protocol_version = 2 moves camera 1 on a gantry and camera 2 on a "
                                          r"track; this table's cameras ride gantry, track, track: set "
                                          r"protocol_version = 3"):
        load_config(doc_rig_file(tmp_path, "[controller]\nprotocol_version = 2\n"))


def test_the_thesis_rig_still_runs_on_protocol_version_2(tmp_path):
    """Version 2 reports the gantry's x, y and the track's y; the rig completes the eyes."""
    path = tmp_path / "two.toml"
    path.write_text('kind = "simulated"\n[controller]\nprotocol_version = 2\n'
                    '[table]\ncamera1 = [[0, 30], [90, 45]]\ncamera2 = [-40, 40]\n')
    with SimulatedHardwareRig(EyeRenderer(), load_config(path)) as rig:
        rig.move((1, 1))
        assert rig.last_move.version == 2 and [len(r) for r in rig.last_move.reached] == [2, 1]
        for cam, img in enumerate(rig.capture().images):
            assert decode_eye(img) == pytest.approx(rig.table.views[cam][1].eye, abs=LINEAR_RESOLUTION_M)
        assert rig.controller_sim.executed[-1].move.cameras[1] == (rig.table.views[1][1].pan, 0.0)
