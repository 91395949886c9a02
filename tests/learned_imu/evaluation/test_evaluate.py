"""evaluate(): exact on a perfect IMU, sensitive to a known bias, the paper's baseline on real EuRoC data."""

from __future__ import annotations

import numpy as np
import pytest

from learned_imu.datasets import read_sequence
from learned_imu.datasets.simulator import simulate_with_truth
from learned_imu.evaluation.evaluate import evaluate


@pytest.fixture(scope="module")
def sim():
    return simulate_with_truth("drone", duration_s=20.0, rate_hz=200.0, seed=0)


def test_perfect_imu_scores_zero(sim):
    result = evaluate(sim.sequence, 1.0, gyro=sim.clean_gyro, acc=sim.clean_acc)
    assert result.n_windows == 19  # 4000 samples, windows of 200 ending at state <= 3999
    assert (
        result.roe_deg < 1e-9 and result.rpe_m < 1e-9 and result.rpe_rmse_m < 1e-9 and result.pos_rmse_states_m < 1e-9
    )
    assert result.ate_m < 1e-7 and result.ate_aligned_m < 1e-7


def test_constant_gyro_bias_gives_bias_times_interval(sim):
    bias = np.radians([0.5, -0.3, 0.2])  # rad/s
    for interval in (0.5, 2.0):
        result = evaluate(sim.sequence, interval, gyro=sim.clean_gyro + bias, acc=sim.clean_acc)
        expected = np.degrees(np.linalg.norm(bias)) * interval  # a constant rate error integrates linearly
        assert result.roe_deg == pytest.approx(expected, rel=0.02)


def test_frames_and_seconds_agree(sim):
    by_seconds = evaluate(sim.sequence, 0.25, "s")
    by_frames = evaluate(sim.sequence, 50, "frames")
    assert by_seconds.interval_frames == 50
    assert by_seconds.to_json_dict() == by_frames.to_json_dict()
    assert set(by_frames.to_json_dict()) >= {
        "roe_deg",
        "roe_rmse_deg",
        "rpe_m",
        "rpe_rmse_m",
        "rot_rmse_states_deg",
        "ate_m",
        "interval_s",
        "n_windows",
    }


def test_invalid_ground_truth_windows_are_skipped(sim):
    seq = sim.sequence
    valid = seq.gt.valid.copy()
    valid[1000:1100] = False
    holed = type(seq)(**{**seq.__dict__, "gt": type(seq.gt)(seq.gt.rot, seq.gt.pos, seq.gt.vel, valid)})
    # states 1000..1099 end window [800, 1000] and fall inside window [1000, 1200]
    assert evaluate(holed, 1.0).n_windows == evaluate(seq, 1.0).n_windows - 2


@pytest.mark.parametrize(
    ("interval", "unit", "message"),
    [(100.0, "s", "does not fit"), (0.0, "s", "positive"), (1.0, "minutes", "interval unit")],
)
def test_bad_interval_raises(sim, interval, unit, message):
    with pytest.raises(ValueError, match=message):
        evaluate(sim.sequence, interval, unit)


def test_sequence_without_ground_truth_raises(sim):
    seq = sim.sequence
    no_gt = type(seq)(**{**seq.__dict__, "gt": None})
    with pytest.raises(ValueError, match="needs ground truth"):
        evaluate(no_gt, 1.0)


@pytest.mark.parametrize(
    ("folder", "options", "windows"),
    [("MH_01_easy", {}, 181), ("V1_02_medium", {"imu_file": "mav0/imu0/data_partial_first40s.csv"}, 38)],
)
def test_raw_euroc_roe_matches_the_papers_baseline(shared_data, folder, options, windows):
    """Raw EuRoC IMU drifts about 4.5 deg per second in orientation (AirIMU's Baseline; gyro bias)."""
    seq = read_sequence("euroc", shared_data / "euroc" / folder, **options)
    result = evaluate(seq, 1.0)
    assert result.n_windows == windows
    assert 3.5 < result.roe_deg < 5.5
    assert 0.05 < result.rpe_m < 0.5
