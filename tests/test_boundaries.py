"""Layering rules that keep the seams cheap to change."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PRODUCT = ("jaxrecog", "kernels", "hardware", "scripts", "benchmarks")


def _imports(path: Path):
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            yield node


def test_nothing_imports_another_modules_private_names():
    """``from m import _name`` reaches into m; a private *module* (``from . import
    _engine``, ``from ._grid import lse``) is fine, it is its package's own."""
    found = []
    for folder in PRODUCT:
        for path in (ROOT / folder).rglob("*.py"):
            for node in _imports(path):
                for alias in node.names:
                    if alias.name.startswith("_") and not alias.name.startswith("__"):
                        if node.module is None:  # from . import _private_module
                            continue
                        found.append(f"{path.relative_to(ROOT)}: from {node.module} import {alias.name}")
    assert not found, "\n".join(found)


def test_kernels_import_nothing_from_jaxrecog_or_hardware():
    for path in (ROOT / "kernels").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.ImportFrom):
                names = [node.module or ""] if node.level == 0 else []
                assert node.level <= 1, f"{path.name}: relative import leaves the kernels package"
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            for n in names:
                assert not n.startswith("jaxrecog"), f"{path.name} imports {n}"


# ---- layers and import cycles (a core that stands alone) -------------------------------------
#
# The import graph of the jaxrecog.* modules, read from the source: every import
# statement that can run (module level and inside functions; not the ones under
# ``if TYPE_CHECKING:``), resolved to the jaxrecog modules it names.  Layers
# (docs/architecture.md, "Layers"):
#   kernels  (kernels/)         imports nothing else of jaxrecog;
#   core     (jaxrecog/*.py)    kernels; of hardware only the rig interface
#                               (hardware/rigs/rig.py) at module level, the rest inside
#                               functions; never campaigns, cli or envs;
#   campaigns (jaxrecog/campaigns/) core, kernels; hardware as the core may;
#                               never cli or envs;
#   hardware (hardware/)        of the rest only the leaf modules LEAVES; its
#                               subpackages import one another along HARDWARE_AREAS;
#   envs     (jaxrecog/envs/)   core, campaigns, kernels, hardware; never cli;
#   cli      (jaxrecog/cli/)    anything; nothing imports it.

PACKAGE_DIRS = {"jaxrecog": ROOT / "jaxrecog", "jaxrecog.kernels": ROOT / "kernels", "jaxrecog.hardware": ROOT / "hardware"}
LEAVES = {"jaxrecog.problems", "jaxrecog.dbformat", "jaxrecog._files", "jaxrecog.kernels.config_grid"}
HEAVY = ("cv2", "serial", "pybullet", "matplotlib", "ray", "rerun")


def _modules() -> dict[str, Path]:
    out = {}
    for package, folder in PACKAGE_DIRS.items():
        for path in folder.rglob("*.py"):
            parts = list(path.relative_to(folder).with_suffix("").parts)
            if package == "jaxrecog" and parts[0] in ("kernels", "hardware"):  # not installed from there
                continue
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join([package, *parts])] = path
    return out


def _is_type_checking(test) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _import_nodes(body, top: bool = True):
    """(node, at_module_level) for every import that can run: class bodies and
    compound statements count as module level, function bodies do not; an
    ``if TYPE_CHECKING:`` block never runs."""
    for node in body:
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node, top
        elif isinstance(node, ast.If) and _is_type_checking(node.test):
            yield from _import_nodes(node.orelse, top)
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            yield from _import_nodes(node.body, False)
        else:
            for child in ast.iter_child_nodes(node):
                if isinstance(child, ast.stmt):
                    yield from _import_nodes([child], top)
                elif isinstance(child, (ast.ExceptHandler, ast.match_case)):
                    yield from _import_nodes(child.body, top)


def _imports_of(name: str, path: Path, modules) -> list[tuple[str, bool]]:
    """(jaxrecog module named, at module level) for each import of module ``name``."""
    out = []
    for node, top in _import_nodes(ast.parse(path.read_text(), str(path)).body):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        else:
            if node.level:
                base = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
                base = base[:len(base) - (node.level - 1)]
                full = ".".join(base + ([node.module] if node.module else []))
            else:
                full = node.module or ""
            targets = [f"{full}.{a.name}" if f"{full}.{a.name}" in modules else full for a in node.names]
        out += [(t, top) for t in targets if t in modules and t != name]
    return out


