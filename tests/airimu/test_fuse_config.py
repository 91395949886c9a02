"""One fusion configuration: ``configs/fuse.yaml`` is ``FuseConfig()`` written out, ``airimu fuse --config`` reads
another, flags override single keys, and ``--gps-sigma`` reaches the log's own fixes too."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from typer.testing import CliRunner

from airimu.cli import app
from airimu_core.config import to_dict
from airimu_core.errors import ConfigError
from fusion.config import BiasStates, FuseConfig, FusionSettings, OnlineSettings, load_fuse_config
from learned_imu.datasets.simulator import simulate
from tests.airimu.test_fuse import write_bag_with_navsatfix


def test_the_shipped_fuse_yaml_is_the_dataclass_defaults():
    assert load_fuse_config("fuse.yaml") == FuseConfig()
    assert load_fuse_config("configs/fuse.yaml") == FuseConfig()
    # every key of the dataclass is written in the file (the file documents them all)
    import yaml

    from airimu_core.config import config_path

    written = yaml.safe_load(config_path("fuse.yaml").read_text())
    assert written == to_dict(FuseConfig())


def test_the_defaults_are_written_once():
    """The PGO ablation's fixed noise and the bias states' sigmas are FuseConfig's, not copies of the numbers."""
    from airimu.experiments.pgo_config import PgoOptions

    assert (PgoOptions().fixed_gyro_noise_density, PgoOptions().fixed_acc_noise_density) == FuseConfig().noise_density
    assert FuseConfig().bias == BiasStates()
    assert FuseConfig().graph.gps_robust is FusionSettings().gps_robust is None  # Gaussian, batch and online alike


def test_bad_fuse_configs_are_refused_naming_file_and_key(tmp_path):
    path = tmp_path / "fuse.yaml"
    cases = {
        "gps_sigma: 2.0\n": "unknown key 'gps_sigma'",
        "graph: {gps_robust: tukey}\n": "graph.gps_robust",
        "online: {smoother: ekf}\n": "online.smoother': expected one of isam2, fixed_lag",
        "gyro_noise_density: 1.6e-9\n": "gyro_noise_density",
        "keyframe_s: -1\n": "keyframe_s must be a positive interval",
        "bias: {factor: tight}\n": "BiasStates.factor",
    }
    for text, expected in cases.items():
        path.write_text(text)
        with pytest.raises(ConfigError, match=expected) as caught:
            load_fuse_config(path)
        assert str(path) in str(caught.value)


def test_config_file_and_flag_overrides(tmp_path):
    seq = simulate("car", duration_s=30.0, grade="industrial", seed=2)
    bag, _ = write_bag_with_navsatfix(tmp_path / "drive", seq, fixes_every=200, sigma=0.5)
    config = tmp_path / "mine.yaml"
    config.write_text("gyro_noise_density: 0.0003\nacc_noise_density: 0.003\nkeyframe_s: 0.5\n")
    base = [
        "fuse",
        "--dataset",
        "rosbag",
        "--path",
        str(bag),
        "--reader-option",
        "gps_topic=/fix",
        "--config",
        str(config),
    ]
    runs = {
        "file": [],  # keyframes at the fixes and every 0.5 s from the file
        "flag": ["--keyframes", "fixes"],  # the flag wins: a keyframe at every 1 Hz fix alone
        "sigma": ["--keyframes", "fixes", "--gps-sigma", "5.0"],  # the log's own fixes, their sigma replaced
    }
    marginals = {}
    for name, extra in runs.items():
        result = CliRunner().invoke(app, [*base, *extra, "--out", str(tmp_path / name)])
        assert result.exit_code == 0, result.output
        summary = json.loads((tmp_path / name / "summary.json").read_text())
        marginals[name] = np.load(tmp_path / name / "marginals.npz", allow_pickle=False)["pos_cov"]
        assert summary["fused_fixes"] == 30
    assert len(marginals["file"]) == 60 and len(marginals["flag"]) == 30
    # 10x the sigma of the bag's 0.5-m fixes: the fused positions are far less certain (a quietly ignored
    # --gps-sigma would leave them equal)
    spread = {name: np.median(np.trace(cov, axis1=1, axis2=2)) for name, cov in marginals.items()}
    assert spread["sigma"] > 10 * spread["flag"]


def test_online_fusion_takes_the_same_config():
    """OnlineFusion reads FuseConfig's sections (no settings of its own): an unknown type is refused by name."""
    import gtsam

    from airimu_core.errors import InputError
    from fusion.online import OnlineFusion

    seq = simulate("drone", duration_s=3.0, seed=1)
    first = gtsam.NavState(gtsam.Pose3(gtsam.Rot3(seq.gt.rot[0]), seq.gt.pos[0]), seq.gt.vel[0])
    config = dataclasses.replace(FuseConfig(), online=OnlineSettings(keyframe_s=0.5, lag_s=2.0, smoother="fixed_lag"))
    fusion = OnlineFusion(None, seq.gravity, first, config)
    fusion.add_imu(seq.t[:400], seq.gyro[:400], seq.acc[:400])
    assert fusion.keyframes == 4  # 0.5-s keyframes over 2 s of 200 Hz samples
    with pytest.raises(InputError, match="config must be a fusion.config.FuseConfig"):
        OnlineFusion(None, seq.gravity, first, {"keyframe_s": 0.5})


def test_car_config_weakens_the_forward_axis_and_keeps_every_other_default():
    """configs/fuse_car.yaml (by name, as `airimu fuse --config fuse_car.yaml` reads it): the motion factor's x
    variance scaled by 30, y and z as predicted, the IMU's gaps interpolated; everything else the defaults of
    FuseConfig."""
    import dataclasses

    from fusion.config import FuseConfig, MotionSettings, load_fuse_config

    car = load_fuse_config("fuse_car.yaml")
    assert car.motion.cov_scale == (30.0, 1.0, 1.0) and car.imu_gaps == "interpolate"
    assert dataclasses.replace(car, motion=MotionSettings(), imu_gaps="hold") == FuseConfig()
