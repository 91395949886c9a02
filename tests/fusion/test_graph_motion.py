"""Learned body-frame velocities in the batch graph: without GPS they hold a drifting IMU, with GPS outages they
bridge the gap; the graph refuses what it cannot determine; the consistency check names the motion factors."""

from __future__ import annotations

import dataclasses

import gtsam
import numpy as np
import pytest

from airimu.fuse import fuse, write_outputs
from airimu_core.errors import DataError, GraphError, InputError
from airimu_core.motion import BodyVelocities
from factors import MotionFactor
from fusion import consistency
from fusion.config import FuseConfig, MotionSettings
from fusion.graph import build_graph, solve
from learned_imu.datasets.simulator import ImuErrorModel, simulate
from learned_imu.export import keyframes_every, preintegration_export

# white noise and a constant bias the graph does not model: strapdown drifts metres in 30 s
DRIFTING = ImuErrorModel(2e-3, 2e-2, 0.0, 0.0, 2e-3, 5e-2)
VEL_SIGMA = 0.05  # m/s, the simulated motion model's error


def body_velocities(seq, every: int = 9, sigma: float = VEL_SIGMA, seed: int = 0) -> BodyVelocities:
    """The truth's R^T v every ``every`` samples with N(0, sigma^2) noise and that variance: a perfect model."""
    ends = np.arange(every - 1, len(seq.t), every)
    body = np.einsum("nji,nj->ni", seq.gt.rot[ends], seq.gt.vel[ends])
    noisy = body + np.random.default_rng(seed).normal(0.0, sigma, body.shape)
    return BodyVelocities(seq.t[ends], noisy, np.full_like(body, sigma**2))


@pytest.fixture(scope="module")
def drone():
    seq = simulate("drone", duration_s=30.0, error_model=DRIFTING, seed=5, gps_rate_hz=1.0, gps_sigma_m=0.3)
    export = preintegration_export(seq, keyframes_every(seq, 0.2), 2e-3**2, 2e-2**2)
    return seq, export


def position_rmse(solution, seq) -> float:
    truth = seq.gt.pos[np.searchsorted(seq.t, solution.trajectory.t)]
    return float(np.sqrt(np.mean(np.sum((solution.trajectory.pos - truth) ** 2, axis=1))))


def test_without_gps_motion_factors_hold_the_drift(drone):
    seq, export = drone
    alone = solve(*build_graph(export, None), export.keyframe_t)  # the ground truth's first state anchors it
    graph, values = build_graph(export, None, motion=body_velocities(seq))
    solution = solve(graph, values, export.keyframe_t)
    motion = [graph.at(i) for i in range(graph.size()) if isinstance(graph.at(i), MotionFactor)]
    assert len(motion) == len(export.keyframe_t) - 1  # every keyframe after the first output (t >= 8 samples)
    drift, held = position_rmse(alone, seq), position_rmse(solution, seq)
    assert drift > 5.0 and held < 0.02 * drift, (drift, held)  # measured 29.6 m against 0.18 m
    found = consistency.residuals(solution.graph, solution.values)
    assert "motion" in found and 0.3 < found["motion"].per_dof < 3.0  # the variances are the noise's: 0.72


def test_a_graph_without_gps_needs_a_known_first_state(drone):
    seq, export = drone
    blind = dataclasses.replace(export, truth=None)
    with pytest.raises(GraphError, match="first state must be known"):
        build_graph(blind, None, motion=body_velocities(seq))
    pose = gtsam.Pose3(gtsam.Rot3(seq.gt.rot[0]), seq.gt.pos[0])
    graph, values = build_graph(blind, None, initial_state=gtsam.NavState(pose, seq.gt.vel[0]))
    assert graph.error(values) < 1e-6  # dead reckoning is its own solution


