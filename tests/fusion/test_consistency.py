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

from airimu.fuse import fuse, write_outputs
from factors.gps import GpsFactor
from fusion.config import FuseConfig, FusionSettings
from fusion.consistency import HIGH, LOW, check, residuals
from learned_imu.datasets import read_sequence
from learned_imu.datasets.simulator import ImuErrorModel, simulate


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
    # (1/0.5)^2 + (4/2)^2 = 8 and (1/0.5)^2 = 4, the robust one by its Gaussian core; the rotation is not observed,
    # so the graph has no marginals and the dimensions stand in for the degrees of freedom
    assert found.factors == 2 and found.dim == 6 and found.dof == 6 and found.chi2 == pytest.approx(12.0)
    assert found.per_dof == pytest.approx(2.0) and not found.exact
    tiny = dataclasses.replace(found, chi2=1e-6)  # far below LOW per dimension: no verdict without the redundancy
    assert check({"gps": tiny}) == [] and check({"gps": dataclasses.replace(tiny, exact=True)}) != []


def test_degrees_of_freedom_are_the_redundancy_the_states_leave():
    """Two fixes of one position: 6 measurements, 3 unknowns, so 3 degrees of freedom (not 6), and at the solution
    (their mean) a chi-square of |p1 - p2|^2 / (2 sigma^2); a key held by an equality is known, not estimated."""
    from gtsam.symbol_shorthand import B

    values = gtsam.Values()
    values.insert(X(0), gtsam.Pose3(gtsam.Rot3(), np.array([1.0, 2.0, 4.0])))
    values.insert(B(0), gtsam.imuBias.ConstantBias())
    graph = gtsam.NonlinearFactorGraph()
    graph.add(
        gtsam.PriorFactorPose3(
            X(0), values.atPose3(X(0)), gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-3] * 3 + [1e4] * 3))
        )
    )
    sigma = gtsam.noiseModel.Isotropic.Sigma(3, 0.5)
    graph.add(GpsFactor(X(0), np.array([1.0, 2.0, 3.0]), sigma))
    graph.add(GpsFactor(X(0), np.array([1.0, 2.0, 5.0]), sigma))
    graph.add(gtsam.NonlinearEqualityConstantBias(B(0), gtsam.imuBias.ConstantBias()))
    graph.add(gtsam.PriorFactorConstantBias(B(0), gtsam.imuBias.ConstantBias(), gtsam.noiseModel.Isotropic.Sigma(6, 1)))
    found = residuals(graph, values)
    assert found["gps"].dim == 6 and found["gps"].dof == pytest.approx(3.0, abs=1e-6)
    assert found["gps"].chi2 == pytest.approx(2.0**2 / (2 * 0.5**2)) and found["gps"].per_dof == pytest.approx(8 / 3)
    # the pose prior: its rotation alone fixes the rotation (0), its 1e4-m position is outweighed by the fixes (3);
    # the prior on the known bias is all residual (6)
    assert found["prior"].dof == pytest.approx(3.0 + 6.0, abs=1e-6)


def test_a_sparse_graph_with_right_inputs_is_not_called_pessimistic(tmp_path):
    """Keyframes every 0.1 s, a fix every 10 s, an IMU with white noise only, fused with its own densities (the
    PGO ablation's graph, anchored at the true first state): the states absorb the IMU residuals (far below 0.01
    per dimension), but per degree of freedom the fit is about 1 and nothing is warned about."""
    from airimu.experiments.pgo import gps_for
    from fusion.config import FusionSettings
    from fusion.graph import build_graph, solve
    from learned_imu.export import export_preintegration, keyframes_every

    white = ImuErrorModel(3e-4, 3e-3, 0.0, 0.0, 0.0, 0.0)
    drone = simulate("drone", duration_s=60.0, seed=0, error_model=white)
    density = white.noise_densities()
    keyframes = keyframes_every(drone, 0.1)
    export = export_preintegration(tmp_path / "e.npz", drone, keyframes, *density)
    fixes, _ = gps_for(drone, 0.1, 0.1, seed=0)
    graph, values = build_graph(export, fixes, FusionSettings())
    solution = solve(graph, values, drone.t[keyframes], FusionSettings())
    found = residuals(solution.graph, solution.values)
    imu, gps = found["imu"], found["gps"]
    assert imu.chi2 / imu.dim < LOW  # what dividing by the dimensions called "far too pessimistic"
    assert 0.2 < imu.per_dof < 5 and 0.05 < gps.per_dof < 10 and check(found) == []


def test_correct_inputs_stay_quiet(drone, shared_data, caplog):
    with caplog.at_level(logging.WARNING):
        simulated = fuse(drone)
        kitti = read_sequence("kitti", shared_data / "kitti_gtsam")
        real = fuse(kitti, kitti.gps, config=FuseConfig(keyframe_s=1.0))
    for result in (simulated, real):
        assert check(result.residuals) == []
        assert LOW < result.residuals["gps"].per_dof < HIGH and LOW < result.residuals["imu"].per_dof < HIGH
    assert "normalised residual" not in caplog.text
    # measured: see BENCHMARKS ("Faults and consistency")
    assert 0.5 < simulated.residuals["gps"].per_dof < 3  # measured 1.65


@pytest.mark.parametrize(
    "mistake",
    ["gps clock 2 s late", "gps clock 0.5 s late", "imu noise as a variance", "gps sigma 10x too small"],
)
def test_a_plausible_mistake_is_warned_about_naming_its_causes(drone, mistake, caplog, tmp_path):
    gps = drone.gps
    # robust GPS factors, the setting these numbers were measured with (Gaussian ones spread a 0.5-s offset over the
    # IMU factors too: GPS 9.4 per dof, under HIGH; airimu fuse's own clock check finds it: test_fuse_mistakes.py)
    huber = FuseConfig(graph=FusionSettings(gps_robust="huber"))
    options = {"config": huber}
    if mistake.startswith("gps clock"):
        options["gps"] = dataclasses.replace(gps, t=gps.t + (2.0 if "2 s" in mistake else 0.5))
    elif mistake.startswith("imu noise"):
        options["config"] = dataclasses.replace(huber, gyro_noise_density=0.004**2, acc_noise_density=0.08**2)
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


def test_a_high_gps_residual_beside_motion_factors_names_them_too():
    from fusion.consistency import Residual

    found = {
        "gps": Residual("gps", 47, 141, 45.8, 45.8 * 214.0),
        "motion": Residual("motion", 2339, 7017, 5000.0, 4.45e4),
    }
    (line,) = check(found)
    assert "GPS factors' normalised residual" in line and "the motion factors (2339, normalised residual 8.9)" in line
    (plain,) = check({"gps": found["gps"]})
    assert "motion" not in plain
