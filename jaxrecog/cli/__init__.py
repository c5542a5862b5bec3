"""jaxrecog: active multi-camera object recognition (render, train, plan, recognize, experiment).

Exit codes: 0 success, 2 usage error, 1 runtime failure (one line
"jaxrecog: error: ..."; run with --debug for the traceback), 141 when the
reader of the output went away (a pipe into head), as for any Unix tool.
Settings may come from a TOML file (--config FILE): one table per subcommand
with the long option names (or, for experiment, the Settings field names) as
keys; command-line options override the file.
Indices (objects, poses, positions) are 0-based everywhere.

Files: an output file (a model, a plot, a report, --problems-out) is written
only as a regular file into a folder that exists: /dev/null, /dev/full, a
FIFO or a folder at its path is refused, and no missing folder is made for
it.  An output folder (render --out, experiment --out, --plot-dir) is made
with its parents.  One writer at a time: a second train of the same --out,
or render or experiment into the same folder, is refused at once (no wait),
naming the first's PID.  Settings and experiment files are regular UTF-8
files of at most 1 MiB; their values are checked as the options' are.
Output that stdout cannot take (a full disk) is an error (exit 1).
"""

# Subcommands are found, not listed: every public module of this package is
# one, exposing NAME, ORDER (its place in --help), HELP, DESCRIPTION,
# add_arguments(parser) and run(args) -> exit code.  A new subcommand is one
# new module here and nothing else; what several share lives in the private
# modules (_globals: the main parser's options; _options: argparse types and
# option groups; _common: errors, printing, rigs; _images, _reports,
# _bench_runner).  The main parser reads NAME, ORDER and HELP from the
# modules' source (literals) and imports a module, and with it JAX (~1.5 s),
# only when its command runs or its own help or options are asked for:
# ``jaxrecog --help`` and a mistyped command answer without JAX.

from __future__ import annotations

import argparse
import ast
import contextlib
import importlib
import os
import pkgutil
import select
import sys
import types
import warnings
from pathlib import Path
from collections.abc import MutableMapping
from typing import Any, Callable, NamedTuple, Sequence

from .. import __version__
from .._files import check_output_file
from .._config import OPTION_FIELDS, ConfigFileError, load_settings, section
from ..problems import one_line, problem_message, write_problem_list
from .._progress import set_quiet
from ._globals import Formatter, global_options

__all__ = ["main", "build_parser", "subparsers", "CLIError", "UsageError", "COMMANDS", "SUBCOMMANDS"]

_INTERFACE = ("NAME", "ORDER", "HELP", "DESCRIPTION", "add_arguments", "run")
_LISTED = ("NAME", "ORDER", "HELP")   # what the main --help shows: literals in each module's source


class _Command(NamedTuple):
    """A subcommand as the main parser lists it, before its module is imported."""
    name: str
    order: int
    help: str
    module: str


def _listed(module: str, path: Path) -> _Command | None:
    """NAME, ORDER, HELP of a subcommand module, read from its
    source (``None`` where one is not a literal: then it is imported)."""
    try:
        tree = ast.parse(path.read_text(encoding="utf-8"))
    except (OSError, SyntaxError, ValueError):
        return None
    found: dict[str, Any] = {}
    for node in tree.body:
        if isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name) \
                and node.targets[0].id in _LISTED:
            try:
                found[node.targets[0].id] = ast.literal_eval(node.value)
            except ValueError:
                return None
    if set(found) != set(_LISTED):
        return None
    return _Command(found["NAME"], found["ORDER"], found["HELP"], module)


def _load(module: str) -> types.ModuleType:
    """Import a subcommand module and check that it has the whole interface."""
    mod = importlib.import_module(module)
    missing = [a for a in _INTERFACE if not hasattr(mod, a)]
    if missing:
        raise ImportError(f"subcommand module {mod.__name__} lacks {', '.join(missing)}")
    return mod


