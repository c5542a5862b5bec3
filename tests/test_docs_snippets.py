"""Docs are code: every code block of README.md and docs/*.md --
fenced or indented, inside list items too -- has a check, and a block that
none of the rules below claims fails :func:`test_every_code_block_has_a_check`,
so a new block cannot slip in unchecked.

The checks (``check_of``; the blocks each one takes today in brackets):

- ``commands`` (here): every command of a ``sh`` block or of an indented
  block of commands [README ``make``, install, tutorial steps 5-6;
  docs/results.md (14 fenced, 2 indented), docs/envs.md (2),
  docs/campaigns.md (3 indented), docs/cluster.md (3 indented)] parses against the real argument parser of its program --
  ``jaxrecog`` (:func:`jaxrecog.cli.build_parser`), a script's
  ``build_parser()``, ``make -n TARGET`` and the ``jaxrecog`` lines it
  would run, ``python -m MODULE`` importable, ``pip install -e '.[EXTRAS]'``
  extras that pyproject.toml has -- and every repository file it names
  exists.  ``jaxrecog experiment`` also resolves its configuration
  (``--print-config``: cases, planners, Settings fields).  These commands
  run for minutes to hours (campaigns, the photo benchmark, PPO,
  ``make demo``), so they are parsed, not run.  Command templates use the
  :data:`PLACEHOLDERS` (``DB``, ``MODEL``, ...), ``$W`` (the work folder the
  page names) and ``[--optional flags]``; the test parses them with the
  values below and the optional flags given.  A multi-GPU command
  (``--devices N``) is resolved only where N devices exist, else parsed;
- ``tutorial-run``, ``tutorial-output``, ``manifest-example`` (in
  tests/test_readme_tutorial.py): README's tutorial steps 1-4 run in order in
  one folder; the ```text blocks are their output
  (scripts/gen_readme_outputs.py writes them); the manifest example's rows
  are rows of the database the tutorial renders;
- ``python`` (here): the block runs as printed, in a new folder that links
  ``examples/`` [docs/hardware.md ``rig_from_config``, README.md compilation cache];
- ``schema`` (here): a block of class definitions with annotated fields is
  run, and each class has the fields, in order and with the types, of the
  class of that name in the module the section's heading names
  [docs/architecture.md ``CameraModel``, ``SensorModel``];
- ``toml-rig`` / ``toml-experiment`` (here): a rig file loads through
  :func:`jaxrecog.hardware.load_config` (a ``[simulation]`` fragment as part
  of a ``kind = "simulated"`` file) [docs/hardware.md (3); the third camera's
  also runs in tests/test_three_cameras.py], an experiment
  file resolves with ``jaxrecog experiment FILE --print-config``
  [docs/campaigns.md];
- ``toml-layout`` (here): a hand-held rig's layout loads through
  :func:`jaxrecog.hardware.load_layout` and is the shipped example's
  [docs/live.md];
- ``envs-example`` (tests/test_envs_synthetic.py): docs/envs.md's python
  blocks run in order in one namespace and print the ```text block after
  each;
- ``ppo-output`` (here): docs/envs.md's PPO output is what
  scripts/ppo_env.py printed in the run recorded in docs/figures/ppo_env.json
  (rebuilt from it by ``ppo_env.printed``; the run takes minutes);
- ``cli-reference`` (tests/test_cli.py::test_cli_docs_up_to_date):
  docs/cli.md is generated from ``--help``;
- ``protocol-dump`` (tests/test_datagram.py): docs/protocol.md's hex dumps
  are the codec's bytes;
- ``math``: a ```math block is a formula (LaTeX), not code: nothing runs
  [docs/campaigns.md (3), docs/results.md (1)].

71 blocks today: 10 cli-reference, 30 commands, 6 envs-example, 4
tutorial-run, 3 tutorial-output, 1 manifest-example, 4 math, 1 ppo-output,
4 protocol-dump, 2 python, 1 schema, 3 toml-rig, 1 toml-experiment, 1 toml-layout.
"""

from __future__ import annotations

import ast
import contextlib
import importlib
import importlib.util
import io
import json
import os
import re
import shlex
import subprocess
import sys
import tomllib
import types
import typing
from pathlib import Path

import pytest
from clirun import run_cli, script

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
gen = script("gen_readme_outputs")

#: placeholders of the docs' command templates and the words the test parses in their place
PLACEHOLDERS = {"DB": ["db"], "ALL": ["db"], "OLD": ["db"], "NEW": ["db"], "NEW_DB": ["db"],
                "MODEL": ["model.npz"], "M": ["model.npz"], "OUT": ["out.npz"], "R": ["robust"],
                "LIK": ["view-mixture-lowrank"], "PLANNERS": ["mi-class-pairwise", "random"]}
