"""learned_pim: GTSAM's preintegration with per-sample learned noise matches learned_imu.preintegrate."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from factors.learned_pim import learned_pim
from learned_imu import preintegrate

DT = 0.005


def samples(n: int, max_rate: float, seed: int):
    rng = np.random.default_rng(seed)
    gyro = rng.uniform(-max_rate, max_rate, (n, 3))
    acc = rng.normal(0.0, 2.0, (n, 3)) + np.array([0.0, 0.0, 9.81])
    gyro_density = rng.uniform(1e-6, 1e-4, (n, 3))  # varies per sample, like a learned uncertainty
    acc_density = rng.uniform(1e-5, 1e-3, (n, 3))
    return gyro, acc, gyro_density, acc_density


def test_covariance_matches_learned_imu_preintegrate_with_per_sample_noise():
    gyro, acc, gyro_density, acc_density = samples(400, max_rate=1.0, seed=0)
    pim = learned_pim(gyro, acc, DT, gyro_density, acc_density)
    ours = preintegrate(
        *(torch.tensor(x) for x in (gyro, acc)), DT, torch.tensor(gyro_density), torch.tensor(acc_density), at=-1
    )
    ref = pim.preintMeasCov()
    # GTSAM linearises its tangent preintegration slightly differently (issue 2: within 1 % up to 1 rad/s)
    assert np.abs(ours.cov[0].numpy() - ref).max() / np.abs(ref).max() < 0.01
    np.testing.assert_allclose(pim.deltaPij(), ours.pos[0].numpy(), rtol=1e-2)
    np.testing.assert_allclose(pim.deltaVij(), ours.vel[0].numpy(), rtol=1e-2)


def test_per_sample_noise_is_applied_sample_by_sample():
    gyro, acc, gyro_density, acc_density = samples(200, max_rate=0.5, seed=1)
    mean_g, mean_a = gyro_density.mean(axis=0), acc_density.mean(axis=0)
    varying = learned_pim(gyro, acc, DT, gyro_density, acc_density).preintMeasCov()
    constant = learned_pim(gyro, acc, DT, mean_g, mean_a).preintMeasCov()
    doubled = learned_pim(gyro, acc, DT, 2 * gyro_density, 2 * acc_density).preintMeasCov()
    np.testing.assert_allclose(doubled, 2 * varying, rtol=1e-9, atol=1e-18)  # covariance is linear in the noise
    assert np.abs(varying - constant).max() > 1e-3 * np.abs(varying).max()  # and per-sample noise matters


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda g, a, d: (g[:, :2], a, d), "gyro must be"),
        (lambda g, a, d: (g, a[:-1], d), "must both be"),
        (lambda g, a, d: (g, a, -d), "dt must be positive"),
        (lambda g, a, d: (np.where(np.arange(len(g))[:, None] == 3, np.nan, g), a, d), "gyro contains NaN"),
    ],
)
def test_bad_input_raises(change, message):
    gyro, acc, gyro_density, acc_density = samples(10, max_rate=0.5, seed=2)
    g, a, d = change(gyro, acc, DT)
    with pytest.raises(ValueError, match=message):
        learned_pim(g, a, d, gyro_density, acc_density)


def test_negative_density_raises():
    gyro, acc, gyro_density, acc_density = samples(10, max_rate=0.5, seed=3)
    with pytest.raises(ValueError, match="non-negative"):
        learned_pim(gyro, acc, DT, -gyro_density, acc_density)