def test_body_velocities_refuse_bad_values():
    t, vel, var = np.arange(3.0), np.zeros((3, 3)), np.ones((3, 3))
    with pytest.raises(InputError, match="strictly increasing"):
        BodyVelocities(np.array([0.0, 1.0, 1.0]), vel, var)
    with pytest.raises(InputError, match="NaN"):
        BodyVelocities(t, np.full((3, 3), np.nan), var)
    with pytest.raises(InputError, match="positive"):
        BodyVelocities(t, vel, -var)
    with pytest.raises(InputError, match=r"\(M, 3\)"):
        BodyVelocities(t, vel[:, :2], var)
    half = BodyVelocities(t, np.arange(9.0).reshape(3, 3), var).at([0.5, 5.0])
    np.testing.assert_allclose(half[0][0], [1.5, 2.5, 3.5])
    assert half[2].tolist() == [True, False]
    per_axis = BodyVelocities(t, vel, var).scaled([4.0, 1.0, 0.5])
    np.testing.assert_array_equal(per_axis.var, np.tile([4.0, 1.0, 0.5], (3, 1)))
    for bad in (0.0, [1.0, 2.0], [1.0, np.nan, 1.0]):
        with pytest.raises(InputError, match="one or three positive"):
            BodyVelocities(t, vel, var).scaled(bad)


def test_fuse_bridges_a_gps_outage_with_motion_factors(drone, tmp_path, monkeypatch):
    seq, _ = drone
    velocities = body_velocities(seq)
    import learned_imu.network.motion as motion_module

    # a "model" that is the truth plus noise: fuse's passes, keyframes and outputs are under test, not a network
    monkeypatch.setattr(motion_module, "predict_velocities", lambda model, sequence, rot: velocities)
    config = FuseConfig(gyro_noise_density=2e-3, acc_noise_density=2e-2, keyframe_s=0.2)
    outage = ((10.0, 15.0),)
    plain = fuse(seq, config=config, outages=outage)
    assert not np.any((plain.gps.t >= seq.t[0] + 10.0) & (plain.gps.t < seq.t[0] + 25.0))
    with_motion = fuse(seq, config=config, motion_model=object(), outages=outage)
    summaries = [
        write_outputs(r, tmp_path / name, reference=seq.gps)[0] for r, name in ((plain, "a"), (with_motion, "b"))
    ]
    errors = [s.outages[0]["error_to_truth_m"] for s in summaries]
    # the causal estimate at the outage's end (the fix that ends it not fused): measured 24.7 m against 0.06 m
    assert errors[0] > 5.0 and errors[1] < 0.05 * errors[0], errors
    assert summaries[1].motion_factors > 100 and summaries[0].motion_factors == 0
    assert summaries[1].outages[0]["end_t_s"] == pytest.approx(seq.t[0] + 25.0)
    assert (tmp_path / "b" / "fused.png").stat().st_size > 0


def test_an_outage_ending_one_sample_after_a_keyframe_is_scored(drone, monkeypatch):
    seq, _ = drone
    velocities = body_velocities(seq)
    import learned_imu.network.motion as motion_module

    monkeypatch.setattr(motion_module, "predict_velocities", lambda model, sequence, rot: velocities)
    dt = float(seq.t[1] - seq.t[0])
    config = FuseConfig(gyro_noise_density=2e-3, acc_noise_density=2e-2, keyframe_s=0.2)
    # the 0.2-s grid has a keyframe one sample before the outage's end: it moves to the end (was a singular interval)
    done = fuse(seq, config=config, motion_model=object(), outages=((10.0, 15.0 + 1.2 * dt),))
    ((end_t, end_pos),) = done.outage_ends
    assert end_t == pytest.approx(seq.t[0] + 15.0 + 10.0 + dt)
    assert np.linalg.norm(end_pos - seq.gt.pos[np.searchsorted(seq.t, end_t)]) < 1.0


