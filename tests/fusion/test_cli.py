"""The ``airimu`` console script: ``--help`` is instant (no heavy import), and commands run for real."""

from __future__ import annotations

import subprocess
import sys


def test_help_lists_commands_without_importing_torch_gtsam_or_rerun():
    code = (
        "import sys\n"
        "from fusion.cli import app\n"
        "from typer.testing import CliRunner\n"
        "result = CliRunner().invoke(app, ['--help'])\n"
        "assert result.exit_code == 0, result.output\n"
        "print(result.output)\n"
        "print('HEAVY:', sorted(m for m in ('torch', 'gtsam', 'rerun') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout
    assert "demo" in out
    assert "HEAVY: []" in out
