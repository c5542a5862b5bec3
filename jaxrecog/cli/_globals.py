"""What the main parser needs before any subcommand is loaded: the help
formatter and the global options.  Nothing here imports JAX, so ``jaxrecog
--help`` and a mistyped command answer at once."""

from __future__ import annotations

import argparse

__all__ = ["Formatter", "global_options"]


class Formatter(argparse.RawDescriptionHelpFormatter):
    """Raw descriptions; ``(default: X)`` after each help where a default means something."""

    def _get_help_string(self, action):
        text = action.help or ""
        d = action.default
        if "%(default)" in text or d is None or d is False or d is argparse.SUPPRESS or not action.option_strings:
            return text
        shown = " ".join(map(str, d)) if isinstance(d, (list, tuple)) else d
        return f"{text} (default: {shown})"


def global_options(parser: argparse.ArgumentParser, suppress: bool) -> None:
    """``--quiet``, ``--debug``, ``--config``, ``--problems-out``, ``--no-compile-cache`` on the main
    parser and (``suppress``: without overriding the main parser's values) on every subcommand."""
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
    parser.add_argument("--no-compile-cache", dest="compile_cache", action="store_false",
                        default=d if suppress else True,
                        help="compile every program afresh instead of loading it from the persistent compilation "
                             "cache (default folder ~/.cache/jaxrecog/jax; JAXRECOG_COMPILE_CACHE=0 or =FOLDER "
                             "turns it off or moves it; README, 'Compilation cache')")
