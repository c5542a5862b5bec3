"""Strict test settings (docs/style.md, item 11): rank promotion raises, strict dtype
promotion for the numerics modules, a ``getkey`` fixture, an ``x64`` fixture
for numerics tests that need double precision, and the session's shared
end-to-end inputs: one trained model of the moving database, one rendered
database of the strided thesis table, and the CLI tests' tiny database and
model (with a stub of the thesis campaigns)."""

from __future__ import annotations

import atexit
import contextlib
import itertools
import os
import shutil
import sys
import tempfile
from pathlib import Path

import jax
import jax.random as jr
import jaxtyping
import numpy as np
import pytest

jax.config.update("jax_numpy_rank_promotion", "raise")
jax.config.update("jax_numpy_dtype_promotion", "standard")


def _share_compilations() -> None:
    """One persistent XLA compilation cache for the whole run: this process,
    the xdist workers and every subprocess the tests start (the CLI, the demo,
    the scripts) read it through ``JAX_COMPILATION_CACHE_DIR``.

    On this CPU one XLA compilation costs ~60 ms even for a one-op program,
    and the suite compiles the same programs again and again from different
    function objects (each test builds its own recognizer; each subprocess
    starts cold), which the in-memory cache cannot see.  A hit costs ~10 ms.
    The folder is new for every run (nothing carries over from an earlier run,
    as on a fresh clone) unless ``JAXRECOG_TEST_JAX_CACHE`` names one (``off``:
    no cache).  jaxrecog's own cache (``jaxrecog.compile_cache``, on by
    default in the CLI and the package's names) keeps a folder that JAX's
    settings name, so no test writes into the user's cache folder.  Results
    are unchanged (the cached executable is the compiled one) and
    ``tests/compiles.py`` still counts every compilation (jax logs it before it
    looks the program up)."""
    folder = os.environ.get("JAXRECOG_TEST_JAX_CACHE")
    if folder == "off":  # to measure what the cache saves
        os.environ["JAXRECOG_COMPILE_CACHE"] = "0"  # nor jaxrecog's own (the user's folder: never from a test)
        return
    if not folder:
        folder = tempfile.mkdtemp(prefix="jaxrecog-xla-cache-")
        os.environ["JAXRECOG_TEST_JAX_CACHE"] = folder  # xdist workers inherit it
        atexit.register(shutil.rmtree, folder, ignore_errors=True)
    settings = {"JAX_COMPILATION_CACHE_DIR": folder, "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0",
                "JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES": "0"}
    os.environ.update(settings)  # subprocesses
    os.environ.pop("JAXRECOG_COMPILE_CACHE", None)  # a folder of the user's would win over JAX's setting
    jax.config.update("jax_compilation_cache_dir", folder)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)


_share_compilations()


def _quick_exit() -> None:
    """A test process exits without tearing its JAX state down.

    A test worker ends the run holding thousands of compiled programs (each
    test builds its own recognizers).  Tearing them down took 8-10 s at exit
    (JAX's ``atexit`` ``clean_up`` clearing its caches one by one, then the
    interpreter's finalisation in C), while xdist's controller waited for the
    worker to go: measured with ``JAXRECOG_TEST_TIMELINE`` (its stacks of a
    worker still alive 2 s after its exit handlers: in ``clear_all_caches``,
    then in no Python frame), the last worker's end to the summary took 10 s.
    The operating system frees the memory either way.  So: no ``clean_up``
    in any test process, and an xdist worker, whose results have all gone to
    the controller by the time the interpreter exits, leaves with
    ``os._exit`` once its output is flushed (registered at the end of the
    session, so this handler runs before the others).  Subprocesses (the CLI
    under test) keep JAX's behaviour."""
    from jax._src import api

    clean_up = getattr(api, "clean_up", None)
    if clean_up is not None:
        atexit.unregister(clean_up)


_quick_exit()


#: more to do at the end of the session (the timeline's records); their exit
#: handlers are registered after ``leave``, so they run before it
_AT_SESSION_FINISH = []


def pytest_sessionfinish(session, exitstatus):
    if os.environ.get("PYTEST_XDIST_WORKER"):
        def leave():
            for stream in (sys.stdout, sys.stderr):
                with contextlib.suppress(Exception):
                    stream.flush()
            os._exit(0)

        atexit.register(leave)
    for finish in _AT_SESSION_FINISH:
        finish()

