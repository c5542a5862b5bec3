"""Rigs: the ``Rig`` interface, appendix-C kinematics, the synthetic (rendered)
rig, the dataset replay rig and the real hardware (PTU serial, UDP controller,
cameras) with device simulators."""

from .kinematics import (
    Workspace,
    WorkspaceError,
    camera1_angles,
    camera1_position,
    camera2_angles,
    camera2_position,
)
from .occluders import Board, OccluderLayout, random_occluders
from .rig import Capture, Rig, RigError, config_from_index, index_from_config
from .camera import Camera, CameraError, CameraLostError, ImageSequenceCamera, VideoCamera
from .config import ConfigError, RigConfig, load_config
from .controller_sim import ControllerSimulator, LinkFaults
from .hardware_rig import HardwareRig, Reconnect, SimulatedHardwareRig, rig_from_config
from .pan_tilt import PanTilt, PanTiltConnectionError, PanTiltError, register_pan_tilt
from .ptu import PTU, PTUError, PTUErrorReply, PTUGarbageError, PTUHomingTimeout, PTULimitError, PTUTimeoutError
from .ptu_sim import PTUSimulator
from .datagram import SharedKey
from .udp_link import ControllerLink, ControllerRejected, ControllerRestarted, LinkError, LinkTimeoutError
from .udp_link import SessionClosed, SessionRefused

# The synthetic rig renders with pybullet, imported only when a scene is built
# (scene.require_pybullet), so this package imports without the `sim` extra.
from .render_db import contact_sheet, lookalike_distances, render_database
from .scene import Intrinsics, Lighting, ObjectSpec, Part, Scene, default_objects
from .synthetic import Noise, SyntheticRig
from .dataset_rig import DatasetRig
from .rig_pool import CaptureJob, LocalRigs, ProcessRigs, RigPool, SceneSpec

__all__ = [
    "Capture",
    "Camera",
    "CameraError",
    "CameraLostError",
    "ConfigError",
    "ControllerLink",
    "ControllerRejected",
    "ControllerRestarted",
    "ControllerSimulator",
    "HardwareRig",
    "ImageSequenceCamera",
    "LinkError",
    "LinkFaults",
    "LinkTimeoutError",
    "PTU",
    "PTUError",
    "PTUErrorReply",
    "PTUGarbageError",
    "PTUHomingTimeout",
    "PTULimitError",
    "PTUSimulator",
    "PTUTimeoutError",
    "PanTilt",
    "PanTiltConnectionError",
    "PanTiltError",
    "Reconnect",
    "RigConfig",
    "SessionClosed",
    "SessionRefused",
    "SharedKey",
    "SimulatedHardwareRig",
    "VideoCamera",
    "load_config",
    "register_pan_tilt",
    "rig_from_config",
    "Board",
    "CaptureJob",
    "DatasetRig",
    "LocalRigs",
    "ProcessRigs",
    "RigPool",
    "SceneSpec",
    "Intrinsics",
    "Lighting",
    "Noise",
    "ObjectSpec",
    "OccluderLayout",
    "Part",
    "Scene",
    "SyntheticRig",
    "contact_sheet",
    "default_objects",
    "lookalike_distances",
    "random_occluders",
    "render_database",
    "Rig",
    "RigError",
    "Workspace",
    "WorkspaceError",
    "camera1_angles",
    "camera1_position",
    "camera2_angles",
    "camera2_position",
    "config_from_index",
    "index_from_config",
]
