"""HardwareRig against disappearing pan-tilt devices, and the pan-tilt driver registry."""

from __future__ import annotations

import dataclasses
import threading
import time

import numpy as np
import pytest

from jaxrecog.hardware import RigError
from jaxrecog.hardware.physical.config import ConfigError, ControllerConfig, PTUConfig, RigConfig, default_mounts, load_config
from jaxrecog.hardware.sim.controller_sim import ControllerSimulator
from jaxrecog.hardware.physical.hardware_rig import HardwareRig, Reconnect, SimulatedHardwareRig
from jaxrecog.hardware.geometry.kinematics import ptu_angles
from jaxrecog.hardware.devices.pan_tilt import PanTilt, open_pan_tilt, pan_tilt_driver, register_pan_tilt
from jaxrecog.hardware.geometry.positions import default_table
from jaxrecog.hardware.devices.pan_tilt_drivers.ptu_d46 import PTU
from jaxrecog.hardware.sim.ptu_sim import PTUSimulator
from jaxrecog.hardware.devices.udp_link import ControllerLink

H, W = 120, 160


class FlatRenderer:
    def reset(self, object, pose, occluders=None):
        pass

    def render_at(self, camera, eye):
        return np.full((H, W), 100 + camera, np.uint8), 0.0


class FakeCamera:
    def read(self):
        return np.full((H, W), 90, np.uint8)

    def close(self):
        pass


def mounts(**change) -> tuple[PTUConfig, ...]:
    return tuple(dataclasses.replace(m, timeout_s=0.2, **change) for m in default_mounts(2))


@pytest.fixture
def rig():
    with SimulatedHardwareRig(FlatRenderer(), RigConfig("simulated", default_table(), ptus=mounts(reconnect_s=3.0))) as r:
        yield r


# ---------------------------------------------------------------- reconnecting
@pytest.mark.parametrize("new_path,homing_s", [(False, 0.0), (True, 0.0), (True, 100.0)],
                         ids=["same-path", "new-path", "new-path-power-cycled"])
def test_unit_unplugged_mid_move_is_reconnected_reread_and_the_move_repeated_once(rig, caplog, new_path, homing_s):
    rig.move((3, 2))
    sim = rig.ptu_sims[0]
    old = sim.port
    sim.back_after_s, sim.back_new_path, sim.back_homing_s = 0.15, new_path, homing_s
    sim.inject("unplug")  # the PP of camera 1's next pointing meets the unplug
    before = len(sim.log)
    rig.move((12, 4))  # no error: the rig brought the unit back and pointed it again
    assert rig.in_position
    (r,) = rig.reconnects
    assert r.camera == 0 and r.port == sim.port and r.seconds >= 0.15 * 0.9 and r.attempts >= 1
    if new_path:
        assert sim.port != old
    after = sim.log[before:]
    assert {"ED", "FT", "PR", "TR", "PN", "PX", "TN", "TX"} <= set(after)  # the unit was read again
    moves = [c for c in after if c.startswith("PP") and c != "PP"]  # (a bare PP is the position query)
    assert len(moves) == 2  # the interrupted command, then the repeat, once
    assert sim.stats["lost_while_homing"] == 0  # a power-cycled unit was waited for, not sent moves
    assert len(rig.capture().images) == 2  # and it points at the object (checked through the driver)
    assert "is back on" in caplog.text


def test_unit_not_back_in_time_fails_the_move_with_one_rig_error_and_the_rig_recovers_later():
    cfg = RigConfig("simulated", default_table(), ptus=mounts(reconnect_s=0.3))
    with SimulatedHardwareRig(FlatRenderer(), cfg) as rig:
        rig.move((3, 2))
        sim = rig.ptu_sims[1]
        sim.back_after_s = None  # stays away
        sim.inject("unplug")
        t0 = time.monotonic()
        with pytest.raises(RigError, match=r"^pan-tilt unit of camera 1: lost its device and it did not come back "
                                           r"within reconnect_s = 0.3 s"):
            rig.move((5, 5))
        assert time.monotonic() - t0 < 0.3 + 2.5  # gives up after about reconnect_s, not a hang (slack for a loaded box)
        assert not rig.in_position and not rig.reconnects
        sim.replug(new_path=True)
        rig.move((5, 5))  # the next move finds it
        assert rig.in_position and [r.camera for r in rig.reconnects] == [1]


