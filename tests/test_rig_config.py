"""Rig files checked when they are loaded: two pan-tilt units on one port,
bad numbers naming the key and the file, the file's units, the table against each
unit's range, the shared key, and pan-tilt drivers found only through registration
(a rig file imports nothing)."""

from __future__ import annotations

import importlib
import os
import re
import sys
from pathlib import Path

import numpy as np
import pytest

from jaxrecog.hardware.devices import pan_tilt
from jaxrecog.hardware.physical.config import ConfigError, load_config
from jaxrecog.hardware.physical.hardware_rig import SimulatedHardwareRig
from jaxrecog.hardware.devices.pan_tilt import ENTRY_POINT_GROUP, pan_tilt_driver, pan_tilt_drivers
from jaxrecog.hardware.devices.pan_tilt_drivers.ptu_d46 import PTU

MOUNTS = """
[[ptu]]
pan_zero_deg = -22.5
tilt_zero_deg = -45.0
{ptu1}
[[ptu]]
pan_zero_deg = -90.0
pan_sign = -1
{ptu2}
"""


def hardware_file(tmp_path, ptu1="", ptu2="", extra=""):
    return write(tmp_path, f"""kind = "hardware"
[controller]
port = 5005
{extra}
{MOUNTS.format(ptu1=ptu1, ptu2=ptu2)}
[[camera]]
source = 0
[[camera]]
source = 1
""")


