"""Dependencies flow one way: learned_imu (torch) <- factors (gtsam + numpy) <- fusion (both; the only place that
imports rerun, in fusion.recording). Checked twice: every submodule's import statements, function-level (lazy)
imports included, read with ``ast``; and what importing every submodule of a package actually loads."""

from __future__ import annotations

import ast
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
# package -> top-level modules its code must never import (at module level or inside a function)
FORBIDDEN = {
    "learned_imu": {"gtsam", "rerun", "factors", "fusion", "matplotlib"},
    "factors": {"torch", "rerun", "learned_imu", "fusion", "matplotlib"},
    "fusion": set(),
}
RERUN_HOME = "fusion.recording"  # the one module that imports rerun


def submodules(package: str) -> list[str]:
    found = [package]
    for info in pkgutil.walk_packages([str(REPO / package)], prefix=f"{package}."):
        found.append(info.name)
    return found


def imported_roots(module: str) -> set[str]:
    path = REPO / Path(*module.split("."))
    source = (path / "__init__.py") if path.is_dir() else path.with_suffix(".py")
    roots = set()
    for node in ast.walk(ast.parse(source.read_text(), str(source))):
        if isinstance(node, ast.Import):
            roots |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            roots.add(node.module.split(".")[0])
    return roots


ALL = [m for package in FORBIDDEN for m in submodules(package)]


def test_every_submodule_is_walked():
    expected = {"learned_imu.datasets.csv", "factors.imu", "fusion.recording", "learned_imu.geometry.preintegration"}
    assert expected <= set(ALL)


@pytest.mark.parametrize("module", ALL)
def test_imports_flow_one_way(module):
    roots = imported_roots(module)
    bad = roots & FORBIDDEN[module.split(".")[0]]
    assert not bad, f"{module} imports {sorted(bad)}"
    if "rerun" in roots:
        assert module == RERUN_HOME, f"{module} imports rerun; recordings live in {RERUN_HOME}"


def _loaded_after_importing(package: str) -> set[str]:
    names = [m for m in submodules(package) if not m.endswith("__main__")]
    code = f"import importlib, sys\nfor m in {names!r}: importlib.import_module(m)\nprint(' '.join(sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True, cwd=REPO).stdout
    return {name.split(".")[0] for name in out.split()}


def test_importing_all_of_factors_never_loads_torch():
    assert not {"torch", "rerun"} & _loaded_after_importing("factors")


def test_importing_all_of_learned_imu_never_loads_gtsam_or_rerun():
    assert not {"gtsam", "rerun"} & _loaded_after_importing("learned_imu")


def imported_modules(module: str, known: set[str]) -> set[str]:
    """Our modules that ``module`` imports anywhere (module level, in functions, under TYPE_CHECKING), each
    ``from a.b import c`` counted as a.b.c when that is a module of ours, else a.b."""
    path = REPO / Path(*module.split("."))
    source = (path / "__init__.py") if path.is_dir() else path.with_suffix(".py")
    found = set()
    for node in ast.walk(ast.parse(source.read_text(), str(source))):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names if alias.name in known}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module in known:
            subs = {f"{node.module}.{alias.name}" for alias in node.names} & known
            found |= subs or {node.module}
    return found - {module}


def test_no_module_imports_itself_round_a_circle():
    """The import graph of learned_imu, factors and fusion (packages' __init__ re-exports aside) has no cycle."""
    modules = set(ALL)
    graph = {m: {d for d in imported_modules(m, modules) if d not in FORBIDDEN} for m in ALL if m not in FORBIDDEN}
    state, cycles = {}, []

    def visit(node, stack):
        state[node] = "open"
        for target in sorted(graph.get(node, ())):
            if state.get(target) == "open":
                cycles.append(stack[stack.index(target) :] + [target])
            elif target not in state:
                visit(target, [*stack, target])
        state[node] = "done"

    for module in sorted(graph):
        if module not in state:
            visit(module, [module])
    assert not cycles, "import cycles: " + "; ".join(" -> ".join(c) for c in cycles)


def test_the_user_facing_fuse_does_not_import_the_ablation():
    """``airimu fuse`` (``fusion.fuse``) and what it imports stand without ``fusion.pgo`` (the PGO ablation)."""
    modules = set(ALL)
    seen, todo = set(), ["fusion.fuse"]
    while todo:
        module = todo.pop()
        if module not in seen:
            seen.add(module)
            todo.extend(imported_modules(module, modules) - set(FORBIDDEN))
    assert "fusion.pgo" not in seen and "learned_imu.training.experiment" not in seen, sorted(seen)
