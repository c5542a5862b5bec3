"""Rigs and models for the environment, by name.

- ``"synthetic"`` (default): the rendered thesis rig of
  :func:`jaxrecog.campaigns.make_rig` (``settings.stride`` thins its table);
  ``case="occluded"`` adds the campaigns' cardboard occluders per episode.
  Without a model, :func:`jaxrecog.campaigns.prepare` renders the training
  database and trains the case's model (DB1 clean, DB2 occluded), cached in
  ``settings.workdir``.
- ``"dataset:FOLDER"``: a :class:`~jaxrecog.hardware.DatasetRig` replaying the
  database's ``test`` split (a model is required; clean only).
- ``"hardware-sim"``: the hardware code path (PTU and motion-controller
  simulators speaking the real protocols) around the synthetic renderer.
- any object with the ``Rig`` methods, used as it is.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

__all__ = ["CASES", "build_rig", "load_env_model"]

#: Scene options of the synthetic rig, and the database whose model fits each.
CASES = {"clean": "DB1", "occluded": "DB2"}


def _check_case(case: str) -> None:
    if case not in CASES:
        raise ValueError(f"case must be one of {', '.join(CASES)}, got {case!r}")


def build_rig(rig: Any, case: str, settings, cameras: tuple[int, ...] | None) -> tuple[Any, Callable | None]:
    """``(rig, occluder factory or None)`` for a rig name or a rig object.

    The factory is the campaigns' own (:func:`jaxrecog.scene.occluder_factory`), so an
    episode's scene is drawn exactly as a campaign trial's."""
    from ..campaigns import make_rig
    from ..scene import occluder_factory

    _check_case(case)
    if isinstance(rig, str):
        if rig == "synthetic":
            rig = make_rig(settings, cameras, seed=settings.seed)
        elif rig == "hardware-sim":
            from ..hardware import SimulatedHardwareRig
            from ..hardware.physical.config import RigConfig

            renderer = make_rig(settings, cameras, seed=settings.seed)
            rig = SimulatedHardwareRig(renderer, RigConfig("simulated", renderer.table))
        elif rig.startswith("dataset:"):
            from ..hardware import DatasetRig

            folder = rig.split(":", 1)[1]
            if not folder:
                raise ValueError("rig 'dataset:FOLDER' needs a folder, e.g. 'dataset:data/db'")
            rig = DatasetRig.from_folder(folder, seed=settings.seed)
        else:
            raise ValueError(f"unknown rig {rig!r}; choose 'synthetic', 'dataset:FOLDER', 'hardware-sim' or pass a Rig")
    missing = [m for m in ("positions", "image_shape", "reset", "reseed", "move", "capture", "close") if not hasattr(rig, m)]
    if missing:
        raise ValueError(f"rig {rig!r} lacks the Rig interface's {', '.join(missing)}")
    if case == "clean":
        return rig, None
    # occluders are placed by the renderer: the synthetic rig or a hardware
    # rig closed around it
    scene = getattr(rig, "renderer", rig)
    if not (hasattr(scene, "table") and hasattr(scene, "radius")):
        raise ValueError(f"case 'occluded' needs a rendered scene to place occluders in; {type(rig).__name__} has none")
    return rig, occluder_factory(scene)


def load_env_model(model: Any, rig: Any, case: str, settings, cameras: tuple[int, ...] | None):
    """The sensor model: a :class:`~jaxrecog.SensorModel`, a model file, or
    (``None``, synthetic rigs only) the case's model trained by
    :func:`jaxrecog.campaigns.prepare`; restricted to ``cameras``."""
    from ..campaigns import prepare
    from ..modelfile import load_model
    from ..recognizer import restrict_cameras

    _check_case(case)
    if model is None:
        if rig not in ("synthetic", "hardware-sim"):
            raise ValueError("a model (SensorModel or model file) is required unless the rig is 'synthetic' or 'hardware-sim'")
        kind = CASES[case]
        model = prepare(settings, databases=(kind,)).models[kind]
    if isinstance(model, (str, Path)):
        model = load_model(model)
    if not all(hasattr(model, a) for a in ("cameras", "n_objects", "n_poses", "levels", "image_shape")):
        raise ValueError(f"model must be a SensorModel or a model file, got {type(model).__name__}")
    return restrict_cameras(model, cameras) if cameras is not None else model
