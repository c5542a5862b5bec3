"""Write the printed output of README.md's tutorial into its ```text blocks:
run the tutorial's commands in order in a fresh folder and put each shown
output in place (docs are code: the README shows what the commands print,
as docs/cli.md shows what ``--help`` prints).

    python scripts/gen_readme_outputs.py            # run the tutorial, rewrite README.md
    python scripts/gen_readme_outputs.py --check    # exit 1 if README.md shows something else

The rules (tests/test_readme_tutorial.py runs the same commands, in its own
process, and compares):

- every ```sh block of the section "Tutorial" runs, in order, in one new
  folder that links ``examples/`` as the repository root has it; a command
  that fails stops the run with its stderr.  Campaigns (``jaxrecog
  experiment``: minutes to hours) do not run: tests/test_docs_snippets.py
  parses them (and resolves them with ``--print-config``) in that folder;
- a ```text block right after a ```sh block (nothing but blank lines
  between) shows the standard output of the block's last command, whole.
  Progress bars and warnings go to stderr and are not shown.  The outputs
  are deterministic (every random draw is seeded; the commands print no
  times on stdout except ``render`` and ``train``, which are never the last
  command of a shown block -- ``--check`` finds it if one is).

The module also holds the Markdown and shell readers the docs tests use:
:func:`markdown_blocks` finds every code block of a page and
:func:`shell_commands` splits a sh block into argument lists.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import re
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Callable, Sequence

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
TUTORIAL = "## Tutorial"
#: jaxrecog subcommands the tutorial does not run (they are parsed and resolved instead)
NOT_RUN = ("experiment",)

_FENCE = re.compile(r"^( *)(`{3,}|~{3,})\s*([^`\s]*)[^`]*$")
_LIST_ITEM = re.compile(r"^( *)([-*+]|\d{1,9}[.)])( +|$)")


@dataclasses.dataclass(frozen=True)
class Block:
    """One code block of a Markdown page.

    Attributes:
        path: the page, as given to :func:`markdown_blocks`.
        line: 1-based line of the opening fence (of the first line for an
            indented block).
        info: the fence's language (``"sh"``, ``"text"``, ...; ``""`` for
            none and for indented blocks).
        fenced: a fenced block (else an indented one).
        indent: the spaces taken off every content line (a block inside a
            list item is indented with it).
        first, stop: the content's 0-based line range ``[first, stop)`` in
            the page (the fences excluded).
        text: the content, dedented, one ``\\n`` after every line.
    """

    path: str
    line: int
    info: str
    fenced: bool
    indent: int
    first: int
    stop: int
    text: str

    @property
    def end(self) -> int:
        """0-based index of the first line after the block (after its closing fence)."""
        return self.stop + 1 if self.fenced else self.stop

    def __str__(self) -> str:
        return f"{self.path}:{self.line} ({self.info or ('fenced' if self.fenced else 'indented')})"


def _indent(line: str) -> int:
    return len(line) - len(line.lstrip(" "))


def _dedent(lines: Sequence[str], n: int) -> str:
    return "".join(l[min(n, _indent(l)):] + "\n" for l in lines)


def markdown_blocks(text: str, path: str = "") -> list[Block]:
    """Every code block of a Markdown page, in order: fenced ones (```, ~~~,
    at any indentation, e.g. inside a list item) and indented ones (four
    spaces more than the enclosing list item's content, after a blank line,
    as CommonMark reads them: a continuation line of a paragraph or list
    item is not a code block).  An unclosed fence is a ``ValueError``."""
    lines = text.split("\n")
    blocks: list[Block] = []
    items: list[int] = []  # content columns of the enclosing list items
    blank = True
    i = 0
    while i < len(lines):
        line = lines[i]
        if not line.strip():
            blank, i = True, i + 1
            continue
        ind = _indent(line)
        item = _LIST_ITEM.match(line)
        if blank or item:
            while items and ind < items[-1]:
                items.pop()
        base = items[-1] if items else 0
        fence = _FENCE.match(line)
        if fence:
            mark = fence.group(2)
            close = re.compile(rf"^ *{re.escape(mark[0])}{{{len(mark)},}}\s*$")
            j = i + 1
            while j < len(lines) and not close.match(lines[j]):
                j += 1
            if j == len(lines):
                raise ValueError(f"{path}:{i + 1}: the code fence {mark} is never closed")
            blocks.append(Block(path, i + 1, fence.group(3), True, len(fence.group(1)), i + 1, j,
                                _dedent(lines[i + 1:j], len(fence.group(1)))))
            blank, i = False, j + 1
            continue
        if blank and not item and ind >= base + 4:
            j = i
            while j < len(lines) and (not lines[j].strip() or _indent(lines[j]) >= base + 4):
                j += 1
            while not lines[j - 1].strip():
                j -= 1
            blocks.append(Block(path, i + 1, "", False, base + 4, i, j, _dedent(lines[i:j], base + 4)))
            blank, i = False, j
            continue
        if item:
            items.append(len(item.group(0)) if item.group(3) else len(item.group(0)) + 1)
        blank, i = False, i + 1
    return blocks


def _words(line: str) -> list[str]:
    lex = shlex.shlex(line, posix=True, punctuation_chars=True)
    lex.whitespace_split = True
    return list(lex)


def _expand(word: str, variables: dict[str, str]) -> str:
    def value(m: re.Match) -> str:
        name = m.group(1) or m.group(2)
        if name not in variables:
            raise ValueError(f"${name} is used but never set in the block")
        return variables[name]

    return re.sub(r"\$\{(\w+)\}|\$(\w+)", value, word)


def shell_commands(script: str, variables: dict[str, str] | None = None) -> list[list[str]]:
    """The commands of a sh block as argument lists, in order.

    Comments are dropped and ``\\`` continuations joined; a ``NAME=value``
    line sets a variable that later ``$NAME`` / ``${NAME}`` words use; a
    ``for NAME in A B ...; do`` ... ``done`` loop gives its body once per
    value.  Any other shell syntax (pipes, ``;``, ``&&``, redirections) is a
    ``ValueError``: a block the docs tests cannot follow fails instead of
    passing unchecked."""
    variables = dict(variables or {})
    rows = [w for w in (_words(l) for l in re.sub(r"\\\n", " ", script).split("\n")) if w]
    out: list[list[str]] = []

    def run(rows: list[list[str]], variables: dict[str, str]) -> None:
        k = 0
        while k < len(rows):
            words = rows[k]
            if words[0] == "for":
                if len(words) < 6 or words[2] != "in" or words[-2:] != [";", "do"]:
                    raise ValueError(f"cannot read the loop {' '.join(words)!r} (for NAME in A B ...; do)")
                depth, j = 1, k + 1
                while j < len(rows) and depth:
                    depth += (rows[j][0] == "for") - (rows[j] == ["done"])
                    j += 1
                if depth:
                    raise ValueError(f"the loop {' '.join(words)!r} has no 'done'")
                for v in words[3:-2]:
                    run(rows[k + 1:j - 1], {**variables, words[1]: _expand(v, variables)})
                k = j
                continue
            bad = [w for w in words if w and set(w) <= set(";&|<>()")]
            if bad:
                raise ValueError(f"{' '.join(words)!r}: the docs tests follow plain commands only, not {bad[0]!r}")
            if len(words) == 1 and re.fullmatch(r"[A-Za-z_]\w*=.*", words[0]):
                name, _, value = words[0].partition("=")
                variables[name] = _expand(value, variables)
            else:
                out.append([_expand(w, variables) for w in words])
            k += 1

    run(rows, variables)
    return out


@dataclasses.dataclass(frozen=True)
class Step:
    """One ```sh block of the tutorial: its commands and the ```text block
    that shows the last command's output (``None``: nothing shown)."""

    block: Block
    commands: list[list[str]]
    shown: Block | None


def tutorial_steps(readme: str, path: str = "README.md") -> list[Step]:
    """The ```sh blocks of README's "Tutorial" section, in order, each with
    the ```text block right after it, if any."""
    start = readme.index("\n" + TUTORIAL) + 1
    stop = readme.find("\n## ", start)
    first = readme[:start].count("\n")
    last = readme.count("\n") + 1 if stop < 0 else readme[:stop].count("\n") + 1
    lines = readme.split("\n")
    blocks = [b for b in markdown_blocks(readme, path) if first <= b.first < last]
    steps = []
    for b, nxt in zip(blocks, blocks[1:] + [None]):
        if b.info != "sh":
            continue
        follows = nxt is not None and nxt.info == "text" and all(not l.strip() for l in lines[b.end:nxt.first - 1])
        steps.append(Step(b, shell_commands(b.text), nxt if follows else None))
    return steps


def runs(command: Sequence[str]) -> bool:
    """Whether the tutorial runs ``command`` (a ``jaxrecog`` subcommand other than a campaign)."""
    return command[0] == "jaxrecog" and (len(command) < 2 or command[1] not in NOT_RUN)


Runner = Callable[[Sequence[str], Path], "subprocess.CompletedProcess"]


def subprocess_runner(args: Sequence[str], cwd: Path):
    """``jaxrecog ARGS`` as a user's shell runs it (a new interpreter)."""
    return subprocess.run([sys.executable, "-m", "jaxrecog.cli", *args], cwd=cwd, capture_output=True, text=True)


def prepare_folder(folder: Path) -> Path:
    """The tutorial's working folder: new, with ``examples/`` linked in (the
    README's commands name ``examples/...`` from the repository root)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    link = folder / "examples"
    if not link.exists():
        link.symlink_to(ROOT / "examples", target_is_directory=True)
    return folder


def run_tutorial(readme: str, folder: Path, run: Runner = subprocess_runner) -> dict[int, str]:
    """Run the tutorial's commands in ``folder``, in order; returns the
    standard output of the last command of every block that shows one,
    keyed by the ```text block's :attr:`Block.first`.  A command that fails
    is a ``RuntimeError`` with its stderr."""
    outputs = {}
    for step in tutorial_steps(readme):
        out = None
        for cmd in step.commands:
            if not runs(cmd):
                out = None
                continue
            p = run(cmd[1:], folder)
            if p.returncode != 0:
                raise RuntimeError(f"README.md:{step.block.line}: `{shlex.join(cmd)}` exited with {p.returncode}:\n"
                                   f"{p.stderr}")
            out = p.stdout
        if step.shown is not None:
            if out is None:
                raise RuntimeError(f"{step.shown}: shows the output of a command the tutorial does not run")
            outputs[step.shown.first] = out
    return outputs


def with_outputs(readme: str, outputs: dict[int, str]) -> str:
    """``readme`` with each shown output (:func:`run_tutorial`) written into
    its ```text block, indented as the block is."""
    lines = readme.split("\n")
    blocks = {b.first: b for b in markdown_blocks(readme)}
    for first in sorted(outputs, reverse=True):
        b = blocks[first]
        new = [(" " * b.indent + l) if l.strip() else "" for l in outputs[first].rstrip("\n").split("\n")]
        lines[b.first:b.stop] = new
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", action="store_true", help="only check that README.md shows the tutorial's output")
    ap.add_argument("--folder", type=Path, help="run the tutorial here (default: a new temporary folder)")
    args = ap.parse_args(argv)
    readme = README.read_text()
    with tempfile.TemporaryDirectory(prefix="jaxrecog-readme-") as tmp:
        folder = prepare_folder(args.folder or Path(tmp))
        try:
            new = with_outputs(readme, run_tutorial(readme, folder))
        except RuntimeError as e:
            print(e, file=sys.stderr)
            return 1
    if args.check:
        if new != readme:
            print("README.md's tutorial output is out of date: run python scripts/gen_readme_outputs.py",
                  file=sys.stderr)
            return 1
        return 0
    README.write_text(new)
    print(f"wrote {README}")
    return 0


if __name__ == "__main__":
    os.environ.setdefault("COLUMNS", "100")
    sys.exit(main())
