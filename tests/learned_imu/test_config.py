"""Configs: shipped files load; unknown, missing and ill-typed keys name the file and the key."""

from __future__ import annotations

from pathlib import Path

import pytest

from airimu_core.config import from_dict, to_dict
from airimu_core.errors import ConfigError
from learned_imu.config import ExperimentConfig, load_config

# experiment configs: every shipped YAML but the PGO ablation's and the fusion's (tests/airimu/test_fuse_config.py)
CONFIGS = sorted(
    p for p in (Path(__file__).parents[2] / "configs").glob("*.yaml") if not p.name.startswith(("pgo_", "fuse"))
)
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
    from airimu.experiments.pgo_config import load_pgo_config

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
        ("model: {init_gyro_density: 1.0e-8}\n", r"'model.init_gyro_density' is now 'model.init_gyro_cov' \(sigma\^2"),
        ("train: {window: 1000, chunk: 500}\n", r"train.chunk must be 0 \(windows one by one\) or at least"),
        ("train: {gt_rotation: true}\n", "train.gt_rotation must be false unless train.chunk is set"),
        ("train: {lr: 1.0e-3, min_lr: 1.0e-2}\n", r"train.min_lr must be in \[0, train.lr"),
        ("train: {val_stride: -1}\n", "train.val_stride must be a whole number >= 0"),
        ("loss: {covariance_by_block: 1}\n", "key 'loss.covariance_by_block': expected bool"),
    ],
)
def test_bad_keys_are_named(tmp_path, extra, message):
    path = write(tmp_path, MINIMAL + extra)
    with pytest.raises(ConfigError, match=message) as info:
        load_config(path)
    assert str(path) in str(info.value)


def test_a_key_given_twice_is_refused_naming_both_lines(tmp_path):
    """PyYAML keeps the last of two equal keys without a word: a forgotten ``epochs: 30`` below ``epochs: 3`` trained
    30 epochs. Refused, in nested mappings and at the top, naming both lines."""
    text = "name: t\ndata:\n  train: [{dataset: simulator}]\n  val: [{dataset: simulator}]\ntrain:\n  epochs: 3\n"
    with pytest.raises(ConfigError, match=r"key 'epochs' given twice \(lines 6 and 7\).*remove one"):
        load_config(write(tmp_path, text + "  epochs: 30\n"))
    with pytest.raises(ConfigError, match=r"key 'name' given twice \(lines 1 and 7\)"):
        load_config(write(tmp_path, text + "name: u\n"))
    with pytest.raises(ConfigError, match=r"key 'dataset' given twice"):
        load_config(write(tmp_path, text.replace("train: [{dataset: simulator}]", "train: [{dataset: a, dataset: b}]")))
    assert load_config(write(tmp_path, text)).train.epochs == 3


def test_missing_key_and_bad_yaml(tmp_path):
    with pytest.raises(ConfigError, match="missing key 'data.val'"):
        load_config(write(tmp_path, "name: t\ndata:\n  train: [{dataset: simulator}]\n"))
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(write(tmp_path, "name: [unclosed\n"))
    with pytest.raises(ConfigError, match="cannot read"):
        load_config(tmp_path / "absent.yaml")


PAPER_TRAIN = {"MH_01_easy", "MH_03_medium", "MH_05_difficult", "V1_02_medium", "V2_01_easy", "V2_03_difficult"}
PAPER_TEST = {"MH_02_easy", "MH_04_difficult", "V1_03_difficult", "V2_02_medium", "V1_01_easy"}


