"""LearnedImuFactor against gtsam.ImuFactor (error and linearisation) and numerical derivatives in float64."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import B, V, X

from factors.imu import LearnedImuFactor
from tests.helpers import error_jacobian, factor_from_pim, factor_with_bias_from_samples, gtsam_pim


def random_values(rng: np.random.Generator, pim=None) -> gtsam.Values:
    """Random states; with ``pim``, the state at j is near the prediction (a realistic linearisation point)."""
    values = gtsam.Values()
    pose_i = gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3)), rng.normal(size=3) * 5)
    vel_i = rng.normal(size=3)
    values.insert(X(0), pose_i)
    values.insert(V(0), vel_i)
    if pim is None:
        values.insert(X(1), gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3)), rng.normal(size=3) * 5))
        values.insert(V(1), rng.normal(size=3))
    else:
        pred = pim.predict(gtsam.NavState(pose_i, vel_i), gtsam.imuBias.ConstantBias())
        values.insert(X(1), pred.pose().retract(rng.normal(size=6) * 0.05))
        values.insert(V(1), pred.velocity() + rng.normal(size=3) * 0.05)
    values.insert(B(0), gtsam.imuBias.ConstantBias())
    return values


def rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-300))


@pytest.mark.parametrize("near_prediction", [False, True])
def test_error_and_linearisation_equal_gtsam_imu_factor(near_prediction):
    rng = np.random.default_rng(0)
    for seed in range(5):
        pim = gtsam_pim(seed)
        ours = factor_from_pim(pim)
        ref = gtsam.ImuFactor(X(0), V(0), X(1), V(1), B(0), pim)
        values = random_values(rng, pim if near_prediction else None)
        assert rel(ours.unwhitenedError(values), ref.unwhitenedError(values)) < 1e-6
        assert ours.error(values) == pytest.approx(ref.error(values), rel=1e-6)
        a_ours, b_ours = ours.linearize(values).jacobian()
        a_ref, b_ref = ref.linearize(values).jacobian()
        assert rel(a_ours, a_ref[:, :18]) < 1e-6  # gtsam's last 6 columns are the bias
        assert rel(b_ours, b_ref) < 1e-6


def test_jacobians_equal_numerical_derivatives():
    rng = np.random.default_rng(1)
    pim = gtsam_pim(7)
    factor = factor_from_pim(pim)
    values = random_values(rng)
    jacobians = [np.zeros((9, 6)), np.zeros((9, 3)), np.zeros((9, 6)), np.zeros((9, 3))]
    factor._evaluate(factor, values, jacobians)
    for index, key in enumerate((X(0), V(0), X(1), V(1))):
        numeric = error_jacobian(factor, values, key)
        assert np.abs(jacobians[index] - numeric).max() < 1e-6 * max(1.0, np.abs(numeric).max()), index


def test_swapping_into_a_graph_gives_the_same_solution():
    """A small IMU chain with a pose prior: LM with ours and with gtsam.ImuFactor lands on the same states."""
    rng = np.random.default_rng(2)
    pims = [gtsam_pim(s, n=100) for s in range(3)]
    solutions = []
    for use_ours in (True, False):
        graph = gtsam.NonlinearFactorGraph()
        graph.add(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 1e-3)))
        graph.add(gtsam.PriorFactorVector(V(0), np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, 1e-3)))
        graph.add(
            gtsam.PriorFactorConstantBias(B(0), gtsam.imuBias.ConstantBias(), gtsam.noiseModel.Isotropic.Sigma(6, 1e-9))
        )
        initial = gtsam.Values()
        initial.insert(B(0), gtsam.imuBias.ConstantBias())
        for i, pim in enumerate(pims):
            if use_ours:
                f = factor_from_pim(pim)
                graph.add(
                    LearnedImuFactor(
                        X(i),
                        V(i),
                        X(i + 1),
                        V(i + 1),
                        f.delta_rot,
                        f.delta_pos,
                        f.delta_vel,
                        f.dt,
                        pim.preintMeasCov(),
                        gravity=f.gravity,
                    )
                )
            else:
                graph.add(gtsam.ImuFactor(X(i), V(i), X(i + 1), V(i + 1), B(0), pim))
        for i in range(len(pims) + 1):
            initial.insert(X(i), gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3) * 0.01), rng.normal(size=3)))
            initial.insert(V(i), rng.normal(size=3))
        result = gtsam.LevenbergMarquardtOptimizer(graph, initial).optimize()
        solutions.append([result.atPose3(X(i)).translation() for i in range(len(pims) + 1)])
    np.testing.assert_allclose(solutions[0], solutions[1], atol=1e-6)


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("cov", -np.eye(9), "positive definite"),
        ("cov", np.eye(8), "shape"),
        ("delta_pos", [np.nan, 0.0, 0.0], "NaN"),
        ("delta_rot", np.eye(3) * 2, "rotation"),
        ("dt", 0.0, "dt must be positive"),
    ],
)
def test_bad_measurement_raises(field, value, message):
    args = {"delta_rot": np.eye(3), "delta_pos": np.zeros(3), "delta_vel": np.zeros(3), "dt": 0.1, "cov": np.eye(9)}
    args[field] = value
    with pytest.raises(ValueError, match=message):
        LearnedImuFactor(X(0), V(0), X(1), V(1), **args)


def test_bias_key_jacobians_equal_numerical_derivatives():
    ours, pim = factor_with_bias_from_samples(3)
    rng = np.random.default_rng(4)
    values = random_values(rng, pim)
    values.update(B(0), gtsam.imuBias.ConstantBias(rng.normal(0, 0.1, 3), rng.normal(0, 0.01, 3)))
    jacobians = [np.zeros((9, d)) for d in (6, 3, 6, 3, 6)]
    ours._evaluate(ours, values, jacobians)
    for index, key in enumerate((X(0), V(0), X(1), V(1), B(0))):
        numeric = error_jacobian(ours, values, key)
        assert np.abs(jacobians[index] - numeric).max() < 1e-6 * max(1.0, np.abs(numeric).max()), index


def test_bias_correction_agrees_with_gtsam_imu_factor():
    """The change of the error caused by a bias equals gtsam.ImuFactor's (same sign and [acc, gyro] order) to
    first order; GTSAM integrates in its tangent chart, so agreement is to ~1 %, not round-off."""
    ours, pim = factor_with_bias_from_samples(5)
    ref = gtsam.ImuFactor(X(0), V(0), X(1), V(1), B(0), pim)
    rng = np.random.default_rng(6)
    values = random_values(rng, pim)
    base_ours, base_ref = ours.unwhitenedError(values), ref.unwhitenedError(values)
    values.update(B(0), gtsam.imuBias.ConstantBias(np.array([0.05, -0.03, 0.02]), np.array([0.002, 0.001, -0.003])))
    effect_ours = ours.unwhitenedError(values) - base_ours
    effect_ref = ref.unwhitenedError(values) - base_ref
    assert np.abs(effect_ref).max() > 1e-3  # the bias matters
    assert np.abs(effect_ours - effect_ref).max() < 0.01 * np.abs(effect_ref).max()


def test_bias_key_needs_the_bias_jacobian():
    args = {"delta_rot": np.eye(3), "delta_pos": np.zeros(3), "delta_vel": np.zeros(3), "dt": 0.1, "cov": np.eye(9)}
    with pytest.raises(ValueError, match="both bias"):
        LearnedImuFactor(X(0), V(0), X(1), V(1), **args, bias=B(0))