#: XLA flags of the test run.  The suite's time is compile time
#: (tests/conftest.py::_share_compilations), and nine tenths of that is XLA's
#: CPU backend, not JAX's tracing or lowering (measured per test with
#: ``jax.monitoring``'s ``backend_compile_duration``).  The settings:
#:
#: - the LLVM optimisations off (``jax_disable_most_optimizations``: XLA's
#:   backend optimisation level 0 and its expensive LLVM passes off): for the
#:   larger programs (a recognizer step with the CRLB planner on three
#:   cameras) they halve the compile (19 s -> 9 s of CPU for that test); a
#:   test whose programs run long takes the :func:`optimized_xla` fixture;
#: - the classic elemental emitters instead of the MLIR fusion emitters
#:   (``xla_cpu_use_fusion_emitters=false``): tests/test_recognizer.py's
#:   backend compile 64.5 s -> 24.8 s, the two-step lookahead kernel 1.58 s
#:   -> 0.64 s a program;
#: - one LLVM module per program instead of parallel codegen splits
#:   (``xla_cpu_parallel_codegen_split_count=1``): a further ~15 % on two
#:   cores, where the test workers already use both.
#:
#: They change how the code is generated, not what it computes (the numerics
#: tests compare against the NumPy oracles at unchanged tolerances).
#: Benchmarks and the product do not use them.  ``JAXRECOG_TEST_XLA_OPT=1``
#: keeps XLA's defaults.
FAST_COMPILE_FLAGS = ("--xla_llvm_disable_expensive_passes=true", "--xla_cpu_use_fusion_emitters=false",
                      "--xla_cpu_parallel_codegen_split_count=1")


def _fast_compiles() -> None:
    if os.environ.get("JAXRECOG_TEST_XLA_OPT") == "1":
        return
    flags = os.environ.get("XLA_FLAGS", "").split()
    add = [f for f in FAST_COMPILE_FLAGS if f.split("=")[0] not in {g.split("=")[0] for g in flags}]
    os.environ["XLA_FLAGS"] = " ".join(flags + add)  # read when the backend starts; subprocesses inherit it
    os.environ["JAX_DISABLE_MOST_OPTIMIZATIONS"] = "1"  # subprocesses
    jax.config.update("jax_disable_most_optimizations", True)  # read at every compile


_fast_compiles()


@pytest.fixture
def optimized_xla():
    """The test's programs compiled at XLA's default optimisation level (the
    suite compiles at level 0: :data:`FAST_COMPILE_FLAGS`; the expensive LLVM
    passes stay off), for a test whose programs run long rather than many:
    tests/test_soak.py's 10 000 steps take 2.5 s so against 11.8 s, its whole
    test 7 s against 15 s.  The setting is not part of JAX's in-memory jit
    cache key: a program this process compiled before (the same function,
    shapes and settings) is reused as it was compiled, and one compiled here
    is reused by later tests of the process (both compute the same values to
    rounding; the tests that compare programs bit for bit compile their
    own)."""
    yield from _jax_setting("jax_disable_most_optimizations", False)


def _jax_setting(name: str, value):
    """A fixture's body: JAX's setting ``name`` is ``value`` for the test, as
    it was afterwards."""
    previous = jax.config.read(name)
    jax.config.update(name, value)
    try:
        yield
    finally:
        jax.config.update(name, previous)


@pytest.fixture
def strict_dtype_promotion():
    """Run the test under strict dtype promotion: mixing float32 and float64
    (or int and float arrays) without an explicit cast raises.  The numerics
    modules use it for every test (``pytestmark``)."""
    with jax.numpy_dtype_promotion("strict"):
        yield


@pytest.fixture
def unchecked():
    """``with unchecked(): ...`` turns the run-time type checker off inside the
    block: for the tests of the product's own guards against wrongly typed
    input (what a caller without the checker, e.g. a settings file, gets)."""

    @contextlib.contextmanager
    def block():
        previous = jaxtyping.config.jaxtyping_disable
        jaxtyping.config.update("jaxtyping_disable", True)
        try:
            yield
        finally:
            jaxtyping.config.update("jaxtyping_disable", previous)

    return block


@pytest.fixture
def getkey():
    """Return a function that hands out fresh, deterministic PRNG keys."""
    counter = itertools.count()
    base = jr.PRNGKey(0)

    def _getkey():
        return jr.fold_in(base, next(counter))

    return _getkey


@pytest.fixture
def rng():
    """A seeded NumPy generator for reference computations."""
    return np.random.default_rng(1234)


