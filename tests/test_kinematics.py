import math

import numpy as np
import pytest

from jaxrecog.hardware import (
    Workspace,
    WorkspaceError,
    camera1_angles,
    camera1_position,
    camera2_angles,
    camera2_position,
    config_from_index,
    index_from_config,
)


@pytest.mark.parametrize("pan_deg", [-170, -90, -30, 0, 10, 45, 90, 135, 180])
@pytest.mark.parametrize("tilt_deg", [25, 40, 60, 80])
def test_camera1_round_trip(pan_deg, tilt_deg):
    ws = Workspace()
    pan, tilt = math.radians(pan_deg), math.radians(tilt_deg)
    x, y, z = camera1_position(ws, pan, tilt)
    assert z == ws.carriers[0].z
    pan2, tilt2 = camera1_angles(ws, x, y)
    # pan is periodic: compare on the circle
    assert abs(math.remainder(pan2 - pan, 2 * math.pi)) < 1e-12
    assert tilt2 == pytest.approx(tilt, abs=1e-12)
    # the defining relations C.27-C.28 hold
    dx, dy, dz = x - ws.object_xyz[0], y - ws.object_xyz[1], z - ws.object_xyz[2]
    assert math.atan2(dx, dy) == pytest.approx(math.remainder(pan, 2 * math.pi), abs=1e-12) or abs(pan_deg) == 180
    assert math.tan(tilt) == pytest.approx(dz / math.hypot(dx, dy), rel=1e-12)


def test_printed_c32_c33_are_inconsistent():
    """Document why we do not use the printed C.32-C.33: they fail C.27."""
    ws = Workspace()
    pan, tilt = math.radians(30), math.radians(45)
    dz = ws.carriers[0].z - ws.object_xyz[2]
    x_printed = dz * math.cos(pan) / math.tan(tilt)
    y_printed = dz * math.cos(pan) / (math.tan(tilt) * math.tan(pan))
    # C.27 holds for the printed form ...
    assert math.atan2(x_printed, y_printed) == pytest.approx(pan)
    # ... but C.28 does not: the tilt it implies is off by more than 10 degrees.
    tilt_printed = math.atan2(dz, math.hypot(x_printed, y_printed))
    assert abs(tilt_printed - tilt) > math.radians(10)


@pytest.mark.parametrize("pan_deg", [-60, -40, -20, 0, 20, 40, 60])
def test_camera2_round_trip(pan_deg):
    ws = Workspace()
    (x, y, z), tilt = camera2_position(ws, math.radians(pan_deg))
    assert (x, z) == (ws.carriers[1].x, ws.carriers[1].z)
    pan2, tilt2 = camera2_angles(ws, y)
    assert pan2 == pytest.approx(math.radians(pan_deg), abs=1e-12)
    assert tilt2 == pytest.approx(tilt, abs=1e-12)


def test_limits_are_checked():
    ws = Workspace()
    with pytest.raises(WorkspaceError, match="tilt"):
        camera1_position(ws, 0.0, math.radians(5))
    with pytest.raises(WorkspaceError, match="gantry"):
        camera1_position(ws, 0.0, math.radians(12))
    with pytest.raises(WorkspaceError, match="pan"):
        camera2_position(ws, math.radians(95))
    with pytest.raises(WorkspaceError, match="track"):
        camera2_position(ws, math.radians(80))


def test_configuration_index_is_row_major():
    positions = (32, 7)
    seen = set()
    for a in range(32 * 7):
        cfg = config_from_index(a, positions)
        assert index_from_config(cfg, positions) == a
        seen.add(cfg)
    assert len(seen) == 224
    assert config_from_index(7 * 5 + 3, positions) == (5, 3)
    assert np.ravel_multi_index((31, 6), positions) == 223


def test_default_table_is_thesis_sized_and_round_trips():
    from jaxrecog.hardware.geometry.positions import CameraTable, default_table

    table = default_table()
    assert table.positions == (32, 7)
    again = CameraTable.from_dict(table.to_dict())
    assert again.positions == (32, 7)
    for a, b in zip(table.views[0] + table.views[1], again.views[0] + again.views[1]):
        assert a.eye == pytest.approx(b.eye, abs=1e-12)
    # every camera-1 eye sees the object along the planned angles
    for v in table.views[0]:
        assert camera1_angles(table.workspace, v.eye[0], v.eye[1]) == pytest.approx(
            (math.remainder(v.pan, 2 * math.pi), v.tilt), abs=1e-12
        )
