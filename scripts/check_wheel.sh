#!/usr/bin/env bash
# Build the wheel, install it with the demo's extras (sim: pybullet renders the
# database; plot: matplotlib) into a fresh virtual environment outside the
# clone, and run the quick demo there: the package works without the sources.
# Minutes (the installs; pip's cache is reused), so not part of the test suite;
# tests/test_wheel.py checks the wheel's contents.
#
#   scripts/check_wheel.sh            # PYTHON=python3.12 scripts/check_wheel.sh for another interpreter
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
PYTHON="${PYTHON:-python3}"
WORK="$(mktemp -d "${TMPDIR:-/tmp}/jaxrecog-wheel.XXXXXX")"
trap 'rm -rf "$WORK"' EXIT
start=$(date +%s)

echo "== build (python -m build --wheel) into $WORK/dist"
# the build tool from the project's venv when it has one (the test extra), else this python's
BUILDER="$ROOT/.venv/bin/python"
[ -x "$BUILDER" ] || BUILDER="$PYTHON"
"$BUILDER" -m build --wheel --outdir "$WORK/dist" "$ROOT" >"$WORK/build.log" 2>&1 \
  || { tail -20 "$WORK/build.log"; exit 1; }
WHEEL="$(ls "$WORK"/dist/jaxrecog-*.whl)"
echo "   $(basename "$WHEEL") ($(du -k "$WHEEL" | cut -f1) KiB)"

echo "== fresh venv, pip install the wheel with [sim,plot]"
"$PYTHON" -m venv "$WORK/venv"
"$WORK/venv/bin/python" -m pip install --quiet --upgrade pip
"$WORK/venv/bin/python" -m pip install --quiet "$WHEEL[sim,plot]"

echo "== jaxrecog demo --quick (run outside the clone)"
cd "$WORK"
"$WORK/venv/bin/python" -c "import jaxrecog, sys; assert '$ROOT' not in jaxrecog.__file__, jaxrecog.__file__; print('   jaxrecog from', jaxrecog.__file__)"
"$WORK/venv/bin/jaxrecog" --quiet demo --quick --out "$WORK/demo"
echo "== wheel check passed in $(( $(date +%s) - start )) s"