@pytest.fixture
def x64():
    """Run the test with 64-bit floats; restores the previous setting afterwards."""
    yield from _jax_setting("jax_enable_x64", True)


@pytest.fixture
def saved_figures(monkeypatch):
    """The texts of every figure :mod:`jaxrecog.plots` saves during the test,
    in order (the file is still written): ``{"titles", "xlabels", "ylabels",
    "xticks", "yticks", "legend"}``, each a list over the figure's axes (the
    suptitle first among the titles), to check what a reader sees -- e.g.
    one numbering of objects and cameras in tables, plots and the CLI."""
    from jaxrecog import plots

    seen: list[dict] = []
    real = plots.save

    def save(fig, path):
        axes = fig.axes
        seen.append({
            "titles": ([fig._suptitle.get_text()] if fig._suptitle is not None else []) + [a.get_title() for a in axes],
            "xlabels": [a.get_xlabel() for a in axes], "ylabels": [a.get_ylabel() for a in axes],
            "xticks": [[t.get_text() for t in a.get_xticklabels()] for a in axes],
            "yticks": [[t.get_text() for t in a.get_yticklabels()] for a in axes],
            "legend": [t.get_text() for a in axes if a.get_legend() for t in a.get_legend().get_texts()],
        })
        return real(fig, path)

    monkeypatch.setattr(plots, "save", save)
    return seen


@pytest.fixture(scope="session")
def moving_model():
    """``builders.moving_database()`` and its DB1 model (K = 2, 10 samples per
    image), trained once per session for every test that recognises on it
    (the database and the model are only read)."""
    from builders import moving_database

    from jaxrecog import train_model

    db = moving_database()
    return db, train_model(db, kind="DB1", n_components=2, samples_per_image=10)


@pytest.fixture(scope="session")
def small_db():
    """A tiny in-memory database (``builders.make_database``: (2, 2) positions,
    2 objects x 2 poses, 16 x 20 images, 2 test images per view) for the
    training and likelihood tests (only read)."""
    from builders import make_database

    return make_database(positions=(2, 2), n_objects=2, n_poses=2, image_shape=(16, 20), n_test=2)


@pytest.fixture(scope="session")
def strided_database(tmp_path_factory) -> Path:
    """The thesis table at stride 8 (4 x 1 positions, 8 objects x 4 poses: 160
    images), rendered once per session by the product's own cache path
    (``campaigns.prepare``), for the end-to-end runs to start from."""
    from jaxrecog.campaigns import Settings, prepare

    work = tmp_path_factory.mktemp("strided")
    prepare(Settings(workdir=work, stride=8), databases=())
    return work / "database-stride8"


@pytest.fixture
def strided_workdir(strided_database):
    """``seed(workdir)`` copies the session's rendered strided database into a
    fresh work folder, where ``prepare`` finds it instead of rendering again
    (each run still trains and writes its own models, trials and tables)."""

    def seed(workdir: Path) -> Path:
        shutil.copytree(strided_database, Path(workdir) / strided_database.name)
        return Path(workdir)

    return seed


@pytest.fixture(scope="session")
def tiny(tmp_path_factory):
    """The CLI tests' inputs (tests/test_cli.py, tests/test_cli_json.py): a
    2-object, 2-pose, (3, 2)-position database of 30 x 40 images with a test
    split, and its DB2 model (K = 3), written once per session (only read)."""
    from builders import write_synthetic_database

    from jaxrecog.modelfile import save_model
    from jaxrecog.train import train_model

    root = tmp_path_factory.mktemp("tiny")
    db = write_synthetic_database(root / "db", positions=(3, 2), n_objects=2, n_poses=2,
                                  image_shape=(30, 40), n_test=1)
    db = db if db.is_dir() else db.parent
    model, info = train_model(db, kind="DB2", n_components=3, samples_per_image=6, return_info=True)
    path = save_model(root / "model.npz", model, training=info.params, manifest_sha256=info.manifest_sha256)
    return {"root": root, "db": db, "model": Path(path)}


def _fake_results(M=2, n=3):
    from jaxrecog.results import TrialResult

    out = []
    for m in range(M):
        for t in range(n):
            out.append(TrialResult(m * n + t, m, 0, m if t else 1 - m, 0, 0.97, 2 + t, True,
                                   object_probs=((0.5, 0.5), (0.9, 0.1))))
    return out


