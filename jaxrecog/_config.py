"""CLI settings from a TOML file; command-line options override them.

The file holds one table per subcommand, with the long option names (dashes
or underscores) as keys, plus an optional ``[global]`` table::

    [global]
    quiet = true

    [train]
    kind = "DB2"
    components = 20

    [experiment]
    trials = 24
    planners = ["mi", "crlb", "random"]

One configuration dialect: an option whose name differs from the
:class:`~jaxrecog.campaigns.Settings` field it sets (:data:`OPTION_FIELDS`,
e.g. ``trials`` <-> ``trials_per_object``) may be given under either name, here
and in an experiment file; the same setting under both names is an error naming
both.  A key the table does not know is an error naming the file, the table and
the key, with the nearest accepted key ("did you mean ...?").
"""

from __future__ import annotations

import difflib
import os
import tomllib
from pathlib import Path
from typing import Any, Sequence

from ._files import read_text
from .problems import one_line, problem_message

__all__ = ["ConfigFileError", "FIELD_OPTIONS", "LIKELIHOOD_OPTION_KEYS", "OPTION_FIELDS", "load_settings",
           "read_toml", "resolve_keys", "section"]

#: The one alias table: command-line option name (``dest``) -> the
#: :class:`~jaxrecog.campaigns.Settings` field it sets, where the two names
#: differ.  Every other option of ``jaxrecog experiment`` that sets a field has
#: the field's name (``samples``, ``seed``, ``stride``, ``min_views``, ...).
OPTION_FIELDS: dict[str, str] = {
    "trials": "trials_per_object",
    "threshold": "p_threshold",
    "exclude_visited": "exclude_visited_positions",
    "rotation": "max_rotation",
    "scale": "max_scale",
    "blur": "blur_sigma",
    "gain": "gain_amplitude",
}
#: Settings field name -> option name (the inverse of :data:`OPTION_FIELDS`).
FIELD_OPTIONS: dict[str, str] = {f: o for o, f in OPTION_FIELDS.items()}
#: Options that set one entry of ``Settings.likelihood_options`` (``rank = 4``
#: is ``likelihood_options = {rank = 4}``).
LIKELIHOOD_OPTION_KEYS: tuple[str, ...] = ("rank", "nu", "occluded_jitter")


class ConfigFileError(ValueError):
    """The settings file is missing, is not TOML, or names an unknown option."""


def read_toml(path: str | os.PathLike, what: str = "settings file") -> dict[str, Any]:
    """Parse a TOML file; a missing, unreadable, oversized (more than
    :data:`~jaxrecog._files.MAX_TEXT_BYTES`), non-regular (``/dev/zero``, a
    FIFO), non-UTF-8 or invalid file is a :class:`ConfigFileError` that names
    ``what`` and the path (:func:`jaxrecog._files.read_text`: the size is
    checked before reading and the read is capped)."""
    p = Path(path)
    try:
        text = read_text(p, what)
    except FileNotFoundError:
        raise ConfigFileError(f"{what} {p} not found") from None
    except OSError as e:  # TextFileError: one line naming the file already
        raise ConfigFileError(str(e)) from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ConfigFileError(f"{what} {p} is not valid TOML: {e}") from None
    except RecursionError:  # absurdly nested arrays or tables
        raise ConfigFileError(f"{what} {p} is not valid TOML: nested too deeply") from None


def load_settings(path: str | os.PathLike) -> dict[str, Any]:
    """Read the whole settings file (tables by subcommand name)."""
    p = Path(path)
    data = read_toml(p)
    for k, v in data.items():
        if not isinstance(v, dict):
            raise ConfigFileError(f"settings file {p}: top-level key {k!r} must be a table "
                                  f"like [train] or [global]")
    return data


def resolve_keys(tables: Sequence[tuple[str, dict[str, Any]]], names: dict[str, str] | set[str],
                 where: str) -> dict[str, Any]:
    """The keys of ``tables`` (pairs of a table's label, e.g. ``"[experiment]"``,
    and its contents) as their canonical names: ``names`` maps every accepted
    key (underscores; a key's dashes count as underscores) to its canonical
    name (a set: each its own).  An unknown key, or one setting given twice
    (under two names, or in two of the tables), raises :class:`ConfigFileError`
    naming ``where``, the table and the key(s) (one line each; the nearest
    accepted key as "did you mean ...?")."""
    names = dict.fromkeys(names, None) if isinstance(names, (set, frozenset)) else names
    names = {k: (k if v is None else v) for k, v in names.items()}
    out: dict[str, Any] = {}
    given: dict[str, tuple[str, str]] = {}
    problems: list[str] = []
    for table, data in tables:
        for key, value in data.items():
            k = str(key).replace("-", "_")
            if k not in names:
                close = difflib.get_close_matches(k, list(names), n=1)
                hint = f" (did you mean {close[0]!r}?)" if close else ""
                problems.append(f"{table}: unknown key {one_line(repr(key), 80)}{hint}")
                continue
            canon = names[k]
            if canon in given:
                t0, k0 = given[canon]
                both = f"{table}: {k0!r} and {key!r}" if t0 == table else f"{k0!r} ({t0}) and {key!r} ({table})"
                problems.append(f"{both} are the same setting ({canon}); give one of them")
                continue
            given[canon] = (table, str(key))
            out[canon] = value
    if problems:
        raise ConfigFileError(problem_message(where, problems))
    return out


def section(data: dict[str, Any], name: str, known: dict[str, str] | set[str], where: str) -> dict[str, Any]:
    """The table ``name`` with keys normalised to argparse ``dest`` names
    (dashes to underscores; ``known`` maps each accepted key to its ``dest``,
    or is the set of ``dest`` names); unknown or doubled keys raise
    :class:`ConfigFileError` (:func:`resolve_keys`)."""
    return resolve_keys([(f"[{name}]", data.get(name, {}))], known, f"settings file {where}")