def test_reconnect_s_zero_fails_at_once(rig):
    cfg = RigConfig("simulated", default_table(), ptus=mounts(reconnect_s=0.0))
    with SimulatedHardwareRig(FlatRenderer(), cfg) as r:
        r.ptu_sims[0].back_after_s = None
        r.ptu_sims[0].inject("unplug")
        with pytest.raises(RigError, match="within reconnect_s = 0 s"):
            r.move((1, 1))


def test_hardware_rig_finds_the_unit_again_through_reconnect_glob(tmp_path):
    """A real rig: the unit's by-id style link disappears and comes back under another
    name matching ``reconnect_glob``; the other unit's device is never tried."""
    link_a, link_b = tmp_path / "ptu-cam1-a", tmp_path / "ptu-cam1-b"
    table = default_table()
    with ControllerSimulator(table.workspace, time_scale=0.001) as ctl, \
            PTUSimulator(time_scale=0.001, link=link_a) as p1, PTUSimulator(time_scale=0.001) as p2:
        m1, m2 = default_mounts(2)
        ptus = (dataclasses.replace(m1, port=str(link_a), reconnect_glob=str(tmp_path / "ptu-cam1-*"), timeout_s=0.2),
                dataclasses.replace(m2, port=p2.port, timeout_s=0.2))
        cfg = RigConfig("hardware", table, controller=ControllerConfig(port=ctl.address[1]), ptus=ptus)
        link = ControllerLink(ctl.address, timeout=0.1, retries=2)
        with link, HardwareRig(cfg, link=link, cameras=[FakeCamera(), FakeCamera()]) as rig:
            rig.move((3, 2))
            p1.unplug()
            threading.Timer(0.1, lambda: p1.replug(new_path=True, link=link_b)).start()
            rig.move((20, 5))
            assert rig.in_position and rig.reconnects[0].port == str(link_b)
            assert rig.ptus[0].url == str(link_b) and rig.ptus[1].url == p2.port
            want = ptu_angles(rig.eyes[0], table.workspace.object_xyz, m1)
            assert rig.ptus[0].position() == pytest.approx(want, abs=185.1428 / 3600)


def test_controller_restart_mid_move_is_one_rig_error_and_the_next_move_works(rig):
    rig.move((3, 2))
    rig.controller_sim.inject_restart("after_execute")
    with pytest.raises(RigError, match=r"^motion controller: move to configuration \(4, 4\) failed: "
                                       r"motion controller restarted .* not resent"):
        rig.move((4, 4))
    assert not rig.in_position and rig.link.stats["controller_restart"] == 1
    rig.move((4, 4))  # commanded again, on the new session
    assert rig.in_position and rig.last_move.seq == 1


# ---------------------------------------------------------------- the driver registry
class FakePanTilt:
    """A second pan-tilt driver, as a user would add one: the PanTilt members only."""

    opened: list["FakePanTilt"] = []

    def __init__(self, url: str, config: PTUConfig):
        self.url, self.config = url, config
        self.moves: list[tuple[float | None, float | None]] = []
        self.awaited = 0
        self.speeds: list[tuple] = []
        FakePanTilt.opened.append(self)

    @classmethod
    def from_config(cls, config, port=None):
        return cls(config.port if port is None else port, config)

    def move_to(self, pan=None, tilt=None, *, wait=True):
        self.moves.append((pan, tilt))

    def await_motion(self):
        self.awaited += 1

    def position(self):
        return self.moves[-1] if self.moves else (0.0, 0.0)

    def set_speed(self, pan=None, tilt=None):
        self.speeds.append((pan, tilt))

    def reconnect(self, url=None):
        pass

    def close(self):
        pass


@pytest.fixture
def fake_driver():
    FakePanTilt.opened = []
    register_pan_tilt("fake-unit", FakePanTilt)
    yield FakePanTilt
    from jaxrecog.hardware.devices import pan_tilt

    del pan_tilt._DRIVERS["fake-unit"]