@pytest.fixture
def fake_experiments(monkeypatch, tiny):
    """Stub ``campaigns.prepare/run_case/run_trace`` (the real ones render the
    1248-image thesis database); the CLI's wiring, files and plots are real.
    The stubs' arguments are recorded in the returned dict."""
    from jaxrecog import campaigns as ex
    from jaxrecog.results import summarize

    calls = {}

    def prepare(settings, **kw):
        calls["prepare"] = settings
        return ex.Prepared(tiny["db"], {"DB2": tiny["model"], "DB1": tiny["model"]})

    def run_case(name, settings, planners=None, **kw):
        calls["run_case"] = (name, settings, planners)
        planners = list(planners or ex.CASES[name].planners)
        res = {p: _fake_results() for p in planners}
        return ex.CaseReport(ex.CASES[name], settings, {p: summarize(r, 2) for p, r in res.items()}, res,
                             {p: 1.0 for p in planners})

    def run_trace(settings, *, object=5, planner="mi", prepared=None, **kw):
        return _fake_results()[1]

    monkeypatch.setattr(ex, "prepare", prepare)
    monkeypatch.setattr(ex, "run_case", run_case)
    monkeypatch.setattr(ex, "run_trace", run_trace)
    return calls


def _timeline() -> None:
    """``JAXRECOG_TEST_TIMELINE=FOLDER``: each worker appends one line per test
    to ``FOLDER/<worker>.tsv``: start, stop, XLA backend-compile seconds and
    the node id: to see where the suite's time goes (compile or run) and how
    evenly the workers share it."""
    folder = os.environ.get("JAXRECOG_TEST_TIMELINE")
    if not folder:
        return
    import logging
    import time

    import jax.monitoring

    compiled = [0.0]

    def listen(event, duration, **_):
        if event == "/jax/compilation_cache/compile_time_saved_sec":
            return
        if "backend_compile" in event:
            compiled[0] += duration

    jax.monitoring.register_event_duration_secs_listener(listen)
    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    out = Path(folder) / f"{worker}.tsv"
    out.parent.mkdir(parents=True, exist_ok=True)
    programs = open(Path(folder) / f"{worker}.programs.tsv", "a", buffering=1)
    with open(Path(folder) / f"{worker}.events.tsv", "a") as f:
        f.write(f"{time.time():.3f}\tconftest\n")
    current = [""]

    class Programs(logging.Handler):  # "Finished XLA compilation of NAME in S sec" (cache hits included)
        def emit(self, record):
            msg = record.getMessage()
            if msg.startswith("Finished XLA compilation of "):
                name, _, rest = msg[len("Finished XLA compilation of "):].rpartition(" in ")
                programs.write(f"{rest.split()[0]}\t{name}\t{current[0]}\n")

    log = logging.getLogger("jax._src.dispatch")
    log.addHandler(Programs())
    log.setLevel(logging.DEBUG)

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_protocol(item, nextitem):
        start, before = time.time(), compiled[0]
        current[0] = item.nodeid
        yield
        with open(out, "a") as f:
            f.write(f"{start:.3f}\t{time.time():.3f}\t{compiled[0] - before:.3f}\t{item.nodeid}\n")

    def session_finish():  # what follows the last test: fixtures' teardown, the exit
        with open(Path(folder) / f"{worker}.events.tsv", "a") as f:
            f.write(f"{time.time():.3f}\tsessionfinish\n")
        def at_exit():
            import faulthandler

            with open(Path(folder) / f"{worker}.events.tsv", "a") as f:
                f.write(f"{time.time():.3f}\texit\n")
            # a process still alive 2 s later: where it waits (xdist's controller waits up to 10 s for it)
            stacks = open(Path(folder) / f"{worker}.exit-stacks.txt", "w")
            faulthandler.dump_traceback_later(2.0, file=stacks)

        atexit.register(at_exit)

    def pytest_testnodedown(node, error):  # the controller: a worker is gone
        with open(Path(folder) / f"{worker}.events.tsv", "a") as f:
            f.write(f"{time.time():.3f}\tnodedown {node.gateway.id}\n")

    globals()["pytest_runtest_protocol"] = pytest_runtest_protocol
    _AT_SESSION_FINISH.append(session_finish)
    if worker == "main":
        globals()["pytest_testnodedown"] = pytest_testnodedown


_timeline()


def pytest_collection_modifyitems(config, items):
    """The slowest test files first (tests/timeline_order.py: the workers of
    ``make test`` take whole files in this order)."""
    from timeline_order import listed

    rank = listed()
    last = len(rank)
    items.sort(key=lambda item: rank.get(item.nodeid.split("::")[0], last))  # stable: the rest keep their order
