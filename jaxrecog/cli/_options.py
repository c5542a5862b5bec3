"""Argparse types and the option groups that several subcommands share."""

from __future__ import annotations

import argparse

from ..planners import DEFAULT_MIN_PER_STRATUM, planner_names

__all__ = [
    "PLANNERS", "Formatter", "config_tuple", "int_at_least", "positive", "nonneg", "object_choice", "probability",
    "global_options", "table_options", "planner_size_options", "skip_invalid_option",
    "motion_weight", "choice_options",
]

#: The choices of ``--planner`` / ``--planners``: the planner registry's names
#: (``planners.PLANNERS``), the one place the CLI takes them from.
PLANNERS = planner_names()


class Formatter(argparse.RawDescriptionHelpFormatter):
    """Raw descriptions; ``(default: X)`` after each help where a default means something."""

    def _get_help_string(self, action):
        text = action.help or ""
        d = action.default
        if "%(default)" in text or d is None or d is False or d is argparse.SUPPRESS or not action.option_strings:
            return text
        shown = " ".join(map(str, d)) if isinstance(d, (list, tuple)) else d
        return f"{text} (default: {shown})"


def config_tuple(text: str) -> tuple[int, ...]:
    """An argparse type: one position per camera, ``"3,2"``."""
    try:
        vals = tuple(int(x) for x in str(text).replace(" ", "").split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected positions like '3,2' (one per camera), got {text!r}") from None
    if any(v < 0 for v in vals):
        raise argparse.ArgumentTypeError(f"positions must be >= 0, got {text!r}")
    return vals


def int_at_least(low: int, what: str):
    """An argparse type: an integer >= ``low``, described as ``what`` in errors."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
        if v < low:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
        return v

    return parse


positive = int_at_least(1, "a positive integer")
nonneg = int_at_least(0, "an integer >= 0")


def object_choice(text: str | int) -> int | str:
    """An argparse type: ``N`` (the first N thesis objects, an int) or
    ``random:N`` (N random_urdfs meshes, kept as the string ``"random:N"``)."""
    from ..hardware.random_objects import parse_objects

    if isinstance(text, int) and not isinstance(text, bool):
        text = str(text)
    try:
        kind, n = parse_objects(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return n if kind == "thesis" else f"random:{n}"


def probability(text: str) -> float:
    """An argparse type: a probability in (0, 1]."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a probability, got {text!r}") from None
    if not 0.0 < v <= 1.0:
        raise argparse.ArgumentTypeError(f"expected a probability in (0, 1], got {text!r}")
    return v


def motion_weight(text: str) -> float:
    """An argparse type: the motion cost λ, a finite number >= 0."""
    from ..motion import check_weight

    try:
        return check_weight(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def choice_options(p: argparse.ArgumentParser, *, unset: bool = False) -> None:
    """How the next configuration is chosen beyond the planner's scores
    (``experiment`` and ``recognize``): ``--exclude-visited`` and
    ``--motion-cost``.  Both depart from the thesis and are off by default.
    ``unset``: leave them ``None`` when not given (``experiment``, where an
    experiment TOML may set them)."""
    g = p.add_argument_group("view choice (departures from the thesis, off by default)")
    g.add_argument("--exclude-visited", action="store_true", default=None if unset else False,
                   help="never send a camera back to a position it already took an image from (the thesis "
                        "excludes only whole configurations already used, so one camera may stay on its view)")
    g.add_argument("--motion-cost", type=motion_weight, metavar="LAMBDA", default=None if unset else 0.0,
                   help="score(a) - LAMBDA * seconds to move the rig to a: LAMBDA >= 0 in score units per second "
                        "(nats/s for the MI planners); travel times from the rig's geometry and axis speeds "
                        "(a rig file's [motion] table; 0 = off)")


def global_options(parser: argparse.ArgumentParser, suppress: bool) -> None:
    """``--quiet``, ``--debug``, ``--config`` on the main parser and (``suppress``:
    without overriding the main parser's values) on every subcommand."""
    d = argparse.SUPPRESS if suppress else None
    parser.add_argument("--quiet", "-q", action="store_true", default=d if suppress else False,
                        help="no progress bars (they are also off when output is not a terminal)")
    parser.add_argument("--debug", action="store_true", default=d if suppress else False,
                        help="show the full traceback on errors")
    parser.add_argument("--config", metavar="FILE.TOML", default=d,
                        help="read option defaults from this TOML file ([global] and one table per subcommand)")


def table_options(p: argparse.ArgumentParser) -> None:
    """The synthetic rig's layout (``render`` and ``recognize``)."""
    g = p.add_argument_group("synthetic rig layout (must match the model's positions)")
    g.add_argument("--cameras", type=int, choices=(1, 2), default=2,
                   help="cameras of the thesis rig to use (1 = camera 1 only)")
    g.add_argument("--stride", type=positive, default=1,
                   help="keep every STRIDE-th position of each camera (1 = the full 32 x 7 table)")
    g.add_argument("--objects", type=object_choice, default=8,
                   help="number of objects (the first N of the 8), or random:N: N of pybullet_data's 1000 "
                        "random_urdfs meshes, gray, fitted to the thesis objects' bounding radius")
    g.add_argument("--poses", type=positive, default=4, help="poses per object (pose p at 360*p/POSES degrees)")


def planner_size_options(p: argparse.ArgumentParser) -> None:
    """The planners' Monte Carlo size (``plan`` and ``recognize``)."""
    p.add_argument("--samples", type=positive, default=1024, help="Monte Carlo samples of the planner")
    p.add_argument("--min-per-stratum", type=positive, default=DEFAULT_MIN_PER_STRATUM,
                   help="at least this many samples per state (object, pose, levels): with an occlusion model "
                        "1024 samples alone give one draw per state, too few to see a sticker view")


def skip_invalid_option(p: argparse.ArgumentParser) -> None:
    """``--skip-invalid`` (``plan`` and ``recognize``: see :mod:`._images`)."""
    p.add_argument("--skip-invalid", action="store_true",
                   help="an image the belief cannot use (wrong size, NaN, all black, constant) is a warning, "
                        "and the belief goes on without it, instead of an error (exit 1)")