def _discover() -> tuple[_Command, ...]:
    """The subcommands of this package (its public modules), in ``ORDER``."""
    found = []
    for info in pkgutil.iter_modules(__path__):
        if info.name.startswith("_"):
            continue
        module = f"{__name__}.{info.name}"
        cmd = _listed(module, Path(__path__[0]) / f"{info.name}.py")
        if cmd is None:
            mod = _load(module)
            cmd = _Command(mod.NAME, mod.ORDER, mod.HELP, module)
        found.append(cmd)
    return tuple(sorted(found, key=lambda c: (c.order, c.name)))


_COMMANDS = _discover()


class _Commands(MutableMapping):
    """Subcommand name -> its ``run(args)``, in ``--help`` order; a module is
    imported when its entry is first read (an entry set here, e.g. by a test,
    replaces the module's ``run`` until deleted)."""

    def __init__(self) -> None:
        self._runs: dict[str, Callable[[argparse.Namespace], int]] = {}

    def __getitem__(self, name: str) -> Callable[[argparse.Namespace], int]:
        if name not in self._runs:
            cmd = next((c for c in _COMMANDS if c.name == name), None)
            if cmd is None:
                raise KeyError(name)
            self._runs[name] = _load(cmd.module).run
        return self._runs[name]

    def __setitem__(self, name: str, run: Callable[[argparse.Namespace], int]) -> None:
        self._runs[name] = run

    def __delitem__(self, name: str) -> None:
        del self._runs[name]

    def __iter__(self):
        return iter([c.name for c in _COMMANDS])

    def __len__(self) -> int:
        return len(_COMMANDS)


#: Subcommand name -> its ``run(args)``.
COMMANDS = _Commands()


class _Parser(argparse.ArgumentParser):
    """argparse's parser, except that a failed write of help or usage (stdout
    on a full disk, ``> /dev/full``) is raised, not silently dropped: the
    command then exits 1 with one line instead of 0 with nothing written.
    The subcommands' parsers (:class:`_SubcommandParser`) derive from it."""

    def _print_message(self, message, file=None):
        if message:
            (file or sys.stderr).write(message)


def __getattr__(name: str) -> Any:
    """``SUBCOMMANDS`` (the modules, in ``--help`` order), ``CLIError``,
    ``UsageError``: imported when first asked for."""
    if name == "SUBCOMMANDS":
        return tuple(_load(c.module) for c in _COMMANDS)
    if name in ("CLIError", "UsageError"):
        from . import _common
        return getattr(_common, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


class _SubcommandParser(_Parser):
    """A subcommand's parser that adds the subcommand's description and own
    options (importing its module) the first time it parses or prints its help
    or usage."""

    def __init__(self, *args: Any, command: _Command | None = None, **kwargs: Any):
        super().__init__(*args, **kwargs)
        self._command = command

    def load(self) -> "_SubcommandParser":
        if self._command is not None:
            command, self._command = self._command, None
            mod = _load(command.module)
            self.description = mod.DESCRIPTION
            mod.add_arguments(self)
        return self

    def parse_known_args(self, args=None, namespace=None):
        self.load()
        return super().parse_known_args(args, namespace)

    def format_usage(self) -> str:
        self.load()
        return super().format_usage()

    def format_help(self) -> str:
        self.load()
        return super().format_help()


def build_parser(lazy: bool = False) -> argparse.ArgumentParser:
    """The whole parser (``lazy``: each subcommand's options are added when
    that subcommand is parsed or its help shown, as :func:`main` does)."""
    parser = _Parser(prog="jaxrecog", description=__doc__, formatter_class=Formatter)
    global_options(parser, suppress=False)
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True, parser_class=_SubcommandParser)
    for cmd in _COMMANDS:
        p = sub.add_parser(cmd.name, help=cmd.help, formatter_class=Formatter, command=cmd)
        global_options(p, suppress=True)
        if not lazy:
            p.load()
    return parser


def subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """Subcommand name -> its parser."""
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            return dict(a.choices)
    return {}