def test_euroc_config_is_the_papers_split_and_validation_never_touches_a_test_flight(shared_data):
    config = load_config(Path(__file__).parents[2] / "configs" / "euroc.yaml", data_root=shared_data)
    name = lambda spec: Path(spec.path).name  # noqa: E731
    assert {name(s) for s in config.data.train} == PAPER_TRAIN
    assert all(s.span == (0.0, 1.0) for s in config.data.train)  # the six flights in full, as the official code
    assert {name(s) for s in config.data.val} <= PAPER_TRAIN  # the official "test" loader: training flights only
    assert {name(s) for s in config.data.evaluate} == {"MH_04_difficult", "V1_03_difficult", "V2_02_medium"}
    assert {name(s) for s in config.data.evaluate} <= PAPER_TEST
    assert not config.train.scale_noise_on_val  # no held-out flight to scale the noise on
    assert (config.train.stride, config.train.window, config.train.every) == (10, 1000, 50)  # the official density
    assert config.train.chunk >= config.train.window and config.evaluation.frames == 10


def test_euroc_protocol_configs_choose_on_training_flights_only(shared_data):
    """configs/euroc_official.yaml validates on its training flights (the official protocol); euroc_leave_out.yaml
    holds two training flights out whole and validates on them; neither trains or selects on a test flight (the
    official one scores the test flights after training, the leave-out one not even that)."""
    name = lambda spec: Path(spec.path).name  # noqa: E731
    configs = Path(__file__).parents[2] / "configs"
    official = load_config(configs / "euroc_official.yaml", data_root=shared_data)
    assert {name(s) for s in official.data.train} == {name(s) for s in official.data.val} == PAPER_TRAIN
    leave_out = load_config(configs / "euroc_leave_out.yaml", data_root=shared_data)
    train, val = {name(s) for s in leave_out.data.train}, {name(s) for s in leave_out.data.val}
    assert train | val == PAPER_TRAIN and not train & val and len(val) == 2
    for config in (official, leave_out):
        assert not {name(s) for s in config.data.train + config.data.val} & PAPER_TEST
    assert not {name(s) for s in leave_out.data.evaluate} & PAPER_TEST


def test_data_root_override_moves_every_sequence_list(tmp_path, shared_data):
    """A user's own copy of the official download: ``--data-root`` is where train, val and evaluate are read."""
    from airimu_core.errors import DataError
    from learned_imu.training.experiment import load_sequences

    root = tmp_path / "official"
    (root / "euroc").mkdir(parents=True)
    (root / "euroc" / "V2_02_medium").symlink_to(shared_data / "euroc" / "V2_02_medium")
    (root / "euroc" / "V1_01_easy").symlink_to(shared_data / "euroc" / "V1_01_easy")  # ground truth only here
    text = (
        "name: five\ndata:\n  root: /nowhere\n  train: [{dataset: euroc, path: euroc/V2_02_medium}]\n"
        "  val: [{dataset: euroc, path: euroc/V2_02_medium}]\n"
        "  evaluate: [{dataset: euroc, path: euroc/V2_02_medium}, {dataset: euroc, path: euroc/V1_01_easy}]\n"
    )
    config = load_config(write(tmp_path, text), data_root=root)
    assert config.data.root == str(root.resolve())
    assert [s.name for s in load_sequences(config.data.evaluate[:1], config.data.root)] == ["V2_02_medium"]
    with pytest.raises(DataError, match=r"V1_01_easy.*imu_file"):  # what the shared data lacks, said plainly
        load_sequences(config.data.evaluate[1:], config.data.root)


def test_renamed_keys_name_the_new_key(tmp_path):
    from airimu.experiments.pgo_config import load_pgo_config

    pgo = tmp_path / "pgo.yaml"
    pgo.write_text("name: p\nexperiment: e.yaml\nrun: r\noptions: {fixed_gyro_density: 0.004}\n")
    with pytest.raises(ConfigError, match=r"'options.fixed_gyro_density' is now 'options.fixed_gyro_noise_density'"):
        load_pgo_config(pgo)
    # checkpoints written before the naming rule keep loading: tests/learned_imu/network/test_checkpoint.py


