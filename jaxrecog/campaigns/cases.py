"""The thesis's cases (chapter 7, docs/design.md §4) and what a case fixes: its
off-grid amounts, its model and its trials.

============== ======== =========== ======= ======================
name           database scene       cameras planners (default)
============== ======== =========== ======= ======================
i              DB1      clean       both    mi, mi-class, crlb, random
ii             DB1      occluders   both    mi, mi-class, crlb
iii            DB2      occluders   both    mi, mi-class, crlb
single-clean   DB1      clean       cam 0   mi, mi-class
single-occluded DB2     occluders   cam 0   mi, mi-class
jitter         DB1      clean,      both    mi-class, mi-class-pairwise, random
                        off-grid
jitter-occluded DB2     occluders,  both    mi-class, mi-class-pairwise, random
                        off-grid
============== ======== =========== ======= ======================

Off-grid cases (not in the thesis): every trial's object
sits turned ``U(-20°, 20°)`` off its training pose (drawn per trial, the same
for every planner), and every capture moves each camera's eye and jitters the
light (:class:`~jaxrecog.hardware.render.synthetic.OffGrid`, :data:`JITTER`), so no
test image is a training view.  ``Settings.off_grid_deg`` /
``off_grid_eye`` / ``off_grid_light`` override a case's amounts (``None``:
the case's; 0 for the thesis cases).

Occluders: one cardboard board in front of every camera's *initial* view, so
that the first images of both cameras are occluded (thesis §7.2); the
recognizer has to move to see past them (:func:`jaxrecog.scene.occluder_factory`).
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

from ..campaign import TrialSpec, plan_trials
from ..scene import occluder_factory
from .settings import Settings

if TYPE_CHECKING:
    from .preparation import Prepared

__all__ = ["Case", "CASES", "JITTER", "OFF_GRID_FIELDS", "case_settings", "off_grid", "case_model", "case_trials"]


@dataclasses.dataclass(frozen=True)
class Case:
    name: str
    title: str
    database: str  # "DB1" | "DB2"; for run_dataset: the database folder
    occluded: bool
    cameras: tuple[int, ...] | None  # None = all cameras
    planners: tuple[str, ...]
    #: (yaw bound in degrees, eye offset, light jitter) of the captures
    #: (:class:`~jaxrecog.hardware.render.synthetic.OffGrid`); zeros = on the grid
    off_grid: tuple[float, float, float] = (0.0, 0.0, 0.0)


#: The off-grid amounts of the ``jitter`` cases: object yaw within ±20° of the
#: training pose (per trial; the table's poses are 90° apart and camera 1's
#: positions ~11° apart in azimuth), eye offset 0.04 (rms 4 % of the eye-object
#: distance, ~2.3° of viewing direction) and light jitter 0.2 per capture: twice
#: :class:`~jaxrecog.hardware.render.synthetic.Perturb`'s defaults (0.02, 0.1) for eye
#: and light, as the yaw is ~7x its 3°.  ``scripts/difficulty_sweep.py`` scales
#: all three with the angle A: (A, 0.002 A, 0.01 A).
JITTER: tuple[float, float, float] = (20.0, 0.04, 0.2)

CASES: dict[str, Case] = {
    c.name: c
    for c in (
        Case("i", "Case (i): non-occluded objects, DB1 model", "DB1", False, None, ("mi", "mi-class", "crlb", "random")),
        Case("ii", "Case (ii): occluded objects, no occlusion model (DB1)", "DB1", True, None, ("mi", "mi-class", "crlb")),
        Case("iii", "Case (iii): occluded objects, occlusion model (DB2)", "DB2", True, None, ("mi", "mi-class", "crlb")),
        Case("single-clean", "Single camera (camera 0), non-occluded, DB1", "DB1", False, (0,), ("mi", "mi-class")),
        Case("single-occluded", "Single camera (camera 0), occluded, DB2", "DB2", True, (0,), ("mi", "mi-class")),
        Case("jitter", "Off-grid captures (yaw ±20°, eye and light jitter), non-occluded objects, DB1", "DB1", False,
             None, ("mi-class", "mi-class-pairwise", "random"), JITTER),
        Case("jitter-occluded", "Off-grid captures (yaw ±20°, eye and light jitter), occluded objects, DB2", "DB2",
             True, None, ("mi-class", "mi-class-pairwise", "random"), JITTER),
    )
}

#: The Settings fields of the off-grid amounts, in ``Case.off_grid``'s order.
OFF_GRID_FIELDS = ("off_grid_deg", "off_grid_eye", "off_grid_light")


def case_settings(case: Case, settings: Settings) -> Settings:
    """``settings`` with the off-grid amounts it leaves at ``None`` taken from
    the case (``Case.off_grid``), so the run id and the reports name the
    amounts the campaign ran with."""
    fill = {k: float(v) for k, v in zip(OFF_GRID_FIELDS, case.off_grid) if getattr(settings, k) is None}
    return dataclasses.replace(settings, **fill) if fill else settings


def off_grid(settings: Settings):
    """The :class:`~jaxrecog.hardware.render.synthetic.OffGrid` of ``settings``
    (``None`` amounts count as 0), or ``None`` when all are 0 (on the grid)."""
    from ..hardware.render.synthetic import OffGrid

    og = OffGrid(*(getattr(settings, k) or 0.0 for k in OFF_GRID_FIELDS))
    return None if og.off else og


def case_trials(case: Case, settings: Settings, rig, n_objects: int, n_poses: int, objects=None) -> list[TrialSpec]:
    """The case's trials on ``rig`` (:func:`~jaxrecog.campaign.plan_trials`):
    ``settings.trials_per_object`` per object, the boards of
    :func:`~jaxrecog.scene.occluder_factory` when the case is occluded, the
    case's yaw bound."""
    return plan_trials(
        n_objects,
        n_poses,
        rig.positions,
        settings.trials_per_object,
        seed=settings.seed,
        objects=objects,
        occluders=occluder_factory(rig) if case.occluded else None,
        yaw_deg=case_settings(case, settings).off_grid_deg or 0.0,
    )


def case_model(prepared: "Prepared", case: Case):
    """The case's model (DB1 or DB2 of ``prepared``), restricted to its cameras."""
    from ..modelfile import load_model
    from ..recognizer import restrict_cameras

    model = load_model(prepared.models[case.database])
    return restrict_cameras(model, case.cameras) if case.cameras is not None else model
