"""The IMU + GPS pose graph: fusion beats GPS alone, both backends agree, TUM output reads back in evo."""

from __future__ import annotations

import dataclasses

import gtsam
import numpy as np
import pytest

from airimu.experiments.pgo import ate_m, gps_for
from airimu_core.sequence import GpsFixes
from factors import load_export
from fusion.config import FusionSettings
from fusion.graph import build_graph, solve, with_marginals
from learned_imu.datasets.simulator import ImuErrorModel, simulate
from learned_imu.export import export_preintegration, keyframes_every

WHITE = ImuErrorModel(1e-4, 1e-3, 0.0, 0.0, 0.0, 0.0)  # white noise only: the exported covariance is exact


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    seq = simulate("drone", duration_s=20.0, error_model=WHITE, seed=3)
    path = tmp_path_factory.mktemp("graph") / "sim.npz"
    export_preintegration(path, seq, keyframes_every(seq, 0.1), 1e-4**2, 1e-3**2)
    return seq, load_export(path)


def test_fusion_is_better_than_gps_alone_and_backends_agree(setup):
    seq, export = setup
    fuse, truth = gps_for(seq, 1.0, 0.5, seed=0)  # 1 Hz GPS with 0.5 m noise
    solutions = {}
    for backend in ("gtsam", "custom"):
        settings = FusionSettings(backend=backend, relative_error_tol=1e-10)
        graph, values = build_graph(export, fuse, settings)
        solutions[backend] = solve(graph, values, export.keyframe_t, settings)
    gps_error = np.sqrt(np.mean(np.sum((fuse.pos - seq.gt.pos[np.searchsorted(seq.t, fuse.t)]) ** 2, axis=1)))
    fused = ate_m(solutions["gtsam"], truth)
    assert fused < 0.3 * gps_error  # measured 0.15 m vs 0.87 m
    assert solutions["gtsam"].iterations < 10 and solutions["custom"].iterations < 10
    assert abs(solutions["custom"].final_error - solutions["gtsam"].final_error) < 1e-3 * solutions["gtsam"].final_error
    assert abs(ate_m(solutions["custom"], truth) - fused) < 0.005


def test_marginals_tum_output_and_evo(setup, tmp_path):
    from evo.tools import file_interface

    seq, export = setup
    fuse, _ = gps_for(seq, 1.0, 0.1, seed=1)
    graph, values = build_graph(export, fuse)
    solution = solve(graph, values, export.keyframe_t)
    trajectory = with_marginals(solution)
    assert trajectory.pos_cov.shape == (len(export.keyframe_t), 3, 3)
    assert np.all(np.linalg.eigvalsh(trajectory.pos_cov) > 0)
    # fusing 20 fixes through the IMU leaves less position uncertainty than one fix (0.1 m per axis)
    sigma = np.sqrt(np.trace(trajectory.pos_cov, axis1=1, axis2=2))
    assert np.all(sigma < 0.1 * np.sqrt(3)) and np.median(sigma) < 0.1  # measured 0.07-0.12 m
    assert sigma[-1] > sigma[len(sigma) // 2]  # and it grows after the last fix (19 s)
    tum = trajectory.write_tum(tmp_path / "fused.tum")
    read = file_interface.read_tum_trajectory_file(str(tum))
    np.testing.assert_allclose(read.positions_xyz, trajectory.pos, atol=1e-8)
    np.testing.assert_allclose(read.timestamps, trajectory.t, atol=1e-8)
    quat_wxyz = read.orientations_quat_wxyz
    from scipy.spatial.transform import Rotation

    rot = Rotation.from_quat(quat_wxyz[:, [1, 2, 3, 0]]).as_matrix()
    np.testing.assert_allclose(rot, trajectory.rot, atol=1e-7)


def test_gps_far_from_keyframes_is_an_error(setup):
    _, export = setup
    far = GpsFixes(np.array([1e6]), np.zeros((1, 3)), np.full((1, 3), 0.1))
    with pytest.raises(ValueError, match="no GPS fix"):
        build_graph(export, far)


@pytest.mark.slow
def test_without_ground_truth_the_first_state_is_aligned_to_the_gps_track(tmp_path):
    """No known first state (as on KITTI): roll/pitch from gravity and the heading found by search, whatever the
    platform's true heading; the fused trajectory is as good as with the true first state."""
    import dataclasses

    from gtsam.symbol_shorthand import X

    seq = simulate("car", duration_s=60.0, error_model=WHITE, seed=5)
    path = tmp_path / "no_gt.npz"
    export_preintegration(path, dataclasses.replace(seq, gt=None), keyframes_every(seq, 0.5), 1e-4**2, 1e-3**2)
    export = load_export(path)
    assert export.truth is None
    fuse, truth = gps_for(seq, 0.2, 0.1, seed=0)  # a fix every 5 s
    first = int(export.keyframe_index[0])
    known = gtsam.NavState(gtsam.Pose3(gtsam.Rot3(seq.gt.rot[first]), seq.gt.pos[first]), seq.gt.vel[first])
    ates, first_rot = {}, {}
    for name, initial in (("aligned", None), ("known", known)):
        graph, values = build_graph(export, fuse, initial_state=initial)
        solution = solve(graph, values, export.keyframe_t)
        ates[name] = ate_m(solution, truth)
        first_rot[name] = solution.values.atPose3(X(0)).rotation().matrix()
    cos = (np.trace(seq.gt.rot[first].T @ first_rot["aligned"]) - 1) / 2
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))) < 1.0  # measured 0.05 deg
    assert ates["aligned"] < 0.3  # measured 0.156 m (GPS sigma 0.1 m, fixes 5 s apart)
    assert abs(ates["aligned"] - ates["known"]) < 0.02  # measured 0.005 m


