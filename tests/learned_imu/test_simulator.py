"""The simulator: deterministic, consistent with the discrete integrator, noise as its grade says."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from learned_imu import NavState, predict, preintegrate
from learned_imu.simulator import GRADES, PROFILES, ImuErrorModel, simulate, simulate_with_truth


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
    start = NavState(*(torch.tensor(x[0], dtype=f64) for x in (seq.gt.rot, seq.gt.vel, seq.gt.pos)))
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


def test_white_noise_and_bias_match_the_grade():
    model = ImuErrorModel.from_grade("industrial")
    sim = simulate_with_truth("drone", duration_s=200.0, rate_hz=200.0, grade="industrial", seed=2)
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
