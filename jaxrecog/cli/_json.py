"""``--json`` (``plan``, ``recognize``, ``inspect``, ``experiment``): one JSON
document on stdout instead of the text, with the keys of :data:`SCHEMAS`.

:data:`SCHEMAS` is the one place the keys are written down:
``scripts/gen_cli_docs.py`` renders it into docs/cli.md ("JSON output"), and
the tests check every emitted document against it (:func:`check`).  Keys are
stable: a document has every documented key of its objects (``null`` where a
value does not apply), and a key is added, never renamed or dropped, without
raising :data:`SCHEMA_VERSION`.

Values: a non-finite float (NaN, ±inf: not JSON) is ``null``; tuples and
NumPy arrays are arrays; paths are strings.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import sys
from pathlib import PurePath
from typing import Any, Callable

import numpy as np

__all__ = ["SCHEMA_VERSION", "SCHEMAS", "Key", "check", "clean", "dumps", "json_option", "run_reporting",
           "schema_markdown"]

#: ``schema_version`` of every document: raised when a key changes meaning or goes away.
SCHEMA_VERSION = 1

_TYPES: dict[str, Callable[[Any], bool]] = {
    "string": lambda v: isinstance(v, str),
    "integer": lambda v: isinstance(v, int) and not isinstance(v, bool),
    "number": lambda v: isinstance(v, (int, float)) and not isinstance(v, bool),
    "boolean": lambda v: isinstance(v, bool),
    "null": lambda v: v is None,
    "array": lambda v: isinstance(v, list),
    "object": lambda v: isinstance(v, dict),
    "any": lambda v: True,
}


@dataclasses.dataclass(frozen=True)
class Key:
    """One documented key.

    Attributes:
        type: ``|``-separated JSON types (``"number|null"``) from string,
            integer, number, boolean, null, array, object, any.
        doc: what it holds.
        fields: the keys of the object (``type`` object), or of each object
            item (``type`` array, ``items`` ``"object"``); ``None`` for an
            object whose keys are not fixed (documented in ``doc``).
        items: an array's item type (a ``|``-separated type as ``type``).
    """

    type: str
    doc: str
    fields: dict[str, Key] | None = None
    items: str | None = None

    def allows(self, value: Any) -> bool:
        return any(_TYPES[t](value) for t in self.type.split("|"))


def _obj(doc: str, fields: dict[str, Key], nullable: bool = False) -> Key:
    return Key("object|null" if nullable else "object", doc, fields)


def _rows(doc: str, fields: dict[str, Key]) -> Key:
    return Key("array", doc, fields, items="object")


def _common(command: str) -> dict[str, Key]:
    return {
        "command": Key("string", f'"{command}"'),
        "schema_version": Key("integer", f"{SCHEMA_VERSION}; raised when a key changes meaning or goes away"),
    }


_WRITTEN = Key("array", "files written (the plots of --plot / --plot-dir, the tables and plots of a campaign)",
               items="string")

_STATE = {
    "object": Key("integer", "object (0-based)"),
    "pose": Key("integer", "pose (0-based)"),
    "probability": Key("number", "its posterior probability"),
}

_RECIPE_DOC = "the recipe the file records: the parts of jaxrecog.recipes.Recipe (`jaxrecog recipes`), and recorded"


def _recipe_fields() -> dict[str, Key]:
    from ..recipes import Recipe

    types = {"name": "string", "version": "integer", "summary": "string", "likelihood": "string",
             "likelihood_options": "object", "interpolate": "integer", "interpolation": "string",
             "view_jitter": "boolean|string", "calibrate": "boolean|string", "calib_pool": "boolean", "max_shift": "integer",
             "p_threshold": "number", "min_views": "integer", "exclude_visited": "boolean",
             "adaptive_scale": "number", "planner": "string"}
    fields = {f.name: Key(types.get(f.name, "any"), f"the recipe's {f.name}") for f in dataclasses.fields(Recipe)}
    fields["recorded"] = Key("boolean", "false: a file written before recipes (the thesis recipe is assumed)")
    return fields


def _settings_fields() -> dict[str, Key]:
    from ..campaigns import Settings

    return {name: Key("any", "jaxrecog.campaigns.Settings." + name) for name in Settings.FIELDS}


def _schemas() -> dict[str, dict[str, Key]]:
    plan_row = {
        "rank": Key("integer", "1 = best"),
        "config": Key("array", "the configuration: one position per camera (0-based)", items="integer"),
        "index": Key("integer", "its flat index"),
        "score": Key("number|null", "the planner's score (higher = better; null: a failed estimate); round-off "
                                    "below 1e-6 of the largest absolute score is 0, as in the text"),
    }
    plan = {
        **_common("plan"),
        "model": Key("string", "the model file"),
        "planner": Key("string", "the planner that scored"),
        "samples": Key("integer", "--samples"),
        "min_per_stratum": Key("integer", "--min-per-stratum"),
        "seed": Key("integer", "--seed"),
        "adaptive_scale": Key("number", "--adaptive-scale (default the model's recipe's): how the --images "
                                        "were weighed (1 = off)"),
        "positions": Key("array", "positions per camera", items="integer"),
        "belief": Key("string", '"uniform" or "images" (the belief after --images at --at)'),
        "images": _obj("the --images and the belief after them; null for the uniform belief", {
            "paths": Key("array", "the image files, one per camera", items="string"),
            "at": Key("array", "the configuration they were taken at", items="integer"),
            "used": Key("boolean", "false: an image was unusable (--skip-invalid) and the belief is unchanged"),
            **{k: Key(v.type, f"the best (object, pose) after them: {v.doc}") for k, v in _STATE.items()},
        }, nullable=True),
        "configurations": Key("integer", "how many configurations were scored"),
        "best": _obj("the best configuration (rank 1)", plan_row),
        "ranking": _rows("the --top best configurations, best first", plan_row),
        "written": _WRITTEN,
    }
    step = {
        "step": Key("integer", "1-based"),
        "config": Key("array", "where the images were taken (one position per camera)", items="integer"),
        **{k: Key(v.type, f"the best (object, pose) after the step: {v.doc}") for k, v in _STATE.items()},
        "valid": Key("boolean", "false: the images could not be used (--skip-invalid) and the belief is unchanged"),
        "occluded": Key("array", "occluded fraction of each camera's image (empty: the rig does not say)",
                        items="number"),
        "stop": Key("boolean", "the trial stopped after this step"),
        "next": Key("array|null", "the configuration chosen next (null on the stopping step)", items="integer"),
        "belief": _rows("the five most probable (object, pose) states after the step, most probable first",
                        dict(_STATE)),
        "object_probabilities": Key("array", "the belief over objects (summed over poses), one per object",
                                    items="number|null"),
    }
    recognize = {
        **_common("recognize"),
        "model": Key("string", "the model file"),
        "rig": Key("string", "--rig"),
        "object": Key("integer", "the object placed (--object)"),
        "pose": Key("integer", "its pose (--pose)"),
        "planner": Key("string", "the planner"),
        "threshold": Key("number", "the stop probability P_th"),
        "max_steps": Key("integer", "--max-steps"),
        "min_views": Key("integer", "never stop on P_th before this many image sets"),
        "exclude_visited": Key("boolean", "never send a camera back to a visited position"),
        "adaptive_scale": Key("number", "the largest per-capture variance factor of the adaptive scale (1 = off)"),
        "shared_view": Key("boolean", "--shared-view"),
        "motion_cost": Key("number", "--motion-cost (0 = off)"),
        "recipe": Key("string", "the model's recipe (where the defaults of the stop rule and planner came from)"),
        "seed": Key("integer", "--seed"),
        "start": Key("array", "the first configuration", items="integer"),
        "steps": _rows("one per image set, in order", step),
        "result": _obj("the decision at the last step", {
            **_STATE,
            "steps": Key("integer", "image sets taken"),
            "correct": Key("boolean", "the decision is the placed object and pose"),
            "travel_s": Key("number|null", "seconds of rig motion (null: the rig has no geometry)"),
        }),
        "written": _WRITTEN,
    }
    camera = {
        "camera": Key("integer", "0-based"),
        "eigenspaces": Key("integer", "its positions (one eigenspace each)"),
        "eigenvalue_sum": Key("array", "[min, max] over its positions of the eigenvalues' sum", items="number|null"),
        "feature_sd": Key("array", "[min, max] of the likelihood's feature standard deviations", items="number|null"),
        "variance_factors": Key("array|null", "calibrated: [position][occlusion level] variance factors; null: "
                                              "not calibrated", items="array"),
    }
    model = {
        "cameras": Key("integer", "number of cameras"),
        "positions": Key("array", "positions per camera", items="integer"),
        "objects": Key("integer", "number of objects"),
        "poses": Key("integer", "poses per object"),
        "classes": Key("integer", "objects x poses"),
        "image_shape": Key("array", "[height, width] in pixels", items="integer"),
        "components": Key("integer", "eigenspace dimension K"),
        "levels": Key("array", "occlusion levels of the likelihood", items="number"),
        "likelihood": Key("string", "the likelihood kind (diag, full, student-t, ...)"),
        "per_camera": _rows("one per camera", camera),
        "recipe": _obj(_RECIPE_DOC, _recipe_fields()),
        "training": Key("object|null", "the training parameters the file records (train_model's: kind, K, "
                                       "n_components, samples_per_image, likelihood, augment, seed, ...; the keys "
                                       "are the file's, older files have fewer); null: none recorded"),
    }
    database = {
        "root": Key("string", "the database folder"),
        "images": Key("integer", "rows (images) of the manifest"),
        "image_shape": Key("array", "[height, width] in pixels", items="integer"),
        "cameras": Key("integer", "number of cameras"),
        "positions": Key("array", "positions per camera", items="integer"),
        "objects": Key("integer", "number of objects"),
        "poses": Key("integer", "poses per object"),
        "splits": Key("object", "rows per split: train, test, calib, and jitter when it has any"),
        "shared_files": Key("integer", "image files used by more than one row (turntable views)"),
    }
    inspect = {
        **_common("inspect"),
        "path": Key("string", "the file or folder inspected"),
        "kind": Key("string", '"model" or "database"'),
        "model": _obj("the model file's summary; null for a database", model, nullable=True),
        "database": _obj("the database's summary; null for a model file", database, nullable=True),
        "written": _WRITTEN,
    }
    row = {
        "label": Key("string", '"0".."M-1" (the object, 0-based as everywhere) or "Average"'),
        "trials": Key("integer", "trials of the row"),
        "rate": Key("number|null", "recognition rate, percent"),
        "exit_prob": Key("number|null", "mean exit probability"),
        "views": Key("number|null", "mean number of image sets"),
        "confident_errors": Key("number|null", "wrong and stopped on P_th, percent (null: not recorded)"),
        "travel_s": Key("number|null", "mean seconds of travel per trial (null: not recorded)"),
        "rate_ci": Key("array", "95 % Wilson score interval of rate, [low, high] percent (the average row's: of "
                                "all its trials pooled; nulls: no trials)", items="number|null"),
        "confident_errors_ci": Key("array", "95 % Wilson score interval of confident_errors, [low, high] percent",
                                   items="number|null"),
        "thesis": _obj("the thesis's published row for comparison (null: none)", {
            "rate": Key("number|null", "percent"),
            "exit_prob": Key("number|null", "mean exit probability"),
            "views": Key("number|null", "mean number of views"),
        }, nullable=True),
    }
    experiment = {
        **_common("experiment"),
        "case": Key("string", 'the thesis case ("i", "iii", ...) or "dataset" for --rig dataset:FOLDER'),
        "title": Key("string", "the case's title"),
        "rig": Key("string", '"synthetic" or "dataset:FOLDER"'),
        "model": Key("string|null", "--model (a database campaign), null for a thesis case"),
        "settings": _obj("the run's settings: every field of jaxrecog.campaigns.Settings", _settings_fields()),
        "planners": _rows("one per planner, in the order run", {
            "planner": Key("string", "the planner"),
            "trials_per_object": Key("integer", "trials per object"),
            "seconds": Key("number|null", "the planner's campaign time"),
            "rows": _rows("the results table: one row per object, then the average", row),
        }),
        "seconds": Key("number", "wall time of the whole command"),
        "out": Key("string", "--out, where the tables and plots went"),
        "written": _WRITTEN,
    }
    return {"plan": plan, "recognize": recognize, "inspect": inspect, "experiment": experiment}


#: command -> its document's keys (top level).
SCHEMAS: dict[str, dict[str, Key]] = _schemas()


def json_option(p) -> None:
    """``--json`` on a subcommand's parser."""
    p.add_argument("--json", action="store_true",
                   help="write one JSON document on stdout instead of the text (its keys: docs/cli.md, "
                        "'JSON output'); messages go to stderr")


