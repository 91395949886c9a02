"""The ``airimu`` console script: ``--help`` is instant (no heavy import), and commands run for real."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest


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


def test_demo_runs_through_the_console_script():
    script = Path(sys.executable).with_name("airimu")
    env = {**os.environ, "COLUMNS": "200"}  # no line wrapping by rich
    run = subprocess.run([str(script), "demo", "--duration", "6"], check=True, capture_output=True, text=True, env=env)
    out = run.stdout
    assert "windows of 1 s preintegrated with covariance" in out
    ratio = float(out.split("PreintegratedImuMeasurements (first window): ")[1].split()[0])
    assert ratio < 0.01  # our covariance equals GTSAM's within 1 %


def test_evaluate_writes_the_issue_keys(shared_data, tmp_path):
    from typer.testing import CliRunner

    from fusion.cli import app

    out = tmp_path / "metrics.json"
    seq = shared_data / "euroc" / "V1_02_medium"
    args = [
        "evaluate",
        "--dataset",
        "euroc",
        "--path",
        str(seq),
        "--imu-file",
        "mav0/imu0/data_partial_first40s.csv",
        "--interval",
        "10",
        "--interval-unit",
        "frames",
        "--json",
        str(out),
    ]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    data = json.loads(out.read_text())
    assert {"roe_deg", "rpe_m", "r_rmse_deg", "p_rmse_m", "ate_m", "interval_s", "n_windows"} <= set(data)
    assert data["interval_s"] == pytest.approx(0.05, abs=1e-4) and data["n_windows"] == 779
