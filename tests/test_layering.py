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
