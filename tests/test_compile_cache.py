"""The persistent compilation cache (jaxrecog.compile_cache): where it lives,
that a program is saved once and found again, that another program or
another version folder is never served a stale one, that two processes share
a folder, that an unusable folder costs one warning and nothing else, and the
start-up work it sits beside: ``jaxrecog --help`` without JAX, ``plan``'s
compilations."""

from __future__ import annotations

import errno
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import numpy as np
import pytest
from clirun import run_cli
from compiles import count_compiles

from jaxrecog import compile_cache
from jaxrecog.compile_cache import ENV, CompileCacheWarning, default_folder, version_tag

ROOT = Path(__file__).resolve().parent.parent
_SETTINGS = ("jax_enable_compilation_cache", "jax_compilation_cache_dir",
             "jax_persistent_cache_min_compile_time_secs", "jax_persistent_cache_min_entry_size_bytes")


@pytest.fixture
def moved_cache(monkeypatch):
    """A test that points the cache elsewhere: the run's cache settings (tests/conftest.py) come back after it."""
    from jax.experimental.compilation_cache import compilation_cache as cc

    saved = {n: getattr(jax.config, n) for n in _SETTINGS}
    state = dict(compile_cache._state)
    yield
    for n, v in saved.items():
        jax.config.update(n, v)
    cc.reset_cache()
    compile_cache._state.clear()
    compile_cache._state.update(state)


def _entries(folder: Path) -> set[str]:
    return {p.name for p in folder.glob("*-cache")}


def _hits():
    """A list that grows by one at every persistent-cache hit while the listener is registered."""
    hits: list[str] = []

    def listen(event, **_):
        if event == "/jax/compilation_cache/cache_hits":
            hits.append(event)
    return hits, listen


def _probe():
    """The same program from a new function object, as a new process would
    build it (the in-memory caches do not know it, the disk may)."""
    def cache_probe(x):
        return jax.numpy.sin(x) * 3.0 + 1.0
    return jax.jit(cache_probe)


def test_the_folder_is_per_version_under_the_user_cache_and_the_variable_moves_or_disables_it(tmp_path):
    tag = version_tag()
    assert tag.startswith("jaxrecog-") and f"-jax-{jax.__version__}-jaxlib-" in tag
    assert default_folder({"XDG_CACHE_HOME": str(tmp_path)}) == tmp_path / "jaxrecog" / "jax" / tag
    assert default_folder({}) == Path("~/.cache/jaxrecog/jax").expanduser() / tag
    assert default_folder({ENV: str(tmp_path / "mine")}) == tmp_path / "mine" / tag
    for off in ("0", "off", "False", " no "):
        assert default_folder({ENV: off, "XDG_CACHE_HOME": str(tmp_path)}) is None


def test_a_program_is_saved_once_and_found_again_and_a_new_shape_or_version_compiles_afresh(
        tmp_path, monkeypatch, moved_cache):
    monkeypatch.setenv(ENV, str(tmp_path))
    first = compile_cache.configure()
    assert first == tmp_path / version_tag() and jax.config.jax_compilation_cache_dir == str(first)
    x3, x4 = np.ones(3, np.float32), np.ones(4, np.float32)
    _probe()(x3).block_until_ready()
    saved = _entries(first)
    assert len(saved) == 1 and next(iter(saved)).startswith("jit_cache_probe-")
    hits, listen = _hits()
    jax.monitoring.register_event_listener(listen)
    try:
        _probe()(x3).block_until_ready()  # only the disk has it
        assert len(hits) == 1 and _entries(first) == saved
        _probe()(x4).block_until_ready()  # other shapes: another program, another entry
        assert len(hits) == 1 and len(_entries(first)) == 2
        monkeypatch.setattr(compile_cache, "version_tag", lambda: "jaxrecog-9.9-jax-9.9-jaxlib-9.9")
        upgraded = compile_cache.configure()
        assert upgraded == tmp_path / "jaxrecog-9.9-jax-9.9-jaxlib-9.9"
        _probe()(x3).block_until_ready()  # cold: compiled and saved, not read from the old folder
        assert len(hits) == 1 and len(_entries(upgraded)) == 1
    finally:
        jax.monitoring.unregister_event_listener(listen)
    assert not list(tmp_path.rglob("*.tmp"))


def test_an_entry_that_cannot_be_written_leaves_no_partial_file_and_warns_once(tmp_path, monkeypatch):
    cache_type = compile_cache.atomic_file_cache()
    monkeypatch.setattr(cache_type, "failed", False)
    cache = cache_type(str(tmp_path), max_size=-1)
    cache.put("a", b"program a")
    assert cache.get("a") == b"program a"

    def full(src, dst):
        raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr(os, "replace", full)
    with pytest.warns(CompileCacheWarning, match="No space left on device") as caught:
        cache.put("b", b"program b")
        cache.put("c", b"program c")  # writing is off now: no second warning
    assert len(caught) == 1
    assert cache.get("b") is None and sorted(p.name for p in tmp_path.iterdir()) == ["a-cache"]


_SHARER = textwrap.dedent("""
    import sys, jax, numpy as np
    from jaxrecog import compile_cache
    compile_cache.configure(sys.argv[1])
    hits = []
    jax.monitoring.register_event_listener(
        lambda e, **_: hits.append(e) if e == "/jax/compilation_cache/cache_hits" else None)
    for n in range(1, 9):
        jax.jit(lambda x: jax.numpy.cos(x) * n)(np.ones(n, np.float32)).block_until_ready()
    print(len(hits))
""")