def test_position_at_interpolates_between_keyframes():
    """Cubic Hermite on keyframe positions and velocities: exact for a constant-acceleration path, and what ATE
    uses to compare at the reference's own times (not the nearest keyframe's)."""
    from fusion.graph import Trajectory

    t = np.arange(0.0, 5.01, 1.0)
    acc, vel0 = np.array([0.3, -0.2, 0.1]), np.array([10.0, 2.0, 0.0])
    pos = vel0 * t[:, None] + 0.5 * acc * t[:, None] ** 2
    traj = Trajectory(t, np.repeat(np.eye(3)[None], len(t), 0), pos, vel0 + acc * t[:, None])
    query = np.array([0.0, 0.25, 1.5, 3.99, 5.0])
    expected = vel0 * query[:, None] + 0.5 * acc * query[:, None] ** 2
    np.testing.assert_allclose(traj.position_at(query), expected, atol=1e-12)
    with pytest.raises(ValueError, match="position_at"):
        traj.position_at([5.5])


def test_bias_states_match_a_graph_of_gtsams_own_preintegration(tmp_path):
    """GTSAM's IMUKittiExampleGPS.py graph (a bias per keyframe, its random walk and prior) built from an export:
    the same solution as the graph of GTSAM's own ``PreintegratedImuMeasurements``, and the bias is found."""
    import gtsam

    from factors import learned_pim
    from fusion.config import BiasStates
    from fusion.graph import B, V, X

    biased = ImuErrorModel(1e-4, 1e-3, 0.0, 0.0, 0.02, 0.1)  # turn-on biases: 0.02 rad/s, 0.1 m/s^2 (one sigma)
    seq = simulate("car", duration_s=30.0, error_model=biased, seed=4)
    index = keyframes_every(seq, 0.5)
    export = load_export(export_preintegration(tmp_path / "raw.npz", seq, index, 1e-4**2, 1e-3**2))
    fuse, truth = gps_for(seq, 1.0, 0.1, seed=0)
    bias = BiasStates(acc_walk_sigma=1e-4, gyro_walk_sigma=1e-5, acc_prior_sigma=1.0, gyro_prior_sigma=0.1)
    settings = FusionSettings(relative_error_tol=1e-12, absolute_error_tol=1e-12)
    graph, values = build_graph(export, fuse, settings, bias=bias)
    ours = solve(graph, values, export.keyframe_t, settings)
    without = solve(*build_graph(export, fuse, settings), export.keyframe_t, settings)

    reference = gtsam.NonlinearFactorGraph()  # GTSAM's preintegration in place of the export's IMU factors
    intervals = len(index) - 1
    for k in range(intervals):
        take = slice(index[k], index[k + 1])
        pim = learned_pim(seq.gyro[take], seq.acc[take], seq.dt[take], 1e-4**2, 1e-3**2, seq.gravity)
        reference.add(gtsam.ImuFactor(X(k), V(k), X(k + 1), V(k + 1), B(k), pim))
    for i in range(intervals, graph.size()):  # GPS factors, priors, bias walk and prior, in build_graph's order
        reference.add(graph.at(i))
    theirs = solve(reference, values, export.keyframe_t, settings)
    np.testing.assert_allclose(ours.trajectory.pos, theirs.trajectory.pos, atol=1e-3)
    found = [ours.values.atConstantBias(B(k)) for k in (0, intervals)]
    expected = [theirs.values.atConstantBias(B(k)) for k in (0, intervals)]
    for a, b in zip(found, expected, strict=True):
        np.testing.assert_allclose(a.vector(), b.vector(), atol=1e-4)
    assert ate_m(ours, truth) < 0.5 * ate_m(without, truth)  # estimating the bias pays on a biased IMU
    with pytest.raises(ValueError, match="acc_walk_sigma"):
        BiasStates(0.0, 1e-5, 1.0, 0.1)

    # the same bias model through gtsam.CombinedImuFactor (the random walk inside the preintegration)
    combined = dataclasses.replace(bias, factor="combined")
    graph, values = build_graph(export, fuse, settings, bias=combined)
    assert sum(isinstance(graph.at(i), gtsam.CombinedImuFactor) for i in range(graph.size())) == intervals
    solved = solve(graph, values, export.keyframe_t, settings)
    assert ate_m(solved, truth) < 0.5 * ate_m(without, truth)
    np.testing.assert_allclose(solved.trajectory.pos, ours.trajectory.pos, atol=0.05)  # two models of one walk