#: variables the pages set in prose ("work folder W")
VARIABLES = {"W": "out/thesis"}
#: options whose value is a file or folder a command writes (need not exist)
OUTPUT_OPTIONS = ("--out", "--workdir", "--figure", "--plot", "--plot-dir", "--problems-out")
#: top folders of the repository: a command word under one of them names a file that must exist
REPO_FOLDERS = ("scripts", "examples", "docs", "data", "benchmarks", "tests", "jaxrecog", "kernels", "hardware")
PROGRAMS = ("jaxrecog", "python", "python3", "nice", "make", "pip")


def _blocks():
    return [b for page in PAGES for b in gen.markdown_blocks(page.read_text(), str(page.relative_to(ROOT)))]


BLOCKS = _blocks()


def _page(b) -> str:
    return (ROOT / b.path).read_text()


def _after(b):
    """The block right after ``b`` on its page (nothing but blank lines between), or None."""
    lines = _page(b).split("\n")
    later = [c for c in BLOCKS if c.path == b.path and c.first > b.first]
    if later and all(not l.strip() for l in lines[b.end:later[0].first - 1]):
        return later[0]
    return None


def _before(b):
    earlier = [c for c in BLOCKS if c.path == b.path and c.first < b.first]
    return earlier[-1] if earlier and _after(earlier[-1]) == b else None


def _is_commands(b) -> bool:
    try:
        commands = gen.shell_commands(b.text, VARIABLES)
    except ValueError:
        return b.info == "sh"  # a sh block the reader cannot follow: `commands` fails it with the reason
    return bool(commands) and all(Path(c[0]).name in PROGRAMS for c in commands)


def _tutorial():
    readme = (ROOT / "README.md").read_text()
    return gen.tutorial_steps(readme)


def _is_schema(b) -> bool:
    tree = ast.parse(b.text)
    classes = [n for n in tree.body if isinstance(n, ast.ClassDef)]
    return bool(classes) and all(
        isinstance(s, (ast.AnnAssign, ast.Pass)) or (isinstance(s, ast.Expr) and isinstance(s.value, ast.Constant))
        for c in classes for s in c.body)


def check_of(b) -> str | None:
    """The check that covers block ``b`` (a key of the module docstring's list), or None."""
    if b.info == "math":
        return "math"
    if b.path == "docs/cli.md":
        return "cli-reference" if "generated by scripts/gen_cli_docs.py" in _page(b) else None
    if b.path == "docs/protocol.md" and b.fenced and not b.info:
        section = _page(b).split("## Example", 1)
        return "protocol-dump" if len(section) == 2 and b.text in section[1] else None
    steps = _tutorial() if b.path == "README.md" else []
    if any(s.block == b and all(gen.runs(c) for c in s.commands) for s in steps):
        return "tutorial-run"
    if any(s.shown == b for s in steps):
        return "tutorial-output"
    if b.info == "python":
        if b.path == "docs/envs.md":
            import test_envs_synthetic

            return "envs-example" if b.text in [code for code, _ in test_envs_synthetic.docs_blocks()] else None
        return "schema" if _is_schema(b) else "python"
    if b.info == "toml":
        keys = set(tomllib.loads(b.text))
        if keys & {"kind", "ptu", "controller", "camera", "simulation", "table"}:
            return "toml-rig"
        if keys & {"case", "rig", "model", "planners"}:
            return "toml-experiment"
        if keys & {"cameras"}:
            return "toml-layout"
        return None
    if b.info == "text":
        prev = _before(b)
        if b.path == "docs/envs.md" and prev is not None and prev.info == "python":
            import test_envs_synthetic

            return "envs-example" if b.text in [t for _, t in test_envs_synthetic.docs_blocks()] else None
        earlier = [c for c in BLOCKS if c.path == b.path and c.first < b.first]
        if b.path == "docs/envs.md" and earlier and earlier[-1].text.startswith("nice python scripts/ppo_env.py"):
            return "ppo-output"  # the block after the script's command (a sentence between)
        if b.path == "README.md" and b.text.startswith("path,camera,position,object,pose,split\n"):
            return "manifest-example"
        return None
    if b.info in ("sh", "") and _is_commands(b):
        return "commands"
    return None


def blocks_of(check: str) -> list:
    return [b for b in BLOCKS if check_of(b) == check]


