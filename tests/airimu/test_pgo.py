"""The PGO ablation end to end on the simulator (tiny model), and the Rerun recording read back."""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

TINY = """
name: tiny
data:
  train: [{dataset: simulator, options: {duration_s: 12.0, seed: 1, device_seed: 5}}]
  val: [{dataset: simulator, options: {duration_s: 8.0, seed: 2, device_seed: 5}}]
model: {conv_channels: [8, 16], gru_sizes: [16], decoder_hidden: 16}
train: {window: 200, every: 50, batch_size: 4, epochs: 2, lr: 3e-3, calibration_steps: 10}
"""


@pytest.fixture(scope="module")
def ablation(tmp_path_factory):
    from typer.testing import CliRunner

    from airimu.cli import app

    tmp = tmp_path_factory.mktemp("pgo")
    (tmp / "tiny.yaml").write_text(TINY)
    (tmp / "pgo.yaml").write_text(
        f"name: tiny_pgo\nexperiment: tiny.yaml\nrun: {tmp / 'run'}\n"
        "options: {gps_hz: [1.0, 0.25], seeds: 2, keyframe_interval_s: 0.2}\n"
    )
    files = {k: tmp / f"out.{k}" for k in ("json", "csv", "rrd", "png")}
    args = ["ablate-pgo", "--config", str(tmp / "pgo.yaml"), "--out", str(tmp / "out"), "--no-progress"]
    args += [a for k, p in files.items() for a in (f"--{k}", str(p))]
    result = CliRunner().invoke(app, args, env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output
    return result.output, files


@pytest.mark.slow
def test_table_rows_and_files(ablation):
    output, files = ablation
    rows = json.loads(files["json"].read_text())
    first = [(r["setting"], r["gps_hz"]) for r in rows][:2]
    assert first == [("raw IMU + fixed cov", 1.0), ("raw IMU + fixed cov", 0.25)]
    keys = {
        "setting",
        "gps_hz",
        "sequence",
        "ate_mean_m",
        "ate_std_m",
        "gps_chi2_per_dof",
        "imu_chi2_per_dof",
        "paper_ate_m",
    }
    assert len(rows) == 8 and all(set(r) == keys for r in rows)
    # every solve checked against its own noise model: the simulator's GPS sigma is the one fused, so the GPS
    # factors fit (of order 1, below it: the states absorb part of the residuals)
    assert all(0.05 < r["gps_chi2_per_dof"] < 3 for r in rows), [r["gps_chi2_per_dof"] for r in rows]
    assert all(r["imu_chi2_per_dof"] > 0 for r in rows)
    assert all(r["paper_ate_m"] is None for r in rows)  # a simulated sequence: the paper has no value for it
    by = {(r["setting"], r["gps_hz"]): r["ate_mean_m"] for r in rows}
    assert all(0 < v < 5 for v in by.values())
    assert by[("raw IMU + fixed cov", 1.0)] < by[("raw IMU + fixed cov", 0.25)]  # more GPS, less error
    assert "AirIMU + learned cov" in output and "+-" in output
    header = "setting,gps_hz,sequence,ate_mean_m,ate_std_m,gps_chi2_per_dof,imu_chi2_per_dof,paper_ate_m"
    assert files["csv"].read_text().splitlines()[0] == header
    assert files["png"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_recording_reads_back(ablation):
    from rerun.chunk import RrdReader

    _, files = ablation
    chunks = RrdReader(files["rrd"]).stream().to_chunks()
    rows = Counter()
    for chunk in chunks:
        rows[chunk.entity_path] += chunk.num_rows
    n = 8 * 200  # 8 s at 200 Hz
    k = 40  # keyframes every 0.2 s
    for entity in ("/imu/gyro", "/imu/acc", "/correction/gyro", "/sigma/acc"):
        assert rows[entity] == n + 1, entity  # x, y, z per sample, and the static series names and colours
    for entity in (
        "/world/ground_truth",
        "/world/dead_reckoning/raw_imu",
        "/world/dead_reckoning/airimu",
        "/world/gps",
    ):
        assert rows[entity] == 1, entity  # static: one strip / one point cloud
    assert rows["/world/fused/airimu_learned_cov/covariance"] == k + 1
    assert rows["/error/position/airimu_learned_cov"] == k + 1
    error = next(
        c for c in chunks if c.entity_path == "/error/position/raw_imu_fixed_cov" and c.num_rows == k
    ).to_record_batch()
    values = np.array(error.column("Scalars:scalars").to_pylist()).ravel()
    assert np.all(values >= 0) and np.all(values < 5)
    ellipsoids = next(c for c in chunks if c.entity_path == "/world/fused/airimu_learned_cov/covariance")
    half = np.array(ellipsoids.to_record_batch().column("Ellipsoids3D:half_sizes").to_pylist()).reshape(k, 3)
    assert np.all(half > 0) and np.all(half < 10)
    assert RrdReader(files["rrd"]).blueprints()  # the layout travels with the recording


def test_pgo_rows_of_the_papers_sequences_carry_its_ate():
    from airimu.experiments.pgo import PgoRow, paper_ate

    assert paper_ate(PgoRow("AirIMU + learned cov", 0.1, "V2_02_medium", 0.9, 0.1)) == 0.8927
    assert paper_ate(PgoRow("raw IMU + fixed cov", 1.0, "MH_04_difficult", 0.2, 0.0)) == 0.1491
    assert paper_ate(PgoRow("AirIMU + learned cov", 0.25, "MH_04_difficult", 0.2, 0.0)) is None


def test_ate_can_be_scored_between_the_first_and_last_fused_fix(tmp_path):
    from airimu.experiments.pgo import ate_m
    from airimu_core.sequence import GpsFixes
    from fusion.graph import Solution, Trajectory

    t = np.arange(0.0, 10.01, 0.5)
    pos = np.zeros((len(t), 3))
    pos[t > 8.0, 0] = 1.0  # the last two seconds dead-reckoned 1 m off
    traj = Trajectory(t, np.repeat(np.eye(3)[None], len(t), 0), pos, np.zeros((len(t), 3)))
    solution = Solution(traj, None, None, 0, 0.0)
    truth = GpsFixes(t, np.zeros((len(t), 3)), np.zeros((len(t), 3)))
    fused = GpsFixes(np.array([0.0, 4.0, 8.0]), np.zeros((3, 3)), np.full((3, 3), 0.1))
    assert ate_m(solution, truth) == pytest.approx(np.sqrt(4 / 21))  # 4 of 21 reference times 1 m off
    assert ate_m(solution, truth, fused) == 0.0
    bad = tmp_path / "pgo.yaml"
    bad.write_text("name: x\nexperiment: e.yaml\nrun: r\noptions: {score_span: everywhere}\n")
    from airimu.experiments.pgo_config import load_pgo_config
    from airimu_core.errors import ConfigError

    with pytest.raises(ConfigError, match=r"pgo\.yaml.*options.*score_span.: expected one of keyframes, gps"):
        load_pgo_config(bad)


def test_motion_rows_run_on_the_solution_attitude_and_beat_their_rows_between_sparse_fixes(tmp_path, monkeypatch):
    """The motion rows of run_sequence: each pass reads the previous solution (never the truth), and with 0.1 Hz
    fixes a good velocity factor (the truth's plus 0.05 m/s noise) beats the same row without it."""
    import torch

    import airimu.experiments.pgo as pgo
    from airimu.experiments.pgo_config import PgoOptions
    from airimu_core.motion import BodyVelocities
    from fusion.config import MotionSettings
    from learned_imu.datasets.simulator import ImuErrorModel, simulate
    from learned_imu.network.model import Correction

    seq = simulate("drone", duration_s=40.0, error_model=ImuErrorModel(2e-3, 2e-2, 0.0, 0.0, 2e-3, 5e-2), seed=5)
    ends = np.arange(8, len(seq.t), 9)
    body = np.einsum("nji,nj->ni", seq.gt.rot[ends], seq.gt.vel[ends])
    body = body + np.random.default_rng(0).normal(0.0, 0.05, body.shape)
    calls = []

    def velocities(result, motion, settings, solve_with=None):
        calls.append(result.solution.trajectory.rot)  # the solution it reads
        return BodyVelocities(result.sequence.t[ends], body, np.full_like(body, 0.05**2))

    monkeypatch.setattr(pgo, "motion_on", velocities)
    gyro, acc = torch.as_tensor(seq.gyro), torch.as_tensor(seq.acc)
    zero = torch.zeros_like(gyro)
    raw = Correction(gyro, acc, zero, zero, torch.full_like(gyro, 2e-3**2), torch.full_like(gyro, 2e-2**2))
    options = PgoOptions(gps_hz=(0.1,), seeds=1, keyframe_interval_s=0.2, fixed_gyro_noise_density=2e-3,
                         fixed_acc_noise_density=2e-2)  # fmt: skip
    rows, _ = pgo.run_sequence(seq, raw, tmp_path, options, motion=object(), motion_settings=MotionSettings(passes=2))
    ate = {row.setting: row.ate_mean_m for row in rows}
    assert set(ate) >= {"AirIMU + learned cov + motion", "raw IMU + fixed cov + motion"}
    assert len(calls) == 4  # two motion rows x two passes
    assert ate["raw IMU + fixed cov + motion"] < 0.2 * ate["raw IMU + fixed cov"], ate  # measured 0.23 m against 4.2 m


def test_a_pgo_run_may_name_a_shipped_model(tmp_path, monkeypatch):
    """PgoConfig.run: a shipped model's name (no folder of that name here) is used as it is, nothing trained; a
    folder is trained or resumed, as before."""
    import airimu.experiments.pgo as pgo
    from learned_imu.network.shipped import shipped_path

    trained = []
    monkeypatch.setattr(pgo, "train_run", lambda experiment, run, **_: trained.append(run))
    monkeypatch.chdir(tmp_path)
    assert pgo.correction_checkpoint("euroc", experiment=None) == shipped_path("euroc") and not trained
    (tmp_path / "euroc").mkdir()  # a run folder of that name wins
    assert pgo.correction_checkpoint("euroc", experiment=None) == Path("euroc") / "best.pt"
    assert pgo.correction_checkpoint("runs/mine", experiment=None) == Path("runs/mine") / "best.pt"
    assert trained == [Path("euroc"), Path("runs/mine")]
