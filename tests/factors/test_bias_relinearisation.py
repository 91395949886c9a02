"""Bias re-linearisation on the export route: each interval preintegrated again around the current bias estimate
(GTSAM's ``biasHat``) gives GTSAM's own re-preintegrated solution; the first-order bias Jacobian alone does not."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import B, V, X

from factors import GpsFactor, from_export, gps_noise, learned_combined_pim, load_export
from learned_imu.datasets.simulator import ImuErrorModel, simulate
from learned_imu.export import export_preintegration, keyframes_every

GYRO_COV, ACC_COV = 1e-4**2, 1e-3**2
# turn-on biases drawn with 0.2 rad/s and 0.1 m/s^2 one-sigma: gyro biases of 0.1-0.3 rad/s, as in ImuFactorExample
ERRORS = ImuErrorModel(1e-4, 1e-3, 0.0, 0.0, 0.2, 0.1)


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    seq = simulate("car", duration_s=20.0, error_model=ERRORS, seed=7)
    path = tmp_path_factory.mktemp("relin") / "raw.npz"
    export_preintegration(path, seq, keyframes_every(seq, 1.0), GYRO_COV, ACC_COV)
    return seq, load_export(path)


def others(seq, export) -> gtsam.NonlinearFactorGraph:
    """GPS at every keyframe, the first state from ground truth, the bias walk and a loose bias prior."""
    graph = gtsam.NonlinearFactorGraph()
    gt, index = seq.gt, export.keyframe_index
    rng = np.random.default_rng(0)
    for k, i in enumerate(index):
        graph.add(GpsFactor(X(k), gt.pos[i] + rng.normal(0, 0.1, 3), gps_noise(0.1)))
    graph.add(
        gtsam.PriorFactorPose3(
            X(0), gtsam.Pose3(gtsam.Rot3(gt.rot[0]), gt.pos[0]), gtsam.noiseModel.Isotropic.Sigma(6, 1e-3)
        )
    )
    graph.add(gtsam.PriorFactorVector(V(0), gt.vel[0], gtsam.noiseModel.Isotropic.Sigma(3, 1e-3)))
    loose = gtsam.noiseModel.Isotropic.Sigma(6, 1.0)
    graph.add(gtsam.PriorFactorConstantBias(B(0), gtsam.imuBias.ConstantBias(), loose))
    for k in range(len(index) - 1):
        walk = gtsam.noiseModel.Isotropic.Sigma(6, 1e-4)
        graph.add(gtsam.BetweenFactorConstantBias(B(k), B(k + 1), gtsam.imuBias.ConstantBias(), walk))
    return graph


def initial(seq, export) -> gtsam.Values:
    values = gtsam.Values()
    for k, i in enumerate(export.keyframe_index):
        values.insert(X(k), gtsam.Pose3(gtsam.Rot3(seq.gt.rot[i]), seq.gt.pos[i] + 0.5))
        values.insert(V(k), seq.gt.vel[i] + 0.3)
        values.insert(B(k), gtsam.imuBias.ConstantBias())
    return values


def solve(graph, values) -> gtsam.Values:
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-14)
    params.setAbsoluteErrorTol(1e-14)
    params.setMaxIterations(200)
    return gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()


def relinearised(seq, export, imu_factors) -> gtsam.Values:
    """Solve, preintegrate every interval again at its solved bias, solve again (5 rounds)."""
    values = initial(seq, export)
    for _ in range(5):
        graph = others(seq, export)
        for factor in imu_factors(values):
            graph.add(factor)
        values = solve(graph, values)
    return values


def test_relinearised_learned_route_equals_gtsams_re_preintegrated_route(drive):
    seq, export = drive
    n = len(export.keyframe_index)

    def learned(values):
        return from_export(export, bias=lambda k: values.atConstantBias(B(k)))[0]

    def gtsams_own(values):  # GTSAM's preintegration of the raw samples at the current bias estimate
        params = gtsam.PreintegrationParams(seq.gravity)
        params.setGyroscopeCovariance(np.eye(3) * GYRO_COV)
        params.setAccelerometerCovariance(np.eye(3) * ACC_COV)
        params.setIntegrationCovariance(np.zeros((3, 3)))
        out = []
        for k, (a, b) in enumerate(zip(export.keyframe_index[:-1], export.keyframe_index[1:], strict=True)):
            pim = gtsam.PreintegratedImuMeasurements(params, values.atConstantBias(B(k)))
            for i in range(a, b):
                pim.integrateMeasurement(seq.acc[i], seq.gyro[i], seq.t[i + 1] - seq.t[i])
            out.append(gtsam.ImuFactor(X(k), V(k), X(k + 1), V(k + 1), B(k), pim))
        return out

    ours, theirs = relinearised(seq, export, learned), relinearised(seq, export, gtsams_own)
    graph = others(seq, export)
    for factor in from_export(export)[0]:  # the export's zero-bias deltas, bias to first order only
        graph.add(factor)
    first_order = solve(graph, initial(seq, export))
    for k in range(n):
        np.testing.assert_allclose(ours.atPose3(X(k)).translation(), theirs.atPose3(X(k)).translation(), atol=1e-6)
        np.testing.assert_allclose(ours.atConstantBias(B(k)).vector(), theirs.atConstantBias(B(k)).vector(), atol=1e-6)
    gyro_bias = theirs.atConstantBias(B(0)).gyroscope()
    assert 0.1 < np.abs(gyro_bias).max() < 0.5  # the large biases the test is about
    gap = max(
        np.linalg.norm(first_order.atPose3(X(k)).translation() - theirs.atPose3(X(k)).translation()) for k in range(n)
    )
    assert gap > 1e-3  # the first-order correction alone is off by far more than the re-linearised route


def test_combined_factors_from_an_export(drive):
    seq, export = drive
    params = gtsam.PreintegrationCombinedParams(seq.gravity)
    params.setIntegrationCovariance(np.zeros((3, 3)))
    params.setBiasAccCovariance(np.eye(3) * 1e-6)
    params.setBiasOmegaCovariance(np.eye(3) * 1e-8)
    factors, times = from_export(export, factor="combined", params=params)
    assert len(factors) == len(times) - 1 and all(isinstance(f, gtsam.CombinedImuFactor) for f in factors)
    a, b = export.keyframe_index[2], export.keyframe_index[3]
    pim = learned_combined_pim(seq.gyro[a:b], seq.acc[a:b], np.diff(seq.t)[a:b], GYRO_COV, ACC_COV, params=params)
    np.testing.assert_allclose(factors[2].preintegratedMeasurements().preintMeasCov(), pim.preintMeasCov(), rtol=1e-12)
    with pytest.raises(ValueError, match="PreintegrationCombinedParams"):
        from_export(export, factor="combined")
    wrong = gtsam.PreintegrationParams.MakeSharedU(9.8)  # the export holds the simulator's 9.81
    with pytest.raises(ValueError, match="gravity"):
        from_export(export, params=wrong)
    with pytest.raises(ValueError, match="need backend='gtsam'"):
        from_export(export, backend="custom", bias=gtsam.imuBias.ConstantBias())


def test_solve_relinearised_is_the_loop_built_in(drive):
    """``factors.solve_relinearised`` from the first-order graph reaches GTSAM's own re-preintegrated solution."""
    from factors import solve_relinearised

    seq, export = drive
    n = len(export.keyframe_index)

    theirs = relinearised(seq, export, lambda values: gtsams_own(seq, export, values))
    graph = first_order_graph(seq, export)
    lm = tight_lm()
    done = solve_relinearised(graph, initial(seq, export), export, tol=1e-9, lm_params=lm)
    assert 2 <= done.rounds < 10 and done.bias_change < 1e-9
    for k in range(n):
        np.testing.assert_allclose(
            done.values.atPose3(X(k)).translation(), theirs.atPose3(X(k)).translation(), atol=1e-6
        )
    with pytest.raises(ValueError, match="IMU factors"):
        solve_relinearised(others(seq, export), initial(seq, export), export)