def write(tmp_path, text, name="rig.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


class FlatRenderer:
    def reset(self, object, pose, occluders=None):
        pass

    def render_at(self, camera, eye):
        return np.full((120, 160), 100 + camera, np.uint8), 0.0


# ---------------------------------------------------------------- one port, two units
def test_two_pan_tilt_units_on_one_port_are_refused_naming_both(tmp_path):
    ok = load_config(hardware_file(tmp_path, 'port = "/dev/ttyUSB0"', 'port = "/dev/ttyUSB1"'))
    assert [p.port for p in ok.ptus] == ["/dev/ttyUSB0", "/dev/ttyUSB1"]
    path = hardware_file(tmp_path, 'port = "/dev/ttyUSB0"', 'port = "/dev/ttyUSB0"')
    with pytest.raises(ConfigError, match=rf"^{path}: \[\[ptu\]\] #1 and \[\[ptu\]\] #2 both have "
                                          r"port = '/dev/ttyUSB0': each pan-tilt unit needs its own serial port$"):
        load_config(path)


@pytest.mark.parametrize("first,second", [
    ("spy:///dev/ttyUSB0", "/dev/ttyUSB0"),
    ("spy:///dev/ttyUSB0?file=spy.log", "alt:///dev/ttyUSB0?class=PosixPollSerial"),
    ("rfc2217://HOST:7001", "rfc2217://host:7001"),
    ("socket://Rig.Local.:7001?logging=debug", "socket://rig.local:7001"),
    ("rfc2217://[::1]:7001", "RFC2217://[::1]:7001/"),
])
def test_a_url_and_the_port_it_names_are_the_same_port(tmp_path, first, second):
    """A spy:// (or alt://) URL opens the port after it; a network port is its scheme, host
    (case-free) and port: both used to pass the duplicate check beside the plain name."""
    path = hardware_file(tmp_path, f'port = "{first}"', f'port = "{second}"')
    with pytest.raises(ConfigError, match=rf"\[\[ptu\]\] #1 and \[\[ptu\]\] #2 both have ports "
                                          rf"{re.escape(repr(first))} and {re.escape(repr(second))} \(the same "
                                          rf"device\): each pan-tilt unit needs its own serial port$"):
        load_config(path)


def test_a_spy_url_of_a_link_is_the_device_behind_the_link(tmp_path):
    dev = tmp_path / "ttyUSB7"
    dev.write_text("")
    os.symlink(dev, tmp_path / "usb-FTDI_cam1")
    path = hardware_file(tmp_path, f'port = "spy://{tmp_path / "usb-FTDI_cam1"}"', f'port = "{dev}"')
    with pytest.raises(ConfigError, match=r"\(the same device\)"):
        load_config(path)


@pytest.mark.parametrize("first,second", [
    ("rfc2217://host:7001", "rfc2217://host:7002"),
    ("rfc2217://host:7001", "socket://host:7001"),
    ("spy:///dev/ttyUSB0", "/dev/ttyUSB1"),
])
def test_different_devices_stay_different(tmp_path, first, second):
    assert [p.port for p in load_config(hardware_file(tmp_path, f'port = "{first}"', f'port = "{second}"')).ptus] == \
        [first, second]


def test_two_names_of_one_device_are_the_same_port(tmp_path):
    dev = tmp_path / "ttyUSB7"
    dev.write_text("")
    os.symlink(dev, tmp_path / "usb-FTDI_cam1")
    path = hardware_file(tmp_path, f'port = "{dev}"', f'port = "{tmp_path / "usb-FTDI_cam1"}"')
    with pytest.raises(ConfigError, match=r"\[\[ptu\]\] #1 and \[\[ptu\]\] #2 both have ports .* \(the same device\)"):
        load_config(path)


# ---------------------------------------------------------------- numbers, units, ranges
@pytest.mark.parametrize(
    "section,line,match",
    [
        ("[controller]", "timeout_s = -1", "timeout_s = -1 must be a number > 0 and <= 3600 seconds"),
        ("[controller]", "timeout_s = inf", "timeout_s = inf must be a number > 0 and <= 3600 seconds"),
        ("[controller]", "timeout_s = nan", "timeout_s = nan must be a number > 0 and <= 3600 seconds"),
        ("[controller]", "max_motion_s = 1e300", r"max_motion_s = 1e\+300 must be a number > 0 and <= 86400 seconds"),
        ("[controller]", "retries = 2.5", "retries = 2.5 must be an integer >= 0 and <= 10000"),
        ("[controller]", "port = 70000", "port = 70000 must be an integer >= 0 and <= 65535"),
        ("[controller]", "protocol_version = 5", "protocol_version = 5 must be one of 1, 2, 3, 4"),
        ("[[ptu]]", "timeout_s = inf", "timeout_s = inf must be a number > 0 and <= 3600 seconds"),
        ("[[ptu]]", "timeout_s = -1", "timeout_s = -1 must be a number > 0 and <= 3600 seconds"),
        ("[[ptu]]", "speed_deg_s = -5", "speed_deg_s = -5 must be a number > 0 and <= 100000 degrees/s"),
        ("[[ptu]]", 'speed_deg_s = "fast"', "speed_deg_s = 'fast' must be a number > 0 and <= 100000 degrees/s"),
        ("[[ptu]]", "baudrate = 0", "baudrate = 0 must be an integer > 0 and <= 10000000"),
        ("[[ptu]]", "tilt_range_deg = [10, -10]",
         r"tilt_range_deg = \[10, -10\] must be \[min, max\] with -180 <= min < max <= 180 degrees"),
        ("[[camera]]", "reconnect_s = inf", "reconnect_s = inf must be a number >= 0 and <= 86400 seconds"),
        ("[[camera]]", "black_level = 300", "black_level = 300 must be an integer >= 0 and <= 255"),
        ("[simulation]", "time_scale = -1", "time_scale = -1 must be a number >= 0 and <= 1000"),
        ("[simulation.faults]", "delay_s = [0.5, 0.1]",
         r"delay_s = \[0.5, 0.1\] must be \[min, max\] with 0 <= min <= max <= 60 seconds"),
        ("[simulation.faults]", "loss = nan", "loss = nan must be a number >= 0 and <= 1"),
    ],
)
def test_a_bad_number_names_the_file_the_section_and_the_key(tmp_path, section, line, match):
    """``timeout_s = -1`` or ``inf`` used to load, then fail (ValueError, OverflowError)
    naming neither the key nor the file when the rig was built."""
    if section == "[[ptu]]":
        text, where = f'kind = "simulated"\n{MOUNTS.format(ptu1=line, ptu2="")}', r"\[\[ptu\]\] #1"
    elif section == "[[camera]]":
        text, where = f'kind = "simulated"\n[[camera]]\n{line}\n', r"\[\[camera\]\] #1"
    else:
        text, where = f'kind = "simulated"\n{section}\n{line}\n', re.escape(section)
    path = write(tmp_path, text)
    with pytest.raises(ConfigError, match=rf"^{re.escape(str(path))}: {where}: {match}$"):
        load_config(path)


def test_a_camera2_pan_outside_the_workspace_is_reported_in_degrees(tmp_path):
    path = write(tmp_path, 'kind = "simulated"\n[table]\ncamera1 = [[0, 30]]\ncamera2 = [0, 95]\n')
    with pytest.raises(ConfigError, match=r"\[table\]: camera2\[1\] = 95 deg: camera 1 pan = 95 deg must lie in "
                                          r"\(-90, 90\) deg$"):
        load_config(path)
    path = write(tmp_path, 'kind = "simulated"\n[table]\ncamera1 = [[0, 30]]\n[table.workspace]\ngantry_x = [1, -1]\n')
    with pytest.raises(ConfigError, match=r"workspace gantry_x = \[1, -1\] must be \[min, max\] with min <= max \(metres\)"):
        load_config(path)


def test_a_table_position_outside_a_units_range_fails_at_load_not_at_the_first_move(tmp_path):
    """Camera 1 at tilt 12 deg would need the PTU at +33 deg (its range ends at +31.06):
    refused when the file is loaded, naming the position, the unit and the key to change."""
    table = """
[table]
camera1 = [[0, 30], [0, 12], [90, 12]]
camera2 = [0]
[table.workspace]
gantry_x = [-5, 5]
gantry_y = [-5, 5]
"""
    path = write(tmp_path, 'kind = "simulated"\n' + MOUNTS.format(ptu1="", ptu2="") + table)
    with pytest.raises(ConfigError, match=rf"^{path}: \[table\] camera1\[1\] = \[0, 12\] deg: \[\[ptu\]\] #1 would have "
                                          r"to tilt to 33 deg, outside its range \[-46.65, 31.06\] deg \(and 1 more "
                                          r"position\(s\)\); change the mount .* tilt_range_deg$"):
        load_config(path)
    # the unit's own range key lets a wider unit through; the rig then moves there
    path = write(tmp_path, 'kind = "simulated"\n' + MOUNTS.format(ptu1="tilt_range_deg = [-47, 34]", ptu2="") + table)
    cfg = load_config(path)
    assert cfg.ptus[0].tilt_range_deg == (-47.0, 34.0)
    # (the simulator's unit is a -17.5, so that position really is out of its reach)
    with SimulatedHardwareRig(FlatRenderer(), cfg) as rig:
        rig.move((0, 0))
        assert rig.in_position
    # without [[ptu]] entries the default mounts are checked the same way
    path = write(tmp_path, 'kind = "simulated"\n' + table)
    with pytest.raises(ConfigError, match=r"the default mount of camera 0 would have to tilt to 33 deg"):
        load_config(path)


def test_the_default_table_and_the_example_fit_their_units():
    cfg = load_config("examples/simulated_rig.toml")
    assert cfg.ptus[0].pan_range_deg is None and PTU.nominal_range_deg[1] == pytest.approx((-46.6457, 31.0628), abs=1e-4)


# ---------------------------------------------------------------- the shared key
SECRET = "the rig's shared key, 30 bytes"


def private(path: Path, text: str) -> Path:
    """A key file as the docs ask for it: its owner's only (mode 0600)."""
    path.write_text(text)
    path.chmod(0o600)
    return path


@pytest.mark.skipif(os.name != "posix", reason="file modes are POSIX")
@pytest.mark.parametrize("mode", [0o644, 0o640, 0o604, 0o620], ids=lambda m: f"{m:04o}")
def test_a_key_file_others_may_open_is_refused_in_one_line(tmp_path, mode):
    """docs/hardware.md: the key file must be its owner's only.  A key file of mode 0644
    was read without a word."""
    (tmp_path / "rig.key").write_text(SECRET)
    (tmp_path / "rig.key").chmod(mode)
    path = write(tmp_path, 'kind = "simulated"\n[controller]\nkey_file = "rig.key"\n')
    with pytest.raises(ConfigError) as e:
        load_config(path)
    assert str(e.value) == (f"{path}: [controller]: key_file = 'rig.key': the key file is open to its group or "
                            f"others (mode {mode:04o}); a shared key must be its owner's only: chmod 600 it")
    assert SECRET not in str(e.value)
    (tmp_path / "rig.key").chmod(0o400)  # read-only for its owner is fine too
    assert load_config(path).controller.key is not None


def test_the_shared_key_comes_from_a_file_or_the_environment_and_is_never_shown(tmp_path, monkeypatch):
    private(tmp_path / "rig.key", SECRET + "\n")
    cfg = load_config(write(tmp_path, 'kind = "simulated"\n[controller]\nkey_file = "rig.key"\n'))
    assert cfg.controller.key is not None and SECRET not in repr(cfg) and SECRET not in str(cfg)
    monkeypatch.setenv("JAXRECOG_TEST_RIG_KEY", SECRET)
    cfg2 = load_config(write(tmp_path, 'kind = "simulated"\n[controller]\nkey_env = "JAXRECOG_TEST_RIG_KEY"\n'))
    assert cfg2.controller.key == cfg.controller.key  # the same bytes (the file's newline dropped)
    with SimulatedHardwareRig(FlatRenderer(), cfg2) as rig:  # both ends keyed: the simulated rig works
        rig.move((3, 2))
        assert rig.controller_sim.key == cfg.controller.key and rig.controller_sim.stats["unauthenticated"] == 0
        assert rig.link.key is cfg2.controller.key


@pytest.mark.parametrize(
    "lines,match",
    [
        ('key_file = "missing.key"', r"key_file = 'missing.key': cannot read it: No such file"),
        ('key_env = "JAXRECOG_TEST_NO_SUCH_VARIABLE"',
         r"key_env = 'JAXRECOG_TEST_NO_SUCH_VARIABLE': the environment variable is not set"),
        ('key_file = "short.key"', r"key_file = 'short.key': a shared key needs at least 16 bytes, got 5"),
        ('key_file = "rig.key"\nkey_env = "X"', r"give key_file or key_env, not both"),
        ('key_file = "rig.key"\nprotocol_version = 1', r"a shared key .* needs protocol_version = 2"),
        ('key = "inline secret in the file"', r"unknown key\(s\) \['key'\]"),
    ],
)
def test_a_bad_key_setting_is_a_clear_error_without_the_key(tmp_path, lines, match):
    private(tmp_path / "rig.key", SECRET)
    private(tmp_path / "short.key", "short")
    path = write(tmp_path, f'kind = "simulated"\n[controller]\n{lines}\n')
    with pytest.raises(ConfigError, match=rf"^{re.escape(str(path))}: \[controller\]: {match}") as e:
        load_config(path)
    assert SECRET not in str(e.value) and "short\n" not in str(e.value)


# ---------------------------------------------------------------- drivers are registered, not imported
def test_a_module_path_as_driver_imports_nothing(tmp_path, monkeypatch):
    """``driver = "this:Nope"`` used to import the module named (it ran) before the error."""
    marker = tmp_path / "imported"
    (tmp_path / "jaxrecog_test_side_effect.py").write_text(
        f"open({str(marker)!r}, 'w').close()\nclass Unit:\n    pass\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    importlib.invalidate_caches()
    for driver in ("jaxrecog_test_side_effect:Unit", "this:Nope", "jaxrecog_test_side_effect"):
        path = write(tmp_path, f'kind = "simulated"\n[[ptu]]\ndriver = "{driver}"\n[[ptu]]\n')
        with pytest.raises(ConfigError, match=rf"^{path}: \[\[ptu\]\] #1: driver = '{driver}': unknown pan-tilt "
                                              rf"driver '{driver}'.*known: \['ptu-d46'\]"):
            load_config(path)
    assert not marker.exists()
    assert "jaxrecog_test_side_effect" not in sys.modules and "this" not in sys.modules


def _fake_driver(path, marker, cls: str = "Unit", extra: str = "") -> None:
    """A driver module at ``path`` that touches ``marker`` when it is imported."""
    path.write_text(f"""
open({str(marker)!r}, 'w').close()
class {cls}:
    url = ""
    @classmethod
    def from_config(cls, config, port=None):
        return cls()
{extra}""")


def _install_fake_distribution(tmp_path, monkeypatch):
    """A package that declares a pan-tilt driver entry point, as pip would install it."""
    marker = tmp_path / "imported"
    _fake_driver(tmp_path / "jaxrecog_test_unit.py", marker)
    info = tmp_path / "jaxrecog_test_unit-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: jaxrecog-test-unit\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(f"[{ENTRY_POINT_GROUP}]\ntest-unit = jaxrecog_test_unit:Unit\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    importlib.invalidate_caches()
    monkeypatch.delitem(sys.modules, "jaxrecog_test_unit", raising=False)
    return marker


def test_a_driver_registered_as_an_entry_point_is_found_and_imported_only_when_named(tmp_path, monkeypatch):
    marker = _install_fake_distribution(tmp_path, monkeypatch)
    assert "test-unit" in pan_tilt_drivers() and not marker.exists()  # listing imports nothing
    path = write(tmp_path, 'kind = "simulated"\n' + MOUNTS.format(ptu1='driver = "test-unit"', ptu2=""))
    cfg = load_config(path)
    assert marker.exists() and cfg.ptus[0].driver == "test-unit"
    assert pan_tilt_driver("test-unit").__module__ == "jaxrecog_test_unit"


def test_the_built_in_driver_works_without_any_metadata(monkeypatch):
    monkeypatch.setattr(pan_tilt, "_entry_points", lambda: {})  # stale or missing metadata
    assert pan_tilt_driver("ptu-d46") is PTU and pan_tilt_drivers() == ("ptu-d46",)


def test_a_new_pan_tilt_protocol_is_one_module_in_pan_tilt_drivers(tmp_path, monkeypatch):
    """The cost of a change: a new built-in driver is its module in
    hardware/devices/pan_tilt_drivers/ (here a folder added to that package's path)
    plus the rig file's driver key; listing imports nothing, naming it imports it."""
    from jaxrecog.hardware.devices import pan_tilt_drivers as package

    marker = tmp_path / "imported"
    _fake_driver(tmp_path / "acme_pt9.py", marker, "AcmePT9", "DRIVER = AcmePT9\n")
    (tmp_path / "_acme_wire.py").write_text("raise AssertionError('a helper module is not a driver')\n")
    monkeypatch.setattr(package, "__path__", [*package.__path__, str(tmp_path)])
    monkeypatch.delitem(sys.modules, f"{package.__name__}.acme_pt9", raising=False)
    assert pan_tilt_drivers() == ("acme-pt9", "ptu-d46") and not marker.exists()  # listing imports nothing
    path = write(tmp_path, 'kind = "simulated"\n' + MOUNTS.format(ptu1='driver = "acme-pt9"', ptu2=""))
    cfg = load_config(path)
    assert marker.exists() and cfg.ptus[0].driver == "acme-pt9"
    assert pan_tilt_driver("acme-pt9").__name__ == "AcmePT9"
    with pytest.raises(KeyError, match="unknown pan-tilt driver"):  # the driver's name, not its module's
        pan_tilt_driver("acme_pt9")


def test_a_broken_registered_driver_is_a_clear_error(tmp_path, monkeypatch):
    info = tmp_path / "jaxrecog_test_broken-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: jaxrecog-test-broken\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(f"[{ENTRY_POINT_GROUP}]\nbroken-unit = jaxrecog_test_not_there:Unit\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    importlib.invalidate_caches()
    path = write(tmp_path, 'kind = "simulated"\n[[ptu]]\ndriver = "broken-unit"\n[[ptu]]\n')
    with pytest.raises(ConfigError, match=r"driver = 'broken-unit': cannot import pan-tilt driver 'broken-unit' "
                                          r"\(jaxrecog_test_not_there:Unit\): ModuleNotFoundError"):
        load_config(path)


def test_the_rig_file_of_docs_hardware_md_loads(tmp_path):
    """Docs are code: the annotated TOML of docs/hardware.md is a valid hardware rig file."""
    text = (Path(__file__).parents[1] / "docs" / "hardware.md").read_text(encoding="utf-8")
    block = text[text.index("## The TOML file"):].split("```toml\n", 1)[1].split("```", 1)[0]
    cfg = load_config(write(tmp_path, block))
    assert cfg.kind == "hardware" and cfg.controller.protocol_version == 4 and cfg.controller.key is None
    assert [p.port for p in cfg.ptus] == ["/dev/ttyUSB0", "/dev/ttyUSB1"] and cfg.cameras[0].reconnect_s == 5.0


def test_a_rig_file_is_read_bounded_and_as_utf8(tmp_path):
    """A rig file is read as every settings file is: /dev/zero (which would
    grow without end), a FIFO (which would block) or a file over 1 MiB is
    refused before it is parsed, and a non-UTF-8 file is one line naming the
    byte, not a traceback."""
    fifo = tmp_path / "rig.fifo"
    os.mkfifo(fifo)
    big = tmp_path / "big.toml"
    big.write_bytes(b"#" * ((1 << 20) + 1))
    latin = tmp_path / "latin.toml"
    latin.write_bytes(b'name = "caf\xe9"\n')
    for path, needle in [("/dev/zero", "character device"), (fifo, "FIFO"), (big, "more than the 1048576 a rig file may have"),
                         (latin, "not UTF-8 text (byte 0xe9")]:
        with pytest.raises(ConfigError, match=re.escape(needle)) as e:
            load_config(path)
        assert "\n" not in str(e.value) and "rig file" in str(e.value)
