"""MotionFactor against numerical derivatives in float64 and its Gaussian error; motion_factors' keys and refusals;
solve_with_python_factors against gtsam.LevenbergMarquardtOptimizer."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import B, L, M, S, V, X

from airimu_core.errors import GraphError, InputError
from factors.motion import MotionFactor, MotionTerms, motion_factors, solve_with_python_factors
from tests.helpers import GRAVITY, error_jacobian


def random_state(rng: np.random.Generator, k: int = 0) -> gtsam.Values:
    values = gtsam.Values()
    values.insert(X(k), gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3)), rng.normal(size=3) * 5))
    values.insert(V(k), rng.normal(size=3) * 3)
    return values


def random_keyframes(rng: np.random.Generator, count: int) -> gtsam.Values:
    """Poses and velocities of keyframes 0 .. count-1 at random."""
    values = gtsam.Values()
    for k in range(count):
        values.insert(X(k), gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3)), rng.normal(size=3)))
        values.insert(V(k), rng.normal(size=3) * 3)
    return values


def random_cov(rng: np.random.Generator) -> np.ndarray:
    """A full 3x3 covariance with correlations, (m/s)^2."""
    a = rng.normal(size=(3, 3)) * 0.1
    return a @ a.T + np.eye(3) * 1e-3


def hat(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


@pytest.mark.parametrize("seed", range(5))
def test_jacobians_equal_numerical_derivatives(seed):
    rng = np.random.default_rng(seed)
    values = random_state(rng)
    factor = MotionFactor(X(0), V(0), rng.normal(size=3), random_cov(rng))
    jacobians = [np.zeros((3, 6)), np.zeros((3, 3))]
    factor._evaluate(factor, values, jacobians)
    for analytic, key in zip(jacobians, (X(0), V(0)), strict=True):
        numeric = error_jacobian(factor, values, key)  # central differences: Pose3 retract, vector +
        assert np.abs(analytic - numeric).max() < 1e-8 * max(1.0, np.abs(numeric).max()), key
    # the closed form of the module docstring, sign included
    r = values.atPose3(X(0)).rotation().matrix()
    np.testing.assert_allclose(jacobians[0][:, :3], hat(r.T @ values.atVector(V(0))), atol=1e-12)
    np.testing.assert_allclose(jacobians[0][:, 3:], 0.0, atol=0)
    np.testing.assert_allclose(jacobians[1], r.T, atol=1e-12)


@pytest.mark.parametrize("seed", range(5))
def test_mounted_jacobians_equal_numerical_derivatives(seed):
    """With a mounting rotation M: error M^T R^T v - v_body, every Jacobian (pose, velocity, mount) against central
    differences in float64."""
    rng = np.random.default_rng(seed)
    values = random_state(rng)
    values.insert(M(0), gtsam.Rot3.Expmap(rng.normal(size=3) * 0.3))
    factor = MotionFactor(X(0), V(0), rng.normal(size=3), random_cov(rng), mount_key=M(0))
    assert list(factor.keys()) == [X(0), V(0), M(0)]
    jacobians = [np.zeros((3, 6)), np.zeros((3, 3)), np.zeros((3, 3))]
    error = factor._evaluate(factor, values, jacobians)
    r, m = values.atPose3(X(0)).rotation().matrix(), values.atRot3(M(0)).matrix()
    np.testing.assert_allclose(error, m.T @ r.T @ values.atVector(V(0)) - factor.v_body, atol=1e-12)
    for analytic, key in zip(jacobians, (X(0), V(0), M(0)), strict=True):
        numeric = error_jacobian(factor, values, key)
        assert np.abs(analytic - numeric).max() < 1e-8 * max(1.0, np.abs(numeric).max()), key
    assert np.abs(jacobians[0][:, 3:]).max() == 0.0


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("mounted", [False, True])
def test_scaled_jacobians_equal_numerical_derivatives(seed, mounted):
    """With a speed scale s (and a mount M): error [M^T] R^T v - s v_body, every Jacobian against central
    differences in float64; d e / d s = -v_body."""
    rng = np.random.default_rng(seed)
    values = random_state(rng)
    values.insert(S(3), np.array([rng.uniform(0.5, 1.5)]))
    mount = M(0) if mounted else None
    if mounted:
        values.insert(M(0), gtsam.Rot3.Expmap(rng.normal(size=3) * 0.3))
    factor = MotionFactor(X(0), V(0), rng.normal(size=3), random_cov(rng), mount_key=mount, scale_key=S(3))
    keys = [X(0), V(0), *([M(0)] if mounted else []), S(3)]
    assert list(factor.keys()) == keys
    jacobians = [np.zeros((3, 6)), np.zeros((3, 3)), *([np.zeros((3, 3))] if mounted else []), np.zeros((3, 1))]
    error = factor._evaluate(factor, values, jacobians)
    r = values.atPose3(X(0)).rotation().matrix()
    m = values.atRot3(M(0)).matrix() if mounted else np.eye(3)
    s = values.atVector(S(3))[0]
    np.testing.assert_allclose(error, m.T @ r.T @ values.atVector(V(0)) - s * factor.v_body, atol=1e-12)
    for analytic, key in zip(jacobians, keys, strict=True):
        numeric = error_jacobian(factor, values, key)
        assert np.abs(analytic - numeric).max() < 1e-8 * max(1.0, np.abs(numeric).max()), key
    np.testing.assert_allclose(jacobians[-1][:, 0], -factor.v_body, atol=0)
    assert factor._evaluate(factor, values, None) == pytest.approx(error, abs=1e-14)


def test_a_unit_scale_is_the_factor_without_one():
    rng = np.random.default_rng(4)
    values = random_state(rng)
    values.insert(S(0), np.ones(1))
    cov, v_body = random_cov(rng), rng.normal(size=3)
    plain, scaled = MotionFactor(X(0), V(0), v_body, cov), MotionFactor(X(0), V(0), v_body, cov, scale_key=S(0))
    assert scaled.error(values) == pytest.approx(plain.error(values), rel=1e-14)
    values.update(S(0), np.array([1.1]))
    assert scaled.error(values) != pytest.approx(plain.error(values), rel=1e-3)


def test_scaled_motion_terms_equal_the_factors():
    """MotionTerms with speed scales (two factors per scale key, the 's' character also naming a Pose3 once):
    the factors' error and whitened linearisation."""
    rng = np.random.default_rng(22)
    keyframes = 6
    values = random_keyframes(rng, keyframes)
    for j in range(keyframes // 2):
        values.insert(S(j), np.array([rng.uniform(0.8, 1.2)]))
    scale_keys = [S(k // 2) for k in range(keyframes)]
    made = motion_factors(
        rng.normal(size=(keyframes, 3)), rng.uniform(1e-3, 0.1, (keyframes, 3)), scale_keys=scale_keys
    )
    terms = MotionTerms(made)
    for extra_pose in (False, True):
        if extra_pose:  # read one by one
            values.insert(S(50), gtsam.Pose3())
        assert terms.error(values) == pytest.approx(sum(f.error(values) for f in made), rel=1e-12)
        linear = terms.linearize(values)
        for k, factor in enumerate(made):
            ours, theirs = linear.at(k), factor.linearize(values)
            assert list(ours.keys()) == list(theirs.keys()) == [X(k), V(k), S(k // 2)]
            expected = theirs.augmentedInformation()
            np.testing.assert_allclose(ours.augmentedInformation(), expected, atol=1e-9 * np.abs(expected).max())
    with pytest.raises(GraphError, match="a speed scale or none"):
        MotionTerms([*made, MotionFactor(X(0), V(0), np.zeros(3), np.ones(3))])
    with pytest.raises(GraphError, match="a speed scale or none"):
        MotionTerms([MotionFactor(X(0), V(0), np.zeros(3), np.ones(3), mount_key=M(0), scale_key=S(0))])
    with pytest.raises(InputError, match="scale_keys must be 6 keys"):
        motion_factors(np.zeros((keyframes, 3)), np.ones((keyframes, 3)), scale_keys=scale_keys[:-1])


def test_an_identity_mount_is_the_factor_without_one():
    rng = np.random.default_rng(3)
    values = random_state(rng)
    values.insert(M(0), gtsam.Rot3())
    cov = random_cov(rng)
    v_body = rng.normal(size=3)
    plain, mounted = MotionFactor(X(0), V(0), v_body, cov), MotionFactor(X(0), V(0), v_body, cov, mount_key=M(0))
    assert mounted.error(values) == pytest.approx(plain.error(values), rel=1e-14)
    a_plain, _ = plain.linearize(values).jacobian()
    a_mounted, _ = mounted.linearize(values).jacobian()
    np.testing.assert_allclose(a_mounted[:, :9], a_plain, atol=1e-12)


def test_error_is_zero_for_a_consistent_state():
    rng = np.random.default_rng(10)
    for _ in range(5):
        values = random_state(rng)
        v_body = values.atPose3(X(0)).rotation().matrix().T @ values.atVector(V(0))
        factor = MotionFactor(X(0), V(0), v_body, [0.01, 0.02, 0.03])
        assert np.abs(factor.unwhitenedError(values)).max() < 1e-12
        assert factor.error(values) < 1e-20


@pytest.mark.parametrize("full", [False, True])
def test_error_is_the_mahalanobis_distance_of_the_learned_covariance(full):
    rng = np.random.default_rng(11)
    for _ in range(5):
        values = random_state(rng)
        cov = random_cov(rng) if full else rng.uniform(1e-3, 1e-1, 3)
        v_body = rng.normal(size=3)
        factor = MotionFactor(X(0), V(0), v_body, cov)
        e = values.atPose3(X(0)).rotation().matrix().T @ values.atVector(V(0)) - v_body
        np.testing.assert_allclose(factor.unwhitenedError(values), e, rtol=1e-12, atol=1e-12)
        sigma = cov if full else np.diag(cov)
        assert factor.error(values) == pytest.approx(0.5 * e @ np.linalg.solve(sigma, e), rel=1e-10)


def test_motion_factor_pins_a_velocity_in_a_solve():
    """A fixed attitude, a weak zero prior on the velocity and one motion factor: the solved world velocity is
    R v_body shrunk by the two precisions, (1/s^2) / (1/s^2 + 1/s0^2) -- closed form."""
    rot = gtsam.Rot3.Ypr(0.7, -0.2, 0.1)
    v_body, sigma, sigma_prior = np.array([4.0, -0.5, 0.2]), 0.05, 100.0
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(rot, [1, 2, 3]), gtsam.noiseModel.Isotropic.Sigma(6, 1e-9)))
    graph.add(gtsam.PriorFactorVector(V(0), np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, sigma_prior)))
    graph.add(MotionFactor(X(0), V(0), v_body, np.full(3, sigma**2)))
    initial = gtsam.Values()
    initial.insert(X(0), gtsam.Pose3(rot, [1, 2, 3]))
    initial.insert(V(0), np.array([-3.0, 1.0, 0.0]))
    shrink = sigma**-2 / (sigma**-2 + sigma_prior**-2)
    expected = shrink * rot.matrix() @ v_body
    result = gtsam.LevenbergMarquardtOptimizer(graph, initial).optimize()
    np.testing.assert_allclose(result.atVector(V(0)), expected, atol=1e-8)
    ours = solve_with_python_factors(graph, initial)
    np.testing.assert_allclose(ours.values.atVector(V(0)), expected, atol=1e-8)


def imu_gps_motion_graph(keyframes: int, seed: int):
    """A curved constant-rate path: the graph of ImuFactors (0.1 s of constant samples each) and GPS every 5th
    keyframe, a motion factor for every keyframe (apart), initial values perturbed from the truth."""
    rng = np.random.default_rng(seed)
    params = gtsam.PreintegrationParams.MakeSharedU(GRAVITY)
    params.setGyroscopeCovariance(np.eye(3) * 1e-6)
    params.setAccelerometerCovariance(np.eye(3) * 1e-4)
    params.setIntegrationCovariance(np.eye(3) * 1e-8)
    pim = gtsam.PreintegratedImuMeasurements(params, gtsam.imuBias.ConstantBias())
    for _ in range(10):
        pim.integrateMeasurement(np.array([0.0, 0.5, GRAVITY]), np.array([0.0, 0.02, 0.1]), 0.01)
    truth = [gtsam.NavState(gtsam.Pose3(), np.array([5.0, 0.0, 0.0]))]
    for _ in range(keyframes - 1):
        truth.append(pim.predict(truth[-1], gtsam.imuBias.ConstantBias()))
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorPose3(X(0), truth[0].pose(), gtsam.noiseModel.Isotropic.Sigma(6, 0.01)))
    graph.add(
        gtsam.PriorFactorConstantBias(B(0), gtsam.imuBias.ConstantBias(), gtsam.noiseModel.Isotropic.Sigma(6, 1e-3))
    )
    initial = gtsam.Values()
    initial.insert(B(0), gtsam.imuBias.ConstantBias())
    for k, state in enumerate(truth):
        initial.insert(X(k), state.pose().retract(np.r_[rng.normal(0, 0.01, 3), rng.normal(0, 0.5, 3)]))
        initial.insert(V(k), state.velocity() + rng.normal(0, 0.3, 3))
        if k + 1 < keyframes:
            graph.add(gtsam.ImuFactor(X(k), V(k), X(k + 1), V(k + 1), B(0), pim))
        if k % 5 == 0:
            gps = state.position() + rng.normal(0, 0.5, 3)
            graph.add(gtsam.GPSFactor(X(k), gps, gtsam.noiseModel.Isotropic.Sigma(3, 0.5)))
    v_body = np.array([s.bodyVelocity() for s in truth]) + rng.normal(0, 0.05, (keyframes, 3))
    motion = motion_factors(v_body, np.full((keyframes, 3), 0.05**2))
    return graph, motion, initial, truth


def with_factors(graph: gtsam.NonlinearFactorGraph, factors: list) -> gtsam.NonlinearFactorGraph:
    out = gtsam.NonlinearFactorGraph(graph)
    for factor in factors:
        out.add(factor)
    return out


def test_python_driven_lm_equals_gtsam_lm():
    base, motion, initial, truth = imu_gps_motion_graph(40, seed=3)
    graph = with_factors(base, motion)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, initial)
    reference = optimizer.optimize()
    ours = solve_with_python_factors(graph, initial)
    assert ours.iterations == optimizer.iterations() > 1
    assert ours.error == pytest.approx(graph.error(reference), rel=1e-10)
    for k in range(len(truth)):
        assert ours.values.atPose3(X(k)).equals(reference.atPose3(X(k)), 1e-9)
        np.testing.assert_allclose(ours.values.atVector(V(k)), reference.atVector(V(k)), atol=1e-9)
    # and the motion factors did their job: the velocities are close to the truth
    velocity_error = [np.linalg.norm(ours.values.atVector(V(k)) - s.velocity()) for k, s in enumerate(truth)]
    assert np.mean(velocity_error) < 0.05


