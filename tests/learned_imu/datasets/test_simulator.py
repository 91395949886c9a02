"""The simulator: deterministic, consistent with the discrete integrator, noise as its grade says."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from learned_imu import NavState, predict, preintegrate
from learned_imu.datasets.simulator import GRADES, PROFILES, ImuErrorModel, simulate, simulate_with_truth


def test_same_seed_same_sequence_other_seed_differs():
    a, b, c = (simulate("drone", duration_s=5.0, seed=s) for s in (3, 3, 4))
    assert np.array_equal(a.gyro, b.gyro) and np.array_equal(a.gt.pos, b.gt.pos)
    assert not np.allclose(a.gyro, c.gyro)


@pytest.mark.parametrize("profile", PROFILES)
def test_clean_imu_integrates_exactly_onto_ground_truth(profile):
    sim = simulate_with_truth(profile, duration_s=10.0, seed=1)
    seq = sim.sequence
    f64 = torch.float64
    pre = preintegrate(torch.tensor(sim.clean_gyro), torch.tensor(sim.clean_acc), torch.tensor(seq.dt))
    start = NavState(**{k: torch.tensor(getattr(seq.gt, k)[0], dtype=f64) for k in ("rot", "vel", "pos")})
    end = predict(start, pre, torch.tensor(seq.gravity))
    # predict gives the state after each sample, ground truth the state before it
    assert np.abs(end.pos[:-1].numpy() - seq.gt.pos[1:]).max() < 1e-9
    assert np.abs(end.vel[:-1].numpy() - seq.gt.vel[1:]).max() < 1e-9
    assert np.abs(end.rot[:-1].numpy() - seq.gt.rot[1:]).max() < 1e-9


def test_profiles_have_their_character():
    speeds = {p: np.linalg.norm(simulate(p, duration_s=30.0).gt.vel, axis=1).mean() for p in PROFILES}
    rates = {p: np.linalg.norm(simulate_with_truth(p, duration_s=30.0).clean_gyro, axis=1).max() for p in PROFILES}
    assert speeds["car"] > 5 * speeds["drone"] > 5 * 0.2
    assert rates["handheld"] > rates["drone"] > rates["car"]
    sim = simulate("drone", duration_s=30.0)
    up = np.einsum("nij,nj->ni", sim.gt.rot, simulate_with_truth("drone", duration_s=30.0).clean_acc).mean(axis=0)
    assert up[2] == pytest.approx(9.81, abs=0.1)  # specific force is +g up on average


def only(**fields) -> ImuErrorModel:
    """An error model with every effect off except ``fields``."""
    return ImuErrorModel(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, **fields)


def test_white_noise_and_bias_match_the_grade():
    grade = ImuErrorModel.from_grade("industrial")
    model = replace(  # white noise and biases only: the other effects would leak into the residual
        grade, gyro_scale_misalignment=0.0, acc_scale_misalignment=0.0, gyro_g_sensitivity_rad_s_per_m_s2=0.0
    )
    sim = simulate_with_truth("drone", duration_s=200.0, rate_hz=200.0, error_model=model, seed=2)
    noise = sim.sequence.gyro - sim.clean_gyro - sim.gyro_bias
    expected = model.gyro_noise_density_rad_s_sqrthz * np.sqrt(200.0)
    assert noise.std(axis=0) == pytest.approx(np.full(3, expected), rel=0.02)
    acc_noise = sim.sequence.acc - sim.clean_acc - sim.acc_bias
    assert acc_noise.std(axis=0) == pytest.approx(
        np.full(3, model.acc_noise_density_m_s2_sqrthz * np.sqrt(200)), rel=0.02
    )
    # bias random walk: the increment over T seconds has std density * sqrt(T)
    lag = 200 * 10
    steps = (sim.gyro_bias[lag:] - sim.gyro_bias[:-lag])[::lag]
    assert steps.std() == pytest.approx(model.gyro_bias_rw_rad_s2_sqrthz * np.sqrt(10.0), rel=0.35)


def test_gps_fixes_rate_and_noise():
    seq = simulate("car", duration_s=100.0, gps_rate_hz=1.0, gps_sigma_m=0.5, seed=5)
    assert len(seq.gps.t) == 100 and np.allclose(np.diff(seq.gps.t), 1.0)
    idx = np.searchsorted(seq.t, seq.gps.t)
    assert (seq.gps.pos - seq.gt.pos[idx]).std() == pytest.approx(0.5, rel=0.15)


def test_grades_are_ordered_and_unknown_names_raise():
    order = ["consumer", "industrial", "tactical", "navigation"]
    densities = [GRADES[g].gyro_noise_density_rad_s_sqrthz for g in order]
    assert densities == sorted(densities, reverse=True)
    with pytest.raises(ValueError, match="known grades"):
        ImuErrorModel.from_grade("military")
    with pytest.raises(ValueError, match="known profiles"):
        simulate("boat")


def residual(fields: dict, duration_s: float = 60.0, seed: int = 7):
    sim = simulate_with_truth("handheld", duration_s=duration_s, error_model=only(**fields), seed=seed)
    return sim, sim.sequence.gyro - sim.clean_gyro, sim.sequence.acc - sim.clean_acc


def test_scale_misalignment_and_g_sensitivity_are_linear_in_the_true_signal():
    sim, gyro_err, acc_err = residual({"gyro_scale_misalignment": 1e-2, "acc_scale_misalignment": 1e-2})
    gyro_m, *_ = np.linalg.lstsq(sim.clean_gyro, sim.sequence.gyro, rcond=None)
    assert np.abs(sim.clean_gyro @ gyro_m - sim.sequence.gyro).max() < 1e-12  # exactly M @ clean
    assert 1e-3 < np.abs(gyro_m.T - np.eye(3)).max() < 0.05
    assert np.abs(acc_err).max() > 1e-2
    sim, gyro_err, _ = residual({"gyro_g_sensitivity_rad_s_per_m_s2": 1e-3})
    g_sens, *_ = np.linalg.lstsq(sim.clean_acc, gyro_err, rcond=None)
    assert np.abs(sim.clean_acc @ g_sens - gyro_err).max() < 1e-12 and np.abs(g_sens).max() > 1e-4


def test_bias_instability_is_a_stationary_gauss_markov_process():
    sim, gyro_err, _ = residual({"gyro_bias_instability_rad_s": 1e-3, "bias_correlation_time_s": 1.0}, 300.0)
    assert gyro_err.std() == pytest.approx(1e-3, rel=0.15)
    lag = 200  # one correlation time at 200 Hz
    corr = np.mean([np.corrcoef(gyro_err[:-lag, i], gyro_err[lag:, i])[0, 1] for i in range(3)])
    assert corr == pytest.approx(np.exp(-1.0), abs=0.1)


def test_temperature_drift_is_slow_and_bounded():
    sim, _, acc_err = residual({"acc_temperature_drift_m_s2": 0.05, "temperature_period_s": 60.0})
    assert np.abs(acc_err).max() == pytest.approx(0.05, rel=0.05)
    assert np.abs(np.diff(acc_err, axis=0)).max() < 0.05 * 2 * np.pi / 60.0 * 0.005 * 1.01  # max slope x dt


def test_vibration_comes_in_bursts_at_its_frequency():
    sim, _, acc_err = residual({"vibration_acc_m_s2": 1.0, "vibration_duty": 0.2, "vibration_hz": 37.0}, 120.0)
    shaking = np.abs(acc_err).max(axis=1) > 0
    assert 0.1 < shaking.mean() < 0.3
    spectrum = np.abs(np.fft.rfft(acc_err[:, 0]))
    assert np.fft.rfftfreq(len(acc_err), 0.005)[spectrum.argmax()] == pytest.approx(37.0, abs=0.1)


@pytest.mark.slow
def test_two_hour_sequence_fits_in_memory():
    seq = simulate("car", duration_s=7200.0, grade="consumer", seed=1)
    assert len(seq) == 1_440_000 and np.isfinite(seq.acc).all()
