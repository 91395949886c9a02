"""The motion model's speed envelope: beyond the speeds it was trained on, its along-track velocity is left to the
IMU (batch passes and the online stream alike); the training speed is recorded in the checkpoint."""

from __future__ import annotations

import dataclasses
import logging
from types import SimpleNamespace

import gtsam
import numpy as np
import pytest
import torch

from airimu.fuse import fuse
from airimu_core.errors import ConfigError, DataError, InputError
from airimu_core.motion import ALONG_TRACK_FREE, BodyVelocities
from airimu_core.sequence import GroundTruth, ImuSequence
from fusion.config import FuseConfig, MotionSettings, OnlineSettings
from fusion.online import OnlineFusion
from learned_imu.network.checkpoint import TrainedOn, _trained_on
from learned_imu.network.motion import Motion
from learned_imu.training.experiment import training_speed

SLOW = 0.7  # the stand-in model's forward speed against the truth's: one that extrapolates low (KITTI seq 01)
SIGMA = 0.1  # m/s, its predicted sigma on every axis
TRAINED_M_S = 10.0  # the stand-in models' training speed: the car drives 12-18 m/s


@pytest.fixture(scope="module")
def car():
    """A level car heading along world x at 15 +- 3 m/s for 40 s, 200 Hz, IMU x forward: white noise and a small
    accelerometer bias (strapdown alone: metres)."""
    rate, duration = 200.0, 40.0
    t = np.arange(0.0, duration, 1.0 / rate)
    w = 2 * np.pi / 20.0
    vel = np.zeros((len(t), 3))
    vel[:, 0] = 15.0 + 3.0 * np.sin(w * t)
    pos = np.zeros((len(t), 3))
    pos[:, 0] = 15.0 * t - 3.0 / w * (np.cos(w * t) - 1.0)
    gravity = np.array([0.0, 0.0, -9.81])
    accel = np.zeros((len(t), 3))
    accel[:, 0] = 3.0 * w * np.cos(w * t)
    rng = np.random.default_rng(3)
    acc = accel - gravity + np.array([5e-3, -5e-3, 0.0]) + rng.normal(0.0, 2e-3 * np.sqrt(rate), (len(t), 3))
    gyro = rng.normal(0.0, 2e-4 * np.sqrt(rate), (len(t), 3))
    rot = np.repeat(np.eye(3)[None], len(t), axis=0)
    gt = GroundTruth(rot, pos, vel, np.ones(len(t), dtype=bool))
    return ImuSequence("straight car", t, gyro, acc, gravity, gt, None, "test")


def slow_body(seq, ends):
    body = np.einsum("nji,nj->ni", seq.gt.rot[ends], seq.gt.vel[ends])
    return body * np.array([SLOW, 1.0, 1.0])


def test_outside_envelope_frees_the_along_track_axis_only():
    t = np.arange(3.0)
    vel, var = np.array([[10.0, 0.1, 0.0], [25.0, 0.2, 0.1], [0.3, -30.0, 0.0]]), np.ones((3, 3))
    estimate = np.array([[12.0, 0.1, 0.0], [26.0, 0.5, 0.0], [0.0, -22.0, 1.0]])  # speeds 12, 26, 22
    out, beyond = BodyVelocities(t, vel, var).outside_envelope(estimate, 20.0)
    assert beyond.tolist() == [False, True, True]
    expected = np.ones((3, 3))
    expected[1, 0] = expected[2, 1] = ALONG_TRACK_FREE  # the axis the estimate is mostly along
    np.testing.assert_array_equal(out.var, expected)
    np.testing.assert_array_equal(out.vel, vel)
    with pytest.raises(InputError, match="estimate must be"):
        BodyVelocities(t, vel, var).outside_envelope(estimate[:2], 20.0)
    with pytest.raises(InputError, match="limit_m_s"):
        BodyVelocities(t, vel, var).outside_envelope(estimate, 0.0)


def test_speed_limit_reads_the_models_training_speed():
    model = SimpleNamespace(trained_on=TrainedOn(100.0, ("kitti_raw",), 19.9))
    assert MotionSettings().speed_limit_m_s(model) == pytest.approx(19.9)
    assert MotionSettings(speed_envelope=1.5).speed_limit_m_s(model) == pytest.approx(29.85)
    assert MotionSettings(speed_envelope=None).speed_limit_m_s(model) is None
    assert MotionSettings().speed_limit_m_s(SimpleNamespace(trained_on=TrainedOn(100.0, ("x",)))) is None
    assert MotionSettings().speed_limit_m_s(SimpleNamespace()) is None  # a model built in code
    for bad in (0.0, -1.0, float("nan"), True, "fast"):
        with pytest.raises(ConfigError, match="motion.speed_envelope"):
            MotionSettings(speed_envelope=bad)


