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

Keys the subcommand does not know are an error naming the file and the key.
"""

from __future__ import annotations

import os
import tomllib
from pathlib import Path
from typing import Any

from .problems import problem_message

__all__ = ["ConfigFileError", "load_settings", "read_toml", "section"]


class ConfigFileError(ValueError):
    """The settings file is missing, is not TOML, or names an unknown option."""


def read_toml(path: str | os.PathLike, what: str = "settings file") -> dict[str, Any]:
    """Parse a TOML file; a missing, unreadable or invalid file is a
    :class:`ConfigFileError` that names ``what`` and the path."""
    p = Path(path)
    try:
        with open(p, "rb") as f:
            return tomllib.load(f)
    except FileNotFoundError:
        raise ConfigFileError(f"{what} {p} not found") from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigFileError(f"{what} {p} is not valid TOML: {e}") from None
    except OSError as e:
        raise ConfigFileError(f"{what} {p} cannot be read: {e.strerror}") from None


def load_settings(path: str | os.PathLike) -> dict[str, Any]:
    """Read the whole settings file (tables by subcommand name)."""
    p = Path(path)
    data = read_toml(p)
    for k, v in data.items():
        if not isinstance(v, dict):
            raise ConfigFileError(f"settings file {p}: top-level key {k!r} must be a table "
                                  f"like [train] or [global]")
    return data


def section(data: dict[str, Any], name: str, known: set[str], where: str) -> dict[str, Any]:
    """The table ``name`` with keys normalised to argparse ``dest`` names
    (dashes to underscores); unknown keys raise :class:`ConfigFileError`,
    which lists them all (:func:`~jaxrecog.problems.problem_message`)."""
    out = {k.replace("-", "_"): v for k, v in data.get(name, {}).items()}
    unknown = [repr(k) for k in data.get(name, {}) if k.replace("-", "_") not in known]
    if unknown:
        raise ConfigFileError(problem_message(
            f"settings file {where}: [{name}] has unknown option(s) "
            f"(known: {', '.join(sorted(x.replace('_', '-') for x in known))})", unknown))
    return out
