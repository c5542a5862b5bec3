"""HardwareRig / SimulatedHardwareRig: pointing geometry, TOML configs, the closed loop with a fake renderer."""

from __future__ import annotations

import dataclasses
import math
import os

import cv2
import numpy as np
import pytest

from jaxrecog.hardware import Rig, RigError
from jaxrecog.hardware.devices.camera import CameraError
from jaxrecog.hardware.physical.config import ConfigError, ControllerConfig, PTUConfig, RigConfig, default_mounts, load_config
from jaxrecog.hardware.sim.controller_sim import LINEAR_RESOLUTION_M, ControllerSimulator
from jaxrecog.hardware.physical.hardware_rig import (
    HardwareRig,
    SimulatedHardwareRig,
    rig_from_config,
)
from jaxrecog.hardware.geometry.kinematics import DEFAULT_MOUNTS, Mount, Workspace, line_of_sight, ptu_angles
from jaxrecog.hardware.geometry.positions import default_table
from jaxrecog.hardware.devices.pan_tilt_drivers.ptu_d46 import PTU
from jaxrecog.hardware.sim.ptu_sim import PTUSimulator
from jaxrecog.hardware.devices.udp_link import ControllerLink, ControllerRejected

EXAMPLE = os.path.join(os.path.dirname(__file__), "..", "examples", "simulated_rig.toml")
H, W = 120, 160


class EyeRenderer:
    """Renders an image whose first row carries the eye position as float64 bytes."""

    def __init__(self):
        self.resets = []
        self.renders = []

    def reset(self, object, pose, occluders=None):
        self.resets.append((object, pose, occluders))

    def render_at(self, camera, eye):
        self.renders.append((camera, tuple(eye)))
        img = np.full((H, W), 128, np.uint8)
        img[0, :24] = np.frombuffer(np.asarray(eye, np.float64).tobytes(), np.uint8)
        img[1, 0] = camera
        return img, 0.1 * camera


def decode_eye(img):
    return tuple(np.frombuffer(img[0, :24].tobytes(), np.float64))


@pytest.fixture
def rig():
    with SimulatedHardwareRig(EyeRenderer()) as r:
        yield r


# ---------------------------------------------------------------- geometry
def test_ptu_angles_and_line_of_sight_are_inverse(rng):
    for _ in range(50):
        eye, target = rng.normal(size=3), rng.normal(size=3)
        mount = PTUConfig(pan_zero_deg=rng.uniform(-180, 180), tilt_zero_deg=rng.uniform(-60, 60),
                          pan_sign=int(rng.choice([-1, 1])))
        pan, tilt = ptu_angles(eye, target, mount)
        assert -180 <= pan <= 180
        want = (target - eye) / np.linalg.norm(target - eye)
        np.testing.assert_allclose(line_of_sight(pan, tilt, mount), want, atol=1e-12)


def test_the_rig_file_default_mounts_are_the_kinematic_defaults():
    """config.default_mounts (PTU entries) and kinematics.DEFAULT_MOUNTS (the travel
    times' default) hold the same angles; the old import path of the angle functions works."""
    from jaxrecog.hardware.physical import hardware_rig

    assert [Mount(m.pan_zero_deg, m.tilt_zero_deg, m.pan_sign) for m in default_mounts(2)] == list(DEFAULT_MOUNTS)
    assert default_mounts(1) == default_mounts(2)[:1]
    assert hardware_rig.ptu_angles is ptu_angles and hardware_rig.line_of_sight is line_of_sight


def test_default_mounts_keep_the_default_table_inside_the_ptu_limits():
    table = default_table()
    res, (plo, phi), (tlo, thi) = 185.1428 / 3600, (-3090, 3090), (-907, 604)
    for cam, mount in enumerate(default_mounts(2)):
        for v in table.views[cam]:
            pan, tilt = ptu_angles(v.eye, table.workspace.object_xyz, mount)
            assert plo * res <= pan <= phi * res and tlo * res <= tilt <= thi * res, (cam, v)


# ---------------------------------------------------------------- closed loop
def test_simulated_rig_is_a_rig(rig):
    assert isinstance(rig, Rig)
    assert rig.positions == (32, 7) and rig.image_shape == (H, W)


