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
from .rig import Rig, RigError, config_from_index, index_from_config

__all__ = [
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