def test_a_second_driver_registered_from_a_test_is_the_one_the_rig_talks_to(tmp_path, fake_driver):
    with ControllerSimulator(time_scale=0.001) as ctl:
        toml = tmp_path / "rig.toml"
        toml.write_text(f"""
kind = "hardware"
[controller]
port = {ctl.address[1]}
[[ptu]]
driver = "fake-unit"
port = "fake:1"
pan_zero_deg = -22.5
tilt_zero_deg = -45.0
speed_deg_s = 40.0
[[ptu]]
driver = "fake-unit"
port = "fake:2"
pan_zero_deg = -90.0
pan_sign = -1
[[camera]]
source = 0
[[camera]]
source = 1
""")
        cfg = load_config(toml)
        assert [p.driver for p in cfg.ptus] == ["fake-unit", "fake-unit"]
        with HardwareRig(cfg, cameras=[FakeCamera(), FakeCamera()]) as rig:
            assert [u.url for u in rig.ptus] == ["fake:1", "fake:2"]
            assert all(isinstance(u, FakePanTilt) and isinstance(u, PanTilt) for u in rig.ptus)
            rig.move((12, 4))
            for i, unit in enumerate(rig.ptus):
                assert unit.moves == [pytest.approx(ptu_angles(rig.eyes[i], rig.table.workspace.object_xyz, cfg.ptu(i)))]
                assert unit.awaited == 1
            assert rig.ptus[0].speeds == [(40.0, 40.0)] and rig.ptus[1].speeds == []


def test_the_default_driver_is_the_ptu_d46_and_old_files_load_unchanged():
    assert pan_tilt_driver(PTUConfig().driver) is PTU
    with pytest.raises(KeyError, match="not a module to import"):  # a module path is no driver name
        pan_tilt_driver("jaxrecog.hardware.devices.pan_tilt_drivers.ptu_d46:PTU")
    cfg = load_config("examples/simulated_rig.toml")
    assert {p.driver for p in cfg.ptus} == {"ptu-d46"}
    with PTUSimulator(time_scale=0.001) as sim:
        unit = open_pan_tilt(dataclasses.replace(cfg.ptus[0], homing_timeout_s=1.5), port=sim.port)
        with unit:
            assert isinstance(unit, PTU) and unit.homing_timeout == 1.5 and unit.url == sim.port


@pytest.mark.parametrize(
    "line,match",
    [
        ('driver = "nonesuch"', r"\[\[ptu\]\] #1: driver = 'nonesuch': unknown pan-tilt driver 'nonesuch'; "
                                r"known: \['ptu-d46'\]; a third-party driver: register it as an entry point in group "
                                r"'jaxrecog.pan_tilt'"),
        ('driver = "no.such.module:Unit"', r"\[\[ptu\]\] #1: driver = 'no.such.module:Unit': unknown pan-tilt driver "
                                           r"'no.such.module:Unit': a rig file names a registered driver, not a module"),
        ('driver = 3', r"driver = 3 must be a string"),
        ("reconnect_s = -1.0", r"reconnect_s = -1.0 must be a number >= 0 and <= 86400 seconds"),
        ("homing_timeout_s = 0", r"homing_timeout_s = 0 must be a number > 0 and <= 86400 seconds"),
    ],
)
def test_a_bad_driver_or_reconnect_key_is_a_clear_config_error(tmp_path, line, match):
    toml = tmp_path / "rig.toml"
    toml.write_text(f'kind = "simulated"\n[[ptu]]\n{line}\n[[ptu]]\n')
    with pytest.raises(ConfigError, match=match):
        load_config(toml)


# ---------------------------------------------------------------- a camera lost during capture
class USBCamera:
    """A video device behind ``VideoCamera(capture_factory=...)``: unplugging it kills every
    capture opened so far (they read nothing for good); while it is away it cannot be
    opened; plugged back in, a new capture works."""

    def __init__(self, value=120):
        self.plugged, self.generation, self.opens, self.value, self.black = True, 0, 0, value, False
        self.unstuck = threading.Event()  # cleared: every read blocks until it is set
        self.unstuck.set()

    def factory(self, source):
        self.opens += 1
        cam, gen = self, self.generation

        class Capture:
            def isOpened(self):
                return cam.plugged

            def read(self):
                cam.unstuck.wait(10.0)
                if not (cam.plugged and cam.generation == gen):
                    return False, None
                return True, np.full((H, W), 0 if cam.black else cam.value, np.uint8)

            def release(self):
                pass

        return Capture()

    def unplug(self, back_after_s=None):
        self.plugged = False
        self.generation += 1
        if back_after_s is not None:
            threading.Timer(back_after_s, self.replug).start()

    def replug(self):
        self.plugged = True


