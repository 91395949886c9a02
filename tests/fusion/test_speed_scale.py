"""Speed-scale states on the motion factors (``motion.scale_sigma``): a model that reads a drive a few percent slow
all the way has an error correlated over the whole drive; a scale state lets the IMU set it."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import S

from airimu.fuse import fuse, speed_scales
from airimu_core.errors import ConfigError, InputError
from airimu_core.motion import BodyVelocities
from fusion.config import FuseConfig, MotionSettings
from fusion.online import OnlineFusion
from tests.fusion.test_speed_envelope import SIGMA, car  # noqa: F401  (the straight car fixture)

READS = 0.9  # the stand-in model's velocities against the truth's: 10 % slow, all the way


def test_config_refuses_bad_scale_settings():
    assert MotionSettings().speed_scale() is None
    assert MotionSettings(scale_sigma=0.2, scale_walk=0, scale_interval_s=5).speed_scale() == (0.2, 0.0, 5.0)
    for bad in ({"scale_sigma": 0.0}, {"scale_sigma": float("nan")}, {"scale_sigma": True}, {"scale_sigma": "1"}):
        with pytest.raises(ConfigError, match="motion.scale_sigma"):
            MotionSettings(**bad)
    with pytest.raises(ConfigError, match="motion.scale_walk"):
        MotionSettings(scale_sigma=0.1, scale_walk=-0.01)
    for bad in (0.0, float("inf"), None):
        with pytest.raises(ConfigError, match="motion.scale_interval_s"):
            MotionSettings(scale_sigma=0.1, scale_interval_s=bad)


def slow_model(monkeypatch):
    def predict(model, sequence, rot):  # the stand-in: read nothing, give the truth's body velocity x READS
        ends = np.arange(8, len(sequence.t), 9)
        body = np.einsum("nji,nj->ni", sequence.gt.rot[ends], sequence.gt.vel[ends]) * READS
        return BodyVelocities(sequence.t[ends], body, np.full_like(body, SIGMA**2))

    monkeypatch.setattr("learned_imu.network.motion.predict_velocities", predict)
    return SimpleNamespace()  # no training speed: no envelope


def solved(car, model, **scale):  # noqa: F811
    motion = MotionSettings(cov_scale=30.0, **scale)
    config = FuseConfig(gyro_noise_density=2e-4, acc_noise_density=2e-3, motion=motion)
    result = fuse(dataclasses.replace(car, gps=None), None, None, config, model, start="ground-truth")
    trajectory, values = result.solution.trajectory, result.solution.values
    end = float(np.linalg.norm(trajectory.pos[-1] - car.gt.pos[np.searchsorted(car.t, trajectory.t[-1])]))
    scales = speed_scales(values)  # summary.json's
    count = 0
    while values.exists(S(count)):
        count += 1
    assert (scales is None) == (count == 0) and len(scales or []) == count
    return end, np.array(scales or [])


def test_a_scale_state_takes_up_a_model_that_reads_slow(car, monkeypatch):  # noqa: F811
    model = slow_model(monkeypatch)
    white, none = solved(car, model)
    assert len(none) == 0
    constant, scales = solved(car, model, scale_sigma=0.3, scale_walk=0.0)
    assert len(scales) == 1 and scales[0] == pytest.approx(1 / READS, rel=0.01), scales
    walking, walked = solved(car, model, scale_sigma=0.3, scale_walk=0.003, scale_interval_s=10.0)
    assert len(walked) == 4  # 40 s in intervals of 10 s
    np.testing.assert_allclose(walked, 1 / READS, rtol=0.02)
    assert white > 20.0, white  # white noise: the slow model wins over the IMU
    assert constant < 0.05 * white and walking < 0.05 * white, (white, constant, walking)


def test_the_online_smoother_refuses_scale_states(car):  # noqa: F811
    config = FuseConfig(motion=MotionSettings(scale_sigma=0.1))
    start = gtsam.NavState(gtsam.Pose3(), np.zeros(3))
    model = SimpleNamespace(training=False)
    with pytest.raises(InputError, match="motion.scale_sigma .speed-scale states. is batch only"):
        OnlineFusion(None, car.gravity, start, config, motion_model=model)