@pytest.mark.slow
def test_two_processes_share_a_folder(tmp_path):
    """Two processes that compile the same 8 programs at once into one new
    folder: no warning (``-W error``: a partial entry read would be one), and
    a third finds all 8."""
    run = [sys.executable, "-W", "error", "-c", _SHARER, str(tmp_path)]
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    both = [subprocess.Popen(run, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
            for _ in range(2)]
    for p in both:
        out, err = p.communicate(timeout=300)
        assert p.returncode == 0, err
    third = subprocess.run(run, capture_output=True, text=True, env=env, timeout=300)
    assert third.returncode == 0, third.stderr
    assert int(third.stdout) == 8 and len(_entries(tmp_path)) == 8
    assert not list(tmp_path.glob(".*.tmp"))


@pytest.mark.parametrize("how", ["under-a-file", "not-writable"])
@pytest.mark.filterwarnings("always::jaxrecog.compile_cache.CompileCacheWarning")
def test_an_unusable_folder_costs_one_warning_line_and_the_command_runs(tiny, tmp_path, monkeypatch, moved_cache,
                                                                       how):
    if how == "under-a-file":
        (tmp_path / "file").write_text("")
        folder = tmp_path / "file" / "cache"
    else:  # a folder no one may make, root included (a read-only folder root would still write into)
        folder = Path("/proc/jaxrecog-compile-cache")
    monkeypatch.setenv(ENV, str(folder))
    p = run_cli("plan", tiny["model"], "--top", "2", "--samples", "16")
    assert p.returncode == 0, p.stderr
    warned = [line for line in p.stderr.splitlines() if "warning" in line]
    assert len(warned) == 1 and warned[0].startswith("jaxrecog: warning: compilation cache "), p.stderr
    assert "not usable" in warned[0] and jax.config.jax_enable_compilation_cache is False
    assert "rank" in p.stdout


def test_no_compile_cache_turns_it_off(tiny, moved_cache):
    p = run_cli("--no-compile-cache", "inspect", tiny["model"])
    assert p.returncode == 0, p.stderr
    assert jax.config.jax_enable_compilation_cache is False


def test_help_and_argument_errors_do_not_import_jax():
    """``jaxrecog --help`` and a mistyped command or option answer from the
    subcommand modules' source, in a fresh interpreter, without importing JAX
    (~1.5 s); a subcommand's own help still lists its options."""
    code = textwrap.dedent("""
        import contextlib, io, sys
        from jaxrecog.cli import main
        out = io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
            codes = [main(["--help"]), main(["frobnicate"]), main(["--config"]), main([])]
        print(codes, "jax" in sys.modules, "plan " in out.getvalue() and "recognize" in out.getvalue())
    """)
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert p.returncode == 0, p.stderr
    assert p.stdout.split() == ["[0,", "2,", "2,", "2]", "False", "True"]


def test_plan_compiles_its_scores_as_one_program_and_loading_a_model_compiles_nothing(tiny):
    """``plan`` on the uniform belief: the planner's scores are one compiled
    program (op by op, the pairwise kernel compiled ~30), and ``load_model``
    uploads the arrays without compiling (``jnp.asarray`` compiled one program
    per array shape)."""
    from jaxrecog.modelfile import load_model

    with count_compiles() as loading:
        load_model(str(tiny["model"]))
    assert sum(loading.values()) == 0, dict(loading)
    with count_compiles() as planning:
        p = run_cli("plan", tiny["model"], "--planner", "mi-class-pairwise", "--top", "2")
    assert p.returncode == 0, p.stderr
    assert sum(planning.values()) <= 12, dict(planning)


def test_a_settings_file_turns_it_off_or_moves_it(tiny, tmp_path, moved_cache):
    settings = tmp_path / "run.toml"
    settings.write_text("[global]\ncompile_cache = false\n")
    assert run_cli("--config", settings, "inspect", tiny["model"]).returncode == 0
    assert jax.config.jax_enable_compilation_cache is False
    settings.write_text(f"[global]\ncompile_cache = {str(tmp_path / 'mine')!r}\n")
    assert run_cli("--config", settings, "inspect", tiny["model"]).returncode == 0
    assert jax.config.jax_enable_compilation_cache is True
    assert jax.config.jax_compilation_cache_dir == str(tmp_path / "mine" / version_tag())
    settings.write_text("[global]\ncompile_cache = 3\n")
    p = run_cli("--config", settings, "inspect", tiny["model"])
    assert p.returncode == 2 and "compile_cache: expected true, false or a folder, got 3" in p.stderr


def test_the_package_names_resolve_on_first_use():
    """``import jaxrecog`` imports no submodule; each name of ``__all__`` comes
    from its module when first used, and an unknown name is an AttributeError."""
    import importlib

    import jaxrecog

    for name in jaxrecog.__all__:
        value = getattr(jaxrecog, name)
        assert getattr(importlib.import_module(f"jaxrecog.{jaxrecog._WHERE[name]}"), name) is value, name
    assert set(jaxrecog.__all__) <= set(dir(jaxrecog))
    assert jaxrecog.kernels is importlib.import_module("jaxrecog.kernels")
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        jaxrecog.nope  # noqa: B018
