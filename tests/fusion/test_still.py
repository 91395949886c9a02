"""``fusion.still``: a still start gives the raw gyro's bias and roll / pitch, only when the motion confirms it;
``fuse`` takes the bias out (real data: a BROAD trial)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from airimu_core.sequence import GpsFixes
from fusion.config import FuseConfig
from fusion.still import still_start

BIAS = np.array([0.004, -0.002, 0.006])  # rad/s


def _log(still_s: float = 6.0, seconds: float = 10.0, rate: float = 100.0):
    """A still start of ``still_s`` (gyro = BIAS + noise, acc = gravity + noise, tilted 3 degrees about x), then a
    turn at 0.5 rad/s while accelerating at 1 m/s^2."""
    rng = np.random.default_rng(0)
    t = np.arange(0.0, seconds, 1.0 / rate)
    tilt = np.radians(3.0)
    up = np.array([0.0, np.sin(tilt), np.cos(tilt)])
    gyro = BIAS + rng.normal(0.0, 2e-3, (len(t), 3))
    acc = 9.81 * up + rng.normal(0.0, 0.02, (len(t), 3))
    moving = t >= still_s
    gyro[moving, 2] += 0.5
    acc[moving, 0] += 1.0
    return t, gyro, acc, up


def test_a_still_start_gives_the_gyro_bias_and_gravity_with_their_sigmas():
    t, gyro, acc, up = _log()
    still = still_start(t, gyro, acc, start_velocity=np.zeros(3))
    assert still is not None and 5.4 <= still.duration_s <= 6.0
    assert np.all(np.abs(still.gyro_bias - BIAS) < 4.0 * still.gyro_bias_sigma + 1e-4)
    assert np.all(still.gyro_bias_sigma < 5e-4)
    assert np.degrees(np.arccos(np.clip(still.up @ up, -1.0, 1.0))) < 3.0 * np.degrees(still.tilt_sigma_rad)


def test_a_still_start_needs_the_motion_to_confirm_it():
    t, gyro, acc, _ = _log()
    assert still_start(t, gyro, acc) is None  # the IMU alone cannot tell still from cruising
    assert still_start(t, gyro, acc, start_velocity=np.array([5.0, 0.0, 0.0])) is None
    still_fixes = GpsFixes(np.arange(0.0, 10.0), np.zeros((10, 3)), np.full((10, 3), 0.3))
    assert still_start(t, gyro, acc, fixes=still_fixes).duration_s >= 5.4
    moved = np.zeros((10, 3))
    moved[3:, 0] = 5.0 * np.arange(1, 8)  # the GPS moves from 3 s on: the span ends at the fix before
    cut = still_start(t, gyro, acc, fixes=dataclasses.replace(still_fixes, pos=moved))
    assert cut is not None and 2.0 <= cut.duration_s <= 2.01
    short = still_start(*_log(still_s=1.0)[:3], start_velocity=np.zeros(3))
    assert short is None  # under MIN_S
    # moving from the first sample while the fixes stand still up to 3 s: the fixes confirm nothing the IMU did not
    # show (the span is never taken from the GPS alone)
    t, gyro, acc, _ = _log(still_s=0.0)
    assert still_start(t, gyro, acc, fixes=dataclasses.replace(still_fixes, pos=moved)) is None


def test_fuse_takes_a_still_starts_gyro_bias_out_on_a_real_broad_trial(shared_data):
    """BROAD trial 03 starts still for ~35 s with a gyro bias of ~9 mrad/s: dead reckoning from its ground-truth
    start, the keyframe attitudes end far closer to the truth with the bias taken out than without."""
    from scipy.spatial.transform import Rotation

    from airimu.fuse import fuse, still_summary
    from learned_imu.datasets import read_sequence

    seq = read_sequence("broad", shared_data / "broad" / "03_undisturbed_slow_rotation_C.mat")
    seq = seq.between(seq.t[0], seq.t[0] + 80.0)
    errors = {}
    for on in (True, False):
        config = FuseConfig(keyframe_s=1.0, still_start=on)
        result = fuse(seq, None, None, config, start="ground-truth")
        traj = result.solution.trajectory
        at = np.searchsorted(seq.t, traj.t)
        relative = np.einsum("nji,njk->nik", seq.gt.rot[at], traj.rot)
        errors[on] = float(np.degrees(Rotation.from_matrix(relative).magnitude()).max())
        if on:
            assert result.still is not None and result.still.duration_s > 30.0
            assert np.abs(result.still.gyro_bias * 1e3 - [8.72, -3.26, -4.35]).max() < 0.1  # mrad/s
            summary = still_summary(result)
            assert summary["tilt_error_deg"] < 0.3 and summary["tilt_sigma_deg"] >= 0.29
        else:
            assert result.still is None
    assert errors[True] < 0.2 * errors[False], errors


def test_an_aligned_start_takes_roll_and_pitch_from_the_still_gravity(shared_data):
    """KITTI 2011_09_26_drive_0018 parks for 18.6 s: without --start, the prior on the first pose has the still
    start's tilt sigma about the horizontal axes (not the loose 0.2 rad), and its tilt is within 0.5 deg of the
    truth the fusion never read (measured 0.34 deg)."""
    import gtsam

    from airimu.experiments.pgo import gps_for
    from airimu.fuse import fuse, initial_attitude_error
    from learned_imu.datasets import read_sequence

    seq = read_sequence(
        "kitti_raw",
        shared_data / "kitti_raw" / "2011_09_26_drive_0018.csv",
        on_backward="drop",
        on_duplicate="drop",
        on_gap="keep",
    )
    fixes = gps_for(seq, 1.0, 0.5, seed=0, source="simulated")[0]
    result = fuse(dataclasses.replace(seq, gps=None), fixes, None, FuseConfig(keyframe_s=1.0))
    assert result.still is not None and result.still.duration_s > 15.0
    graph = result.solution.graph
    priors = [
        graph.at(i)
        for i in range(graph.size())
        if isinstance(graph.at(i), gtsam.PriorFactorPose3) and graph.at(i).keys()[0] == gtsam.symbol_shorthand.X(0)
    ]
    assert len(priors) == 1
    cov = np.linalg.inv(priors[0].noiseModel().information())[:3, :3]  # body-frame rotation tangent
    rot = priors[0].prior().rotation().matrix()
    world = rot @ cov @ rot.T
    np.testing.assert_allclose(np.sqrt(np.linalg.eigvalsh(world[:2, :2])), result.still.tilt_sigma_rad, rtol=1e-6)
    assert np.sqrt(world[2, 2]) == pytest.approx(0.2)  # heading: the aligned prior's loose sigma
    assert initial_attitude_error(result)["tilt"] < 0.5


def test_the_bias_prior_after_a_still_start_is_the_still_spans_own_sigma(tmp_path):
    """With the still start's bias taken out, the prior on the gyro bias left is the still span's sigma (floored at
    ``GYRO_BIAS_FLOOR_RAD_S``, capped by the configured prior), not the configured 0.1 rad/s; the accelerometer's is
    the configured one."""
    import gtsam

    from fusion.config import BiasStates, FusionSettings
    from fusion.graph import build_graph
    from fusion.still import GYRO_BIAS_FLOOR_RAD_S, StillStart
    from learned_imu.datasets.simulator import simulate
    from learned_imu.export import export_preintegration, keyframes_every

    sigma = np.array([2e-5, 3e-4, 0.5])
    still = StillStart(300, 3.0, np.zeros(3), sigma, np.array([0.0, 0.0, 1.0]), 0.005)
    np.testing.assert_allclose(still.gyro_prior_sigma(0.1), [GYRO_BIAS_FLOOR_RAD_S, 3e-4, 0.1])

    seq = simulate("car", duration_s=6.0, seed=1)
    export = export_preintegration(tmp_path / "raw.npz", seq, keyframes_every(seq, 1.0), 1e-4**2, 1e-3**2)
    bias = BiasStates(acc_walk_sigma=1e-4, gyro_walk_sigma=1e-5, acc_prior_sigma=1.0, gyro_prior_sigma=0.1)
    found = {}
    for name, start in (("configured", None), ("still", still)):
        graph, _ = build_graph(export, None, FusionSettings(), bias=bias, still=start)
        priors = [graph.at(i) for i in range(graph.size()) if isinstance(graph.at(i), gtsam.PriorFactorConstantBias)]
        assert len(priors) == 1
        found[name] = priors[0].noiseModel().sigmas()
    np.testing.assert_allclose(found["configured"], [1.0] * 3 + [0.1] * 3)
    np.testing.assert_allclose(found["still"], [1.0] * 3 + [GYRO_BIAS_FLOOR_RAD_S, 3e-4, 0.1])
