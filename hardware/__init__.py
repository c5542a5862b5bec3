"""Rigs: the ``Rig`` interface, appendix-C kinematics, the synthetic (rendered)
rig, the dataset replay rig and the real hardware (PTU serial, UDP controller,
cameras) with device simulators.

The package imports its modules lazily (PEP 562): ``from jaxrecog.hardware
import SyntheticRig`` imports ``synthetic.py`` (and pybullet when a scene is
built) on first use, so importing the recognition core, which needs only the
rig interface (:mod:`.rig`), loads neither OpenCV (cameras), pyserial (the
PTU driver), sockets (the UDP link) nor the renderer.  :data:`__all__` lists
every name; :data:`_EXPORTS` says which module holds it.
"""

from __future__ import annotations

import importlib

# name -> the module of this package that defines it (imported on first access)
_EXPORTS: dict[str, str] = {
    **dict.fromkeys(["camera1_angles", "camera1_position", "camera2_angles", "camera2_position",
                     "Workspace", "WorkspaceError"], "kinematics"),
    **dict.fromkeys(["Board", "OccluderLayout", "random_occluders"], "occluders"),
    **dict.fromkeys(["Capture", "CaptureJob", "config_from_index", "index_from_config", "Rig", "RigError", "RigPool",
                     "SceneSpec"], "rig"),
    **dict.fromkeys(["Camera", "CameraError", "CameraLostError", "ImageSequenceCamera", "VideoCamera"], "camera"),
    **dict.fromkeys(["ConfigError", "load_config", "RigConfig"], "config"),
    **dict.fromkeys(["ControllerSimulator", "LinkFaults"], "controller_sim"),
    **dict.fromkeys(["HardwareRig", "Reconnect", "rig_from_config", "SimulatedHardwareRig"], "hardware_rig"),
    **dict.fromkeys(["PanTilt", "PanTiltConnectionError", "PanTiltError", "register_pan_tilt"], "pan_tilt"),
    **dict.fromkeys(["PTU", "PTUError", "PTUErrorReply", "PTUGarbageError", "PTUHomingTimeout",
                     "PTULimitError", "PTUTimeoutError"], "ptu"),
    **dict.fromkeys(["PTUSimulator"], "ptu_sim"),
    **dict.fromkeys(["SharedKey"], "datagram"),
    **dict.fromkeys(["ControllerLink", "ControllerRejected", "ControllerRestarted", "LinkError",
                     "LinkTimeoutError", "SessionClosed", "SessionRefused"], "udp_link"),
    **dict.fromkeys(["contact_sheet", "lookalike_distances", "render_database"], "render_db"),
    **dict.fromkeys(["default_objects", "Intrinsics", "Lighting", "ObjectSpec", "Part", "Scene"], "scene"),
    **dict.fromkeys(["Noise", "SyntheticRig"], "synthetic"),
    **dict.fromkeys(["DatasetRig"], "dataset_rig"),
    **dict.fromkeys(["LocalRigs", "ProcessRigs"], "rig_pool"),
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

