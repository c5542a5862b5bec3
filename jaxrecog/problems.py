"""One rule for every error that lists problems: readable at any length.

A message names the count, shows the first :data:`SHOWN` problems one per
line and says how to see the full list (``--debug``, which prints the
exception's ``problems``, or ``--problems-out FILE``, which writes them to a
new file of the user's choosing: a command never writes a problem list into
the folder it reads).  A single problem stays one line.  Every
problem line is flattened to one line and capped at :data:`LINE_CAP`
characters, so a stray newline or a 10 kB field in the input cannot blow up
the message.

This is a leaf module of the core (standard library only): ``jaxrecog``,
its CLI and ``jaxrecog.hardware`` all use it (``docs/architecture.md``, Layers).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

__all__ = ["SHOWN", "LINE_CAP", "DEBUG_HINT", "one_line", "problem_message", "write_problem_list"]

SHOWN = 10
LINE_CAP = 240
DEBUG_HINT = "run with --debug to see all, or --problems-out FILE to write them to a file"


def one_line(text: object, cap: int = LINE_CAP) -> str:
    """``text`` with every run of whitespace (newlines included) and every
    control character as one space, cut to ``cap`` characters (``...`` marks a cut)."""
    s = "".join(ch if ch.isprintable() else " " for ch in str(text))
    s = " ".join(s.split())
    return s if len(s) <= cap else s[: cap - 3] + "..."


def problem_message(head: str, problems: Sequence[str], *, full_list: str | os.PathLike | None = None,
                    shown: int = SHOWN, counted: bool = False) -> str:
    """The message for ``problems`` found in ``head`` (e.g. ``"invalid image database db/"``).

    One problem: ``"{head}: {problem}"``.  More: ``"{head}: {n} problems"``
    (``counted=True``: ``head`` states the count itself, e.g. ``"3 of 18 views
    have no image"``, and stands alone), then the first ``shown`` problems one
    per line (indented), then, when some were left out, where the rest are:
    ``full_list`` (a file holding the whole list) or :data:`DEBUG_HINT`.
    """
    head = one_line(head, cap=4 * LINE_CAP)
    probs = [one_line(p) for p in problems]
    if not probs:
        return head
    if len(probs) == 1:
        return f"{head}: {probs[0]}"
    lines = [head if counted else f"{head}: {len(probs)} problems", *probs[:shown]]
    if len(probs) > shown:
        where = f"full list in {full_list}" if full_list is not None else DEBUG_HINT
        lines.append(f"... {len(probs) - shown} more ({where})")
    return "\n  ".join(lines)


def write_problem_list(path: str | os.PathLike, head: str, problems: Sequence[str]) -> Path:
    """Write ``head`` and every problem, one per line, to the *new* file
    ``path`` (created exclusively, never through a symbolic link: an existing
    file or link is left alone); returns the path.

    Raises:
        FileExistsError: ``path`` exists (or is a link).
        OSError: it cannot be created (no such folder, no permission).
    """
    p = Path(path)
    text = "\n".join([one_line(head, cap=4 * LINE_CAP), *(one_line(x, cap=4 * LINE_CAP) for x in problems)]) + "\n"
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
    fd = os.open(p, flags, 0o666)
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(text)
    return p