def test_the_training_speed_is_recorded_and_checked(car, tmp_path):
    speed = training_speed([car, dataclasses.replace(car, gt=None)])
    truth = np.linalg.norm(car.gt.vel, axis=1)
    assert truth.max() * 0.98 < speed <= truth.max()  # the 99.9th percentile of the one with ground truth
    assert training_speed([dataclasses.replace(car, gt=None)]) is None
    record = TrainedOn(100.0, ("simulator",), speed)
    assert _trained_on(record.to_dict(), tmp_path / "m.pt") == record
    assert "speed_m_s" not in TrainedOn(100.0, ("simulator",)).to_dict()  # older files read as before
    with pytest.raises(DataError, match="trained_on.speed_m_s"):
        _trained_on({"rate_hz": 100.0, "datasets": [], "speed_m_s": -3.0}, tmp_path / "m.pt")


def test_batch_passes_leave_a_too_fast_along_track_speed_to_the_imu(car, monkeypatch, caplog):
    def predict(model, sequence, rot):  # the stand-in: read nothing, give the slow velocities
        ends = np.arange(8, len(sequence.t), 9)
        body = slow_body(sequence, ends)
        return BodyVelocities(sequence.t[ends], body, np.full_like(body, SIGMA**2))

    monkeypatch.setattr("learned_imu.network.motion.predict_velocities", predict)
    model = SimpleNamespace(trained_on=TrainedOn(200.0, ("test",), TRAINED_M_S))

    def end_error(envelope):
        config = FuseConfig(
            gyro_noise_density=2e-4, acc_noise_density=2e-3, motion=MotionSettings(speed_envelope=envelope)
        )
        result = fuse(dataclasses.replace(car, gps=None), None, None, config, model, start="ground-truth")
        trajectory = result.solution.trajectory
        return float(np.linalg.norm(trajectory.pos[-1] - car.gt.pos[np.searchsorted(car.t, trajectory.t[-1])]))

    trusted = end_error(None)
    with caplog.at_level(logging.WARNING):
        guarded = end_error(1.0)
    assert "faster than the motion model's training speeds (10.0 m/s)" in caplog.text
    assert trusted > 100.0 and guarded < 0.05 * trusted, (trusted, guarded)


class SlowStream:
    """``MotionNet``'s streaming interface over the slow velocities (``slow_body``)."""

    training = False
    block = 9
    trained_on = TrainedOn(200.0, ("test",), TRAINED_M_S)

    def __init__(self, seq):
        self.body = slow_body(seq, np.arange(len(seq.t)))

    def initial_state(self, batch):
        return 0

    def stream(self, gyro, acc, up, state, flush=False):
        total = state + gyro.shape[1]
        ends = [e for e in range(self.block - 1, total, self.block) if e >= state]
        vel = torch.as_tensor(self.body[ends], dtype=torch.float32)[None]
        return Motion(vel, torch.full_like(vel, SIGMA**2)), total


def test_the_online_stream_applies_the_envelope_too(car):
    def end_error(envelope):
        config = FuseConfig(
            gyro_noise_density=2e-4,
            acc_noise_density=2e-3,
            online=OnlineSettings(keyframe_s=0.45),
            motion=MotionSettings(speed_envelope=envelope),
        )
        pose = gtsam.Pose3(gtsam.Rot3(car.gt.rot[0]), car.gt.pos[0])
        fusion = OnlineFusion(None, car.gravity, gtsam.NavState(pose, car.gt.vel[0]), config, SlowStream(car))
        for start in range(0, len(car.t), 10):
            fusion.add_imu(car.t[start : start + 10], car.gyro[start : start + 10], car.acc[start : start + 10])
        fusion.flush()
        trajectory = fusion.trajectory()
        error = np.linalg.norm(trajectory.pos[-1] - car.gt.pos[np.searchsorted(car.t, trajectory.t[-1])])
        return fusion.beyond_envelope, float(error)

    none, trusted = end_error(None)
    some, guarded = end_error(1.0)
    assert none == 0 and some > 0
    assert trusted > 100.0 and guarded < 0.05 * trusted, (trusted, guarded, some)
