"""OnlineFusion with a motion model: the stream's velocity factors hold a drifting IMU without GPS, the model reads
the attitude the graph predicts (not ground truth), and a model of another rate is refused."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
import torch

from airimu_core.errors import InputError
from fusion.config import FuseConfig, OnlineSettings
from fusion.online import OnlineFusion
from learned_imu.datasets.simulator import ImuErrorModel, simulate
from learned_imu.network.checkpoint import TrainedOn
from learned_imu.network.motion import Motion

DRIFTING = ImuErrorModel(2e-3, 2e-2, 0.0, 0.0, 2e-3, 5e-2)  # a constant bias the graph does not model
VEL_SIGMA = 0.05  # m/s


class TruthMotion:
    """A stand-in for ``MotionNet``'s streaming interface: the truth's body-frame velocity plus noise at every block
    end; it records the up axis it was given (what a real model reads)."""

    training = False
    block = 9

    def __init__(self, seq):
        self.body = np.einsum("nji,nj->ni", seq.gt.rot, seq.gt.vel)
        self.body = self.body + np.random.default_rng(0).normal(0.0, VEL_SIGMA, self.body.shape)
        self.up = []

    def initial_state(self, batch):
        return 0  # samples streamed so far

    def stream(self, gyro, acc, up, state, flush=False):
        total = state + gyro.shape[1]
        self.up.append(up[0].numpy())
        ends = [e for e in range(self.block - 1, total, self.block) if e >= state]
        vel = torch.as_tensor(self.body[ends], dtype=torch.float32)[None]
        return Motion(vel, torch.full_like(vel, VEL_SIGMA**2)), total


def run(seq, motion):
    pose = gtsam.Pose3(gtsam.Rot3(seq.gt.rot[0]), seq.gt.pos[0])
    config = FuseConfig(gyro_noise_density=2e-3, acc_noise_density=2e-2, online=OnlineSettings(keyframe_s=0.45))
    fusion = OnlineFusion(None, seq.gravity, gtsam.NavState(pose, seq.gt.vel[0]), config, motion_model=motion)
    for start in range(0, len(seq.t), 10):
        fusion.add_imu(seq.t[start : start + 10], seq.gyro[start : start + 10], seq.acc[start : start + 10])
    fusion.flush()
    trajectory = fusion.trajectory()
    truth = seq.gt.pos[np.searchsorted(seq.t, trajectory.t)]
    return fusion, float(np.linalg.norm(trajectory.pos[-1] - truth[-1]))


def test_online_motion_factors_hold_the_drift_and_read_the_graphs_attitude():
    seq = simulate("drone", duration_s=30.0, error_model=DRIFTING, seed=5)
    _, drift = run(seq, None)
    motion = TruthMotion(seq)
    fusion, held = run(seq, motion)
    assert drift > 5.0 and held < 0.02 * drift, (drift, held)  # measured 72.9 m against 0.38 m
    up = np.concatenate(motion.up)
    assert len(up) == fusion.trajectory().t.size * 90 - 90  # every sample of every interval, keyframes 90 apart
    truth_up = seq.gt.rot[: len(up), 2, :]
    angle = np.degrees(np.arccos(np.clip(np.sum(up * truth_up, axis=1), -1.0, 1.0)))
    assert 0.0 < angle.max() < 3.0  # the estimate carried by the gyro: close to the truth (0.77 deg), not equal


def test_a_motion_model_of_another_rate_is_refused_by_the_stream():
    seq = simulate("drone", duration_s=2.0, seed=1)
    motion = TruthMotion(seq)
    motion.trained_on = TrainedOn(100.0, ("kitti_raw",))
    pose = gtsam.Pose3(gtsam.Rot3(seq.gt.rot[0]), seq.gt.pos[0])
    fusion = OnlineFusion(None, seq.gravity, gtsam.NavState(pose, seq.gt.vel[0]), motion_model=motion)
    with pytest.raises(InputError, match="trained at 100.0 Hz"):
        fusion.add_imu(seq.t[:50], seq.gyro[:50], seq.acc[:50])


def test_a_mount_state_is_refused_online():
    from fusion.config import MotionSettings

    seq = simulate("drone", duration_s=2.0, seed=1)
    pose = gtsam.Pose3(gtsam.Rot3(seq.gt.rot[0]), seq.gt.pos[0])
    config = FuseConfig(motion=MotionSettings(mount_sigma_rad=0.01))
    with pytest.raises(InputError, match="mount_sigma_rad"):
        OnlineFusion(None, seq.gravity, gtsam.NavState(pose, seq.gt.vel[0]), config, motion_model=TruthMotion(seq))


def test_interpolated_imu_gaps_are_refused_online():
    seq = simulate("drone", duration_s=2.0, seed=1)
    pose = gtsam.Pose3(gtsam.Rot3(seq.gt.rot[0]), seq.gt.pos[0])
    with pytest.raises(InputError, match="imu_gaps"):
        OnlineFusion(None, seq.gravity, gtsam.NavState(pose, seq.gt.vel[0]), FuseConfig(imu_gaps="interpolate"))