def _apply_config(parser: argparse.ArgumentParser, path: str) -> dict[str, Any]:
    """Set option defaults from the TOML file (command line still wins)."""
    data = load_settings(path)
    known_global = {"quiet", "debug", "compile_cache"}
    glob = section(data, "global", known_global, path)
    for k, v in glob.items():  # switches, as --quiet and --debug are (compile_cache, which may also name
        if k != "compile_cache" and not isinstance(v, bool):  # a folder, is checked where it is applied)
            raise ConfigFileError(f"settings file {path}: [global] {k} = {one_line(repr(v), 60)}: expected true "
                                  f"or false (as --{k})")
    subs = subparsers(parser)
    unknown = sorted(set(data) - set(subs) - {"global"})
    if unknown:
        raise ConfigFileError(problem_message(f"settings file {path}: unknown table(s) "
                                              f"(known: global, {', '.join(subs)})", unknown))
    for name, sp in subs.items():
        if name not in data:
            continue
        if isinstance(sp, _SubcommandParser):
            sp.load()
        dests = {a.dest for a in sp._actions if a.option_strings and a.dest not in ("help", "config")}
        # one dialect: an option's Settings field name too; a subcommand's CONFIG_FIELDS (Settings
        # fields without an option) arrive together as args.config_fields
        names = {d: d for d in dests}
        names.update({f: o for o, f in OPTION_FIELDS.items() if o in dests and f not in dests})
        module = next(c.module for c in _COMMANDS if c.name == name)
        extra = [f for f in getattr(_load(module), "CONFIG_FIELDS", ()) if f not in names]
        names.update({f: f for f in extra})
        values = section(data, name, names, path)
        fields = {k: values.pop(k) for k in extra if k in values}
        if fields:
            values["config_fields"] = fields
        if values:
            sp.set_defaults(**_checked_values(sp, name, values, path))
    return glob


def _checked_values(sp: argparse.ArgumentParser, table: str, values: dict[str, Any], path: str) -> dict[str, Any]:
    """``values`` of the table ``[table]`` converted and checked as the
    command line's options are (each option's ``type`` and ``choices``; a
    switch takes true or false): ``max_steps = 0`` is refused as
    ``--max-steps 0`` is.  The first bad value raises :class:`ConfigFileError`,
    one line naming the file, the table and the key."""
    actions = {a.dest: a for a in sp._actions if a.option_strings}
    out = dict(values)
    for dest, value in values.items():
        a = actions.get(dest)
        if a is None:
            continue
        try:
            out[dest] = _checked_value(a, value)
        except (argparse.ArgumentTypeError, ValueError, TypeError) as e:
            raise ConfigFileError(f"settings file {path}: [{table}] {dest} = {one_line(repr(value), 60)}: "
                                  f"{one_line(e) or 'invalid value'} (as {a.option_strings[-1]})") from None
    return out


def _checked_value(a: argparse.Action, value: Any) -> Any:
    """One settings-file value through the option's own checks."""
    if a.nargs == 0:  # store_true / store_false / a BooleanOptionalAction switch
        if not isinstance(value, bool):
            raise ValueError("expected true or false")
        return value
    many = a.nargs in ("+", "*") or isinstance(a.nargs, int)
    if many and not isinstance(value, list):
        value = [value]
    if not many and isinstance(value, list):
        value = ",".join(str(v) for v in value)  # e.g. start = [3, 2], as --start 3,2

    def one(v: Any) -> Any:
        if isinstance(v, (dict, list)):
            raise ValueError(f"expected one value, got a {'table' if isinstance(v, dict) else 'list'}")
        if a.type is not None:
            if isinstance(v, bool):
                raise ValueError(f"expected a value for {a.option_strings[-1]}, got {str(v).lower()}")
            v = a.type(v if isinstance(v, str) else str(v))
        if a.choices is not None and v not in a.choices:
            raise ValueError(f"invalid choice {v!r} (choose from {', '.join(map(str, a.choices))})")
        return v

    return [one(v) for v in value] if many else one(value)


#: The exit code when stdout's reader went away: 128 + SIGPIPE, what a shell
#: reports for a Unix tool that the signal ended.
BROKEN_PIPE = 141