@pytest.mark.parametrize("full", [False, True])
def test_motion_terms_equal_the_factors(full):
    """Bulk evaluation: the same error and the same linearised factors (their information), with keys numbered
    from 1 and other values in the way (a bias, a landmark, a pose under the velocities' symbol character)."""
    rng = np.random.default_rng(20)
    keyframes = 6
    values = gtsam.Values()
    for k in range(keyframes):
        values.insert(X(k + 1), gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3)), rng.normal(size=3)))
        values.insert(V(k + 1), rng.normal(size=3) * 3)
    values.insert(B(0), gtsam.imuBias.ConstantBias())
    values.insertPoint3(L(0), np.ones(3))
    cov = np.stack([random_cov(rng) for _ in range(keyframes)]) if full else rng.uniform(1e-3, 0.1, (keyframes, 3))
    made = motion_factors(rng.normal(size=(keyframes, 3)), cov, lambda k: X(k + 1), lambda k: V(k + 1))
    terms = MotionTerms(made)
    for extra_pose in (False, True):
        if extra_pose:  # the 'v' character now also names a Pose3: velocities are read one by one
            values.insert(V(99), gtsam.Pose3())
        assert terms.error(values) == pytest.approx(sum(f.error(values) for f in made), rel=1e-12)
        linear = terms.linearize(values)
        assert linear.size() == keyframes
        for k, factor in enumerate(made):
            ours, theirs = linear.at(k), factor.linearize(values)
            assert list(ours.keys()) == list(theirs.keys())
            expected = theirs.augmentedInformation()
            np.testing.assert_allclose(ours.augmentedInformation(), expected, atol=1e-9 * np.abs(expected).max())


