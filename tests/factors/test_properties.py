"""Property-based tests (hypothesis): the analytic Jacobians of LearnedImuFactor (with and without a bias key) and
GpsFactor equal central numerical derivatives in float64 at random states, measurements and noise. Derandomized,
so every run checks the same examples. The measurement builders and the numerical derivative are ``tests.helpers``'."""

from __future__ import annotations

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, V, X
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from factors.gps import GpsFactor, gps_noise
from tests.helpers import error_jacobian, factor_from_pim, factor_with_bias_from_samples, gtsam_pim

PROPERTY = settings(
    max_examples=40,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.too_slow],
)
# a rotation of angle pi has two logarithms: near it the error's rotation part jumps and no derivative exists
MAX_ERROR_ANGLE_RAD = np.pi - 0.05


def vectors(bound: float, size: int = 3):
    return arrays(np.float64, size, elements=st.floats(-bound, bound))


@st.composite
def poses(draw, position_bound: float = 50.0) -> gtsam.Pose3:
    return gtsam.Pose3(gtsam.Rot3.Expmap(draw(vectors(np.pi))), draw(vectors(position_bound)))


def assert_jacobian_close(analytic: np.ndarray, numeric: np.ndarray, what) -> None:
    """Agreement to 1e-6 relative to the derivative's size (central differences with JACOBIAN_STEP in float64)."""
    assert np.abs(analytic - numeric).max() < 1e-6 * max(1.0, np.abs(numeric).max()), what


@PROPERTY
@given(
    seed=st.integers(0, 2**32 - 1),
    samples=st.integers(2, 300),  # one sample: pos and vel share one acc noise, cov is singular
    dt=st.floats(1e-3, 0.02),
    with_bias=st.booleans(),
    near_prediction=st.booleans(),
    pose_i=poses(),
    vel_i=vectors(10.0),
    pose_j=poses(),
    vel_j=vectors(10.0),
    tangent_j=vectors(0.3, 9),
    bias=vectors(1.0, 6),
)
def test_imu_factor_jacobians_equal_numerical_derivatives(
    seed, samples, dt, with_bias, near_prediction, pose_i, vel_i, pose_j, vel_j, tangent_j, bias
):
    """Random measurement (``samples`` IMU samples, with or without a bias key and its Jacobian) and random states:
    anywhere, or near the prediction (a realistic linearisation point)."""
    if with_bias:
        factor, pim = factor_with_bias_from_samples(seed, samples, dt)
    else:
        pim = gtsam_pim(seed, samples, dt)
        factor = factor_from_pim(pim)
    if near_prediction:
        pred = pim.predict(gtsam.NavState(pose_i, vel_i), gtsam.imuBias.ConstantBias())
        pose_j, vel_j = pred.pose().retract(tangent_j[:6]), pred.velocity() + tangent_j[6:]
    values = gtsam.Values()
    for key, value in ((X(0), pose_i), (V(0), vel_i), (X(1), pose_j), (V(1), vel_j)):
        values.insert(key, value)
    values.insert(B(0), gtsam.imuBias.ConstantBias(bias[:3] * 0.5, bias[3:] * 0.05))  # m/s^2, rad/s
    assume(np.linalg.norm(factor.unwhitenedError(values)[:3]) < MAX_ERROR_ANGLE_RAD)

    keys = (X(0), V(0), X(1), V(1)) + ((B(0),) if with_bias else ())
    jacobians = [np.zeros((9, 6 if k in (X(0), X(1), B(0)) else 3)) for k in keys]
    error = factor._evaluate(factor, values, jacobians)
    np.testing.assert_allclose(error, factor.unwhitenedError(values), rtol=0, atol=1e-12)
    for key, analytic in zip(keys, jacobians, strict=True):
        numeric = error_jacobian(factor, values, key)
        assert_jacobian_close(analytic, numeric, gtsam.DefaultKeyFormatter(key))


@PROPERTY
@given(
    pose=poses(1e3),
    measured=vectors(1e3),
    lever=vectors(5.0),
    sigma=arrays(np.float64, 3, elements=st.floats(1e-3, 100.0)),
)
def test_gps_factor_error_and_jacobian_equal_the_model(pose, measured, lever, sigma):
    """Error ``t + R l - z`` and its Pose3 Jacobian (GTSAM whitens by 1/sigma per axis; undone here)."""
    values = gtsam.Values()
    values.insert(X(7), pose)
    factor = GpsFactor(X(7), measured, gps_noise(sigma), lever_arm_m=lever)
    expected = pose.translation() + pose.rotation().matrix() @ lever - measured
    scale = 1.0 + np.abs(pose.translation()).max() + np.abs(measured).max()  # the error's round-off grows with these
    np.testing.assert_allclose(factor.unwhitenedError(values), expected, rtol=0, atol=1e-12 * scale)
    whitened, _ = factor.linearize(values).jacobian()
    analytic = whitened * sigma[:, None]
    assert_jacobian_close(analytic, error_jacobian(factor, values, X(7)), "X(7)")