def test_solve_relinearised_on_a_real_flight_with_a_large_gyro_bias(shared_data, tmp_path):
    """116 keyframes of EuRoC V1_03 (its real IMU plus 0.1-0.3 rad/s of gyro bias): the first-order graph is
    centimetres off GTSAM's re-preintegrated solution, the built-in loop equals it to 1e-6 m."""
    import dataclasses

    from factors import solve_relinearised
    from learned_imu.datasets import read_sequence

    seq = read_sequence("euroc", shared_data / "euroc" / "V1_03_difficult")
    seq = dataclasses.replace(seq, gyro=seq.gyro + np.array([0.1, -0.2, 0.3]))
    path = tmp_path / "v103.npz"
    index = keyframes_every(seq, 1.0)[:117]
    export_preintegration(path, seq, index, GYRO_COV, ACC_COV)
    export = load_export(path)

    theirs = relinearised(seq, export, lambda values: gtsams_own(seq, export, values))
    graph = first_order_graph(seq, export)
    lm = tight_lm()
    first = solve(graph, initial(seq, export))
    done = solve_relinearised(graph, initial(seq, export), export, tol=1e-9, lm_params=lm)
    n = len(export.keyframe_index)
    gap = max(np.linalg.norm(first.atPose3(X(k)).translation() - theirs.atPose3(X(k)).translation()) for k in range(n))
    assert gap > 5e-3, gap  # the first-order correction alone: measured 0.30 m (5 solves)
    for k in range(n):
        np.testing.assert_allclose(
            done.values.atPose3(X(k)).translation(), theirs.atPose3(X(k)).translation(), atol=1e-6
        )


def gtsams_own(seq, export, values) -> list:
    """GTSAM's ImuFactors, each interval preintegrated by GTSAM around the bias ``values`` hold for it."""
    params = gtsam.PreintegrationParams(seq.gravity)
    params.setGyroscopeCovariance(np.eye(3) * GYRO_COV)
    params.setAccelerometerCovariance(np.eye(3) * ACC_COV)
    params.setIntegrationCovariance(np.zeros((3, 3)))
    out = []
    for k, (a, b) in enumerate(zip(export.keyframe_index[:-1], export.keyframe_index[1:], strict=True)):
        pim = gtsam.PreintegratedImuMeasurements(params, values.atConstantBias(B(k)))
        for i in range(a, b):
            pim.integrateMeasurement(seq.acc[i], seq.gyro[i], seq.t[i + 1] - seq.t[i])
        out.append(gtsam.ImuFactor(X(k), V(k), X(k + 1), V(k + 1), B(k), pim))
    return out


def first_order_graph(seq, export) -> gtsam.NonlinearFactorGraph:
    """The other factors and the export's first-order IMU factors."""
    graph = others(seq, export)
    for factor in from_export(export)[0]:
        graph.add(factor)
    return graph


def tight_lm() -> gtsam.LevenbergMarquardtParams:
    lm = gtsam.LevenbergMarquardtParams()
    lm.setRelativeErrorTol(1e-14)
    lm.setAbsoluteErrorTol(1e-14)
    lm.setMaxIterations(200)
    return lm
