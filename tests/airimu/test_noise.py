"""``airimu noise``: noise densities from a still recording (Allan deviation, allantools), their datasheet units."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from airimu.cli import app
from airimu_core.errors import DataError, InputError
from learned_imu.evaluation.allan import allan_noise, from_datasheet


def test_known_densities_are_recovered_from_a_simulated_still_imu():
    """One hour at 100 Hz of the simulator's still profile with known white noise and bias random walk: white noise
    within 5 % on every axis (measured 0.2-2.3 % off over three seeds), the random walk's three-axis mean within 20 %
    (one hour holds few independent long clusters: single axes scatter 10-30 %; measured means 8-9 % off)."""
    from learned_imu.datasets.simulator import ImuErrorModel, simulate

    errors = ImuErrorModel(1.7e-4, 2.0e-3, 2e-5, 3e-4, 0.0, 0.0)
    seq = simulate("still", duration_s=3600.0, rate_hz=100.0, error_model=errors, seed=0)
    for samples, white, walk in ((seq.gyro, 1.7e-4, 2e-5), (seq.acc, 2.0e-3, 3e-4)):
        axes = allan_noise(samples, 100.0)
        for axis in axes:
            assert axis.white == pytest.approx(white, rel=0.05)
            assert axis.adev.min() < axis.adev[0]  # the curve has a floor: white noise falls, the walk rises
        assert np.mean([a.random_walk for a in axes]) == pytest.approx(walk, rel=0.2)


@pytest.mark.parametrize(
    ("value", "unit", "si"),
    [
        (0.2, "deg/sqrt(h)", 0.2 * math.pi / 180 / 60),  # angle random walk: 5.82e-5 rad/s/sqrt(Hz)
        (10.0, "deg/h", 10.0 * math.pi / 180 / 3600),  # bias instability: 4.85e-5 rad/s
        (0.007, "deg/s/sqrt(Hz)", 0.007 * math.pi / 180),
        (120.0, "ug/sqrt(Hz)", 120e-6 * 9.80665),  # 1.18e-3 m/s^2/sqrt(Hz)
        (0.03, "mg", 0.03e-3 * 9.80665),
        (40.0, "ug", 40e-6 * 9.80665),
        (0.06, "m/s/sqrt(h)", 0.001),  # velocity random walk
    ],
)
def test_datasheet_units_are_converted(value, unit, si):
    assert from_datasheet(value, unit) == pytest.approx(si, rel=1e-12)


def test_datasheet_mistakes_are_refused():
    with pytest.raises(InputError, match="expected one of"):
        from_datasheet(0.2, "deg/rt-h")
    with pytest.raises(InputError, match="positive"):
        from_datasheet(-1.0, "mg")


def test_airimu_noise_on_a_parked_kitti_car(shared_data, tmp_path):
    """2011_09_28_drive_0002 stands still from 9.8 s to its end: the densities are written in Kalibr's names and as
    GTSAM's covariances (their squares), with the plot; they agree with the second-difference estimate of
    ``factors.noise`` within 2x (measured gyro 5.7e-5 against 4.2e-5, acc 4.6e-4 against 6.2e-4)."""
    from factors.noise import white_noise_density
    from learned_imu.datasets.kitti_raw import read_kitti_raw

    drive = shared_data / "kitti_raw" / "2011_09_28_drive_0002.csv"
    out = tmp_path / "noise"
    args = ["noise", "--dataset", "kitti_raw", "--path", str(drive), "--start", "10", "--out", str(out)]
    args += ["--datasheet", "gyroscope_noise_density=0.2 deg/sqrt(h)"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    assert "gyroscope_noise_density" in result.output and "datasheet 5.82e-05" in result.output
    kalibr = yaml.safe_load((out / "imu_kalibr.yaml").read_text())
    gtsam_cov = yaml.safe_load((out / "gtsam_preintegration.yaml").read_text())
    assert gtsam_cov["gyroscope_covariance"] == pytest.approx(kalibr["gyroscope_noise_density"] ** 2)
    assert kalibr["update_rate"] == pytest.approx(100.0, rel=0.01)
    seq = read_kitti_raw(drive)
    still = seq.t - seq.t[0] >= 10.0
    for key, samples in (("gyroscope_noise_density", seq.gyro), ("accelerometer_noise_density", seq.acc)):
        reference = white_noise_density(samples[still], seq.dt[still])
        assert 0.5 < kalibr[key] / reference < 2.0
    summary = json.loads((out / "allan.json").read_text())
    assert len(summary["axes"]["gyro"]) == 3 and summary["datasheet"]["gyroscope_noise_density"] > 0
    assert (out / "allan.png").read_bytes()[:4] == b"\x89PNG"


def test_a_moving_stretch_is_refused(shared_data):
    from airimu.noise import still_noise
    from learned_imu.datasets.kitti_raw import read_kitti_raw

    seq = read_kitti_raw(shared_data / "kitti_raw" / "2011_09_28_drive_0002.csv")
    with pytest.raises(DataError, match="not a still stretch|no white-noise slope"):
        still_noise(seq, 0.0, 9.0)  # the car drives until 9.8 s
