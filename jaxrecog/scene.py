"""The synthetic scene of a trial as the campaigns, ``jaxrecog recognize
--rig synthetic`` and ``jaxrecog render`` set it up: the capture noise of the
test images and the cardboard boards in front of the first views.

A leaf of the core: the CLI imports it without the campaign machinery
(:mod:`jaxrecog.campaigns`); the boards' geometry is the hardware layer's
(:mod:`jaxrecog.hardware.render.occluders`), imported when a factory is built.
"""

from __future__ import annotations

__all__ = ["CAPTURE_NOISE", "occluder_factory"]

#: (brightness sd, pixel sd, max shift px) of every synthetic capture the
#: recognizer is tested on: campaign captures (``Settings.capture_noise``),
#: ``jaxrecog recognize --rig synthetic`` and the test split of ``jaxrecog render``.
CAPTURE_NOISE: tuple[float, float, int] = (0.05, 2.0, 2)


# the campaigns' board ranges (OCCLUDER_SIZE / OCCLUDER_OFFSET) live with the boards


def occluder_factory(rig, size: tuple[float, float] | None = None, offset: tuple[float, float] | None = None):
    """Cardboard for one trial (thesis §7.2): a board in front of each camera's
    *initial* view, so both first images are occluded, plus one board per
    camera facing a random other position, so moving is not a guaranteed
    escape.  ``size`` / ``offset``: the boards' half-size and offset ranges
    (:func:`~jaxrecog.hardware.random_occluders`; default the campaign's,
    ``OCCLUDER_SIZE`` / ``OCCLUDER_OFFSET`` of :mod:`jaxrecog.hardware.render.occluders`)."""
    from .hardware import OccluderLayout, random_occluders
    from .hardware.render.occluders import OCCLUDER_OFFSET, OCCLUDER_SIZE
    from .hardware.geometry.positions import CameraTable

    size = OCCLUDER_SIZE if size is None else size
    offset = OCCLUDER_OFFSET if offset is None else offset

    def factory(rng, initial):
        first = CameraTable(rig.table.workspace, tuple((views[v],) for views, v in zip(rig.table.views, initial)))
        a = random_occluders(rng, first, radius=rig.radius, size=size, offset=offset)
        b = random_occluders(rng, rig.table, radius=rig.radius, size=size, offset=offset)
        return OccluderLayout(a.boards + b.boards)

    return factory
