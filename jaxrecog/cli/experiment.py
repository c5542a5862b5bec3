"""``jaxrecog experiment``: a thesis case, a TOML experiment or a campaign on an image database."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import time
from pathlib import Path
from typing import Any

from .. import campaigns  # as a module: tests stub its prepare / run_case / run_dataset
from .._config import FIELD_OPTIONS, LIKELIHOOD_OPTION_KEYS, OPTION_FIELDS, ConfigFileError, read_toml, resolve_keys
from .._files import check_output_folder, write_text
from .._lock import folder_lock
from ..campaign import MAX_TRIALS
from ..driver import trial_mesh
from ..modelfile import ModelFileError
from ..planners import DEFAULT_MIN_PER_STRATUM
from .._progress import enabled as progress_bars
from ..problems import one_line
from ._common import UsageError
from ._json import SCHEMA_VERSION, json_option, run_reporting
from ._live import campaign_view, rerun_options, wants_rerun
from ._options import (PLANNERS, capture_options, capture_params, choice_options, default_likelihood, gray_range,
                       model_recipe, nonneg, probability, sigma_range,
                       given_likelihood_options, likelihood_options, positive, render_jitter_options,
                       render_jitter_values, render_workers_option, cluster_option)
from ._reports import QUICK, make_settings, trace_plot, write_report

NAME = "experiment"
ORDER = 60
HELP = "run a thesis case, a TOML experiment or a campaign on an image database"
DESCRIPTION = ("Run a recognition campaign as in thesis chapter 7 and write the tables (Markdown,\n"
               "JSON) and plots into --out.  CASE is a case name (i, ii, iii, single-clean,\n"
               "single-occluded, jitter, jitter-occluded) or a TOML file with 'case' and Settings\n"
               "fields; the case renders and trains its own database and models (cached in\n"
               "--workdir).  The jitter cases capture off the training grid (object yaw within\n"
               "+-20 degrees per trial, camera eye and light jitter per capture).\n\n"
               "With --rig dataset:FOLDER --model MODEL.NPZ (and no CASE) the campaign replays the\n"
               "test split of an image database instead: every object of the model, --trials per\n"
               "object with a random pose and start, any number of cameras and positions (the\n"
               "model's).  A TOML file may give 'rig' and 'model' in place of 'case'.\n\n"
               "An experiment file and the [experiment] table of --config take the same keys: the\n"
               "option names (trials, threshold, ...) or the Settings field names (trials_per_object,\n"
               "p_threshold, ...).  --print-config prints the resolved configuration as an experiment\n"
               "file and exits; every run writes it as config.toml into --out.")

#: Settings fields an [experiment] table of ``--config`` may give besides the
#: options (cli._apply_config): those without an option arrive as ``args.config_fields``.
CONFIG_FIELDS = campaigns.Settings.FIELDS
#: An experiment file's own keys besides the Settings fields and their option names.
FILE_KEYS = ("case", "rig", "model", "planners")


def add_arguments(p) -> None:
    p.add_argument("case", metavar="CASE", nargs="?",
                   help="thesis case name or experiment TOML file (leave out with --rig dataset:FOLDER)")
    p.add_argument("--out", default="out/experiment", metavar="FOLDER", help="where tables and plots go")
    p.add_argument("--workdir", metavar="FOLDER", help="cache of the rendered database and models, and the "
                   "finished trials (default: OUT/work)")
    p.add_argument("--rig", metavar="RIG",
                   help="'synthetic' (the thesis case's rendered rig; the default) or 'dataset:FOLDER' "
                        "(replay an image database's test split; needs --model)")
    p.add_argument("--model", metavar="MODEL.NPZ", help="trained model file for --rig dataset:FOLDER")
    p.add_argument("--planners", nargs="+", choices=PLANNERS, metavar="PLANNER",
                   help=f"planners to compare, from {', '.join(PLANNERS)} (default: the case's; "
                        "the model's recipe's planner and random on a dataset rig)")
    p.add_argument("--trials", type=positive, help=f"trials per object (default: the case's; a campaign runs at "
                                                   f"most {MAX_TRIALS} trials in all)")
    p.add_argument("--samples", type=positive, help="Monte Carlo samples of the planners")
    p.add_argument("--min-per-stratum", type=positive, help="at least this many planner samples per state "
                   f"(default {DEFAULT_MIN_PER_STRATUM})")
    p.add_argument("--batch", type=positive, help="trials run in lockstep")
    p.add_argument("--seed", type=int, help="campaign seed")
    p.add_argument("--threshold", type=probability, help="stop probability P_th (default: the case's 0.95; on a "
                   "database the model's recipe's)")
    p.add_argument("--stride", type=positive,
                   help="synthetic rig: keep every STRIDE-th position of each camera (8 = a 4 x 1 table "
                        "that renders and trains in seconds; default 1 = the thesis's 32 x 7)")
    p.add_argument("--quick", action="store_true", help="small models and fewer planner samples "
                   "(minutes, not hours)")
    p.add_argument("--trace", action="store_true", help="also run one traced trial and plot its belief "
                   "(thesis cases)")
    p.add_argument("--devices", type=positive, metavar="N",
                   help="shard each lockstep batch over N devices (GPUs; the batch is rounded up to a multiple "
                        "of N; the results are the same as on one device; default 1)")
    render_workers_option(p, default=None)
    cluster_option(p, "run the campaign (and render the case's database; --render-workers: Ray workers, 0 = "
                      "one per CPU)")
    choice_options(p, unset=True)
    g = p.add_argument_group("training of the case's models (thesis cases; each choice has its own cached models)")
    likelihood_options(g)
    g.add_argument("--interpolate", type=nonneg, default=None, metavar="N",
                   help="N interpolated views per side toward each neighbouring position (view-mixture components "
                        "between the training views; default 0 = off, the thesis)")
    g.add_argument("--interpolation", choices=("linear", "flow"), default=None,
                   help="how --interpolate's views are made: 'linear' (cross-fade, the default here) or 'flow' "
                        "(optical-flow morph, the robust recipe's)")
    render_jitter_options(g)
    capture_options(p, unset=True)
    p.add_argument("--print-config", action="store_true",
                   help="print the resolved configuration (every Settings field and the planners, an experiment "
                        "file that runs the same campaign) and exit without running")
    json_option(p)
    rerun_options(p)


def _training_values(args, values: dict[str, Any]) -> dict[str, Any]:
    """The Settings fields of ``--likelihood`` / ``--rank`` / ``--nu`` /
    ``--occluded-jitter`` and the capture augmentation flags, over those of an
    experiment file (``values``): the option flags update the file's
    ``likelihood_options``."""
    out: dict[str, Any] = {}
    if args.likelihood is not None:
        out["likelihood"] = args.likelihood
    elif (args.view_jitter or args.interpolate) and "likelihood" not in values:  # a mixture's default family
        out["likelihood"] = default_likelihood(True)
    if args.interpolate is not None:
        out["interpolate"] = args.interpolate
    if args.interpolation is not None:
        out["interpolation"] = args.interpolation
    opts = given_likelihood_options(args)
    if opts:
        base = values.get("likelihood_options") or {}
        out["likelihood_options"] = {**dict(base.items() if hasattr(base, "items") else base), **opts}
    out.update(render_jitter_values(args))
    try:
        out.update(capture_params(args))
    except (ValueError, argparse.ArgumentTypeError) as e:
        raise UsageError(f"--blur: {e}") from None
    return out


def experiment_keys() -> dict[str, str]:
    """Every key an experiment file accepts -> its canonical name: the file's
    own keys, the Settings fields, their option names (:data:`OPTION_FIELDS`)
    and the likelihood's option flags (``rank`` -> ``likelihood_options``'s)."""
    names = {k: k for k in (*FILE_KEYS, *CONFIG_FIELDS)}
    names.update({o: f for o, f in OPTION_FIELDS.items()})
    names.update({k: k for k in LIKELIHOOD_OPTION_KEYS})
    return names


def load_settings_flat(path: str) -> dict[str, Any]:
    """An experiment TOML: top-level keys (``case``, ``planners``, Settings
    fields or their option names); a ``[settings]`` table is merged in too.
    Keys come back as Settings field names (``rank``, ``nu``,
    ``occluded_jitter`` folded into ``likelihood_options``)."""
    data = read_toml(path, "experiment file")
    inner = data.pop("settings", {})
    if not isinstance(inner, dict):
        raise ConfigFileError(f"experiment file {path}: 'settings' must be a table")
    out = resolve_keys([("top level", data), ("[settings]", inner)], experiment_keys(), f"experiment file {path}")
    flags = {k: out.pop(k) for k in LIKELIHOOD_OPTION_KEYS if k in out}
    if flags:
        base = out.get("likelihood_options") or {}
        if not isinstance(base, dict):
            raise ConfigFileError(f"experiment file {path}: likelihood_options must be a table")
        twice = sorted(set(flags) & set(base))
        if twice:
            raise ConfigFileError(f"experiment file {path}: {twice[0]!r} and likelihood_options.{twice[0]} are the "
                                  "same setting; give one of them")
        out["likelihood_options"] = {**base, **flags}
    for field, parse in (("blur_sigma", sigma_range), ("occluder_gray", gray_range)):
        if isinstance(out.get(field), str):  # the option's "LO,HI" form
            try:
                out[field] = parse(out[field])
            except (ValueError, argparse.ArgumentTypeError) as e:
                raise ConfigFileError(f"experiment file {path}: {FIELD_OPTIONS.get(field, field)}: {e}") from None
    return out


def _dataset_folder(rig: str) -> str:
    if not rig.startswith("dataset:"):
        raise UsageError(f"--rig {rig!r}: expected 'synthetic' or 'dataset:FOLDER'")
    folder = rig[len("dataset:"):]
    if not folder:
        raise UsageError("--rig dataset:FOLDER needs a folder")
    return folder


@dataclasses.dataclass(frozen=True)
class _Resolved:
    """What a run does: the campaign (a case name, or a database ``folder``
    and ``model``), its Settings and planners (``None``: the default)."""

    name: str | None
    rig: Any
    model: Any
    folder: str | None
    settings: Any
    planners: list[str] | None
    out: Path

    @property
    def dataset(self) -> bool:
        return self.folder is not None


def _resolve(args) -> _Resolved:
    """The experiment's configuration from the case or experiment file, the
    ``--config`` table and the options (usage errors before anything runs)."""
    values: dict[str, Any] = {}
    planners = args.planners
    name = args.case
    rig, model = args.rig, args.model
    if name is not None and (name.endswith(".toml") or Path(name).is_file()):
        path = name
        try:
            data = load_settings_flat(path)
        except ConfigFileError as e:
            raise UsageError(str(e)) from None
        file_rig, file_model = data.pop("rig", None), data.pop("model", None)
        rig = rig if rig is not None else file_rig
        model = model if model is not None else file_model
        if "case" not in data and rig in (None, "synthetic"):
            raise UsageError(f"experiment file {path}: needs a 'case' key ({', '.join(campaigns.CASES)}) "
                             "or 'rig' = 'dataset:FOLDER' and 'model'")
        name = str(data.pop("case")) if "case" in data else None
        if planners is None and "planners" in data:
            planners = data.pop("planners")
            if (not isinstance(planners, list) or not planners
                    or any(not isinstance(x, str) or x not in PLANNERS for x in planners)):
                raise UsageError(f"experiment file {path}: planners must be a list of planner names "
                                 f"({', '.join(PLANNERS)}), got {one_line(repr(planners), 80)}")
        data.pop("planners", None)
        values.update(data)
    fields = getattr(args, "config_fields", None) or {}  # --config [experiment]: fields without an option
    values.update(fields)
    dataset = rig is not None and str(rig) != "synthetic"
    folder = None
    if dataset:
        folder = _dataset_folder(str(rig))
        if name is not None:
            raise UsageError(f"--rig {rig} replays a database, not a thesis case: leave out the case ({name})")
        if not model:
            raise UsageError("--rig dataset:FOLDER needs --model MODEL.NPZ (a model file trained on the database)")
        if not isinstance(model, str):
            raise UsageError(f"model must be a model file name, got {one_line(repr(model), 80)}")
        if args.trace:
            raise UsageError("--trace works with the thesis cases (synthetic rig) only")
        if (args.stride or values.get("stride", 1)) != 1:
            raise UsageError("--stride selects positions of the synthetic rig; a database has its own positions")
        if _training_values(args, {}):
            raise UsageError("--likelihood, --rank, --nu and the capture augmentation train a thesis case's models; "
                             "a database campaign uses the given --model")
    else:
        if model:
            raise UsageError("--model is used with --rig dataset:FOLDER only (a thesis case trains its own models)")
        if name is None:
            raise UsageError("give a CASE (" + ", ".join(campaigns.CASES) + ") or an experiment TOML file, "
                             "or --rig dataset:FOLDER --model MODEL.NPZ")
        if name not in campaigns.CASES:
            raise UsageError(f"unknown case {name!r}; choose {', '.join(campaigns.CASES)} or a TOML file")
    out = Path(args.out)
    over = {"trials_per_object": args.trials, "samples": args.samples,
            "min_per_stratum": args.min_per_stratum, "batch": args.batch, "seed": args.seed,
            "stride": args.stride, "devices": args.devices,
            "render_workers": args.render_workers, "cluster": args.cluster,
            "exclude_visited_positions": args.exclude_visited,
            "shared_view": args.shared_view, "motion_cost": args.motion_cost, "min_views": args.min_views,
            "p_threshold": args.threshold, "adaptive_scale": args.adaptive_scale}
    values.update({k: v for k, v in over.items() if v is not None})
    if dataset:  # the stop rule: the model's recipe unless an option or the experiment file gives it
        try:
            recipe = model_recipe(str(model))
        except ModelFileError:
            recipe = None   # the campaign's own load of the model reports it, after the usage checks
        except ValueError as e:   # a recipe newer than this code: never run as another recipe
            raise UsageError(f"model {model}: {e}") from None
        for part, field in (("p_threshold", "p_threshold"), ("min_views", "min_views"),
                            ("exclude_visited", "exclude_visited_positions"), ("adaptive_scale", "adaptive_scale")):
            if recipe is not None:
                values.setdefault(field, getattr(recipe, part))
    values.update(_training_values(args, values))
    if args.quick:
        for k, v in QUICK.items():
            values.setdefault(k, v)
    values.setdefault("workdir", args.workdir or str(out / "work"))
    if args.workdir:
        values["workdir"] = args.workdir
    if isinstance(values.get("capture_noise"), list):  # a TOML array: the field is a tuple
        values["capture_noise"] = tuple(values["capture_noise"])
    try:
        settings = make_settings(values, args.case or "experiment")
    except ValueError as e:
        raise UsageError(str(e)) from None
    if dataset and settings.render_workers and not settings.cluster:
        raise UsageError("--render-workers renders the synthetic rig; a replayed database is not rendered")
    if dataset and settings.motion_cost > 0:
        raise UsageError("--motion-cost needs the rig's geometry (travel times); a replayed database has none")
    try:
        trial_mesh(settings.devices)  # too many devices: one clear line before anything renders or trains
    except ValueError as e:
        raise UsageError(f"--devices {settings.devices}: {e}") from None
    return _Resolved(name, rig, model, folder, settings, planners, out)


def _toml_key(k: Any) -> str:
    k = str(k)
    return k if k and all(c.isascii() and (c.isalnum() or c in "_-") for c in k) else json.dumps(k)


def _toml_value(v: Any) -> str | None:
    """``v`` as a TOML value (``None``: TOML has none; the key is left out)."""
    if v is None:
        return None
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, (str, Path)):
        return json.dumps(str(v))  # a JSON string is a TOML basic string
    if isinstance(v, dict):
        items = [(k, _toml_value(x)) for k, x in v.items()]
        return "{" + ", ".join(f"{_toml_key(k)} = {x}" for k, x in items if x is not None) + "}"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) or '""' for x in v) + "]"
    raise TypeError(f"no TOML form for {type(v).__name__}")


def config_text(r: _Resolved) -> str:
    """The resolved configuration as an experiment file: the campaign, the
    planners and every Settings field (under its field name; a field that is
    ``None``, the case's own, as a comment)."""
    lines = ["# jaxrecog experiment: the resolved configuration (run it again: jaxrecog experiment FILE.toml)"]
    if r.dataset:
        lines += [f"rig = {_toml_value(str(r.rig))}", f"model = {_toml_value(str(r.model))}"]
    else:
        lines.append(f"case = {_toml_value(r.name)}")
    planners = r.planners
    if planners is None and not r.dataset:
        planners = list(campaigns.CASES[r.name].planners)
    elif planners is None:
        try:
            planners = list(campaigns.dataset_planners(r.model))
        except (ModelFileError, ValueError, OSError):
            planners = None  # the campaign's own load of the model reports it
    if planners is not None:
        lines.append(f"planners = {_toml_value(list(planners))}")
    for name, v in r.settings.flat().items():
        if name == "likelihood_options":
            v = dict(v)
        text = _toml_value(v)
        lines.append(f"# {name}: not set (the case's)" if text is None else f"{name} = {text}")
    return "\n".join(lines) + "\n"


def _report(args) -> tuple[dict, str]:
    r = _resolve(args)
    name, rig, model, folder, settings, planners, out, dataset = (r.name, r.rig, r.model, r.folder, r.settings,
                                                                  r.planners, r.out, r.dataset)
    if wants_rerun(args) and settings.cluster:
        raise UsageError("--rerun/--rerun-save show the trials run here; on --cluster they run elsewhere")
    live = campaign_view(args)  # a missing rerun: one line, before anything runs
    # one run per --out and work folder: a second is refused, naming the first's PID
    check_output_folder(out, "--out folder")  # a folder (made with its parents) that takes files, before any work
    check_output_folder(settings.workdir, "work folder")
    with folder_lock(out, settings.workdir), contextlib.closing(live) if live else contextlib.nullcontext():
        config = out / "config.toml"  # the resolved configuration beside the results (as hydra does)
        write_text(config, config_text(r), "resolved configuration")
        t0 = time.perf_counter()
        if dataset:
            report = campaigns.run_dataset(folder, model, settings, planners=planners, progress=progress_bars(),
                                           live=live)
            written = write_report(report, "dataset", out, title=f"Database {Path(folder).name}")
            done = f"campaign on {folder}"
        else:
            report = campaigns.run_case(name, settings, planners=planners, progress=progress_bars(), live=live)
            written = write_report(report, name, out)
            if args.trace:
                written += trace_plot(settings, out, planner=(planners or ["mi"])[0], case=name)
            done = f"case {name}"
        written.insert(0, config)
        if args.rerun_save:
            written.append(Path(args.rerun_save))
        seconds = time.perf_counter() - t0
    doc = {"command": NAME, "schema_version": SCHEMA_VERSION, "case": "dataset" if dataset else name,
           "title": report.case.title, "rig": str(rig) if dataset else "synthetic",
           "model": str(model) if dataset else None, "settings": _settings_doc(report.settings),
           "planners": [_planner_doc(report, p) for p in report.rows], "seconds": seconds, "out": str(out),
           "written": [str(p) for p in written]}
    text = "\n".join([report.markdown(), f"{done} in {seconds:.0f} s; wrote:", *(f"  {p}" for p in written)])
    return doc, text


def _settings_doc(settings) -> dict[str, Any]:
    return settings.flat()


def _planner_doc(report, planner: str) -> dict[str, Any]:
    """One planner's results table (``--json``'s ``planners[]``), with the thesis's rows where it has them."""
    ref = report.reference(planner) or []
    rows = []
    for i, r in enumerate(report.rows[planner]):
        thesis = ref[i] if i < len(ref) else None
        rows.append({**dataclasses.asdict(r),
                     "thesis": None if thesis is None else dict(zip(("rate", "exit_prob", "views"), thesis))})
    return {"planner": planner, "trials_per_object": report.settings.trials_per_object,
            "seconds": report.seconds.get(planner), "rows": rows}


def run(args) -> int:
    if args.print_config:
        print(config_text(_resolve(args)), end="")
        return 0
    return run_reporting(args, _report)