def _ids(blocks) -> list[str]:
    return [f"{b.path}:{b.line}" for b in blocks]


# -- coverage ------------------------------------------------------------------


def test_every_code_block_has_a_check():
    missing = [str(b) for b in BLOCKS if check_of(b) is None]
    assert not missing, "code blocks no check covers (tests/test_docs_snippets.py says which exist):\n" + \
        "\n".join(missing)
    assert len(BLOCKS) > 40  # the reader finds the pages' blocks (README alone has 12)


def test_the_block_reader_finds_fenced_indented_and_list_item_blocks():
    page = ("Text\n\n    indented code\n\n    more\n\n- item\n  continued\n\n    code in the item? no: a paragraph\n"
            "\n      code in the item\n\n1. step\n\n   ```sh\n   run it\n   ```\n   ```text\n   out\n   ```\n\n"
            "Para\n    lazy continuation, not code\n\n~~~\ntilde\n~~~\n")
    found = [(b.info, b.fenced, b.text) for b in gen.markdown_blocks(page)]
    assert found == [("", False, "indented code\n\nmore\n"), ("", False, "code in the item\n"),
                     ("sh", True, "run it\n"), ("text", True, "out\n"), ("", True, "tilde\n")]
    with pytest.raises(ValueError, match="never closed"):
        gen.markdown_blocks("```sh\nno end\n")


def test_the_shell_reader_follows_loops_variables_and_continuations():
    text = ("W=/tmp/w   # a folder\nfor c in i ii; do\n  run --case $c \\\n      --workdir ${W}/x  # note\ndone\n"
            "# a comment line\nlast 'a b'\n")
    assert gen.shell_commands(text) == [["run", "--case", "i", "--workdir", "/tmp/w/x"],
                                        ["run", "--case", "ii", "--workdir", "/tmp/w/x"], ["last", "a b"]]
    for bad in ("a | b", "a && b", "a > f", "a; b", "echo $UNSET", "for x in a b; do\nrun\n"):
        with pytest.raises(ValueError):
            gen.shell_commands(bad)


# -- commands: parsed against their programs' parsers ---------------------------------


def _fill(words: list[str]) -> list[str]:
    """A command template with its placeholders filled in and its optional
    ``[--flags]`` given (a ``[description]`` in brackets dropped)."""
    out, k = [], 0
    while k < len(words):
        w = words[k]
        if w.startswith("["):
            j = k
            while not words[j].endswith("]"):
                j += 1
            inner = " ".join(words[k:j + 1])[1:-1].split()
            if inner[0].startswith("-"):
                out += [x for i in inner for x in PLACEHOLDERS.get(i, [i])]
            k = j + 1
            continue
        if w.startswith("dataset:") and w[8:] in PLACEHOLDERS:
            w = "dataset:" + PLACEHOLDERS[w[8:]][0]
        out += PLACEHOLDERS.get(w, [w])
        k += 1
    return out


def _parse(parser, args: list[str], what: str) -> None:
    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        try:
            parser.parse_args(args)
        except SystemExit as e:
            assert e.code == 0, f"`{what}` does not parse: {err.getvalue().strip().splitlines()[-1]}"


def _script_parser(path: Path, monkeypatch):
    assert path.is_file(), f"{path.relative_to(ROOT)} does not exist"
    monkeypatch.syspath_prepend(str(path.parent))  # a script imports its neighbours (add_bench: photo_bench)
    mod = script(path.stem, path.parent.name)
    assert hasattr(mod, "build_parser"), f"{path.relative_to(ROOT)} has no build_parser() to check its commands with"
    return mod.build_parser()


def _devices_here(args: list[str]) -> bool:
    """Whether this machine has the ``--devices N`` a command asks for (a
    multi-GPU command is parsed, not resolved, on a machine with fewer)."""
    if "--devices" not in args:
        return True
    import jax

    return int(args[args.index("--devices") + 1]) <= len(jax.devices())


