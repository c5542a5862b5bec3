"""One configuration dialect: experiment files and ``--config``
tables take the same keys (option names and Settings field names), an unknown
key names its near match, a setting given twice is an error naming both, and
``--print-config`` / ``OUT/config.toml`` hold the resolved configuration."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from jaxrecog import cli
from jaxrecog import campaigns as ex
from jaxrecog._config import OPTION_FIELDS, ConfigFileError
from jaxrecog.cli import _apply_config, build_parser, subparsers

ROOT = Path(__file__).resolve().parent.parent


def _print_config(capsys, *argv) -> str:
    capsys.readouterr()
    assert cli.main(["experiment", *map(str, argv), "--print-config"]) == 0, capsys.readouterr().err
    return capsys.readouterr().out


def _error(capsys, *argv) -> str:
    capsys.readouterr()
    assert cli.main(list(map(str, argv))) == 2
    return capsys.readouterr().err.strip().splitlines()[-1]


def test_alias_table_covers_every_experiment_option_that_sets_a_field():
    dests = {a.dest for a in subparsers(build_parser())["experiment"]._actions if a.option_strings}
    fields = set(ex.Settings.FIELDS)
    assert set(OPTION_FIELDS) <= dests and set(OPTION_FIELDS.values()) <= fields
    assert not set(OPTION_FIELDS) & fields and not set(OPTION_FIELDS.values()) & dests


def test_option_names_and_field_names_give_the_same_configuration(tmp_path, capsys):
    a, b = tmp_path / "a.toml", tmp_path / "b.toml"
    a.write_text('case = "i"\ntrials = 3\nthreshold = 0.9\nexclude-visited = true\nblur = "0.5,1"\nrank = 2\n'
                 'likelihood = "gaussian-lowrank"\n')
    b.write_text('case = "i"\n[settings]\ntrials_per_object = 3\np_threshold = 0.9\nexclude_visited_positions = true\n'
                 'blur_sigma = [0.5, 1.0]\nlikelihood = "gaussian-lowrank"\nlikelihood_options = {rank = 2}\n')
    text = _print_config(capsys, a, "--out", tmp_path / "o")
    assert text == _print_config(capsys, b, "--out", tmp_path / "o")
    assert "trials_per_object = 3\n" in text and "p_threshold = 0.9\n" in text
    assert "exclude_visited_positions = true\n" in text and "likelihood_options = {rank = 2}\n" in text


def test_unknown_and_doubled_keys_in_an_experiment_file(tmp_path, capsys):
    f = tmp_path / "e.toml"
    f.write_text('case = "i"\n[settings]\ntrails = 3\n')
    assert _error(capsys, "experiment", f, "--print-config") == (
        f"jaxrecog experiment: error: experiment file {f}: [settings]: unknown key 'trails' (did you mean 'trials'?)")
    f.write_text('case = "i"\ntrials = 3\ntrials_per_object = 4\n')
    line = _error(capsys, "experiment", f, "--print-config")
    assert "'trials' and 'trials_per_object' are the same setting" in line and str(f) in line
    f.write_text('case = "i"\nrank = 2\nlikelihood_options = {rank = 3}\n')
    assert "'rank' and likelihood_options.rank" in _error(capsys, "experiment", f, "--print-config")


def test_config_tables_take_field_names(tmp_path, capsys):
    cfg = tmp_path / "c.toml"
    cfg.write_text('[experiment]\ntrials_per_object = 4\np_threshold = 0.8\nn_components = 7\n'
                   '[recognize]\nexclude_visited_positions = true\n')
    parser = build_parser()
    _apply_config(parser, str(cfg))
    assert subparsers(parser)["recognize"].get_default("exclude_visited") is True
    text = _print_config(capsys, "--config", cfg, "i", "--trials", 5)
    # Settings field names arrive (n_components has no option); the command line still wins
    assert "trials_per_object = 5\n" in text and "p_threshold = 0.8\n" in text and "n_components = 7\n" in text
    cfg.write_text('[experiment]\ntrials = 4\ntrials-per-object = 4\n')
    with pytest.raises(ConfigFileError, match=r"\[experiment\]: 'trials' and 'trials-per-object' are the same"):
        _apply_config(build_parser(), str(cfg))
    cfg.write_text('[experiment]\nn_componets = 4\n')
    assert _error(capsys, "--config", cfg, "experiment", "i") == (
        f"jaxrecog: error: settings file {cfg}: [experiment]: unknown key 'n_componets' "
        "(did you mean 'n_components'?)")


def test_print_config_round_trips_and_every_run_writes_it(fake_experiments, tmp_path, capsys):
    out = tmp_path / "exp"
    text = _print_config(capsys, "ii", "--out", out, "--quick", "--stride", 8, "--planners", "mi", "random",
                         "--threshold", 0.9)
    assert "run_case" not in fake_experiments and not out.exists()  # nothing ran
    for name in ex.Settings.FIELDS:
        assert re.search(rf"^#? ?{name}\b", text, re.M), name
    first = tmp_path / "printed.toml"
    first.write_text(text)
    assert _print_config(capsys, first) == text
    assert cli.main(["--quiet", "experiment", str(first), "--out", str(out)]) == 0
    name, settings, planners = fake_experiments["run_case"]
    assert (name, planners, settings.stride, settings.p_threshold) == ("ii", ["mi", "random"], 8, 0.9)
    assert (out / "config.toml").read_text() == text


def test_the_docs_snippet_is_an_experiment_file(tmp_path, capsys):
    doc = (ROOT / "docs" / "campaigns.md").read_text()
    section = doc.split("## One configuration dialect", 1)[1]
    snippet = re.search(r"```toml\n(.*?)```", section, re.S).group(1)
    f = tmp_path / "snippet.toml"
    f.write_text(snippet)
    text = _print_config(capsys, f)
    for line in ("trials_per_object = 10", "p_threshold = 0.9", "exclude_visited_positions = true",
                 "n_components = 12", 'planners = ["mi-class-pairwise", "random"]'):
        assert line + "\n" in text


def test_cluster_is_a_setting_like_the_others(tmp_path, capsys):
    """``cluster`` (option and field of the same name) in an experiment file,
    overridden by ``--cluster``; a bad one is one line naming the field."""
    f = tmp_path / "c.toml"
    f.write_text('case = "i"\ncluster = "ray://head:10001"\n')
    assert 'cluster = "ray://head:10001"\n' in _print_config(capsys, f)
    assert 'cluster = "ray"\n' in _print_config(capsys, f, "--cluster", "ray")
    f.write_text('case = "i"\n[settings]\ncluster = "spark"\n')
    assert "cluster must be 'ray' (a local Ray instance) or 'ray://HOST:PORT'" in _error(
        capsys, "experiment", f, "--print-config")
