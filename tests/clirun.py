"""Run the ``jaxrecog`` command and the repo's scripts *in this process*, as a
user's shell would see them: exit code, stdout and stderr.

In-process, each run reuses the session's imports and compilations: a
subprocess starts Python, imports jax and compiles every program again, which
cost ~3 s of CPU per call (test_cli alone made 43 of them: 207 s of CPU
before, 67 s after).  The real entry point still runs in a fresh process
once (``test_cli.py::test_the_installed_command_runs``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib.util
import io
import os
import sys
import traceback
from pathlib import Path
from typing import Callable, Sequence

ROOT = Path(__file__).resolve().parent.parent


@dataclasses.dataclass
class Ran:
    """What a run left (``subprocess.CompletedProcess``'s names)."""

    returncode: int
    stdout: str
    stderr: str


def run_main(main: Callable[[Sequence[str]], int], args: Sequence[object], *, cwd=None) -> Ran:
    """``main([str(a) for a in args])`` with stdout and stderr captured.

    ``SystemExit`` becomes its exit code (argparse's 2); an exception that
    escapes ``main`` (``--debug`` re-raises) prints its traceback to stderr and
    gives exit code 1, as the interpreter would.  ``COLUMNS`` is 100 during
    the run (argparse wraps help to it), and the working folder is ``cwd``."""
    out, err = io.StringIO(), io.StringIO()
    here = os.getcwd()
    old_columns = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "100"
    try:
        if cwd is not None:
            os.chdir(cwd)
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = main([str(a) for a in args])
            except SystemExit as e:
                code = e.code if isinstance(e.code, int) else 1
            except Exception:  # noqa: BLE001 - what the interpreter does with it
                traceback.print_exc(file=err)
                code = 1
    finally:
        os.chdir(here)
        if old_columns is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = old_columns
    return Ran(int(code or 0), out.getvalue(), err.getvalue())


def run_cli(*args, cwd=None) -> Ran:
    """``jaxrecog ARGS`` (:func:`jaxrecog.cli.main`) in this process."""
    from jaxrecog import cli

    return run_main(cli.main, args, cwd=cwd)


_SCRIPTS: dict[str, object] = {}


def script(name: str, folder: str = "scripts"):
    """The module of ``<folder>/<name>.py`` (the repo's ``scripts/`` or
    ``benchmarks/``), loaded once per session (its ``main(argv)`` is what
    ``python scripts/<name>.py`` runs)."""
    key = f"{folder}/{name}"
    if key not in _SCRIPTS:
        path = ROOT / folder / f"{name}.py"
        spec = importlib.util.spec_from_file_location(f"_{folder}_{name}", path)
        mod = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = mod
        spec.loader.exec_module(mod)
        _SCRIPTS[key] = mod
    return _SCRIPTS[key]


def run_script(name: str, *args, cwd=None) -> Ran:
    """``python scripts/<name>.py ARGS`` in this process."""
    return run_main(script(name).main, args, cwd=cwd)


def one_error_line(proc, *needles: str) -> str:
    """The one ``jaxrecog: error:`` line on a run's stderr (a :class:`Ran` or a
    ``subprocess.CompletedProcess``; no traceback), holding every needle."""
    lines = [l for l in proc.stderr.splitlines() if l.startswith("jaxrecog: error:")]
    assert len(lines) == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    for n in needles:
        assert n in lines[0], lines[0]
    return lines[0]