def test_a_variance_given_as_a_noise_density_sigma_is_refused(tmp_path):
    from airimu.experiments.pgo_config import load_pgo_config

    pgo = tmp_path / "pgo.yaml"
    pgo.write_text("name: p\nexperiment: e.yaml\nrun: r\noptions: {fixed_gyro_noise_density: 1.6e-8}\n")
    with pytest.raises(ConfigError, match=r"pgo.yaml.*fixed_gyro_noise_density.*a variance, sigma\^2\? give sigma"):
        load_pgo_config(pgo)
    pgo.write_text("name: p\nexperiment: e.yaml\nrun: r\noptions: {gap_noise_density: [0.06, 70.0]}\n")
    with pytest.raises(ConfigError, match=r"gap_noise_density\[1\]: 70.0 is not an? acc noise density"):
        load_pgo_config(pgo)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        ("train: {lr: 0}\n", r"train.lr must be a positive number, got 0.0"),
        ("train: {lr: .nan}\n", r"train.lr must be a positive number"),
        ("train: {batch_size: 0}\n", r"train.batch_size must be a whole number >= 1"),
        ("train: {window: 200, every: 300}\n", r"train.every must be in \[1, train.window = 200\]"),
        ("train: {epochs: -1}\n", r"train.epochs must be a whole number >= 1"),
        ("train: {plateau_factor: 1.0}\n", r"train.plateau_factor must be in \(0, 1\)"),
        ("model: {dropout: 1.5}\n", r"model.dropout must be in \[0, 1\)"),
        ("evaluation: {interval: 0}\n", r"evaluation.interval must be a positive number"),
        ("evaluation: {interval_unit: minutes}\n", r"key .evaluation.interval_unit.: expected one of s, frames"),
        ("loss: {huber_delta: -1}\n", r"loss.huber_delta must be a positive number"),
    ],
)
def test_out_of_range_values_are_named_at_load_time(tmp_path, extra, message):
    path = write(tmp_path, MINIMAL + extra)
    with pytest.raises(ConfigError, match=message) as info:
        load_config(path)
    assert str(path) in str(info.value)


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ("options: {gps_sigma_m: 0}", r"options.gps_sigma_m must be a positive number"),
        ("options: {gps_hz: [1.0, -0.1]}", r"options.gps_hz must be a list of positive rates"),
        ("options: {seeds: 0}", r"options.seeds must be a whole number >= 1"),
        ("fusion: {prior_pos_sigma_m: 0}", r"fusion.prior_pos_sigma_m must be a positive sigma"),
        ("fusion: {max_iterations: 0}", r"fusion.max_iterations must be a whole number >= 1"),
    ],
)
def test_out_of_range_pgo_values_are_named(tmp_path, options, message):
    from airimu.experiments.pgo_config import load_pgo_config

    pgo = tmp_path / "pgo.yaml"
    pgo.write_text(f"name: p\nexperiment: e.yaml\nrun: r\n{options}\n")
    with pytest.raises(ConfigError, match=message) as info:
        load_pgo_config(pgo)
    assert str(pgo) in str(info.value)


def test_kitti_leave_one_out_never_trains_or_validates_on_its_test_drive(shared_data):
    """benchmarks/motion_kitti_loo.py: each of AI-IMU's ten sequences gets a model trained on every template drive
    but its own, which it alone evaluates; the validation drives are no sequence and never trained on."""
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
    from motion_kitti import SEQUENCES
    from motion_kitti_loo import TEMPLATE, held_out

    template = load_config(TEMPLATE, data_root=shared_data)
    name = lambda spec: Path(spec.path).stem  # noqa: E731
    drives = {drive for drive, *_ in SEQUENCES.values()}
    assert {name(s) for s in template.data.evaluate} == drives
    assert drives <= {name(s) for s in template.data.train}
    assert not {name(s) for s in template.data.val} & (drives | {name(s) for s in template.data.train})
    for sequence, (drive, *_) in SEQUENCES.items():
        config = held_out(template, sequence)
        assert [name(s) for s in config.data.evaluate] == [drive]
        assert drive not in {name(s) for s in config.data.train}
        assert {name(s) for s in config.data.train} == {name(s) for s in template.data.train} - {drive}
        assert config.data.val == template.data.val and config.name.endswith(sequence)