@pytest.fixture
def usb_rig():
    """A HardwareRig (controller simulator, fake pan-tilt units) with two VideoCameras on
    USBCamera devices; camera 1's reconnect_s is 0.4 s."""
    from jaxrecog.hardware.devices.camera import VideoCamera
    from jaxrecog.hardware.physical.config import CameraConfig

    table = default_table()
    devices = [USBCamera(120), USBCamera(130)]
    with ControllerSimulator(table.workspace, time_scale=0.001) as ctl:
        cfg = RigConfig("hardware", table, controller=ControllerConfig(port=ctl.address[1]), ptus=mounts(),
                        cameras=(CameraConfig(source=0, reconnect_s=0.4), CameraConfig(source=1)))
        cams = [VideoCamera(i, capture_factory=d.factory, retries=1) for i, d in enumerate(devices)]
        ptus = [FakePanTilt(f"fake:{i}", m) for i, m in enumerate(cfg.ptus)]
        with ControllerLink(ctl.address, timeout=0.1, retries=2) as link, \
                HardwareRig(cfg, ptus=ptus, link=link, cameras=cams) as rig:
            rig.move((3, 2))
            yield rig, devices


def test_a_camera_unplugged_before_a_capture_is_reopened_and_the_capture_succeeds(usb_rig, caplog):
    rig, (d1, d2) = usb_rig
    assert [int(im.max()) for im in rig.capture().images] == [120, 130]
    d2.unplug(back_after_s=0.15)  # camera 2 (default reconnect_s, 5 s) comes back after 0.15 s
    t0 = time.monotonic()
    images = rig.capture().images  # no error: reopened and read again
    assert [int(im.max()) for im in images] == [120, 130]
    (r,) = rig.reconnects
    assert (r.camera, r.device, r.port) == (1, "camera", "1") and 0.15 * 0.9 <= r.seconds <= time.monotonic() - t0
    assert r.attempts >= 2 and d2.opens >= 3  # failed reopens while it was away, then the one that worked
    assert "camera 1 is back" in caplog.text


def test_a_camera_not_back_in_time_is_one_rig_error_and_a_later_capture_reopens_it(usb_rig):
    rig, (d1, _) = usb_rig
    d1.unplug()  # stays away
    t0 = time.monotonic()
    with pytest.raises(RigError, match=r"^camera 0: lost its device and it did not come back within "
                                       r"reconnect_s = 0.4 s \(\d+ attempts\); last error: .*could not open it"):
        rig.capture()
    assert time.monotonic() - t0 < 0.4 + 1.0 and not rig.reconnects
    d1.replug()
    assert [int(im.max()) for im in rig.capture().images] == [120, 130]
    assert [(r.camera, r.device) for r in rig.reconnects] == [(0, "camera")]


def test_black_frames_are_not_a_lost_camera(usb_rig):
    rig, (d1, _) = usb_rig
    d1.black = True
    opens = d1.opens
    with pytest.raises(RigError, match=r"^camera 0: source 0: no usable frame after 2 attempts: black frame"):
        rig.capture()
    assert d1.opens == opens and not rig.reconnects  # a black frame is not a lost device: nothing reopened
    d1.black = False
    assert len(rig.capture().images) == 2


def test_a_camera_whose_reads_hang_is_one_rig_error_within_its_bounds(usb_rig):
    """A device whose every read blocks used to hang capture() for good; now each read is
    given up after read_timeout_s, the device reopened for reconnect_s, then one RigError."""
    rig, (d1, _) = usb_rig
    rig.cameras[0].read_timeout_s = 0.1
    d1.unstuck.clear()
    t0 = time.monotonic()
    try:
        with pytest.raises(RigError, match=r"^camera 0: lost its device and it did not come back within reconnect_s = "
                                           r"0.4 s \(\d+ attempts\); last error: video source 0: VideoCapture.read "
                                           r"did not return within read_timeout_s = 0.1 s; the capture was abandoned$"):
            rig.capture()
        assert time.monotonic() - t0 < 0.1 + 0.4 + 0.1 + 1.0  # first read, reconnect_s, one last read; slack
    finally:
        d1.unstuck.set()
    assert [int(im.max()) for im in rig.capture().images] == [120, 130]