def main(argv: Sequence[str] | None = None) -> int:
    with warnings.catch_warnings(), _watched_stdout():   # both restored afterwards
        warnings.showwarning = _show_warning
        try:
            code = _main(argv)
            sys.stdout.flush()  # a reader that went away shows here, not as a complaint at exit
            return code
        except BrokenPipeError:
            if not _stdout_gone():
                raise
            return _quiet_after_broken_pipe()
        except OSError as e:  # stdout cannot take the output (a full disk, > /dev/full, an I/O error)
            print(f"jaxrecog: error: {_stdout_error(e)}", file=sys.stderr)
            _quiet_after_broken_pipe()  # the interpreter's last flush would fail again, with a traceback
            return 1


def _stdout_error(e: OSError) -> str:
    """The one line for output that could not be written to stdout."""
    return f"cannot write the output to standard output ({e.strerror or e})"


class _WatchedStdout:
    """stdout, remembering the last error a write or flush of it raised (so
    that a full disk under ``> FILE`` is told apart from one under a file the
    command writes itself)."""

    def __init__(self, stream):
        self._stream, self.failed = stream, None

    def write(self, text):
        try:
            return self._stream.write(text)
        except OSError as e:
            self.failed = e
            raise

    def flush(self):
        try:
            return self._stream.flush()
        except OSError as e:
            self.failed = e
            raise

    def __getattr__(self, name):
        return getattr(self._stream, name)


def _stdout_failed(e: BaseException) -> bool:
    """Whether ``e`` is a failed write to stdout."""
    return isinstance(sys.stdout, _WatchedStdout) and sys.stdout.failed is e


@contextlib.contextmanager
def _watched_stdout():
    """``sys.stdout`` as a :class:`_WatchedStdout` for the ``with`` block."""
    real = sys.stdout
    sys.stdout = _WatchedStdout(real)
    try:
        yield
    finally:
        sys.stdout = real


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """A warning during a command is one line on stderr, ``jaxrecog: warning:
    MESSAGE`` (not Python's two lines with the source file and the category),
    e.g. a colour image converted to gray; the warning filters decide, as
    always, whether it shows at all."""
    print(f"jaxrecog: warning: {one_line(str(message), 300)}", file=sys.stderr if file is None else file)


def _stdout_gone() -> bool:
    """Whether stdout's reader went away (``jaxrecog plan ... | head``): a
    pipe without a reader (poll says so), or a stream that cannot be flushed
    for a broken pipe."""
    try:
        poller = select.poll()
        poller.register(sys.stdout.fileno(), select.POLLOUT)
        if any(ev & select.POLLERR for _, ev in poller.poll(0)):
            return True
    except (AttributeError, OSError, ValueError):  # no poll (Windows), no file descriptor
        pass
    try:
        sys.stdout.flush()
    except BrokenPipeError:
        return True
    except (OSError, ValueError):
        return False
    return False


def _quiet_after_broken_pipe() -> int:
    """Stop quietly: stdout points at the null device from here on, so that
    the interpreter's last flush at exit finds nothing to complain about."""
    try:
        null = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(null, sys.stdout.fileno())
        finally:
            os.close(null)
    except (OSError, ValueError):  # a stdout without a file descriptor (io.UnsupportedOperation is both)
        pass
    return BROKEN_PIPE