def test_images_are_rendered_where_the_simulators_put_the_cameras(rig):
    table = rig.table
    rig.reset(2, 3, occluders="cardboard")
    assert rig.renderer.resets == [(2, 3, "cardboard")]
    assert rig.last_move.turntable == pytest.approx(3 * math.pi / 2)
    configs = [(v1, (5 * v1) % 7) for v1 in range(32)]
    for cfg in configs:
        rig.move(cfg)
        cap = rig.capture()
        imgs = cap.images
        assert len(imgs) == 2 and all(i.dtype == np.uint8 and i.shape == (H, W) for i in imgs)
        for cam, img in enumerate(imgs):
            assert img[1, 0] == cam
            eye = decode_eye(img)
            assert eye == pytest.approx(table.views[cam][cfg[cam]].eye, abs=LINEAR_RESOLUTION_M)
        assert cap.occluded == (0.0, 0.1)
    # the controller executed exactly the planner angles of each configuration
    executed = [e.move for e in rig.controller_sim.executed][1:]  # the first is reset's
    assert [m.cameras for m in executed] == [
        ((table.views[0][a].pan, table.views[0][a].tilt), (table.views[1][b].pan, table.views[1][b].tilt))
        for a, b in configs
    ]
    # and each PTU simulator ends where the driver pointed it
    for cam, sim in enumerate(rig.ptu_sims):
        pan, tilt = ptu_angles(rig.eyes[cam], table.workspace.object_xyz, rig.config.ptu(cam))
        assert sim.position() == (round(pan * 3600 / 185.1428), round(tilt * 3600 / 185.1428))


def test_capture_needs_in_position(rig):
    with pytest.raises(RigError, match="in position"):
        rig.capture()


@pytest.mark.parametrize("cfg,match", [((0,), "2 cameras"), ((32, 0), "camera 0 position 32"), ((0, -1), "camera 1"),
                                       (("a", 0), "not a sequence")])
def test_bad_configuration(rig, cfg, match, unchecked):
    with unchecked(), pytest.raises(RigError, match=match):  # ("a", 0): the rig's guard, not the checker
        rig.move(cfg)


def test_bad_pose(rig):
    with pytest.raises(RigError, match="pose 4"):
        rig.reset(0, 4)


def test_ptu_fault_during_move_is_a_rig_error_and_the_rig_recovers(rig):
    rig.move((0, 0))
    rig.ptu_sims[1].inject("drop")
    with pytest.raises(RigError, match="camera 1.*PTU command '[PT]P"):
        rig.move((9, 6))
    assert not rig.in_position
    rig.move((9, 6))
    assert decode_eye(rig.capture().images[1]) == pytest.approx(rig.table.views[1][6].eye, abs=LINEAR_RESOLUTION_M)


def test_silent_controller_is_a_rig_error_and_the_rig_recovers(rig):
    rig.link.timeout, rig.link.retries = 0.02, 1
    rig.controller_sim.silent = True
    with pytest.raises(RigError, match="motion controller"):
        rig.move((3, 3))
    rig.controller_sim.silent = False
    rig.move((3, 3))
    assert decode_eye(rig.capture().images[0]) == pytest.approx(rig.table.views[0][3].eye, abs=LINEAR_RESOLUTION_M)


def test_misaimed_camera_is_caught_at_capture(rig):
    rig.move((4, 2))
    rig.ptus[0].move_by(tilt=2.0)  # someone nudged the unit
    with pytest.raises(RigError, match="camera 0 points 2.0. deg away"):
        rig.capture()


def test_renderer_with_wrong_image_shape_is_refused():
    class Small(EyeRenderer):
        def render_at(self, camera, eye):
            return np.zeros((10, 10), np.uint8), 0.0

    with SimulatedHardwareRig(Small()) as r:
        r.move((0, 0))
        with pytest.raises(RigError, match=r"expected uint8 \(120, 160\)"):
            r.capture()


# ---------------------------------------------------------------- HardwareRig error wrapping
class FakeCamera:
    """A camera that delivers a gray frame, or raises CameraError while ``fail`` is set."""

    def __init__(self, fail=False):
        self.fail, self.reads = fail, 0

    def read(self):
        self.reads += 1
        if self.fail:
            raise CameraError("no usable frame after 4 tries (black frame)")
        return np.full((H, W), 100, np.uint8)

    def close(self):
        pass


