"""The options of the live view (``--rerun``, ``--rerun-save``) and of the
hand-held rig (``--rig handheld:DEVICE --layout FILE``), shared by
``recognize`` and ``experiment``: parsing and building only, the work is
:mod:`jaxrecog.liveview` and :mod:`jaxrecog.hardware.physical.handheld`."""

from __future__ import annotations

from ._common import CLIError, UsageError

HANDHELD = "handheld:"


def rerun_options(p) -> None:
    g = p.add_argument_group("live view (rerun)")
    g.add_argument("--rerun", action="store_true",
                   help="show every step live in a rerun viewer (started here): images, beliefs, occlusion, "
                        "planner scores, the rig in 3-D (pip install 'jaxrecog[rerun]')")
    g.add_argument("--rerun-save", metavar="FILE.RRD",
                   help="write the live view's recording to this file instead (no viewer; open it with `rerun FILE.RRD`)")


def handheld_options(p) -> None:
    g = p.add_argument_group("hand-held rig (--rig handheld:DEVICE)")
    g.add_argument("--layout", metavar="FILE.TOML", help="the hand-held rig's positions: cameras, position names, angles")
    g.add_argument("--layout-picture", metavar="PNG",
                   help="draw the layout with the next position marked into this file at every move")
    g.add_argument("--no-wait", action="store_true",
                   help="capture right after each instruction (a video or image sequence that holds the views) "
                        "instead of waiting for Enter")


def wants_rerun(args) -> bool:
    return bool(getattr(args, "rerun", False) or getattr(args, "rerun_save", None))


def recorder(args, model, rig=None, label: str = ""):
    """The :class:`~jaxrecog.liveview.RerunRecorder` of ``--rerun``/``--rerun-save``
    (``None`` without them); the 3-D view from ``rig``'s geometry."""
    if not wants_rerun(args):
        return None
    from ..liveview import LiveViewError, RerunRecorder, rig_geometry

    try:
        return RerunRecorder(model, geometry=None if rig is None else rig_geometry(rig), save=args.rerun_save,
                             spawn=bool(args.rerun), label=label)
    except LiveViewError as e:
        raise CLIError(str(e)) from None


def campaign_view(args):
    """The :class:`~jaxrecog.liveview.CampaignView` of ``experiment --rerun``/``--rerun-save``
    (``None`` without them; one line and nothing run if rerun is missing)."""
    if not wants_rerun(args):
        return None
    from ..liveview import CampaignView, LiveViewError

    try:
        return CampaignView(save=args.rerun_save, spawn=bool(args.rerun))
    except LiveViewError as e:
        raise CLIError(str(e)) from None


def check_handheld_flags(args) -> None:
    """The hand-held options need the hand-held rig, and it needs a layout."""
    handheld = str(getattr(args, "rig", "") or "").startswith(HANDHELD)
    if handheld and not args.layout:
        raise UsageError("--rig handheld:DEVICE needs --layout FILE.TOML (the positions to put the camera at)")
    if not handheld and (args.layout or args.layout_picture or args.no_wait):
        raise UsageError("--layout, --layout-picture and --no-wait go with --rig handheld:DEVICE")


def handheld_rig(args, model):
    """The hand-held rig of ``--rig handheld:DEVICE --layout FILE``."""
    from ..hardware.physical.handheld import HandheldRig, LayoutError, load_layout, open_camera

    device = args.rig[len(HANDHELD):]
    if not device:
        raise UsageError("--rig handheld:DEVICE needs a device: a camera index, a video file or an image sequence")
    try:
        layout = load_layout(args.layout)
    except LayoutError as e:
        raise CLIError(str(e)) from None
    camera = open_camera(device, tuple(model.image_shape))
    return HandheldRig(camera, layout, tuple(model.image_shape), wait=(lambda: None) if args.no_wait else None,
                       picture=args.layout_picture)