def check_command(words: list[str], cwd: Path, monkeypatch) -> None:
    """Parse one documented command with its program's parser (module docstring)."""
    what = shlex.join(words)
    words = _fill(words)
    while words[0] == "nice":
        words = words[1:]
    for i, w in enumerate(words[1:], 1):
        if words[i - 1] in OUTPUT_OPTIONS or "/" not in w or w.split("/", 1)[0] not in REPO_FOLDERS:
            continue
        assert (ROOT / w).exists(), f"`{what}` names {w}, which does not exist"
    program, args = Path(words[0]).name, words[1:]
    if program == "jaxrecog":
        from jaxrecog.cli import build_parser

        _parse(build_parser(), args, what)
        if args and args[0] == "experiment" and "--help" not in args and _devices_here(args):
            p = run_cli(*args, "--print-config", cwd=cwd)
            assert p.returncode == 0, f"`{what} --print-config`: {p.stderr.strip()}"
    elif program in ("python", "python3"):
        if args[0] == "-m":
            assert importlib.util.find_spec(args[1]) is not None, f"`{what}`: no module {args[1]}"
        else:
            _parse(_script_parser(ROOT / args[0], monkeypatch), args[1:], what)
    elif program == "pip":
        assert args[:2] == ["install", "-e"] and len(args) == 3, f"`{what}`: only `pip install -e .[EXTRAS]` is known"
        m = re.fullmatch(r"\.(?:\[([\w,-]+)\])?", args[2])
        assert m, f"`{what}`: install the repository ('.' or '.[extras]')"
        extras = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"])
        unknown = set((m.group(1) or "").split(",")) - extras - {""}
        assert not unknown, f"`{what}`: pyproject.toml has no extra {sorted(unknown)}"
    elif program == "make":
        p = subprocess.run(["make", "-n", "-C", str(ROOT), *args], capture_output=True, text=True)
        assert p.returncode == 0, f"`{what}`: {p.stderr.strip()}"
        for line in p.stdout.splitlines():
            run = shlex.split(line)
            if run and Path(run[0]).name == "jaxrecog":
                check_command(run, cwd, monkeypatch)
    else:
        raise AssertionError(f"`{what}`: no parser known for {program!r} (tests/test_docs_snippets.py)")


@pytest.mark.parametrize("block", blocks_of("commands"), ids=_ids(blocks_of("commands")))
def test_every_documented_command_parses(block, tmp_path, monkeypatch):
    cwd = gen.prepare_folder(tmp_path)  # the commands name examples/... from the repository root
    commands = gen.shell_commands(block.text, VARIABLES)
    assert commands
    for words in commands:
        check_command(words, cwd, monkeypatch)


def test_a_wrong_command_is_caught(tmp_path, monkeypatch):
    """The parse check fails on what it should: an unknown option, a missing
    script or example, an unknown case, an unknown extra, a wrong make target."""
    cwd = gen.prepare_folder(tmp_path)
    for words, needle in [
        (["jaxrecog", "train", "db", "--out", "m.npz", "--ouput", "x"], "unrecognized arguments: --ouput x"),
        (["jaxrecog", "experiment", "i", "--planners", "mi", "nope"], "invalid choice: 'nope'"),
        (["jaxrecog", "experiment", "iv", "--trials", "2"], "unknown case 'iv'"),
        (["jaxrecog", "experiment", "examples/nope.toml"], "examples/nope.toml, which does not exist"),
        (["python", "scripts/reproduce_thesis.py", "--case", "iv"], "'iv'"),
        (["python", "scripts/nope.py"], "names scripts/nope.py, which does not exist"),
        ([".venv/bin/pip", "install", "-e", ".[sim,gpu]"], "no extra ['gpu']"),
        (["make", "nope"], "nope"),
        (["ls", "-l"], "no parser known for 'ls'"),
    ]:
        with pytest.raises(AssertionError, match=re.escape(needle)):
            check_command(words, cwd, monkeypatch)


# -- python and toml --------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("block", blocks_of("python"), ids=_ids(blocks_of("python")))
def test_every_python_block_runs(block, tmp_path):
    cwd = gen.prepare_folder(tmp_path)
    here = os.getcwd()
    out = io.StringIO()
    try:
        os.chdir(cwd)
        with contextlib.redirect_stdout(out):
            exec(compile(block.text, str(block), "exec"), {"__name__": "__main__"})
    finally:
        os.chdir(here)
    shown = _after(block)
    if shown is not None and shown.info == "text":
        assert out.getvalue() == shown.text, f"{block} printed\n{out.getvalue()}\nthe page shows\n{shown.text}"


def _heading_module(b) -> str:
    """The module named in backticks by the nearest heading above block ``b``."""
    lines = _page(b).split("\n")[:b.first]
    for line in reversed(lines):
        if line.startswith("#"):
            names = re.findall(r"`(jaxrecog(?:\.\w+)*)`", line)
            assert names, f"{b}: the heading {line!r} names no module to compare the classes with"
            return names[-1]
    raise AssertionError(f"{b}: no heading above the block")


