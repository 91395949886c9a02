"""Configs: shipped files load; unknown, missing and ill-typed keys name the file and the key."""

from __future__ import annotations

from pathlib import Path

import pytest

from learned_imu.config import ExperimentConfig, from_dict, load_config, to_dict
from learned_imu.errors import ConfigError

CONFIGS = sorted(p for p in (Path(__file__).parents[2] / "configs").glob("*.yaml") if not p.name.startswith("pgo_"))
PGO_CONFIGS = sorted((Path(__file__).parents[2] / "configs").glob("pgo_*.yaml"))
MINIMAL = "name: t\ndata:\n  train: [{dataset: simulator}]\n  val: [{dataset: simulator}]\n"


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "c.yaml"
    path.write_text(text)
    return path


def test_shipped_configs_load_and_point_at_existing_data(shared_data):
    assert {"demo.yaml", "euroc.yaml", "kitti.yaml", "broad.yaml"} <= {p.name for p in CONFIGS}
    for path in CONFIGS:
        config = load_config(path, data_root=shared_data if path.name != "demo.yaml" else None)
        for spec in config.data.train + config.data.val + config.data.evaluate:
            if spec.dataset != "simulator":
                assert (Path(config.data.root) / spec.path).exists(), (path, spec.path)


def test_shipped_pgo_configs_load_and_name_an_experiment():
    from fusion.config import load_pgo_config

    assert {"pgo_demo.yaml", "pgo_euroc.yaml", "pgo_kitti.yaml"} <= {p.name for p in PGO_CONFIGS}
    for path in PGO_CONFIGS:
        config = load_pgo_config(path)
        assert Path(config.experiment).is_file() and 0.1 in config.options.gps_hz  # KITTI: 0.1 Hz only
        assert config.options.seeds == 10 and config.options.gps_sigma_m == 0.1


def test_round_trip_and_defaults(tmp_path):
    config = load_config(write(tmp_path, MINIMAL + "train: {lr: 1e-3, epochs: 3}\n"))
    assert config.train.lr == 1e-3 and config.train.epochs == 3 and config.model.use_gru
    assert from_dict(ExperimentConfig, to_dict(config)) == config
    assert Path(config.data.root) == tmp_path.resolve()


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        ("train: {learning_rate: 0.1}\n", "unknown key 'train.learning_rate'"),
        ("model: {use_gru: 'yes'}\n", "key 'model.use_gru': expected bool"),
        ("train: {epochs: 2.5}\n", "key 'train.epochs': expected int"),
        ("model: {gru_sizes: 64}\n", "key 'model.gru_sizes': expected a list"),
        ("train: {lr: fast}\n", "key 'train.lr': expected float"),
        ("bogus: 1\n", "unknown key 'bogus'"),
    ],
)
def test_bad_keys_are_named(tmp_path, extra, message):
    path = write(tmp_path, MINIMAL + extra)
    with pytest.raises(ConfigError, match=message) as info:
        load_config(path)
    assert str(path) in str(info.value)


def test_missing_key_and_bad_yaml(tmp_path):
    with pytest.raises(ConfigError, match="missing key 'data.val'"):
        load_config(write(tmp_path, "name: t\ndata:\n  train: [{dataset: simulator}]\n"))
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(write(tmp_path, "name: [unclosed\n"))
    with pytest.raises(ConfigError, match="cannot read"):
        load_config(tmp_path / "absent.yaml")
