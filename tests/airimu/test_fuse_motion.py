"""``airimu fuse --motion / --start / --no-gps / --gps-outage``: real logs in, the outages scored, bad flags refused."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from airimu.cli import app
from airimu_core.errors import InputError


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--gps-outage", "5"], "START:DURATION"),
        (["--gps-outage", "5:-1"], "START:DURATION"),
        (["--gps-outage", "nan:10"], "START:DURATION"),
        (["--start", "1,2,3"], "10 numbers"),
        (["--start", "0,0,0,2,0,0,0,0,0,0"], "unit norm"),
        (["--no-gps"], "--no-gps needs --start"),
        (["--no-gps", "--start", "ground-truth", "--gps-outage", "1:2"], "leave out --gps"),
    ],
)
def test_bad_motion_flags_are_refused_by_name(flags, message, tmp_path):
    args = ["fuse", "--dataset", "euroc", "--path", str(tmp_path), "--out", str(tmp_path / "out"), *flags]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2 and message in result.output, result.output


@pytest.fixture(scope="module")
def car_motion_model(tmp_path_factory):
    """A small motion model trained for one epoch on simulated 100-Hz car drives (KITTI's OXTS rate)."""
    folder = tmp_path_factory.mktemp("motion")
    config = folder / "car.yaml"
    config.write_text(
        "name: car\ndata:\n"
        "  train: [{dataset: simulator, options: {profile: car, duration_s: 60.0, rate_hz: 100.0, seed: 1}}]\n"
        "  val: [{dataset: simulator, options: {profile: car, duration_s: 30.0, rate_hz: 100.0, seed: 2}}]\n"
        "motion: {gru_sizes: [16], chunk: 900, chunk_stride: 450}\n"
        "train: {model: motion, batch_size: 4, epochs: 1}\n"
    )
    result = CliRunner().invoke(app, ["train", "--config", str(config), "--out", str(folder / "run"), "--no-progress"])
    assert result.exit_code == 0, result.output
    return folder / "run" / "best.pt"


@pytest.mark.slow
def test_fuse_scores_gps_outages_on_gtsams_kitti_drive(shared_data, car_motion_model, tmp_path):
    out = tmp_path / "fused"
    args = ["fuse", "--dataset", "kitti", "--path", str(shared_data / "kitti_gtsam"), "--gps-every", "10",
            "--keyframes", "1s", "--motion", str(car_motion_model), "--gps-outage", "100:30",
            "--gps-outage", "150:20", "--out", str(out)]  # fmt: skip
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    summary = json.loads((out / "summary.json").read_text())
    assert [(o["start_s"], o["duration_s"]) for o in summary["outages"]] == [(100.0, 30.0), (150.0, 20.0)]
    assert all(o["error_to_gps_m"] is not None and o["error_to_gps_m"] >= 0 for o in summary["outages"])
    assert summary["motion_factors"] > 2000  # every 0.2 s over the 470-s drive
    assert "motion" in summary["normalised_residuals"]
    assert "GPS outage 100+30 s: at its end" in result.output
    assert (out / "fused.png").stat().st_size > 0 and (out / "fused.rrd").stat().st_size > 0


@pytest.mark.slow
def test_a_motion_model_of_another_rate_is_refused_naming_both(shared_data, car_motion_model, tmp_path):
    args = ["fuse", "--dataset", "euroc", "--path", str(shared_data / "euroc" / "V2_02_medium"), "--no-gps",
            "--start", "ground-truth", "--motion", str(car_motion_model), "--out", str(tmp_path / "out")]  # fmt: skip
    result = CliRunner().invoke(app, args)  # airimu.cli.main prints the toolkit's InputError as one line
    assert isinstance(result.exception, InputError), result.output
    assert "200.0 Hz" in str(result.exception) and "trained at 100.0 Hz" in str(result.exception)