def test_bias_walk_per_interval_or_cumulative_as_gtsams_kitti_example(setup):
    """The walk's sigma between B(k) and B(k+1): sqrt(samples of the interval) times the per-sample sigma, or with
    ``walk="cumulative"`` sqrt(samples since the first keyframe) times it (IMUKittiExampleGPS.py's count, the rule
    of the PGO ablation's GTSAM row); a cumulative walk needs BetweenFactors."""
    from airimu.experiments.pgo import GTSAM_EXAMPLE
    from airimu_core.errors import ConfigError
    from fusion.config import BiasStates

    seq, export = setup
    fuse, _ = gps_for(seq, 1.0, 0.5, seed=0)
    samples = np.diff(export.keyframe_index)
    per_sample = np.array([1e-4] * 3 + [1e-5] * 3)
    for walk, count in (("per_interval", samples), ("cumulative", np.cumsum(samples))):
        bias = BiasStates(1e-4, 1e-5, 1.0, 0.1, walk=walk)
        graph, _ = build_graph(export, fuse, FusionSettings(), bias=bias)
        sigmas = [
            graph.at(i).noiseModel().sigmas()
            for i in range(graph.size())
            if isinstance(graph.at(i), gtsam.BetweenFactorConstantBias)
        ]
        np.testing.assert_allclose(np.array(sigmas), np.sqrt(count)[:, None] * per_sample, rtol=1e-12)
    assert np.sqrt(np.cumsum(samples)[-1] / samples[-1]) > 10  # the two differ: 200 keyframes, 14x at the end
    assert GTSAM_EXAMPLE.bias.walk == "cumulative"
    with pytest.raises(ConfigError, match="BiasStates.walk must be one of per_interval, cumulative"):
        BiasStates(1e-4, 1e-5, 1.0, 0.1, walk="per_sample")
    with pytest.raises(ConfigError, match="'cumulative' needs factor 'between'"):
        BiasStates(1e-4, 1e-5, 1.0, 0.1, factor="combined", walk="cumulative")


def test_the_first_state_is_a_gtsam_navstate():
    """A (rot, pos, vel) tuple read in another order than learned_imu's NavState(rot, vel, pos): refused, with the
    recipe; a NavState with NaN too."""
    from airimu_core.errors import InputError
    from fusion.initial import first_state

    pose, vel = first_state(gtsam.NavState(gtsam.Pose3(gtsam.Rot3.Rz(0.3), [1.0, 2.0, 3.0]), [4.0, 5.0, 6.0]), "t")
    assert np.allclose(pose.translation(), [1, 2, 3]) and np.allclose(vel, [4, 5, 6])
    with pytest.raises(InputError, match=r"t: initial_state must be a gtsam.NavState, e.g. gtsam.NavState\("):
        first_state((np.eye(3), np.zeros(3), np.zeros(3)), "t")
    with pytest.raises(InputError, match="NaN"):
        first_state(gtsam.NavState(gtsam.Pose3(), [np.nan, 0.0, 0.0]), "t")
