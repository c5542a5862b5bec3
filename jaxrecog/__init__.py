"""jaxrecog: active multi-camera object recognition and pose estimation in JAX.

The method is the thesis "Robust Sequential View Planning for Object Recognition
Using Multiple Cameras": eigenspace features per camera position, occlusion-aware
Gaussian sensor models, a recursive Bayesian belief over (object, pose, occlusion
level per camera), and view planning over all camera configurations by Mutual
Information or a Cramér-Rao bound.
"""

__version__ = "0.1.0"

from .augment import DB1_LEVELS, DB2_LEVELS, SHAPES, AugmentParams, augment_images
from .database import DatabaseError, ImageDatabase, NonGrayImageWarning, load_database, write_database
from .features import ImageError, project, project_batch, project_camera
from .modelfile import (
    FORMAT_VERSION,
    ModelFileContentError,
    ModelFileCorruptError,
    ModelFileError,
    ModelFileMissingError,
    ModelFileTruncatedError,
    ModelFileVersionError,
    load_model,
    save_model,
)
from .sensor_model import CameraModel, SensorModel
from .train import TrainingInfo, train_model
from .kernels import Belief
from .planners import PLANNERS, Planner, PlannerSpec, make_planner, planner_names
from .recognizer import Decision, Recognizer, RecognizerState, StepTrace, restrict_cameras
from .results import TrialResult, TrialStore
from .driver import StepRecord, TrialSpec, run_trials
from .campaign import plan_trials, run_campaign

__all__ = [
    # recognition: what a control loop or a script uses
    "Belief",
    "Decision",
    "PLANNERS",
    "Planner",
    "PlannerSpec",
    "Recognizer",
    "RecognizerState",
    "StepRecord",
    "StepTrace",
    "TrialResult",
    "TrialSpec",
    "TrialStore",
    "make_planner",
    "plan_trials",
    "planner_names",
    "restrict_cameras",
    "run_campaign",
    "run_trials",
    # data, models, training
    "AugmentParams",
    "CameraModel",
    "DB1_LEVELS",
    "DB2_LEVELS",
    "DatabaseError",
    "FORMAT_VERSION",
    "ImageDatabase",
    "ImageError",
    "ModelFileContentError",
    "ModelFileCorruptError",
    "ModelFileError",
    "ModelFileMissingError",
    "ModelFileTruncatedError",
    "ModelFileVersionError",
    "NonGrayImageWarning",
    "SHAPES",
    "SensorModel",
    "TrainingInfo",
    "augment_images",
    "load_database",
    "load_model",
    "project",
    "project_batch",
    "project_camera",
    "save_model",
    "train_model",
    "write_database",
]
