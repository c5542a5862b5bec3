"""README.md's tutorial as a user runs it (docs that run): steps 1-4
(render, inspect, train, plan, recognize) run in order in one new folder, in
this process (``clirun``: the session's imports and compiled programs), and
the ```text blocks show exactly what they print
(scripts/gen_readme_outputs.py writes them; its rules are the test's).  The
campaigns of steps 5-6 are parsed and resolved in tests/test_docs_snippets.py
(they run for minutes)."""

from __future__ import annotations

from pathlib import Path

import pytest
from clirun import one_error_line, run_cli, script

pytest.importorskip("pybullet")

ROOT = Path(__file__).resolve().parent.parent
gen = script("gen_readme_outputs")

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def tutorial(tmp_path_factory):
    """The tutorial's folder after steps 1-4, the README and the outputs shown."""
    folder = gen.prepare_folder(tmp_path_factory.mktemp("tutorial"))
    readme = (ROOT / "README.md").read_text()
    outputs = gen.run_tutorial(readme, folder, run=lambda args, cwd: run_cli(*args, cwd=cwd))
    return folder, readme, outputs


def test_the_readme_shows_what_the_tutorial_prints(tutorial):
    folder, readme, outputs = tutorial
    blocks = {b.first: b for b in gen.markdown_blocks(readme, "README.md")}
    assert outputs  # steps 1, 3 and 4 show theirs
    for first, out in outputs.items():
        assert blocks[first].text == out, (f"{blocks[first]} shows\n{blocks[first].text}\nthe tutorial printed\n{out}"
                                           "(python scripts/gen_readme_outputs.py writes it)")
    assert gen.with_outputs(readme, outputs) == readme


def test_the_tutorial_writes_the_files_it_names(tutorial):
    folder = tutorial[0]
    for name in ("db/manifest.csv", "model.npz", "figs/eigenimages.png", "figs/occlusion_examples.png",
                 "figs/mi.png", "figs/belief.png", "figs/belief.svg"):
        assert (folder / name).is_file(), name


def test_the_manifest_example_is_rows_of_the_tutorials_database(tutorial):
    """The README's manifest.csv example (section "Using your own image
    database") is the header and rows of the database step 1 renders."""
    folder, readme, _ = tutorial
    (block,) = [b for b in gen.markdown_blocks(readme) if b.text.startswith("path,camera,position,object,pose,split")]
    rows = (folder / "db" / "manifest.csv").read_text().splitlines()
    shown = block.text.splitlines()
    assert shown[0] == rows[0]
    assert set(shown[1:]) <= set(rows[1:]), set(shown[1:]) - set(rows[1:])
    assert {r.rsplit(",", 1)[1] for r in shown[1:]} == {"train", "test"}


def test_a_model_of_other_positions_is_refused_by_the_full_rig(tutorial):
    """The tutorial's model (every 8th position) on the full 32 x 7 table: one error line."""
    p = run_cli("recognize", "model.npz", "--samples", 64, cwd=tutorial[0])
    assert p.returncode == 1
    one_error_line(p, "positions")