@pytest.fixture
def hardware(request):
    """A HardwareRig on ready-made devices: PTU drivers and a UDP link against the
    simulators, fake cameras.  An indirect parameter gives the controller's workspace."""
    workspace = getattr(request, "param", None)
    table = default_table()
    with ControllerSimulator(workspace or table.workspace, time_scale=0.001) as ctl, \
            PTUSimulator(time_scale=0.001) as p1, PTUSimulator(time_scale=0.001) as p2:
        ptus = [PTU(p.port, timeout=0.2) for p in (p1, p2)]
        link = ControllerLink(ctl.address, timeout=0.1, retries=2)
        cams = [FakeCamera(), FakeCamera()]
        try:
            with HardwareRig(RigConfig("hardware", table), ptus=ptus, link=link, cameras=cams) as rig:
                yield rig, ctl, (p1, p2), cams
        finally:
            link.close()
            for p in ptus:
                p.close()


def test_camera_error_becomes_a_rig_error_naming_the_camera(hardware):
    rig, _, _, cams = hardware
    rig.move((3, 2))
    assert [i.shape for i in rig.capture().images] == [(H, W), (H, W)]
    cams[1].fail = True
    with pytest.raises(RigError, match=r"^camera 1: no usable frame after 4 tries") as e:
        rig.capture()
    assert isinstance(e.value.__cause__, CameraError)
    cams[1].fail = False
    assert len(rig.capture().images) == 2  # the rig is still usable


_WS = default_table().workspace
NARROW = dataclasses.replace(_WS, carriers=(dataclasses.replace(_WS.carriers[0], x_range=(-0.05, 0.05)),
                                            *_WS.carriers[1:]))


@pytest.mark.parametrize("hardware", [NARROW], indirect=True)
def test_controller_rejection_becomes_a_rig_error_naming_the_motion_controller(hardware):
    """The controller's workspace is narrower than the table the rig was given:
    the controller refuses the move, the rig says so and does not point the PTUs."""
    rig, ctl, sims, _ = hardware
    views = rig.table.views[0]
    wide = max(range(len(views)), key=lambda v: abs(views[v].eye[0]))
    inside = min(range(len(views)), key=lambda v: abs(views[v].eye[0]))
    assert abs(views[wide].eye[0]) > 0.05 >= abs(views[inside].eye[0])
    rig.move((inside, 3))
    before = [s.position() for s in sims]
    with pytest.raises(RigError, match=rf"^motion controller: move to configuration \({wide}, 3\) failed: "
                                       r"controller rejected .*gantry x") as e:
        rig.move((wide, 3))
    assert isinstance(e.value.__cause__, ControllerRejected)
    assert not rig.in_position
    with pytest.raises(RigError, match="in position"):
        rig.capture()
    assert [s.position() for s in sims] == before  # nothing was pointed
    assert [x.move.cameras[0][0] for x in ctl.executed] == [views[inside].pan]
    rig.move((inside, 4))  # a move the controller accepts still works
    assert rig.in_position


def test_device_that_cannot_be_opened_is_a_rig_error():
    cfg = RigConfig("hardware", default_table(), controller=ControllerConfig(port=9),
                    ptus=(PTUConfig(port="/nonexistent/ttyPTU0", timeout_s=0.05),) * 2)
    with pytest.raises(RigError, match="cannot open the rig: PTU command 'open'"):
        HardwareRig(cfg, cameras=[FakeCamera(), FakeCamera()])