def _hint(t) -> str:
    return re.sub(r"\b(?:[A-Za-z_]\w*\.)+([A-Za-z_]\w*)", r"\1", repr(t)).replace("<class '", "").replace("'>", "")


@pytest.mark.parametrize("block", blocks_of("schema"), ids=_ids(blocks_of("schema")))
def test_every_documented_class_has_the_real_fields(block, monkeypatch):
    module = types.ModuleType("docs_schema")  # dataclasses look their module up in sys.modules
    monkeypatch.setitem(sys.modules, module.__name__, module)
    exec(compile(block.text, str(block), "exec"), module.__dict__)
    namespace = module.__dict__
    module = importlib.import_module(_heading_module(block))
    for node in ast.parse(block.text).body:
        if not isinstance(node, ast.ClassDef):
            continue
        doc, real = namespace[node.name], getattr(module, node.name)
        doc_hints, real_hints = typing.get_type_hints(doc), typing.get_type_hints(real)
        assert list(doc_hints) == list(real_hints), f"{block}: {node.name} fields"
        for name in real_hints:
            assert _hint(doc_hints[name]) == _hint(real_hints[name]), f"{block}: {node.name}.{name}"


@pytest.mark.parametrize("block", blocks_of("toml-rig"), ids=_ids(blocks_of("toml-rig")))
def test_every_rig_file_loads(block, tmp_path):
    from jaxrecog.hardware import load_config

    text = block.text if "kind" in tomllib.loads(block.text) else 'kind = "simulated"\n' + block.text
    path = tmp_path / "rig.toml"
    path.write_text(text)
    load_config(path)


@pytest.mark.parametrize("block", blocks_of("toml-layout"), ids=_ids(blocks_of("toml-layout")))
def test_every_layout_file_loads(block, tmp_path):
    from jaxrecog.hardware import load_layout

    path = tmp_path / "layout.toml"
    path.write_text(block.text)
    assert load_layout(path) == load_layout(ROOT / "examples" / "handheld_layout.toml")


@pytest.mark.parametrize("block", blocks_of("toml-experiment"), ids=_ids(blocks_of("toml-experiment")))
def test_every_experiment_file_resolves(block, tmp_path):
    path = tmp_path / "experiment.toml"
    path.write_text(block.text)
    p = run_cli("experiment", path, "--print-config", cwd=gen.prepare_folder(tmp_path / "run"))
    assert p.returncode == 0, p.stderr


# -- outputs of long runs -------------------------------------------------------------


def test_the_ppo_output_is_the_recorded_runs():
    ppo = script("ppo_env")
    (block,) = blocks_of("ppo-output")
    run = json.loads((ROOT / "docs" / "figures" / "ppo_env.json").read_text())
    assert block.text == ppo.printed(run, "docs/figures/ppo_env.png")


def test_the_readme_says_which_extras_make_venv_installs():
    """README's installation paragraph names the extras of the Makefile's
    install line (it used to say "all extras" where `make venv` installs three)."""
    makefile = (ROOT / "Makefile").read_text()
    extras = re.search(r"pip install[^\n]*-e '\.\[([^\]]+)\]'", makefile).group(1)
    if extras == "$(EXTRAS)":  # the install line names the variable: its default is what is installed
        extras = re.search(r"^EXTRAS\s*\?=\s*(\S+)", makefile, re.M).group(1)
    readme = (ROOT / "README.md").read_text()
    para = readme[readme.index("## Installation"):readme.index("```sh", readme.index("## Installation"))]
    assert f"`{extras}`" in para and f"'.[{extras}]'" in para and "all extras" not in para


def test_the_ppo_script_writes_no_tracked_file_by_default():
    """Its figure goes under out/ (WORKDIR) unless --figure names another:
    the default used to overwrite docs/figures/ppo_env.png."""
    ppo = script("ppo_env")
    assert Path(ppo.parse_args([]).figure) == Path("out/ppo-env/ppo_env.png")
    assert Path(ppo.parse_args(["--workdir", "w"]).figure) == Path("w/ppo_env.png")
    assert ppo.parse_args(["--figure", "docs/figures/ppo_env.png"]).figure == "docs/figures/ppo_env.png"


def test_the_claims_of_the_other_test_modules_hold():
    """``envs-example`` and ``protocol-dump`` blocks are the ones those tests read."""
    import test_datagram
    import test_envs_synthetic

    envs = [b.text for b in blocks_of("envs-example")]
    assert envs == [x for pair in test_envs_synthetic.docs_blocks() for x in pair if x is not None]
    assert len(blocks_of("protocol-dump")) == len(test_datagram.documented_examples()) == 4
