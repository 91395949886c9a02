"""The rooms and which way dependencies flow between them:

- ``airimu_core``: the numpy-only base (errors, atomic files, YAML configs, sequences, rotations, the export record);
- ``learned_imu``: torch (readers, simulator, preintegrator, network, training, evaluation, export);
- ``factors``: GTSAM factors (gtsam + numpy, never torch);
- ``fusion``: the estimator (graphs, online fusion, consistency, GPS units): gtsam + numpy; torch (and the network,
  through ``learned_imu``) only inside the functions that run a model, never on import; never rerun, the CLI or the
  ablations;
- ``airimu``: the application on top (CLI, the ``fuse`` runner, recordings and figures in ``viz``, the PGO
  ablation in ``experiments``); rerun only in ``airimu.viz.recording``.

Checked twice: every submodule's import statements read with ``ast`` (function-level imports included, and
separately the module-level ones), and what importing every submodule of a package actually loads."""

from __future__ import annotations

import ast
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
# package -> top-level modules its code must never import (at module level or inside a function)
APP = {"airimu", "typer", "rich", "rerun", "matplotlib"}  # the application and what only it uses
FORBIDDEN = {
    "airimu_core": {"torch", "gtsam", "learned_imu", "factors", "fusion", *APP},
    "learned_imu": {"gtsam", "factors", "fusion", *APP},
    "factors": {"torch", "learned_imu", "fusion", *APP},
    "fusion": set(APP),
    "airimu": set(),
}
# package -> what its modules may import inside a function but never at module level (importing them stays light)
LAZY_ONLY = {"fusion": {"torch", "learned_imu"}}
RERUN_HOME = "airimu.viz.recording"  # the one module that imports rerun


def submodules(package: str) -> list[str]:
    found = [package]
    for info in pkgutil.walk_packages([str(REPO / package)], prefix=f"{package}."):
        found.append(info.name)
    return found


def imported_roots(module: str, module_level: bool = False) -> set[str]:
    """The top-level names ``module`` imports: anywhere, or with ``module_level`` outside functions only."""
    path = REPO / Path(*module.split("."))
    source = (path / "__init__.py") if path.is_dir() else path.with_suffix(".py")
    roots = set()
    tree = ast.parse(source.read_text(), str(source))
    nodes = _outside_functions(tree) if module_level else ast.walk(tree)
    for node in nodes:
        if isinstance(node, ast.Import):
            roots |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            roots.add(node.module.split(".")[0])
    return roots


def _outside_functions(node):
    for child in ast.iter_child_nodes(node):
        if not isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda):
            yield child
            yield from _outside_functions(child)


ALL = [m for package in FORBIDDEN for m in submodules(package)]


def test_every_submodule_is_walked():
    expected = {
        "learned_imu.datasets.csv",
        "factors.imu",
        "airimu.viz.recording",
        "airimu_core.export",
        "fusion.online",
    }
    assert expected <= set(ALL)


@pytest.mark.parametrize("module", ALL)
def test_imports_flow_one_way(module):
    roots = imported_roots(module)
    bad = roots & FORBIDDEN[module.split(".")[0]]
    assert not bad, f"{module} imports {sorted(bad)}"
    if "rerun" in roots:
        assert module == RERUN_HOME, f"{module} imports rerun; recordings live in {RERUN_HOME}"
    eager = imported_roots(module, module_level=True) & LAZY_ONLY.get(module.split(".")[0], set())
    assert not eager, f"{module} imports {sorted(eager)} on import; only inside the functions that need them"


def _loaded_after_importing(package: str) -> set[str]:
    names = [m for m in submodules(package) if not m.endswith("__main__")]
    code = f"import importlib, sys\nfor m in {names!r}: importlib.import_module(m)\nprint(' '.join(sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True, cwd=REPO).stdout
    return {name.split(".")[0] for name in out.split()}


@pytest.mark.parametrize("package", ["airimu_core", "factors", "fusion"])
def test_importing_the_base_the_factors_or_the_estimator_never_loads_torch(package):
    """Every module of the numpy base, the factors and the estimator imports without torch (and without rerun)."""
    assert not {"torch", "rerun", "typer", "matplotlib"} & _loaded_after_importing(package)


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
    """``airimu fuse`` (``airimu.fuse``) and what it imports stand without the PGO ablation (``airimu.experiments``)."""
    modules = set(ALL)
    seen, todo = set(), ["airimu.fuse"]
    while todo:
        module = todo.pop()
        if module not in seen:
            seen.add(module)
            todo.extend(imported_modules(module, modules) - set(FORBIDDEN))
    assert not {m for m in seen if m.startswith("airimu.experiments")}, sorted(seen)
    assert "learned_imu.training.experiment" not in seen, sorted(seen)
