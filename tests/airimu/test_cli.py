"""The ``airimu`` console script: ``--help`` is instant (no heavy import), and commands run for real."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch


def test_help_lists_commands_without_importing_torch_gtsam_or_rerun():
    code = (
        "import sys\n"
        "from airimu.cli import app\n"
        "from typer.testing import CliRunner\n"
        "result = CliRunner().invoke(app, ['--help'])\n"
        "assert result.exit_code == 0, result.output\n"
        "print(result.output)\n"
        "print('HEAVY:', sorted(m for m in ('torch', 'gtsam', 'rerun') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout
    assert "demo" in out
    assert "HEAVY: []" in out


@pytest.mark.slow
def test_demo_runs_through_the_console_script(tmp_path):
    script = Path(sys.executable).with_name("airimu")
    env = {**os.environ, "COLUMNS": "200"}  # no line wrapping by rich
    args = [str(script), "demo", "--out", str(tmp_path / "demo"), "--seeds", "1", "--epochs", "1", "--no-progress"]
    out = subprocess.run(args, check=True, capture_output=True, text=True, env=env, cwd=tmp_path).stdout
    assert "AirIMU + learned cov" in out and "GPS 0.1 Hz" in out
    for name in ("ablation.json", "ablation.csv", "demo.rrd", "demo.png"):
        assert f"written: {tmp_path / 'demo' / name}" in out.replace("\n", ""), name
        assert (tmp_path / "demo" / name).stat().st_size > 0
    rows = json.loads((tmp_path / "demo" / "ablation.json").read_text())
    assert len(rows) == 8 and {r["gps_hz"] for r in rows} == {1.0, 0.1}


def test_evaluate_writes_the_issue_keys(shared_data, tmp_path):
    from typer.testing import CliRunner

    from airimu.cli import app

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
    assert {"roe_deg", "roe_rmse_deg", "rpe_m", "rpe_rmse_m", "ate_m", "interval_s", "n_windows"} <= set(data)
    assert data["interval_s"] == pytest.approx(0.05, abs=1e-4) and data["n_windows"] == 779


TINY_YAML = """
name: tiny
data:
  train: [{dataset: simulator, options: {duration_s: 12.0, seed: 1, device_seed: 5}}]
  val: [{dataset: simulator, options: {duration_s: 6.0, seed: 2, device_seed: 5}}]
model: {conv_channels: [8, 16], gru_sizes: [16], decoder_hidden: 16}
train: {window: 200, every: 50, batch_size: 4, epochs: 2, lr: 3e-3}
"""


@pytest.mark.slow
def test_train_then_evaluate_and_export_with_the_checkpoint(shared_data, tmp_path):
    from typer.testing import CliRunner

    from airimu.cli import app
    from airimu_core.export import load_export
    from learned_imu.datasets import read_sequence
    from learned_imu.evaluation.evaluate import evaluate
    from learned_imu.network.checkpoint import load_checkpoint, model_from_checkpoint
    from learned_imu.network.inference import correct

    config = tmp_path / "tiny.yaml"
    config.write_text(TINY_YAML)
    run = tmp_path / "run"
    result = CliRunner().invoke(app, ["train", "--config", str(config), "--out", str(run), "--no-progress"])
    assert result.exit_code == 0, result.output
    assert "run folder" in result.output and len((run / "metrics.jsonl").read_text().splitlines()) == 2

    seq_path, imu_file = shared_data / "euroc" / "V1_02_medium", "mav0/imu0/data_partial_first40s.csv"
    where = ["--dataset", "euroc", "--path", str(seq_path), "--imu-file", imu_file]
    where += ["--checkpoint", str(run / "best.pt")]
    metrics = tmp_path / "m.json"
    result = CliRunner().invoke(app, ["evaluate", *where, "--json", str(metrics)])
    assert result.exit_code == 0, result.output
    sequence = read_sequence("euroc", seq_path, imu_file=imu_file)
    model, _ = model_from_checkpoint(run / "best.pt")
    corrected = correct(model, sequence)
    expected = evaluate(sequence, 1.0, gyro=corrected.gyro.numpy(), acc=corrected.acc.numpy())
    assert json.loads(metrics.read_text())["roe_deg"] == pytest.approx(expected.roe_deg, rel=1e-12)

    npz = tmp_path / "v102.npz"
    result = CliRunner().invoke(app, ["export", *where, "--keyframes", "0.5s", "--out", str(npz)])
    assert result.exit_code == 0, result.output
    export = load_export(npz)
    np.testing.assert_allclose(export.gyro, corrected.gyro.numpy())
    np.testing.assert_allclose(export.gyro_cov, corrected.gyro_cov.numpy())
    assert export.keyframe_index[1] == 100  # 0.5 s at 200 Hz

    times = tmp_path / "times.txt"
    times.write_text("# keyframe times, s\n" + "\n".join(str(t) for t in sequence.t[[0, 250, 900]]))
    result = CliRunner().invoke(app, ["export", *where, "--keyframes", str(times), "--out", str(npz)])
    assert result.exit_code == 0, result.output
    assert load_export(npz).keyframe_index.tolist() == [0, 250, 900]

    # scale the noise on a held-out sequence: densities scaled exactly, scales kept; a second pass on the same
    # sequence finds nothing left to scale (the fit is at its optimum) and keeps the product
    held_out = ["--dataset", "euroc", "--path", str(seq_path), "--imu-file", imu_file]
    scaled, stored = tmp_path / "scaled.pt", []
    for source in (run / "best.pt", scaled):
        result = CliRunner().invoke(app, ["scale-noise", "--checkpoint", str(source), *held_out, "--out", str(scaled)])
        assert result.exit_code == 0, result.output
        assert "noise scaled by" in result.output and "NSE rot/pos/vel" in result.output
        stored.append(load_checkpoint(scaled).best.noise_scales)
    assert stored[1] == pytest.approx(stored[0], rel=1e-3) and stored[0] != pytest.approx([1.0, 1.0], rel=1e-3)
    first, _ = model_from_checkpoint(run / "best.pt")
    twice, _ = model_from_checkpoint(scaled)
    gyro, acc = (torch.as_tensor(x[None, :900], dtype=torch.float32) for x in (sequence.gyro, sequence.acc))
    with torch.no_grad():
        a, b = first(gyro, acc), twice(gyro, acc)
    assert torch.allclose(b.gyro_cov, stored[1][0] * a.gyro_cov, rtol=1e-4)
    assert torch.allclose(b.acc_cov, stored[1][1] * a.acc_cov, rtol=1e-4)
    assert torch.equal(b.gyro, a.gyro)

    bad = tmp_path / "bad.yaml"
    bad.write_text(TINY_YAML + "extra_key: 1\n")
    result = CliRunner().invoke(app, ["train", "--config", str(bad), "--out", str(tmp_path / "r2")])
    assert result.exit_code != 0 and "unknown key 'extra_key'" in str(result.exception)