def test_mounted_motion_terms_equal_the_factors():
    rng = np.random.default_rng(21)
    keyframes = 5
    values = random_keyframes(rng, keyframes)
    values.insert(M(0), gtsam.Rot3.Expmap([0.01, -0.02, 0.05]))
    made = motion_factors(rng.normal(size=(keyframes, 3)), rng.uniform(1e-3, 0.1, (keyframes, 3)), mount_key=M(0))
    terms = MotionTerms(made)
    assert terms.error(values) == pytest.approx(sum(f.error(values) for f in made), rel=1e-12)
    linear = terms.linearize(values)
    for k, factor in enumerate(made):
        ours, theirs = linear.at(k), factor.linearize(values)
        assert list(ours.keys()) == list(theirs.keys()) == [X(k), V(k), M(0)]
        expected = theirs.augmentedInformation()
        np.testing.assert_allclose(ours.augmentedInformation(), expected, atol=1e-9 * np.abs(expected).max())
    mixed = [*made, MotionFactor(X(0), V(0), np.zeros(3), np.ones(3))]
    with pytest.raises(GraphError, match="one mount key"):
        MotionTerms(mixed)


def test_motion_terms_in_the_python_driven_lm_equal_the_factors_in_gtsam_lm():
    base, motion, initial, truth = imu_gps_motion_graph(40, seed=6)
    reference = gtsam.LevenbergMarquardtOptimizer(with_factors(base, motion), initial).optimize()
    ours = solve_with_python_factors(base, initial, extra=(MotionTerms(motion),))
    assert ours.error == pytest.approx(with_factors(base, motion).error(reference), rel=1e-10)
    for k in range(len(truth)):
        assert ours.values.atPose3(X(k)).equals(reference.atPose3(X(k)), 1e-9)
        np.testing.assert_allclose(ours.values.atVector(V(k)), reference.atVector(V(k)), atol=1e-9)


