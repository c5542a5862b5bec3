"""Argparse types and the option groups that several subcommands share."""

from __future__ import annotations

import argparse

from ..planners import DEFAULT_MIN_PER_STRATUM, planner_names

__all__ = [
    "PLANNERS", "Formatter", "config_tuple", "int_at_least", "positive", "nonneg", "object_choice", "probability",
    "global_options", "table_options", "planner_size_options", "skip_invalid_option",
    "motion_weight", "adaptive_scale", "choice_options", "render_workers_option", "cluster_option", "likelihood_options", "capture_options", "view_jitter_option",
    "render_jitter_options", "render_jitter_values",
    "likelihood_choice", "given_likelihood_options", "default_likelihood", "capture_params", "nu_value",
    "sigma_range", "bounded",
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
    from ..hardware.render.random_objects import parse_objects

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


def adaptive_scale(text: str) -> float:
    """``--adaptive-scale S``: a finite number >= 1 (1 = off)."""
    from ..kernels.adaptive_scale import scale_grid

    try:
        s = float(text)
        scale_grid(s)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a finite number >= 1 (1 = off), got {text!r}") from None
    return s


def choice_options(p: argparse.ArgumentParser, *, unset: bool = False) -> None:
    """How the next configuration is chosen beyond the planner's scores
    and when to stop (``experiment`` and ``recognize``): ``--exclude-visited``,
    ``--shared-view``, ``--motion-cost`` and ``--min-views``.  All depart from the thesis and are off by default.
    ``unset``: leave them ``None`` when not given (``experiment``, where an
    experiment TOML may set them)."""
    g = p.add_argument_group("view choice (departures from the thesis, off by default)")
    g.add_argument("--exclude-visited", action=argparse.BooleanOptionalAction, default=None if unset else False,
                   help="never send a camera back to a position it already took an image from (the thesis "
                        "excludes only whole configurations already used, so one camera may stay on its view)")
    g.add_argument("--shared-view", action="store_true", default=None if unset else False,
                   help="a view-mixture model's component (the object's turn off the training pose) is one per "
                        "trial, shared by every camera and step, and kept in the belief (instead of chosen anew "
                        "for each capture)")
    g.add_argument("--motion-cost", type=motion_weight, metavar="LAMBDA", default=None if unset else 0.0,
                   help="score(a) - LAMBDA * seconds to move the rig to a: LAMBDA >= 0 in score units per second "
                        "(nats/s for the MI planners); travel times from the rig's geometry and axis speeds "
                        "(a rig file's [motion] table; 0 = off)")
    g.add_argument("--min-views", type=positive, metavar="N", default=None if unset else 1,
                   help="never stop on the probability threshold before N image sets: a decision is confirmed "
                        "by N - 1 more views (the thesis stops at the first step that reaches it: 1; at most "
                        "the step limit)")
    g.add_argument("--adaptive-scale", type=adaptive_scale, metavar="S", default=None if unset else 1.0,
                   help="weaken the evidence of a capture that no class explains by the variance factor (up to "
                        "S) under which its best class explains it best, and count only explained image sets "
                        "toward --min-views (jaxrecog.kernels.adaptive_scale; 1 = off, the thesis)")


def model_recipe(path: str):
    """The recipe a model file records (:func:`jaxrecog.recipes.recipe_from_meta`;
    ``thesis`` for files written before recipes).  A file that cannot be read
    raises its :class:`~jaxrecog.modelfile.ModelFileError` (one line)."""
    from ..modelfile import load_model_meta
    from ..recipes import recipe_from_meta

    return recipe_from_meta(load_model_meta(path))


def render_workers_option(p: argparse.ArgumentParser, *, default: int | None) -> None:
    """``--render-workers N`` (``experiment``, ``scripts/reproduce_thesis.py``)."""
    p.add_argument("--render-workers", type=nonneg, metavar="N", default=default,
                   help="render the synthetic rig's captures in N worker processes, side by side (the results "
                        "are the same; rendering is most of a campaign's time; 0 = in this process; default "
                        f"{default if default is not None else 0})")


def cluster_spec(text: str) -> str | None:
    """``--cluster``'s argparse type: ``ray`` or ``ray://HOST:PORT`` (:func:`jaxrecog.cluster.check_cluster`)."""
    from ..cluster import check_cluster

    try:
        return check_cluster(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def cluster_option(p: argparse.ArgumentParser, what: str) -> None:
    """``--cluster SPEC`` (``experiment``, ``render``, the campaign scripts)."""
    p.add_argument("--cluster", type=cluster_spec, metavar="SPEC", default=None,
                   help=f"{what} on Ray: 'ray' starts a local Ray instance, 'ray://HOST:PORT' joins a running "
                        "cluster (docs/cluster.md; needs the 'cluster' extra); the results are the same as here")


def global_options(parser: argparse.ArgumentParser, suppress: bool) -> None:
    """``--quiet``, ``--debug``, ``--config``, ``--problems-out`` on the main parser and (``suppress``:
    without overriding the main parser's values) on every subcommand."""
    d = argparse.SUPPRESS if suppress else None
    parser.add_argument("--quiet", "-q", action="store_true", default=d if suppress else False,
                        help="no progress bars (they are also off when output is not a terminal)")
    parser.add_argument("--debug", action="store_true", default=d if suppress else False,
                        help="show the full traceback on errors")
    parser.add_argument("--config", metavar="FILE.TOML", default=d,
                        help="read option defaults from this TOML file ([global] and one table per subcommand)")
    parser.add_argument("--problems-out", metavar="FILE", default=d,
                        help="on an error that lists problems (an invalid database, settings file, model file), "
                             "write all of them to this new file (never overwritten, never in a database folder; the "
                             "message shows the first 10)")


def table_options(p: argparse.ArgumentParser) -> None:
    """The synthetic rig's layout (``render`` and ``recognize``)."""
    g = p.add_argument_group("synthetic rig layout (must match the model's positions)")
    g.add_argument("--cameras", type=int, choices=(1, 2), default=2,
                   help="cameras of the thesis rig to use (1 = camera 0 only)")
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


def bounded(high: float, what: str, inclusive: bool = False):
    """An argparse type: a number in ``[0, high)`` (``[0, high]`` if ``inclusive``)."""

    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            v = float("nan")
        if not (0.0 <= v <= high if inclusive else 0.0 <= v < high):
            raise argparse.ArgumentTypeError(
                f"expected {what} in [0, {high:g}{']' if inclusive else ')'}, got {text!r}")
        return v

    return parse


def _numbers(text: str) -> list[float]:
    """``"a,b,..."`` as floats (spaces ignored); ``[]`` if any is not a number."""
    try:
        return [float(x) for x in str(text).replace(" ", "").split(",")]
    except ValueError:
        return []


def sigma_range(text: str) -> tuple[float, float]:
    """An argparse type: ``SIGMA`` (= ``0,SIGMA``) or ``LO,HI`` with ``0 <= LO <= HI``."""
    vals = _numbers(text)
    if len(vals) == 1:
        vals = [0.0, vals[0]]
    if len(vals) != 2 or not all(0.0 <= v < float("inf") for v in vals) or vals[0] > vals[1]:
        raise argparse.ArgumentTypeError(f"expected SIGMA or LO,HI with 0 <= LO <= HI (pixels), got {text!r}")
    return vals[0], vals[1]


def stability_weight(text: str) -> float | str:
    """``--stability``: ``auto`` or a finite number >= 0."""
    if text.strip().lower() == "auto":
        return "auto"
    try:
        w = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number >= 0 or 'auto', got {text!r}") from None
    if not 0.0 <= w < float("inf"):
        raise argparse.ArgumentTypeError(f"expected a finite number >= 0 or 'auto', got {text!r}")
    return w


def gray_range(text: str) -> tuple[float, float]:
    """An argparse type: ``LO,HI`` gray levels with ``0 <= LO <= HI <= 255``."""
    vals = _numbers(text)
    if len(vals) != 2 or not all(0.0 <= v <= 255.0 for v in vals) or vals[0] > vals[1]:
        raise argparse.ArgumentTypeError(f"expected LO,HI gray levels with 0 <= LO <= HI <= 255, got {text!r}")
    return vals[0], vals[1]


def nu_value(text: str) -> str | float:
    """An argparse type: ``auto`` or a number > 2."""
    if str(text).strip().lower() == "auto":
        return "auto"
    try:
        v = float(text)
    except ValueError:
        v = float("nan")
    if not v > 2.0 or v == float("inf"):
        raise argparse.ArgumentTypeError(f"expected 'auto' or a number > 2, got {text!r}")
    return v


def likelihood_options(p: argparse._ActionsContainer) -> None:
    """``--likelihood``, ``--rank``, ``--nu``, ``--occluded-jitter`` (``train``, ``experiment``,
    ``scripts/reproduce_thesis.py``; on a parser or an argument group): all default to ``None`` = not given
    (the thesis's diagonal Gaussian; the family's own option defaults)."""
    from ..kernels import DEFAULT_LIKELIHOOD, DEFAULT_VIEW_JITTER_LIKELIHOOD, likelihood_names
    from ..kernels.view_mixture import OCCLUDED_JITTER

    p.add_argument("--likelihood", choices=likelihood_names(), default=None,
                   help=f"sensor-model family (default: {DEFAULT_LIKELIHOOD}, the thesis's; with --view-jitter "
                        f"{DEFAULT_VIEW_JITTER_LIKELIHOOD})")
    p.add_argument("--rank", type=positive, default=None,
                   help="gaussian-lowrank, view-mixture-lowrank: factors R, 1 <= R < K (default: min(4, K - 1))")
    p.add_argument("--nu", type=nu_value, default=None,
                   help="student-t: degrees of freedom, a number > 2, or 'auto' (chosen per level on held-out "
                        "training samples; the default)")
    p.add_argument("--occluded-jitter", choices=OCCLUDED_JITTER, default=None,
                   help="view-mixture, view-mixture-lowrank: 'sampled' (default) augments every jitter image at "
                        "every occlusion level; 'translated' at level 0 only, and moves the training view's "
                        "occluded components by each jitter view's level-0 offset (several times faster)")


_LIKELIHOOD_FLAGS = ("rank", "nu", "occluded_jitter")   # fit options with a flag of their own


def given_likelihood_options(args) -> dict:
    """The fit options given by :func:`likelihood_options`'s flags (those left ``None`` out)."""
    return {k: getattr(args, k) for k in _LIKELIHOOD_FLAGS if getattr(args, k, None) is not None}


def default_likelihood(view_jitter: bool) -> str:
    """The family trained when none is named: the thesis's diagonal Gaussian,
    or with view jitter the low-rank view mixture."""
    from ..kernels import DEFAULT_LIKELIHOOD, DEFAULT_VIEW_JITTER_LIKELIHOOD

    return DEFAULT_VIEW_JITTER_LIKELIHOOD if view_jitter else DEFAULT_LIKELIHOOD


def likelihood_choice(name: str | None, options: dict | None = None, view_jitter: bool = False) -> tuple[str, dict]:
    """The likelihood name (default :func:`default_likelihood`) and its fit
    options (:func:`given_likelihood_options`); an option of another family
    is a ``ValueError`` naming the families that take it."""
    from ..kernels import LIKELIHOODS, likelihood_class

    name = name or default_likelihood(view_jitter)
    family = likelihood_class(name)
    options = dict(options or {})
    for k in options:
        if k not in family.fit_options:
            takers = sorted(c.name or c.kind for c in LIKELIHOODS.values() if k in c.fit_options)
            raise ValueError(f"--{k.replace('_', '-')} applies to {', '.join(takers)}, not to --likelihood {name}")
    return name, options


def capture_options(p: argparse.ArgumentParser, *, unset: bool = False) -> None:
    """The capture augmentation of training (:class:`jaxrecog.augment.AugmentParams`:
    rotation, scale, blur, local gain; off by default).  ``unset``: defaults
    ``None`` = not given (``experiment``, where a TOML file may set them)."""
    g = p.add_argument_group("capture augmentation (what a real capture does off the training grid; off by default)")
    g.add_argument("--rotation", type=bounded(180.0, "degrees", inclusive=True), default=None if unset else 0.0,
                   metavar="DEG", help="in-plane rotation by a uniform angle in +-DEG degrees about the image centre")
    g.add_argument("--scale", type=bounded(1.0, "a fraction"), default=None if unset else 0.0, metavar="FRAC",
                   help="scaling by 1 + a, a uniform in +-FRAC, about the image centre")
    g.add_argument("--blur", type=sigma_range, default=None if unset else "0", metavar="SIGMA|LO,HI",
                   help="Gaussian blur, sigma uniform in [LO, HI] pixels (one number: [0, SIGMA])")
    g.add_argument("--gain", type=bounded(1.0, "a fraction"), default=None if unset else 0.0, metavar="FRAC",
                   help="local gain: a smooth multiplicative field 1 + c, |c| <= FRAC, bilinearly upsampled "
                        "from a CELLS x CELLS grid of uniform values")
    g.add_argument("--gain-cells", type=int_at_least(2, "an integer >= 2"), default=None if unset else 3,
                   metavar="CELLS", help="control grid of the --gain field")
    g.add_argument("--occluder-gray", type=gray_range, default=None if unset else "0,0", metavar="LO,HI",
                   help="DB2: each training occluder's gray level uniform in [LO, HI] (0..255) instead of black "
                        "(the thesis's; a real occluder is rarely black)")
    g.add_argument("--max-shift", type=nonneg, default=None if unset else 3, metavar="PIXELS",
                   help="training samples shifted by up to PIXELS pixels in x and y (default 3; match the largest "
                        "shift of your captures: a wider range widens every class's variance; the synthetic "
                        "rig's captures shift by up to 2)")


def capture_params(args) -> dict:
    """The given capture options of :func:`capture_options` as
    :class:`~jaxrecog.augment.AugmentParams` fields (those left ``None`` out;
    ``--blur`` from a TOML file may be a number or ``[LO, HI]``)."""
    out = {}
    for opt, field in (("rotation", "max_rotation"), ("scale", "max_scale"), ("gain", "gain_amplitude")):
        if getattr(args, opt, None) is not None:
            out[field] = float(getattr(args, opt))
    for opt in ("gain_cells", "max_shift"):
        if getattr(args, opt, None) is not None:
            out[opt] = int(getattr(args, opt))
    for opt, field, parse in (("blur", "blur_sigma", sigma_range), ("occluder_gray", "occluder_gray", gray_range)):
        value = getattr(args, opt, None)
        if value is not None:  # parsed on the command line; a number, string or list from a TOML file
            out[field] = value if isinstance(value, tuple) else parse(
                ",".join(map(str, value)) if isinstance(value, list) else str(value))
    return out


def render_jitter_options(p: argparse._ActionsContainer) -> None:
    """``--view-jitter N`` / ``--view-jitter-deg D`` of the synthetic cases
    (``experiment``, ``scripts/reproduce_thesis.py``): ``Settings.view_jitter``
    / ``view_jitter_deg``; default ``None`` = not given (off)."""
    p.add_argument("--view-jitter", type=int_at_least(0, "an integer >= 0"), default=None, metavar="N",
                   help="render N views near each training view (the object turned up to +-D degrees) and train "
                        "on them as extra samples of that view (not in the thesis; default 0 = off)")
    p.add_argument("--view-jitter-deg", type=bounded(180.0, "degrees"), default=None, metavar="D",
                   help="largest turn of the --view-jitter views (default 10)")


def render_jitter_values(args) -> dict:
    """The given ``--view-jitter`` / ``--view-jitter-deg`` as Settings fields."""
    return {f: getattr(args, a) for a, f in (("view_jitter", "view_jitter"), ("view_jitter_deg", "view_jitter_deg"))
            if getattr(args, a, None) is not None}


def view_jitter_option(p: argparse.ArgumentParser) -> None:
    """``--view-jitter`` (``train``): the database's ``jitter`` rows as extra base images."""
    p.add_argument("--view-jitter", action="store_true",
                   help="use the database's 'jitter' rows (images near a training view, each labelled with that "
                        "view) as extra base images of their view: each gets --samples augmented samples like "
                        "the training image (jaxrecog.train.train_model)")
