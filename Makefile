# Two entry points: `make demo` (the main job) and `make test` (the whole suite).
# Both build a local virtual environment on first use.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
OUTDIR ?= out/demo
# test workers: one per core, at most 4 (each holds its own JAX and session
# fixtures); `make test JOBS=0` runs the suite in this one process.  Each
# worker takes whole files, the slowest first (tests/timeline_order.py)
# what `make venv` installs: the test suite's tools and the extras it exercises
# (rendering, plots, the Gymnasium env, Ray); not rl's torch
EXTRAS ?= test,sim,plot
JOBS   ?= $(shell n=$$(nproc 2>/dev/null || echo 2); [ $$n -gt 4 ] && n=4; echo $$n)

.PHONY: demo test venv bench clean

# uv resolves and installs the same packages as pip in about a third of the
# time on a fresh machine (38 s against 102 s for these extras, cold caches);
# pip takes over where uv cannot run or reach the registry
$(STAMP): pyproject.toml
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet uv
	$(BIN)/python -m uv pip install --quiet --python $(BIN)/python -e '.[$(EXTRAS)]' || $(BIN)/python -m pip install --quiet -e '.[$(EXTRAS)]'
	@touch $(STAMP)

venv: $(STAMP)

demo: $(STAMP)
	$(BIN)/jaxrecog demo --out $(OUTDIR)

# one OpenBLAS thread per test process: two workers on two cores, each with two
# BLAS threads that spin while they wait, took 11-17 s longer (327.9 / 333.9 s
# against 316.5 s of pytest, load ~2)
test: $(STAMP)
	OPENBLAS_NUM_THREADS=1 $(BIN)/python -m pytest -q -n $(JOBS) --dist loadfile --no-loadscope-reorder $(PYTEST_ARGS)

bench: $(STAMP)
	$(BIN)/jaxrecog bench --out out/bench

clean:
	rm -rf $(VENV) out build *.egg-info