def test_python_driven_lm_with_qr_equals_gtsam_lm_with_qr():
    base, motion, initial, truth = imu_gps_motion_graph(30, seed=8)
    params = gtsam.LevenbergMarquardtParams()
    params.setLinearSolverType("MULTIFRONTAL_QR")
    reference = gtsam.LevenbergMarquardtOptimizer(with_factors(base, motion), initial, params).optimize()
    ours = solve_with_python_factors(base, initial, params, extra=(MotionTerms(motion),))
    assert ours.error == pytest.approx(with_factors(base, motion).error(reference), rel=1e-9)
    for k in range(len(truth)):
        assert ours.values.atPose3(X(k)).equals(reference.atPose3(X(k)), 1e-8)


def test_python_driven_lm_retries_an_indeterminate_damped_system_with_more_damping(monkeypatch):
    """GTSAM's tryLambda: a damped system that elimination calls indeterminate is a failed try (lambda grows), not
    the end of the solve; the result is the one without the failure."""
    import factors.motion as module

    base, motion, initial, _ = imu_gps_motion_graph(20, seed=7)
    reference = solve_with_python_factors(base, initial, extra=(MotionTerms(motion),))
    real, tries = module._Damping.damped, []

    def failing_first(self, linear, lam):
        tries.append(lam)
        if len(tries) == 1:  # what GTSAM's Cholesky raises on a tiny pivot
            raise RuntimeError("Indeterminant linear system detected while working near variable 1 (Symbol: x1).")
        return real(self, linear, lam)

    monkeypatch.setattr(module._Damping, "damped", failing_first)
    ours = solve_with_python_factors(base, initial, extra=(MotionTerms(motion),))
    assert tries[1] == pytest.approx(tries[0] * gtsam.LevenbergMarquardtParams().getlambdaFactor())
    assert ours.error == pytest.approx(reference.error, rel=1e-6)


