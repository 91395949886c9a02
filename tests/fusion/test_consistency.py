"""After every solve the result is checked against its own noise model (fusion.consistency): quiet on correct
inputs (simulated and GTSAM's KITTI drive with its real GPS), a warning naming the likely causes on the mistakes that
used to give a confident wrong answer (a GPS clock offset, IMU noise given as a variance, GPS sigmas too small)."""

from __future__ import annotations

import dataclasses
import json
import logging

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import X

from factors.gps import GpsFactor
from fusion.consistency import HIGH, LOW, check, residuals
from fusion.fuse import fuse, write_outputs
from learned_imu.datasets import read_sequence
from learned_imu.datasets.simulator import simulate


@pytest.fixture(scope="module")
def drone():
    return simulate("drone", duration_s=60.0, grade="consumer", seed=0, gps_rate_hz=1.0)


def test_chi_square_of_a_gps_factor_is_its_whitened_residual_robust_or_not():
    values = gtsam.Values()
    values.insert(X(0), gtsam.Pose3(gtsam.Rot3(), np.array([1.0, 2.0, 3.0])))
    graph = gtsam.NonlinearFactorGraph()
    sigma = np.array([0.5, 0.5, 2.0])
    gaussian = gtsam.noiseModel.Diagonal.Sigmas(sigma)
    graph.add(GpsFactor(X(0), np.array([2.0, 2.0, 7.0]), gaussian))
    huber = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(1.345), gaussian)
    graph.add(GpsFactor(X(0), np.array([1.0, 1.0, 3.0]), huber))
    found = residuals(graph, values)["gps"]
    # (1/0.5)^2 + (4/2)^2 = 8 and (1/0.5)^2 = 4, the robust one by its Gaussian core
    assert found.factors == 2 and found.dof == 6 and found.chi2 == pytest.approx(12.0)
    assert found.per_dof == pytest.approx(2.0)


def test_correct_inputs_stay_quiet(drone, shared_data, caplog):
    with caplog.at_level(logging.WARNING):
        simulated = fuse(drone)
        kitti = read_sequence("kitti", shared_data / "kitti_gtsam")
        real = fuse(kitti, kitti.gps, keyframe_s=1.0)
    for result in (simulated, real):
        assert check(result.residuals) == []
        assert LOW < result.residuals["gps"].per_dof < HIGH and LOW < result.residuals["imu"].per_dof < HIGH
    assert "normalised residual" not in caplog.text
    # measured: simulated IMU 0.63, GPS 1.10; KITTI 0027 with its real GPS and default noise IMU 0.068, GPS 0.080
    assert simulated.residuals["gps"].per_dof == pytest.approx(1.0, abs=0.5)


@pytest.mark.parametrize(
    "mistake",
    ["gps clock 2 s late", "gps clock 0.5 s late", "imu noise as a variance", "gps sigma 10x too small"],
)
def test_a_plausible_mistake_is_warned_about_naming_its_causes(drone, mistake, caplog, tmp_path):
    gps = drone.gps
    options = {}
    if mistake.startswith("gps clock"):
        options["gps"] = dataclasses.replace(gps, t=gps.t + (2.0 if "2 s" in mistake else 0.5))
    elif mistake.startswith("imu noise"):
        options["noise_density"] = (0.004**2, 0.08**2)
    else:
        options["gps"] = dataclasses.replace(gps, sigma=gps.sigma / 10)
    with caplog.at_level(logging.WARNING):
        result = fuse(drone, **options)
    assert result.residuals["gps"].per_dof > HIGH  # measured 357, 22.6, 91,672 and 39.9
    assert "GPS factors' normalised residual" in caplog.text and "clock offset" in caplog.text
    if mistake.startswith("imu noise"):
        assert "IMU noise given as a variance" in caplog.text
    summary, _ = write_outputs(result, tmp_path / "out")
    stored = json.loads((tmp_path / "out" / "summary.json").read_text())["normalised_residuals"]
    assert stored["gps"]["chi2_per_dof"] == pytest.approx(result.residuals["gps"].per_dof)
    assert summary.normalised_residuals == stored
