"""Rigs: the ``Rig`` interface, appendix-C kinematics, the synthetic (rendered)
rig, the dataset replay rig and the real hardware (PTU serial, UDP controller,
cameras) with device simulators, in one subpackage per area:

============  ===============================================================
``rigs``      the ``Rig`` interface (``rig.py``), rig pools, the dataset rig
``geometry``  kinematics, carriers, the configuration table, travel times
``devices``   pan-tilt drivers, cameras, the controller datagrams and link
``sim``       the PTU and motion-controller simulators
``render``    the pybullet scene, the synthetic rig, rendered databases
``physical``  the rig file, ``HardwareRig`` / ``SimulatedHardwareRig``, ``HandheldRig``
============  ===============================================================

The package imports its modules lazily (PEP 562): ``from jaxrecog.hardware
import SyntheticRig`` imports ``render/synthetic.py`` (and pybullet when a
scene is built) on first use, so importing the recognition core, which needs
only the rig interface (:mod:`.rigs.rig`), loads neither OpenCV (cameras),
pyserial (the PTU driver), sockets (the UDP link) nor the renderer.
:data:`__all__` lists every name; :data:`_EXPORTS` says which module holds it.
"""

from __future__ import annotations

import importlib

# name -> the module of this package that defines it (imported on first access)
_EXPORTS: dict[str, str] = {
    **dict.fromkeys(["camera1_angles", "camera1_position", "camera2_angles", "camera2_position", "Gantry", "Track",
                     "Workspace", "WorkspaceError"], "geometry.kinematics"),
    **dict.fromkeys(["Board", "OccluderLayout", "random_occluders"], "render.occluders"),
    **dict.fromkeys(["Capture", "CaptureJob", "config_from_index", "index_from_config", "Rig", "RigError", "RigPool",
                     "SceneSpec"], "rigs.rig"),
    **dict.fromkeys(["Camera", "CameraError", "CameraLostError", "ImageSequenceCamera", "VideoCamera"], "devices.camera"),
    **dict.fromkeys(["ConfigError", "load_config", "RigConfig"], "physical.config"),
    **dict.fromkeys(["ControllerSimulator", "LinkFaults"], "sim.controller_sim"),
    **dict.fromkeys(["HardwareRig", "Reconnect", "rig_from_config", "SimulatedHardwareRig"], "physical.hardware_rig"),
    **dict.fromkeys(["PanTilt", "PanTiltConnectionError", "PanTiltError", "register_pan_tilt"], "devices.pan_tilt"),
    **dict.fromkeys(["PTU"], "devices.pan_tilt_drivers.ptu_d46"),
    **dict.fromkeys(["PTUError", "PTUErrorReply", "PTUGarbageError", "PTUHomingTimeout", "PTULimitError",
                     "PTUTimeoutError"], "devices.ptu_protocol"),
    **dict.fromkeys(["PTUSimulator"], "sim.ptu_sim"),
    **dict.fromkeys(["SharedKey"], "devices.datagram"),
    **dict.fromkeys(["ControllerLink", "ControllerRejected", "ControllerRestarted", "LinkError",
                     "LinkTimeoutError", "SessionClosed", "SessionRefused"], "devices.udp_link"),
    **dict.fromkeys(["contact_sheet", "lookalike_distances", "render_database"], "render.render_db"),
    **dict.fromkeys(["default_objects", "Intrinsics", "Lighting", "ObjectSpec", "Part", "Scene"], "render.scene"),
    **dict.fromkeys(["Noise", "SyntheticRig"], "render.synthetic"),
    **dict.fromkeys(["DatasetRig"], "rigs.dataset_rig"),
    **dict.fromkeys(["HandheldRig", "Layout", "LayoutError", "load_layout", "open_camera"], "physical.handheld"),
    **dict.fromkeys(["LocalRigs", "ProcessRigs"], "rigs.rig_pool"),
    **dict.fromkeys(["CaptureMemo", "MemoRigs"], "rigs.capture_memo"),
}

__all__ = sorted(_EXPORTS, key=str.lower)


def __getattr__(name: str):
    """The exported ``name``, its module imported on first access (then cached here)."""
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))