def test_motion_terms_name_a_missing_state():
    terms = MotionTerms(motion_factors(np.zeros((2, 3)), np.ones((2, 3)), keys=[3, 7]))
    values = gtsam.Values()
    values.insert(X(3), gtsam.Pose3())
    values.insert(V(3), np.zeros(3))
    values.insert(V(7), np.zeros(3))
    with pytest.raises(GraphError, match="no Pose3 for x7"):
        terms.error(values)


def test_python_driven_lm_refuses_modes_it_does_not_implement():
    graph, _, initial, _ = imu_gps_motion_graph(3, seed=4)
    params = gtsam.LevenbergMarquardtParams()
    params.setDiagonalDamping(True)
    with pytest.raises(InputError, match="default LM modes"):
        solve_with_python_factors(graph, initial, params)


def test_motion_factors_keys_and_full_covariances():
    rng = np.random.default_rng(5)
    v_body = rng.normal(size=(2, 3))
    cov = np.stack([random_cov(rng), random_cov(rng)])
    made = motion_factors(v_body, cov, pose_key=lambda k: X(k + 1), vel_key=lambda k: V(k + 1), keys=[5, 7])
    assert [list(f.keys()) for f in made] == [[X(6), V(6)], [X(8), V(8)]]
    np.testing.assert_array_equal(made[1].v_body, v_body[1])
    np.testing.assert_allclose(made[1].cov, cov[1])