def test_an_earlier_solution_is_a_candidate_for_the_initial_values(drone):
    seq, export = drone
    idx = np.searchsorted(seq.t, export.keyframe_t)
    truth = gtsam.Values()
    for k, i in enumerate(idx):
        truth.insert(gtsam.symbol("x", k), gtsam.Pose3(gtsam.Rot3(seq.gt.rot[i]), seq.gt.pos[i]))
        truth.insert(gtsam.symbol("v", k), seq.gt.vel[i])
    motion = body_velocities(seq)
    graph, plain = build_graph(export, seq.gps[::10], motion=motion)
    graph, guessed = build_graph(export, seq.gps[::10], motion=motion, guess=truth)
    # the truth fits the graph far better than the guesses built from the IMU, the fixes or the velocities
    assert graph.error(guessed) < 0.1 * graph.error(plain)
    assert guessed.atPose3(gtsam.symbol("x", 7)).equals(truth.atPose3(gtsam.symbol("x", 7)), 1e-12)
    truth.erase(gtsam.symbol("v", 3))
    with pytest.raises(GraphError, match="keyframe 3"):
        build_graph(export, seq.gps[::10], motion=motion, guess=truth)


def test_fuse_without_gps_needs_a_start(drone):
    seq, _ = drone
    blind = dataclasses.replace(seq, gps=None)
    with pytest.raises(DataError, match="--start"):
        fuse(blind, config=FuseConfig(keyframe_s=0.5))
    done = fuse(blind, config=FuseConfig(keyframe_s=0.5), start="ground-truth")
    assert len(done.gps.t) == 0 and done.solution.trajectory.t[0] == seq.t[0]
    with pytest.raises(InputError, match="ground-truth"):
        fuse(blind, config=FuseConfig(keyframe_s=0.5), start="truth")


def test_motion_settings_refuse_out_of_range_values():
    from airimu_core.errors import ConfigError

    for bad in ({"keyframe_s": 0.0}, {"passes": 0}, {"cov_scale": float("nan")}):
        with pytest.raises(ConfigError, match="motion."):
            MotionSettings(**bad)


def test_cov_scale_per_axis_frees_a_biased_axis(drone):
    """motion.cov_scale with three numbers scales each body axis's variance: a model whose x velocity is 0.5 m/s off
    (a car's forward speed it cannot know) pulls the 1-Hz GPS + IMU graph off; x scaled by 1e6 leaves that axis to
    the IMU and the fixes while y and z still hold (measured: 2.20 m against 0.21, the right velocities 0.12, no motion
    factor 0.30)."""
    from airimu_core.config import from_dict

    seq, export = drone
    truth = body_velocities(seq)
    biased = BodyVelocities(truth.t, truth.vel + np.array([0.5, 0.0, 0.0]), truth.var)
    gps = seq.gps
    errors = {}
    for scale in (1.0, (1.0e6, 1.0, 1.0)):
        settings = from_dict(FuseConfig, {"motion": {"cov_scale": scale}}, source="test").motion
        graph, values = build_graph(export, gps, motion=biased.scaled(settings.cov_scale))
        errors[scale] = position_rmse(solve(graph, values, export.keyframe_t), seq)
    graph, values = build_graph(export, gps, motion=truth)
    right = position_rmse(solve(graph, values, export.keyframe_t), seq)
    assert errors[1.0] > 3 * errors[(1.0e6, 1.0, 1.0)], errors
    assert errors[(1.0e6, 1.0, 1.0)] < 3 * right + 0.05, (errors, right)


@pytest.mark.parametrize("bad", [[1.0, 2.0], [1.0, -1.0, 1.0], "x", [1.0, float("inf"), 1.0], True])
def test_cov_scale_is_one_positive_number_or_three(bad):
    from airimu_core.config import from_dict
    from airimu_core.errors import ConfigError

    assert from_dict(FuseConfig, {"motion": {"cov_scale": [1e6, 1, 1]}}, source="t").motion.cov_scale == (1e6, 1, 1)
    assert from_dict(FuseConfig, {"motion": {"cov_scale": 3}}, source="t").motion.cov_scale == 3.0
    assert from_dict(FuseConfig, {"motion": {"cov_scale": [3]}}, source="t").motion.cov_scale == 3.0  # as 3
    with pytest.raises(ConfigError, match="motion.cov_scale"):
        from_dict(FuseConfig, {"motion": {"cov_scale": bad}}, source="t")