# ---------------------------------------------------------------- configs
def test_example_toml_runs_the_closed_loop_under_network_faults():
    cfg = load_config(EXAMPLE)
    assert cfg.kind == "simulated" and cfg.table == default_table()
    assert cfg.simulation.faults.loss == 0.05
    rig = rig_from_config(cfg, renderer=EyeRenderer())
    with rig:
        assert isinstance(rig, SimulatedHardwareRig)
        rig.reset(1, 1)
        for a in range(0, 224, 17):
            cfg_ = (a // 7, a % 7)
            rig.move(cfg_)
            imgs = rig.capture().images
            assert decode_eye(imgs[0]) == pytest.approx(rig.table.views[0][cfg_[0]].eye, abs=LINEAR_RESOLUTION_M)


def test_hardware_rig_built_from_toml(tmp_path, rng):
    """kind = "hardware": every device built from the file (here pointed at the simulators)."""
    frames = [rng.integers(1, 256, (240, 320), dtype=np.uint8) for _ in range(2)]
    for cam, f in enumerate(frames):
        (tmp_path / f"cam{cam}").mkdir()
        cv2.imwrite(str(tmp_path / f"cam{cam}" / "0.png"), f)
    with ControllerSimulator(time_scale=0.001) as ctl, PTUSimulator(time_scale=0.001) as p1, \
            PTUSimulator(time_scale=0.001) as p2:
        text = f"""
kind = "hardware"
[controller]
host = "127.0.0.1"
port = {ctl.address[1]}
[[ptu]]
port = "{p1.port}"
pan_zero_deg = -22.5
tilt_zero_deg = -45.0
speed_deg_s = 100.0
[[ptu]]
port = "spy://{p2.port}"
pan_zero_deg = -90.0
pan_sign = -1
[[camera]]
source = "cam0"
kind = "sequence"
[[camera]]
source = "cam1"
kind = "sequence"
"""
        (tmp_path / "rig.toml").write_text(text)
        with HardwareRig(str(tmp_path / "rig.toml")) as rig:
            assert rig.positions == (32, 7)
            assert p1.axes["P"].speed == round(100 * 3600 / 185.1428)
            rig.reset(0, 1)
            rig.move((12, 4))
            imgs = rig.capture().images
            for f, img in zip(frames, imgs):
                np.testing.assert_array_equal(img, cv2.resize(f, (W, H), interpolation=cv2.INTER_AREA))
            assert ctl.executed[-1].move.turntable == pytest.approx(math.pi / 2)
            assert ctl.executed[-1].reply.reached[0][0] == pytest.approx(rig.table.views[0][12].eye[0], abs=1e-5)


def write(tmp_path, text):
    p = tmp_path / "rig.toml"
    p.write_text(text)
    return p


@pytest.mark.parametrize(
    "text,match",
    [
        ('kind = "simulated"\ncolour = 3\n', r"unknown key\(s\) \['colour'\]"),
        ('kind = "robot"\n', "kind = 'robot'"),
        ('kind = "hardware"\n[controller]\nport = 5\n', "0 \\[\\[ptu\\]\\] entries for 2 cameras"),
        ('kind = "simulated"\n[[ptu]]\npan_sign = 2\n[[ptu]]\n', "pan_sign = 2"),
        ('kind = "simulated"\n[[ptu]]\ntimeout_s = "fast"\n[[ptu]]\n', "timeout_s = 'fast' must be a number"),
        ('kind = "simulated"\n[[ptu]]\nbaud = 9600\n[[ptu]]\n', r"\[\[ptu\]\] #1: unknown key\(s\) \['baud'\]"),
        ('kind = "simulated"\nimage_shape = [120]\n', "image_shape"),
        ('kind = "simulated"\n[simulation.faults]\nloss = 2.0\n', "loss = 2.0"),
        # in the file's units (degrees), naming the entry (it once said radians)
        ('kind = "simulated"\n[table]\ncamera1 = [[0, 5]]\n',
         r"\[table\]: camera1\[0\] = \[0, 5\] deg: camera 0 tilt = 5 deg is outside the workspace limits \[10, 89\] deg$"),
        ('kind = "simulated"\n[[camera]]\nkind = "ir"\n', "kind = 'ir'"),
        ("kind = = 1\n", "not valid TOML"),
    ],
)
def test_config_errors_name_the_culprit(tmp_path, text, match):
    with pytest.raises(ConfigError, match=match):
        load_config(write(tmp_path, text))


def test_single_camera_table(tmp_path):
    cfg = RigConfig("simulated", default_table().single_camera(0))
    with SimulatedHardwareRig(EyeRenderer(), cfg) as r:
        assert r.positions == (32,)
        r.move((7,))
        (img,) = r.capture().images
        assert decode_eye(img) == pytest.approx(r.table.views[0][7].eye, abs=LINEAR_RESOLUTION_M)


def test_simulated_rig_refuses_a_hardware_config():
    cfg = dataclasses.replace(load_config(EXAMPLE), kind="hardware")
    with pytest.raises(ConfigError, match="kind = 'simulated'"):
        SimulatedHardwareRig(EyeRenderer(), cfg)