def clean(value: Any) -> Any:
    """``value`` as plain JSON data: a non-finite float is ``None``, tuples and
    NumPy arrays are lists, NumPy scalars Python numbers, paths strings."""
    if isinstance(value, dict):
        return {str(k): clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [clean(v) for v in value]
    if isinstance(value, np.ndarray):
        return clean(value.tolist())
    if isinstance(value, np.generic):
        return clean(value.item())
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if value is None or isinstance(value, (bool, int, str)):
        return value
    if isinstance(value, PurePath):
        return str(value)
    raise TypeError(f"--json: no JSON form for {type(value).__name__}")


def dumps(doc: dict) -> str:
    """The document as JSON text (``clean`` first: never NaN or Infinity)."""
    return json.dumps(clean(doc), indent=2, allow_nan=False)


def run_reporting(args, report: Callable[[Any], tuple[dict, str]]) -> int:
    """Run ``report(args)`` (the command's work: its document and its text
    form) and print the text, or with ``--json`` the document as JSON: then
    stdout holds the document only (whatever the work prints goes to stderr)."""
    if not getattr(args, "json", False):
        _, text = report(args)
        if text:
            print(text)
        return 0
    out = sys.stdout
    with contextlib.redirect_stdout(sys.stderr):
        doc, _ = report(args)
    out.write(dumps(doc) + "\n")
    return 0


def check(doc: Any, fields: dict[str, Key], where: str = "") -> list[str]:
    """What in ``doc`` differs from the documented ``fields``: a key missing
    or undocumented, or a value of another type (recursively)."""
    if not isinstance(doc, dict):
        return [f"{where or 'document'}: not an object"]
    problems = [f"{where}{k}: missing" for k in fields if k not in doc]
    problems += [f"{where}{k}: not documented" for k in doc if k not in fields]
    for k, key in fields.items():
        if k not in doc:
            continue
        v, at = doc[k], f"{where}{k}"
        if not key.allows(v):
            problems.append(f"{at}: {type(v).__name__} {v!r:.60}, documented as {key.type}")
        elif isinstance(v, dict) and key.fields is not None:
            problems += check(v, key.fields, at + ".")
        elif isinstance(v, list) and key.items is not None:
            item = Key(key.items, "")
            for i, x in enumerate(v):
                if not item.allows(x):
                    problems.append(f"{at}[{i}]: {type(x).__name__}, documented as {key.items}")
                elif isinstance(x, dict) and key.fields is not None:
                    problems += check(x, key.fields, f"{at}[{i}].")
    return problems


def _type_words(key: Key) -> str:
    """``"array|null"`` of ``"number|null"`` as "array of (number or null) or null"."""
    items = key.items or ""
    items = f"({items.replace('|', ' or ')})" if "|" in items else items
    return " or ".join(f"array of {items}" if t == "array" and items else t for t in key.type.split("|"))


def _markdown_rows(fields: dict[str, Key], prefix: str = "") -> list[str]:
    lines = []
    for k, key in fields.items():
        doc = key.doc.replace("|", "\\|")
        lines.append(f"| `{prefix}{k}` | {_type_words(key)} | {doc} |")
        if key.fields is not None:
            inner = f"{prefix}{k}[]." if key.items == "object" else f"{prefix}{k}."
            lines += _markdown_rows(key.fields, inner)
    return lines


def schema_markdown() -> list[str]:
    """The "JSON output" section of docs/cli.md: one table of keys per command."""
    parts = [
        "## JSON output",
        "",
        "`plan`, `recognize`, `inspect` and `experiment` take `--json`: stdout then holds exactly one JSON",
        "document (progress and messages go to stderr; an error is still the one `jaxrecog: error:` line on",
        "stderr and a non-zero exit, with nothing on stdout).  Every key below is always present (`null`",
        "where it does not apply); `a.b` is key `b` of object `a`, `a[].b` key `b` of each object of array",
        "`a`.  A non-finite number (NaN, infinity: not JSON) is `null`.  Keys are added, never renamed or",
        f"removed, while `schema_version` stays {SCHEMA_VERSION}.  Generated from `jaxrecog/cli/_json.py`",
        "(`SCHEMAS`); the tests check each command's document against it.",
        "",
    ]
    for name, fields in SCHEMAS.items():
        parts += [f"### jaxrecog {name} --json", "", "| key | type | holds |", "|---|---|---|",
                  *_markdown_rows(fields), ""]
    return parts