def _main(argv: Sequence[str] | None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(lazy=True)
    debug = "--debug" in argv
    try:
        pre = argparse.ArgumentParser(add_help=False)
        pre.add_argument("--config")
        pre.add_argument("--debug", action="store_true")
        known, _ = pre.parse_known_args(argv)
        glob: dict[str, Any] = {}
        if known.config:
            try:
                glob = _apply_config(parser, known.config)
            except ConfigFileError as e:
                parser.error(str(e))
        args = parser.parse_args(argv)
    except SystemExit as e:  # argparse: --help (0) or usage error (2)
        return int(e.code) if isinstance(e.code, int) else 2
    args.quiet = bool(getattr(args, "quiet", False) or glob.get("quiet", False))
    args.debug = bool(getattr(args, "debug", False) or glob.get("debug", False) or debug)
    set_quiet(args.quiet)
    from ._common import CLIError, UsageError   # the command's module imports it in any case
    try:
        _compile_cache(args, glob)
        _check_problems_out(getattr(args, "problems_out", None))
        return int(COMMANDS[args.command](args) or 0)
    except UsageError as e:
        if args.debug:
            raise
        subparsers(parser)[args.command].print_usage(sys.stderr)
        print(f"jaxrecog {args.command}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("jaxrecog: interrupted", file=sys.stderr)
        return 130
    except Exception as e:  # noqa: BLE001 - the one place that turns failures into exit code 1
        if isinstance(e, BrokenPipeError) and _stdout_gone():
            raise  # main: quiet, not an error
        if _stdout_failed(e) and not args.debug:
            print(f"jaxrecog: error: {_stdout_error(e)}", file=sys.stderr)
            _quiet_after_broken_pipe()
            return 1
        if args.debug:
            for problem in getattr(e, "problems", None) or ():  # the full list, then the traceback
                print(problem, file=sys.stderr)
            raise
        # one line per line of the message: a list of problems stays readable
        msg = "\n  ".join(" ".join(line.split()) for line in str(e).splitlines() if line.strip()) \
            or type(e).__name__
        if not isinstance(e, (CLIError, OSError, ValueError)) and type(e).__name__ not in msg:
            msg = f"{type(e).__name__}: {msg}"
        print(f"jaxrecog: error: {msg}", file=sys.stderr)
        _write_problems(e, getattr(args, "problems_out", None))
        return 1


def _compile_cache(args: argparse.Namespace, glob: dict[str, Any]) -> None:
    """The persistent compilation cache for this command (:mod:`jaxrecog.compile_cache`):
    off with ``--no-compile-cache``; else the settings file's ``[global]``
    ``compile_cache`` (``false``, ``true`` or a folder); else the environment's
    and the default folder."""
    from .. import compile_cache
    from ._common import UsageError

    if not getattr(args, "compile_cache", True):
        compile_cache.configure(False)
        return
    given = glob.get("compile_cache")
    if given is None or given is True:
        compile_cache.configure()
    elif given is False:
        compile_cache.configure(False)
    elif isinstance(given, str):  # as JAXRECOG_COMPILE_CACHE: a folder (its version folder inside), or "0"
        compile_cache.configure(compile_cache.default_folder({compile_cache.ENV: given}) or False)
    else:
        raise UsageError(f"settings file [global] compile_cache: expected true, false or a folder, got {given!r}")


def _check_problems_out(path: str | None) -> None:
    """``--problems-out FILE``, before the command runs: a regular file (or
    none yet) in a folder that exists, and not in an image database folder
    (one holding ``manifest.csv``, at any depth above FILE): a command never
    writes into the database it reads.  A :class:`UsageError` otherwise."""
    if not path:
        return
    from ._common import UsageError

    try:
        p = check_output_file(path, "--problems-out file")
    except OSError as e:
        raise UsageError(str(e)) from None
    folder = Path(os.path.realpath(p.parent if str(p.parent) else "."))
    for f in (folder, *folder.parents):
        if (f / "manifest.csv").is_file():
            raise UsageError(f"--problems-out {path} is in the image database folder {f}: a command never "
                             f"writes into a database folder; choose a file outside it")


def _write_problems(e: BaseException, path: str | None) -> None:
    """``--problems-out FILE``: the failure's whole problem list into a new
    file (exclusive create, no symbolic link followed), one line on stderr
    saying where it went or why not."""
    problems = getattr(e, "problems", None)
    if not path or not problems:
        return
    try:
        write_problem_list(path, str(e).splitlines()[0], problems)
    except FileExistsError:
        print(f"jaxrecog: --problems-out {path} exists; not overwritten (the list was not written)", file=sys.stderr)
    except OSError as err:
        print(f"jaxrecog: --problems-out {path}: {err.strerror or err} (the list was not written)", file=sys.stderr)
    else:
        print(f"jaxrecog: all {len(problems)} problems written to {path}", file=sys.stderr)