def _graph(module_level_only: bool) -> dict[str, set[str]]:
    modules = _modules()
    return {name: {t for t, top in _imports_of(name, path, modules) if top or not module_level_only}
            for name, path in modules.items()}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """One cycle per strongly connected component of more than one module (or a self-import)."""
    index, low, stack, on, found, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1 or v in graph[v]:
                found.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def _layer(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in ("kernels", "hardware", "cli", "envs", "campaigns") else "core"


def test_the_import_graph_is_complete_enough_to_trust():
    graph = _graph(module_level_only=False)
    assert len(graph) > 80
    assert "jaxrecog.kernels.config_grid" in graph["jaxrecog.recognizer"]
    assert "jaxrecog.hardware.rigs.rig" in graph["jaxrecog.driver"]
    assert "jaxrecog.hardware.rigs.rig_pool" in graph["jaxrecog.driver"]  # inside run_trials
    assert "jaxrecog.hardware.rigs.rig_pool" not in _graph(module_level_only=True)["jaxrecog.driver"]
    assert _layer("jaxrecog.campaigns.naming") == "campaigns" and "jaxrecog.campaigns.settings" in graph["jaxrecog.campaigns.naming"]
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


@pytest.mark.parametrize("module_level_only", [True, False], ids=["module-level", "with-deferred"])
def test_no_import_cycles(module_level_only):
    """No cycle among the jaxrecog modules: neither in the imports that run when a
    module is imported nor counting the ones deferred into functions (a deferred
    import that closes a cycle only hides it)."""
    assert _cycles(_graph(module_level_only)) == []


def test_layers_import_only_what_they_may():
    bad = []
    for module, imports in _imports_by_module().items():
        here = _layer(module)
        for target, top in imports:
            there = _layer(target)
            if here == there:
                continue
            if here == "kernels":
                bad.append(f"{module} -> {target} (kernels import nothing else of jaxrecog)")
            elif here == "core" and there in ("cli", "envs", "campaigns"):
                bad.append(f"{module} -> {target} (the core never imports the {there} layer)")
            elif here == "campaigns" and there in ("cli", "envs"):
                bad.append(f"{module} -> {target} (the campaigns never import the {there} layer)")
            elif (here in ("core", "campaigns") and there == "hardware" and top
                  and target not in ("jaxrecog.hardware.rigs.rig",)):
                bad.append(f"{module} -> {target} (at module level the {here} imports only hardware.rigs.rig)")
            elif here == "hardware" and target not in LEAVES:
                bad.append(f"{module} -> {target} (hardware imports only the leaf modules {sorted(LEAVES)})")
            elif here == "envs" and there == "cli":
                bad.append(f"{module} -> {target} (envs never import the CLI)")
    assert bad == [], "\n".join(bad)


def _imports_by_module():
    modules = _modules()
    return {name: _imports_of(name, path, modules) for name, path in modules.items()}


def test_the_leaf_modules_stay_leaves():
    imports = _imports_by_module()
    assert {t for t, _ in imports["jaxrecog.problems"]} == set()
    # the file rules (outputs, bounded text reads) and the image-header reader are leaves too
    assert {t for t, _ in imports["jaxrecog._files"]} <= {"jaxrecog.problems"}
    assert {t for t, _ in imports["jaxrecog._imagesize"]} == set()
    assert {t for t, _ in imports["jaxrecog.dbformat"]} <= {"jaxrecog.problems", "jaxrecog._files",
                                                            "jaxrecog._imagesize"}
    assert {t for t, _ in imports["jaxrecog.kernels.config_grid"]} == set()
    tree = ast.parse((ROOT / "kernels" / "config_grid.py").read_text())
    roots = {a.name.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    roots |= {n.module.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.level == 0}
    assert roots <= {"__future__", "math", "numbers", "numpy", "jax"}, roots


@pytest.mark.parametrize("module", ["jaxrecog", "jaxrecog.kernels"])
def test_importing_the_core_loads_no_device_renderer_or_plotting_library(module):
    """``from jaxrecog import *`` (every public name; ``import jaxrecog`` alone
    imports them on first use) and ``jaxrecog.kernels`` load none of OpenCV,
    pyserial, pybullet, matplotlib, and of the hardware package only the rig
    interface."""
    code = ("import sys, json; from {m} import *; "
            "print(json.dumps(sorted(k for k in sys.modules if k.split('.')[0] in {heavy!r} "
            "or k.startswith('jaxrecog.hardware.'))))").format(m=module, heavy=HEAVY)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    loaded, interface = json.loads(out.stdout.splitlines()[-1]), ["jaxrecog.hardware.rigs", "jaxrecog.hardware.rigs.rig"]
    assert loaded == interface if module == "jaxrecog" else set(loaded) <= set(interface), loaded


def test_hardware_names_resolve_lazily_from_their_modules():
    import importlib

    import jaxrecog.hardware as H

    assert len(H.__all__) > 60 and set(H.__all__) <= set(dir(H))
    for name in H.__all__:
        value = getattr(H, name)
        home = getattr(value, "__module__", None)
        if home is not None and home.startswith("jaxrecog."):
            assert getattr(importlib.import_module(home), name) is value, name
    from jaxrecog.hardware import Capture, RigPool, SyntheticRig
    from jaxrecog.hardware.rigs.rig_pool import RigPool as pool_protocol

    assert Capture is H.rigs.rig.Capture and RigPool is pool_protocol
    assert SyntheticRig is H.render.synthetic.SyntheticRig
    with pytest.raises(AttributeError, match="has no attribute 'NoSuchRig'"):
        H.NoSuchRig  # noqa: B018


# which hardware subpackage may import which (docs/architecture.md, "Layers"): a DAG,
# so each area can be read and tested with only the areas below it
HARDWARE_AREAS = {
    "rigs": set(),  # the Rig interface, pools, the dataset rig
    "geometry": set(),  # kinematics, carriers, the configuration table, travel times
    "devices": set(),  # pan-tilt drivers, cameras, controller datagrams and link
    "sim": {"devices", "geometry"},  # device simulators
    "render": {"geometry", "rigs"},  # the synthetic rig and rendered databases
    "physical": {"rigs", "geometry", "devices", "sim", "render"},  # the rig file, HardwareRig
}


def _area(module: str) -> str | None:
    parts = module.split(".")
    return parts[2] if len(parts) > 3 and parts[1] == "hardware" else None


def test_hardware_subpackages_import_along_their_dag():
    areas = {_area(m) for m in _modules()} - {None}
    assert areas == set(HARDWARE_AREAS), "every hardware module lives in one of the areas"
    assert not [p for p in (ROOT / "hardware").glob("*.py") if p.name != "__init__.py"], "no module outside an area"
    bad = []
    for module, imports in _imports_by_module().items():
        here = _area(module)
        for target, _ in imports:
            there = _area(target)
            if here is not None and there is not None and there != here and there not in HARDWARE_AREAS[here]:
                bad.append(f"{module} -> {target} ({here} may import only {sorted(HARDWARE_AREAS[here])})")
    assert bad == [], "\n".join(bad)


def test_every_subpackage_is_installed():
    """pyproject.toml lists every package folder (a missing one installs without it)."""
    import tomllib

    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = set()
    for package, folder in PACKAGE_DIRS.items():
        for init in folder.rglob("__init__.py"):
            parts = init.parent.relative_to(folder).parts
            if package == "jaxrecog" and parts[:1] in (("kernels",), ("hardware",)):
                continue
            found.add(".".join([package, *parts]))
    assert found == listed


def test_no_module_is_over_600_lines():
    """docs/style.md: one concept per file, none over 600 lines (ptu.py once
    was 650, experiments.py 929), in the package, its kernels and its hardware."""
    long = {str(p.relative_to(ROOT)): n for folder in ("jaxrecog", "kernels", "hardware")
            for p in (ROOT / folder).rglob("*.py") if (n := len(p.read_text().splitlines())) > 600}
    assert long == {}
