"""Held-out captures of a synthetic case: a ``calib`` database rendered near
the training views, occluded when the case is, for what a recipe fits on a
``calib`` split (the variance factors, :mod:`jaxrecog.calibration`; the
planner's stability weight, :mod:`jaxrecog.stability_fit`).

:func:`like_case` draws them as the case's own captures are drawn: on the
training grid for cases (i)-(iii) (capture noise only), with the case's
off-grid yaw, camera offset and light for the jitter cases.  A share of the
views (``occluded_fraction``) gets one board in front of that view, like a
trial's first board (:func:`jaxrecog.scene.occluder_factory`).
"""

from __future__ import annotations

from pathlib import Path

from .cases import Case, case_settings
from .rigs import rig_table
from .settings import Settings

__all__ = ["like_case", "render_held_out"]


def like_case(case: Case, settings: Settings):
    """The :class:`~jaxrecog.hardware.render.synthetic.Perturb` of the case's
    captures: its off-grid amounts (0 on the grid) and the settings' capture noise."""
    from ..hardware.render.synthetic import Noise, Perturb

    s = case_settings(case, settings)
    b, p, shift = s.capture_noise
    return Perturb(yaw_deg=s.off_grid_deg or 0.0, eye_offset=s.off_grid_eye or 0.0, light=s.off_grid_light or 0.0,
                   noise=Noise(brightness=b, pixel=p, max_shift=int(shift)))


def render_held_out(folder: Path, settings: Settings, case: Case, perturb, *, calib_per_view: int = 1,
                    occluded_fraction: float = 0.5, seed: int = 0) -> Path:
    """Render (once: a folder with a manifest is kept) the held-out ``calib``
    views of ``case`` into ``folder``: ``calib_per_view`` per (camera,
    position, object, pose) of the settings' table (its ``stride``) with
    ``perturb``; when the case is occluded, a board in front of a view with
    probability ``occluded_fraction``."""
    from ..hardware import OccluderLayout, random_occluders, render_database
    from ..hardware.geometry.positions import CameraTable
    from ..hardware.render.occluders import OCCLUDER_OFFSET, OCCLUDER_SIZE
    from ..hardware.render.scene import default_objects, object_radius

    if not 0.0 <= occluded_fraction <= 1.0:
        raise ValueError(f"occluded_fraction must lie in [0, 1], got {occluded_fraction!r}")
    folder = Path(folder)
    if (folder / "manifest.csv").exists():
        return folder
    table = rig_table(settings)
    radius = object_radius(default_objects())

    def board_in_front(rng, camera, position):
        """Like the campaigns' first board, for a share of the views."""
        if rng.random() >= occluded_fraction:
            return None
        one = CameraTable(table.workspace, tuple((views[position if i == camera else 0],)
                                                 for i, views in enumerate(table.views)))
        return OccluderLayout(random_occluders(rng, one, radius=radius, cameras=(camera,), size=OCCLUDER_SIZE,
                                               offset=OCCLUDER_OFFSET).boards)

    render_database(folder, table, train=False, calib_per_view=calib_per_view, calib_perturb=perturb,
                    calib_occluders=board_in_front if case.occluded else False, seed=seed)
    return folder
