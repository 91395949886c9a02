"""GpsFactor against gtsam.GPSFactor (zero lever arm) and numerical derivatives (lever arm)."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import X

from factors.gps import GpsFactor, gps_noise
from tests.helpers import error_jacobian


def random_pose(rng: np.random.Generator) -> gtsam.Pose3:
    return gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3)), rng.normal(size=3) * 10)


def test_zero_lever_arm_equals_gtsam_gps_factor():
    rng = np.random.default_rng(0)
    noise = gps_noise([0.1, 0.2, 0.3])
    for _ in range(5):
        values = gtsam.Values()
        values.insert(X(0), random_pose(rng))
        z = rng.normal(size=3) * 10
        ours, ref = GpsFactor(X(0), z, noise), gtsam.GPSFactor(X(0), z, noise)
        np.testing.assert_allclose(ours.unwhitenedError(values), ref.unwhitenedError(values), rtol=1e-12, atol=1e-12)
        a_ours, b_ours = ours.linearize(values).jacobian()
        a_ref, b_ref = ref.linearize(values).jacobian()
        np.testing.assert_allclose(a_ours, a_ref, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(b_ours, b_ref, rtol=1e-12, atol=1e-12)


def test_lever_arm_jacobian_equals_numerical_derivative():
    rng = np.random.default_rng(1)
    for _ in range(5):
        values = gtsam.Values()
        pose = random_pose(rng)
        values.insert(X(3), pose)
        lever = rng.normal(size=3)
        factor = GpsFactor(X(3), rng.normal(size=3), gps_noise(1.0), lever_arm_m=lever)
        # the error is the antenna position minus the fix
        expected = pose.translation() + pose.rotation().matrix() @ lever - factor.position_m
        np.testing.assert_allclose(factor.unwhitenedError(values), expected, atol=1e-12)
        analytic = factor.linearize(values).jacobian()[0]  # whitened by sigma = 1
        np.testing.assert_allclose(analytic, error_jacobian(factor, values, X(3)), atol=1e-8)


def test_robust_noise_downweights_an_outlier():
    values = gtsam.Values()
    values.insert(X(0), gtsam.Pose3())
    gaussian = GpsFactor(X(0), [50.0, 0.0, 0.0], gps_noise(1.0))
    huber = GpsFactor(X(0), [50.0, 0.0, 0.0], gps_noise(1.0, robust="huber"))
    cauchy = GpsFactor(X(0), [50.0, 0.0, 0.0], gps_noise(1.0, robust="cauchy"))
    assert gaussian.error(values) == pytest.approx(0.5 * 50.0**2)
    k = 1.345  # Huber: linear beyond k sigma, rho(r) = k (|r| - k / 2)
    assert huber.error(values) == pytest.approx(k * (50.0 - k / 2))
    assert cauchy.error(values) < huber.error(values) < 0.1 * gaussian.error(values)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"sigma_m": 0.0}, "positive"),
        ({"sigma_m": [0.1, float("nan"), 0.1]}, "positive"),
        ({"sigma_m": 0.1, "robust": "tukey"}, "unknown robust loss"),
    ],
)
def test_bad_noise_raises(kwargs, message):
    with pytest.raises(ValueError, match=message):
        gps_noise(**kwargs)


def test_bad_measurement_raises():
    with pytest.raises(ValueError, match="position_m"):
        GpsFactor(X(0), [1.0, 2.0], gps_noise(0.1))
    with pytest.raises(ValueError, match="lever_arm_m"):
        GpsFactor(X(0), [1.0, 2.0, 3.0], gps_noise(0.1), lever_arm_m=[0.0, np.inf, 0.0])
    with pytest.raises(ValueError, match="dimension 3"):
        GpsFactor(X(0), [1.0, 2.0, 3.0], gtsam.noiseModel.Isotropic.Sigma(2, 0.1))
