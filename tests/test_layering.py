"""Dependencies flow one way: learned_imu (torch) <- factors (gtsam + numpy) <- fusion."""

import subprocess
import sys


def _modules_after_import(module: str) -> set[str]:
    code = f"import sys, {module}; print(' '.join(sorted(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout
    return set(out.split())


def test_factors_never_imports_torch():
    assert "torch" not in _modules_after_import("factors")


def test_learned_imu_never_imports_gtsam_or_rerun():
    mods = _modules_after_import("learned_imu")
    assert "gtsam" not in mods and "rerun" not in mods