def test_bias_states_with_motion_factors_solve_on_the_python_stepped_route(drone, monkeypatch):
    """With bias states the export graph is re-linearised (``factors.solve_relinearised``); its motion factors are
    then solved by ``fusion.graph.solve_motion_graph`` (10-25x faster than GTSAM's LM calling them back), to the
    same solution."""
    import fusion.solve as module

    seq, export = drone
    config, motion = FuseConfig(estimate_bias=True), body_velocities(seq)
    calls, real = [], module.solve_motion_graph
    monkeypatch.setattr(module, "solve_motion_graph", lambda *args: calls.append(1) or real(*args))
    fast, _ = module.solve_export(export, None, config, motion=motion)
    assert calls  # every round of the re-linearisation
    monkeypatch.setattr(module, "fast_route", lambda graph, settings: None)  # GTSAM's LM with the callbacks
    slow, _ = module.solve_export(export, None, config, motion=motion)
    assert len(calls) == fast.iterations  # the slow route did not call it
    np.testing.assert_allclose(fast.trajectory.pos, slow.trajectory.pos, atol=1e-6)
    assert position_rmse(fast, seq) < 1.0


def test_a_mount_state_takes_up_a_rotated_model(drone):
    """A model whose velocities are in a frame 5 degrees off the IMU's (pitch 0.08, yaw -0.05 rad; a car's IMU
    mounted differently from the training drives'): without GPS the plain factors pull the attitude towards that
    frame and gravity leaks into the position; a mount state (``motion.mount_sigma_rad``) finds the rotation and
    holds the track (measured: the rotation to 0.008 rad, 0.19 m against 0.56 without it, the right frame's 0.18)."""
    seq, export = drone
    truth = body_velocities(seq)
    mount = gtsam.Rot3.Ypr(-0.05, 0.08, 0.0)  # IMU body <- the model's frame
    rotated = BodyVelocities(truth.t, truth.vel @ mount.matrix(), truth.var)  # M^T v per row
    plain = solve(*build_graph(export, None, motion=rotated), export.keyframe_t)
    graph, values = build_graph(export, None, motion=rotated, mount_sigma_rad=0.1)
    mounted = solve(graph, values, export.keyframe_t)
    found = mounted.values.atRot3(gtsam.symbol_shorthand.M(0))
    # within 0.012 rad of the 0.04-rad rotation (measured 0.008: the IMU's unmodelled bias, 0.05 m/s^2, tilts it)
    assert np.linalg.norm(gtsam.Rot3.Logmap(found.between(mount))) < 0.012
    right = position_rmse(solve(*build_graph(export, None, motion=truth), export.keyframe_t), seq)
    held = position_rmse(mounted, seq)
    assert position_rmse(plain, seq) > 3 * held and held < 2 * right + 0.05, (position_rmse(plain, seq), held, right)


def test_mount_sigma_is_null_or_one_or_three_sigmas():
    from airimu_core.config import from_dict
    from airimu_core.errors import ConfigError

    assert from_dict(FuseConfig, {}, source="t").motion.mount_sigma_rad is None
    assert from_dict(FuseConfig, {"motion": {"mount_sigma_rad": 0.01}}, source="t").motion.mount_sigma_rad == 0.01
    three = from_dict(FuseConfig, {"motion": {"mount_sigma_rad": [0.1, 0.01, 0.01]}}, source="t").motion
    assert three.mount_sigma_rad == (0.1, 0.01, 0.01)
    for bad in (0.0, -0.01, 2.0, [0.1, 0.1], "x", float("nan"), True):
        with pytest.raises(ConfigError, match="motion.mount_sigma_rad"):
            from_dict(FuseConfig, {"motion": {"mount_sigma_rad": bad}}, source="t")