@pytest.mark.parametrize(
    ("v_body", "cov", "message"),
    [
        ([np.nan, 0.0, 0.0], [1.0, 1.0, 1.0], "v_body contains NaN"),
        ([0.0, 0.0, 0.0], [1.0, np.inf, 1.0], "cov contains NaN"),
        ([0.0, 0.0], [1.0, 1.0, 1.0], "v_body must have shape"),
        ([0.0, 0.0, 0.0], np.ones((3, 4)), "cov must have shape"),
        ([0.0, 0.0, 0.0], [1.0, 0.0, 1.0], "variances must be positive"),
        ([0.0, 0.0, 0.0], -np.eye(3), "positive definite"),
        ([0.0, 0.0, 0.0], [[1.0, 0.5, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], "symmetric"),
        ("fast", [1.0, 1.0, 1.0], "real numbers"),
    ],
)
def test_bad_measurement_is_refused(v_body, cov, message):
    with pytest.raises(InputError, match=message):
        MotionFactor(X(0), V(0), v_body, cov)


@pytest.mark.parametrize(
    ("v_body", "cov", "keys", "message"),
    [
        (np.zeros((3, 3)), np.ones((2, 3)), None, r"cov must have shape \(3, 3\)"),
        (np.zeros(3), np.ones(3), None, r"v_body must have shape \(K, 3\)"),
        (np.zeros((2, 3)), np.ones((2, 3)), [0], "keys must be 2 integer"),
        (np.zeros((2, 3)), np.ones((2, 3)), [0.0, 1.0], "keys must be 2 integer"),
        (np.array([[0, 0, 0], [0, np.nan, 0]]), np.ones((2, 3)), [4, 9], r"row 1 \(keyframe 9\).*v_body contains NaN"),
        (np.zeros((2, 3)), np.array([np.eye(3), -np.eye(3)]), None, r"row 1 .*positive definite"),
    ],
)
def test_motion_factors_refuse_bad_rows_by_name(v_body, cov, keys, message):
    with pytest.raises(InputError, match=message):
        motion_factors(v_body, cov, keys=keys)
