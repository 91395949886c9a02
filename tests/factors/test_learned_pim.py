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
    pim = learned_pim(gyro, acc, DT, gyro_density, acc_density, 9.81)
    ours = preintegrate(
        *(torch.tensor(x) for x in (gyro, acc)), DT, torch.tensor(gyro_density), torch.tensor(acc_density), at=-1
    )
    ref = pim.preintMeasCov()
    # GTSAM linearises its tangent preintegration slightly differently (within 1 % up to 1 rad/s)
    assert np.abs(ours.cov[0].numpy() - ref).max() / np.abs(ref).max() < 0.01
    np.testing.assert_allclose(pim.deltaPij(), ours.pos[0].numpy(), rtol=1e-2)
    np.testing.assert_allclose(pim.deltaVij(), ours.vel[0].numpy(), rtol=1e-2)


def test_per_sample_noise_is_applied_sample_by_sample():
    gyro, acc, gyro_density, acc_density = samples(200, max_rate=0.5, seed=1)
    mean_g, mean_a = gyro_density.mean(axis=0), acc_density.mean(axis=0)
    varying = learned_pim(gyro, acc, DT, gyro_density, acc_density, 9.81).preintMeasCov()
    constant = learned_pim(gyro, acc, DT, mean_g, mean_a, 9.81).preintMeasCov()
    doubled = learned_pim(gyro, acc, DT, 2 * gyro_density, 2 * acc_density, 9.81).preintMeasCov()
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
        learned_pim(g, a, d, gyro_density, acc_density, 9.81)


def test_swapped_gyro_and_acc_are_named():
    gyro, acc, gyro_density, acc_density = samples(50, max_rate=0.5, seed=6)
    with pytest.raises(ValueError, match="swapped"):
        learned_pim(acc, gyro, DT, gyro_density, acc_density, 9.81)
    with pytest.raises(ValueError, match="in g"):
        learned_pim(gyro, acc / 9.81, DT, gyro_density, acc_density, 9.81)


def test_a_cov_beyond_any_imu_is_refused():
    gyro, acc, gyro_density, acc_density = samples(20, max_rate=0.5, seed=7)
    with pytest.raises(ValueError, match="acc_cov 200 is above 100"):
        learned_pim(gyro, acc, DT, gyro_density, 200.0, 9.81)
    distrusted = acc_density.copy()
    distrusted[3] = 596.0  # a model's per-sample output may distrust one sample that much: accepted
    assert learned_pim(gyro, acc, DT, gyro_density, distrusted, 9.81).preintMeasCov()[6, 6] > 1.0


def test_negative_or_zero_density_raises():
    gyro, acc, gyro_density, acc_density = samples(10, max_rate=0.5, seed=3)
    for bad in (-gyro_density, 0.0 * gyro_density, 0.0):  # zero: GTSAM would make it a sigma-0 constraint
        with pytest.raises(ValueError, match="finite and positive"):
            learned_pim(gyro, acc, DT, bad, acc_density, 9.81)


def gtsam_own(pim, gyro, acc, dt):
    """GTSAM's own preintegration of the samples into ``pim`` (constant noise from its params)."""
    for k in range(len(gyro)):
        pim.integrateMeasurement(acc[k], gyro[k], dt)
    return pim


def test_combined_equals_gtsams_own_preintegration_at_constant_noise():
    import gtsam

    from factors import learned_combined_pim

    gyro, acc, _, _ = samples(300, max_rate=1.0, seed=4)
    params = gtsam.PreintegrationCombinedParams.MakeSharedU(9.8)
    params.setGyroscopeCovariance(np.eye(3) * 1.7e-4**2)
    params.setAccelerometerCovariance(np.eye(3) * 2e-3**2)
    params.setIntegrationCovariance(np.eye(3) * 1e-8)
    params.setBiasAccCovariance(np.eye(3) * 4e-5**2)
    params.setBiasOmegaCovariance(np.eye(3) * 2e-6**2)
    params.setBodyPSensor(gtsam.Pose3(gtsam.Rot3.Ypr(0.3, -0.1, 0.2), np.array([0.1, -0.05, 0.2])))
    params.setOmegaCoriolis(np.array([0.0, 4e-5, 6e-5]))
    bias = gtsam.imuBias.ConstantBias(np.array([0.05, -0.02, 0.1]), np.array([0.2, -0.1, 0.3]))  # 0.1-0.3 rad/s
    before = params.serialize()
    ours = learned_combined_pim(gyro, acc, DT, 1.7e-4**2, 2e-3**2, params=params, bias=bias)
    theirs = gtsam_own(gtsam.PreintegratedCombinedMeasurements(params, bias), gyro, acc, DT)
    assert params.serialize() == before  # the caller's params are not changed by the per-sample noise
    np.testing.assert_allclose(ours.preintMeasCov(), theirs.preintMeasCov(), rtol=1e-12, atol=1e-30)
    np.testing.assert_allclose(ours.deltaRij().matrix(), theirs.deltaRij().matrix(), atol=1e-14)
    np.testing.assert_allclose(ours.deltaPij(), theirs.deltaPij(), atol=1e-13)
    np.testing.assert_allclose(ours.deltaVij(), theirs.deltaVij(), atol=1e-13)
    assert ours.preintMeasCov().shape == (15, 15)
    with pytest.raises(TypeError, match="PreintegrationCombinedParams"):
        learned_combined_pim(gyro, acc, DT, 1e-8, 1e-6, params=gtsam.PreintegrationParams.MakeSharedU(9.8))


def test_params_are_honoured_and_gravity_has_no_default():
    import gtsam

    gyro, acc, gyro_density, acc_density = samples(200, max_rate=0.5, seed=5)
    params = gtsam.PreintegrationParams.MakeSharedU(9.8)
    params.setGyroscopeCovariance(np.eye(3) * 1e-6)
    params.setAccelerometerCovariance(np.eye(3) * 1e-4)
    params.setIntegrationCovariance(np.eye(3) * 1e-7)
    params.setBodyPSensor(gtsam.Pose3(gtsam.Rot3.Rz(0.5), np.array([0.2, 0.0, 0.1])))
    params.setOmegaCoriolis(np.array([1e-5, 0.0, 7e-5]))
    ours = learned_pim(gyro, acc, DT, 1e-6, 1e-4, params=params)
    theirs = gtsam_own(gtsam.PreintegratedImuMeasurements(params, gtsam.imuBias.ConstantBias()), gyro, acc, DT)
    np.testing.assert_allclose(ours.preintMeasCov(), theirs.preintMeasCov(), rtol=1e-12, atol=1e-30)
    np.testing.assert_allclose(ours.preintegrated(), theirs.preintegrated(), atol=1e-13)
    plain = learned_pim(gyro, acc, DT, 1e-6, 1e-4, 9.8)  # no bodyPSensor: a different measurement
    assert np.abs(plain.preintegrated() - theirs.preintegrated()).max() > 1e-3
    with pytest.raises(ValueError, match="no default"):
        learned_pim(gyro, acc, DT, gyro_density, acc_density)
    with pytest.raises(ValueError, match="not both"):
        learned_pim(gyro, acc, DT, gyro_density, acc_density, 9.8, params=params)
