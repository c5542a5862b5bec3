"""jaxrecog: active multi-camera object recognition and pose estimation in JAX.

The method is the thesis "Robust Sequential View Planning for Object Recognition
Using Multiple Cameras": eigenspace features per camera position, occlusion-aware
Gaussian sensor models, a recursive Bayesian belief over (object, pose, occlusion
level per camera), and view planning over all camera configurations by Mutual
Information or a Cramér-Rao bound.
"""

from ._version import __version__

# The names below are imported on first use (PEP 562), not here: ``import
# jaxrecog`` (and with it the CLI's ``--help``) does not import JAX, ~1.5 s.
# Using one of them also sets up the persistent compilation cache
# (:mod:`jaxrecog.compile_cache`) unless it is switched off.
_SOURCES = {
    "augment": ("DB1_LEVELS", "DB2_LEVELS", "SHAPES", "AugmentParams", "augment_images"),
    "database": ("DatabaseError", "ImageDatabase", "NonGrayImageWarning", "load_database", "write_database"),
    "features": ("ImageError", "project", "project_batch", "project_camera"),
    "modelfile": ("FORMAT_VERSION", "ModelFileContentError", "ModelFileCorruptError", "ModelFileError", "ModelFileMissingError", "ModelFileTruncatedError", "ModelFileVersionError", "load_model", "save_model"),
    "sensor_model": ("CameraModel", "SensorModel"),
    "train": ("TrainingInfo", "train_model"),
    "kernels": ("Belief",),
    "planners": ("PLANNERS", "Planner", "PlannerSpec", "make_planner", "planner_names"),
    "recognizer": ("Decision", "Recognizer", "RecognizerState", "StepTrace", "restrict_cameras"),
    "results": ("TrialResult", "TrialStore"),
    "driver": ("StepRecord", "TrialSpec", "run_trials"),
    "campaign": ("plan_trials", "run_campaign"),
}
_WHERE = {name: module for module, names in _SOURCES.items() for name in names}


def __getattr__(name: str):
    """A public name (imported from its module on first use) or a submodule."""
    import importlib

    module = _WHERE.get(name)
    if module is None:
        try:
            return importlib.import_module(f"{__name__}.{name}")
        except ModuleNotFoundError as e:
            if e.name != f"{__name__}.{name}":
                raise
            raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None
    from . import compile_cache
    compile_cache.ensure()
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


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
