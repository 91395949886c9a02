"""Run folders: what they hold, exact resumption, safe checkpoints; the IMU ablation; the average bias."""

from __future__ import annotations

import dataclasses
import json
import pickle

import numpy as np
import pytest
import torch
import yaml

from airimu_core.config import from_dict
from airimu_core.errors import ConfigError, DataError, InputError
from learned_imu.config import DataConfig, ExperimentConfig, ModelConfig, SequenceConfig, TrainConfig
from learned_imu.datasets.simulator import ImuErrorModel, simulate_with_truth
from learned_imu.evaluation.ablation import VARIANTS, ablate, write_rows
from learned_imu.evaluation.baselines import average_bias
from learned_imu.network.checkpoint import load_checkpoint, model_from_checkpoint
from learned_imu.training.experiment import train_run, with_epochs


def sim(seed: int, duration_s: float = 16.0) -> SequenceConfig:
    options = {"profile": "drone", "duration_s": duration_s, "grade": "consumer", "seed": seed, "device_seed": 5}
    return SequenceConfig("simulator", options=options)


TINY = ExperimentConfig(
    name="tiny",
    data=DataConfig(train=(sim(1), sim(2)), val=(sim(3, 8.0),)),
    model=ModelConfig(conv_channels=(8, 16), gru_sizes=(16,), decoder_hidden=16),
    train=TrainConfig(window=200, every=50, batch_size=4, epochs=4, lr=3e-3, calibration_steps=20, seed=0),
)


def lines(path):
    return [json.loads(line) for line in path.read_text().splitlines()]


def test_run_folder_holds_config_metrics_and_checkpoints(tmp_path):
    summary = train_run(TINY, tmp_path / "run", progress=False)
    run = tmp_path / "run"
    assert summary.epochs == 4
    resolved = from_dict(ExperimentConfig, yaml.safe_load((run / "config.yaml").read_text()))
    assert resolved == TINY
    log = lines(run / "metrics.jsonl")
    assert [e["epoch"] for e in log] == [0, 1, 2, 3]
    assert {"train_loss", "val_loss", "lr", "val_roe_deg", "val_rpe_rmse_m", "seconds"} <= set(log[0])
    best = min(log, key=lambda e: e["val_loss"])
    assert summary.best_epoch == best["epoch"]
    assert load_checkpoint(run / "best.pt").best.val_loss == best["val_loss"]
    assert load_checkpoint(run / "last.pt").trainer["epochs_done"] == 4
    model, config = model_from_checkpoint(run / "best.pt")
    assert config.model.gru_sizes == (16,) and not model.training
    assert not list(run.glob(".*.tmp"))  # no temporary file left behind
    # the checkpoint records the rate it was trained at; data sampled more than 10 % off it is refused
    assert model.trained_on.rate_hz == pytest.approx(200.0) and model.trained_on.datasets == ("simulator",)
    from airimu_core.errors import InputError
    from learned_imu.datasets.simulator import simulate
    from learned_imu.network.inference import correct

    assert correct(model, simulate("drone", duration_s=2.0, rate_hz=210.0, seed=9)).gyro.shape[1] == 3
    with pytest.raises(InputError, match=r"sampled at 100.0 Hz, but the model was trained at 200.0 Hz \(simulator\)"):
        correct(model, simulate("drone", duration_s=2.0, rate_hz=100.0, seed=9))


@pytest.mark.slow
def test_resumed_run_equals_uninterrupted_run(tmp_path):
    train_run(TINY, tmp_path / "whole", progress=False)
    train_run(with_epochs(TINY, 2), tmp_path / "resumed", progress=False)
    train_run(TINY, tmp_path / "resumed", progress=False)  # picks up after epoch 2
    whole, resumed = lines(tmp_path / "whole" / "metrics.jsonl"), lines(tmp_path / "resumed" / "metrics.jsonl")
    assert [e["train_loss"] for e in whole] == [e["train_loss"] for e in resumed]
    assert [e["val_loss"] for e in whole] == [e["val_loss"] for e in resumed]
    a = load_checkpoint(tmp_path / "whole" / "last.pt").trainer["model"]
    b = load_checkpoint(tmp_path / "resumed" / "last.pt").trainer["model"]
    assert all(torch.equal(a[k], b[k]) for k in a)
    # a finished run returns at once, and a different config is refused by name
    assert train_run(TINY, tmp_path / "whole", progress=False).epochs == 4
    other = dataclasses.replace(TINY, train=dataclasses.replace(TINY.train, lr=1e-2))
    with pytest.raises(ConfigError, match="train.lr"):
        train_run(other, tmp_path / "whole", progress=False)


def test_corrupt_or_foreign_checkpoints_are_named(tmp_path):
    bad = tmp_path / "last.pt"
    bad.write_bytes(b"\x00not a checkpoint")
    with pytest.raises(DataError, match="last.pt.*not a readable torch checkpoint"):
        load_checkpoint(bad)
    torch.save({"format": "something-else"}, bad)
    with pytest.raises(DataError, match="not an AirIMU checkpoint"):
        load_checkpoint(bad)
    torch.save({"format": "airimu-checkpoint", "version": 99}, bad)
    with pytest.raises(DataError, match="version 99"):
        load_checkpoint(bad)
    with pytest.raises(DataError, match="not found"):
        load_checkpoint(tmp_path / "absent.pt")
    # truncated mid-write (what a crash would leave without the atomic rename)
    train_run(with_epochs(TINY, 1), tmp_path / "run", progress=False)
    data = (tmp_path / "run" / "last.pt").read_bytes()
    bad.write_bytes(data[: len(data) // 2])
    with pytest.raises(DataError, match="not a readable torch checkpoint"):
        load_checkpoint(bad)


class _Payload:
    def __reduce__(self):
        return (print, ("a payload ran",))


@pytest.mark.parametrize(
    "name, write, message",
    [
        ("text", lambda path: path.write_text("hello world\n"), r"not a readable torch checkpoint \(KeyError"),
        ("random", lambda path: path.write_bytes(bytes(range(256)) * 8), "not a readable torch checkpoint"),
        ("pickle", lambda path: path.write_bytes(pickle.dumps(_Payload())), "nothing was unpickled"),
        ("torch", lambda path: torch.save({"x": _Payload()}, path), "nothing was unpickled"),
    ],
)
def test_a_file_that_is_no_checkpoint_is_refused_and_never_unpickled(tmp_path, capsys, name, write, message):
    """A text file was a KeyError traceback (torch's legacy reader); a pickle with a payload is refused by the safe
    loader without running it, and the message does not pass on torch's advice to set weights_only=False."""
    path = tmp_path / f"{name}.pt"
    write(path)
    with pytest.raises(DataError, match=message) as error:
        load_checkpoint(path)
    assert "weights_only" not in str(error.value) and "a payload ran" not in capsys.readouterr().out


def test_the_metrics_log_reads_as_epoch_records_and_a_damaged_line_is_named(tmp_path):
    from learned_imu.training.experiment import read_metrics
    from learned_imu.training.train import EpochLog

    run = tmp_path / "run"
    train_run(with_epochs(TINY, 2), run, progress=False)
    history = read_metrics(run / "metrics.jsonl")
    assert [entry.epoch for entry in history] == [0, 1] and all(isinstance(e, EpochLog) for e in history)
    assert all(e.seconds > 0 and e.val_roe_deg is not None for e in history)
    assert [e.to_dict() for e in history] == lines(run / "metrics.jsonl")
    log = run / "metrics.jsonl"
    log.write_text(log.read_text().splitlines()[0] + '\n{"epoch": 1, "train_loss": 0.1, "val_los": 0.2}\n')
    with pytest.raises(DataError, match=r"metrics.jsonl, line 2: field 'epoch': not an epoch record.*val_los"):
        train_run(with_epochs(TINY, 3), run, progress=False)  # resuming reads the log


def test_average_bias_recovers_a_constant_simulated_bias():
    # turn-on biases and white noise only (scale errors and g-sensitivity would add to the mean offset)
    model = ImuErrorModel(1e-4, 1e-3, 0.0, 0.0, np.radians(0.5), 0.05)
    truth = simulate_with_truth("drone", duration_s=30.0, error_model=model, seed=2)
    bias = average_bias([truth.sequence])
    # white noise leaves 1.8e-5 rad/s and 1.8e-4 m/s^2 (one sigma) on the means
    np.testing.assert_allclose(bias.gyro_rad_s, truth.gyro_bias.mean(axis=0), atol=1e-4)
    np.testing.assert_allclose(bias.acc_m_s2, truth.acc_bias.mean(axis=0), atol=1e-3)


@pytest.mark.slow
def test_ablation_scores_every_setting(tmp_path):
    rows = ablate(TINY, tmp_path / "ablation", progress=False)
    assert [r.variant for r in rows] == [v.name for v in VARIANTS]
    by = {r.variant: r for r in rows}
    assert by["Average Bias"].roe_deg < by["Baseline"].roe_deg  # the device's bias dominates the raw error
    assert by["Linear calibration"].roe_deg < by["Baseline"].roe_deg
    assert 0 < by["Baseline"].roe_rmse_10f_deg < by["Baseline"].roe_rmse_deg  # 10 samples drift less than 1 s
    assert np.isnan(by["Baseline"].nse_rot) and np.isfinite(by["AirIMU"].nse_rot)
    no_cov = load_checkpoint(tmp_path / "ablation" / "airimu_no_cov" / "last.pt").config
    assert no_cov.loss.covariance == 0.0
    write_rows(rows, tmp_path / "t.json", tmp_path / "t.csv")
    table = json.loads((tmp_path / "t.json").read_text())["rows"]
    assert table[0]["variant"] == "Baseline" and table[0]["nse_rot"] is None
    assert (tmp_path / "t.csv").read_text().splitlines()[0].startswith("variant,sequence,roe_deg")
    assert (tmp_path / "t_tables.csv").read_text().splitlines()[0].startswith("table,setting,sequence,field")
    assert by["Baseline"].seed is None and by["AirIMU"].seed == TINY.train.seed


@pytest.mark.slow
def test_ablation_over_seeds_trains_each_learned_variant_per_seed(tmp_path):
    from learned_imu.evaluation.ablation import summarise

    learned = [v for v in VARIANTS if v.key == "airimu"]
    rows = ablate(TINY, tmp_path / "seeds", variants=[VARIANTS[0], *learned], progress=False, seeds=[3, 4])
    assert [(r.variant, r.seed) for r in rows] == [("Baseline", None), ("AirIMU", 3), ("AirIMU", 4)]
    for seed in (3, 4):
        config = load_checkpoint(tmp_path / "seeds" / f"airimu_seed{seed}" / "last.pt").config
        assert config.train.seed == seed
    assert rows[1].roe_deg != rows[2].roe_deg  # different seeds, different models
    summary = {s.variant: s for s in summarise(rows)}
    assert summary["AirIMU"].seeds == 2 and summary["Baseline"].seeds == 1
    assert np.isclose(summary["AirIMU"].mean["roe_deg"], (rows[1].roe_deg + rows[2].roe_deg) / 2)
    assert np.isclose(summary["AirIMU"].std["roe_deg"], abs(rows[1].roe_deg - rows[2].roe_deg) / 2)


@pytest.mark.slow
def test_ablate_imu_cli_with_seeds_prints_the_summary_and_writes_seeded_rows(tmp_path):
    from typer.testing import CliRunner

    from airimu.cli import app
    from learned_imu.config import save_config

    config = tmp_path / "tiny.yaml"
    save_config(config, dataclasses.replace(TINY, train=dataclasses.replace(TINY.train, epochs=1, calibration_steps=2)))
    args = ["ablate-imu", "--config", str(config), "--out", str(tmp_path / "abl"), "--seeds", "0,1"]
    result = CliRunner().invoke(app, [*args, "--json", str(tmp_path / "t.json"), "--no-progress"])
    assert result.exit_code == 0, result.output
    assert "mean +- std over seeds 0,1" in result.output
    rows = json.loads((tmp_path / "t.json").read_text())["rows"]
    assert sorted(r["seed"] for r in rows if r["variant"] == "AirIMU") == [0, 1]
    bad = CliRunner().invoke(app, ["ablate-imu", "--config", str(config), "--seeds", "0,x"])
    assert bad.exit_code != 0 and "--seeds" in bad.output


def test_noise_scaled_on_the_validation_windows_when_asked(tmp_path):
    config = dataclasses.replace(
        TINY, train=dataclasses.replace(TINY.train, epochs=1, calibration_steps=2, scale_noise_on_val=True)
    )
    train_run(config, tmp_path / "run", progress=False)
    best = load_checkpoint(tmp_path / "run" / "best.pt")
    scales = best.best.noise_scales
    assert best.best.calibrated and len(scales) == 2 and min(scales) > 0
    model, _ = model_from_checkpoint(tmp_path / "run" / "best.pt")
    init = dataclasses.asdict(TINY.model)
    assert float(model.log_init_gyro_density) == pytest.approx(np.log(init["init_gyro_cov"] * scales[0]), abs=1e-5)
    assert float(model.log_init_acc_density) == pytest.approx(np.log(init["init_acc_cov"] * scales[1]), abs=1e-5)


def test_noise_scaling_asked_for_after_a_run_finished_is_applied_once(tmp_path):
    config = dataclasses.replace(TINY, train=dataclasses.replace(TINY.train, epochs=1, calibration_steps=2))
    train_run(config, tmp_path / "run", progress=False)
    assert load_checkpoint(tmp_path / "run" / "best.pt").best.noise_scales is None
    later = dataclasses.replace(config, train=dataclasses.replace(config.train, scale_noise_on_val=True))
    train_run(later, tmp_path / "run", progress=False)
    first = load_checkpoint(tmp_path / "run" / "best.pt")
    train_run(later, tmp_path / "run", progress=False)  # finished and scaled: nothing changes
    again = load_checkpoint(tmp_path / "run" / "best.pt")
    assert len(first.best.noise_scales) == 2 and first.best == again.best
    model_state = first.trainer["model"]
    assert torch.equal(model_state["log_init_gyro_density"], again.trainer["model"]["log_init_gyro_density"])


def test_linear_calibration_recovers_scale_misalignment_and_bias():
    from learned_imu.evaluation.baselines import linear_calibration

    truth = simulate_with_truth("drone", duration_s=60.0, rate_hz=200.0, seed=3)
    rng = np.random.default_rng(0)
    gyro_m, acc_m = np.eye(3) + 0.02 * rng.standard_normal((3, 3)), np.eye(3) + 0.02 * rng.standard_normal((3, 3))
    gyro_b, acc_b = np.array([0.01, -0.02, 0.005]), np.array([0.1, -0.05, 0.2])
    seq = truth.sequence
    raw = dataclasses.replace(
        seq, gyro=truth.clean_gyro @ gyro_m.T + gyro_b, acc=truth.clean_acc @ acc_m.T + acc_b
    )  # raw = M true + b, so the calibration is M^-1 and offset M^-1 b
    fitted = linear_calibration([raw])
    np.testing.assert_allclose(fitted.gyro_matrix, np.linalg.inv(gyro_m), atol=2e-3)
    np.testing.assert_allclose(fitted.acc_matrix, np.linalg.inv(acc_m), atol=2e-3)
    np.testing.assert_allclose(fitted.gyro_offset_rad_s, np.linalg.solve(gyro_m, gyro_b), atol=2e-4)
    np.testing.assert_allclose(fitted.acc_offset_m_s2, np.linalg.solve(acc_m, acc_b), atol=2e-2)
    gyro, acc = fitted.correct(raw)
    assert np.abs(gyro - truth.clean_gyro).max() < 5e-3 and np.abs(acc - truth.clean_acc).max() < 0.05


def test_a_sequence_part_keeps_its_samples_and_a_bad_span_names_the_file(tmp_path):
    truth = simulate_with_truth("drone", duration_s=10.0, rate_hz=200.0, seed=1)
    seq = truth.sequence
    tail = seq.part(0.75, 1.0)
    assert len(tail) == 500 and tail.name.endswith("[0.75:1]")
    np.testing.assert_array_equal(tail.gyro, seq.gyro[1500:])
    np.testing.assert_array_equal(tail.gt.pos, seq.gt.pos[1500:])
    assert seq.part(0.0, 1.0) is seq
    with pytest.raises(ValueError, match="0 <= start < stop <= 1"):
        seq.part(0.5, 0.5)
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\ndata:\n  train: [{dataset: simulator, span: [0.9, 0.2]}]\n  val: []\n")
    from learned_imu.config import load_config

    with pytest.raises(ConfigError, match=r"bad\.yaml.*data\.train\[0\].*span"):
        load_config(bad)


def test_paper_tables_put_the_papers_values_beside_our_seed_means():
    from learned_imu.evaluation.ablation import AblationRow, paper_tables

    def row(variant, roe, seed=None):
        return AblationRow(variant, "MH_04_difficult", roe, roe, roe, 0.04, 0.02, 0.003, 1.0, seed=seed)

    rows = [row("Baseline", 4.55), row("AirIMU", 0.06, 0), row("AirIMU", 0.08, 1)]
    gyro_table = paper_tables(rows)[0]
    cells = {(c.setting, c.field): c for c in gyro_table.cells}
    assert cells[("AirIMU", "roe_deg")].mean == pytest.approx(0.07) and cells[("AirIMU", "roe_deg")].seeds == 2
    assert cells[("AirIMU", "roe_deg")].std == pytest.approx(0.01)
    assert cells[("AirIMU", "roe_deg")].paper == 0.0708 and cells[("Baseline", "roe_rmse_deg")].paper == 4.5406
    brossard = cells[("Brossard et al.", "roe_deg")]  # quoted from the paper, not run here
    assert brossard.mean is None and brossard.paper == 0.1067
    nse = paper_tables(rows)[3]
    assert all(c.setting != "Baseline" for c in nse.cells)  # no covariance, no paper value: no cell


def test_device_option_is_checked_and_a_run_on_auto_reads_back_on_the_cpu(tmp_path):
    from learned_imu.config import resolve_device

    with pytest.raises(ConfigError, match=r"tiny\.yaml: key .train\.device.: expected one of cpu, cuda, auto"):
        bad = tmp_path / "tiny.yaml"
        bad.write_text("name: x\ndata: {train: [], val: []}\ntrain: {device: gpu}\n")
        from learned_imu.config import load_config

        load_config(bad)
    if torch.cuda.is_available():
        assert resolve_device("cuda") == "cuda" and resolve_device("auto") == "cuda"
    else:
        assert resolve_device("auto") == "cpu"
        with pytest.raises(ConfigError, match="no CUDA device"):
            resolve_device("cuda")
    config = dataclasses.replace(
        TINY, train=dataclasses.replace(TINY.train, epochs=1, calibration_steps=2, device="auto")
    )
    train_run(config, tmp_path / "run", progress=False)
    model, stored = model_from_checkpoint(tmp_path / "run" / "best.pt")
    assert stored.train.device == "auto"
    assert all(p.device.type == "cpu" for p in model.parameters())
    # the device may change on resume (train.device is a resumable change)
    cpu = dataclasses.replace(config, train=dataclasses.replace(config.train, device="cpu", epochs=2))
    assert train_run(cpu, tmp_path / "run", progress=False).epochs == 2


def test_cli_refuses_an_unknown_device_and_a_non_positive_epoch_budget(tmp_path):
    from typer.testing import CliRunner

    from airimu.cli import app
    from learned_imu.config import save_config

    config = tmp_path / "tiny.yaml"
    save_config(config, TINY)
    for flag, value in (("--device", "tpu"), ("--epochs", "0")):
        result = CliRunner().invoke(app, ["train", "--config", str(config), "--out", str(tmp_path / "r"), flag, value])
        assert result.exit_code != 0 and flag in result.output


@pytest.mark.slow
def test_small_euroc_config_trains_and_scores_on_real_data(tmp_path, shared_data):
    """configs/euroc_small.yaml end to end on the real MH_01 / V1_02 excerpt (one epoch: the plumbing, not the
    accuracy; the accuracy is BENCHMARKS.md's)."""
    from pathlib import Path

    from learned_imu.config import load_config

    config = load_config(Path(__file__).parents[3] / "configs" / "euroc_small.yaml", data_root=shared_data)
    config = with_epochs(dataclasses.replace(config, train=dataclasses.replace(config.train, calibration_steps=5)), 1)
    keep = [v for v in VARIANTS if v.key in ("baseline", "linear_calibration", "airimu")]
    rows = ablate(config, tmp_path / "abl", variants=keep, progress=False)
    by = {r.variant: r for r in rows}
    assert {r.sequence for r in rows} == {"V1_02_medium"}
    assert 4.0 < by["Baseline"].roe_deg < 5.0  # raw EuRoC gyro bias, ~4.5 deg per second
    assert by["Linear calibration"].roe_deg < 0.5 and by["AirIMU"].roe_deg < by["Baseline"].roe_deg
    best = load_checkpoint(tmp_path / "abl" / "airimu" / "best.pt").best
    assert best.calibrated and len(best.noise_scales) == 2


def test_rows_of_the_papers_kitti_drives_get_its_kitti_table():
    from learned_imu.evaluation.ablation import AblationRow, paper_tables

    rows = [AblationRow("Baseline", "2011_09_26_drive_0018", 0.15, 0.16, 0.043, 0.07, 0.01, 0.0, 1.0)]
    tables = paper_tables(rows)
    assert tables[0].fields == ("roe_deg", "rpe_m") and "KITTI" in tables[0].title
    cells = {c.field: c for c in tables[0].cells if c.setting == "Baseline"}
    assert cells["roe_deg"].paper == 0.2451 and cells["rpe_m"].paper == 0.0715 and cells["rpe_m"].mean == 0.043


def test_a_second_writer_of_a_run_folder_is_refused_naming_the_first(tmp_path):
    import os

    from airimu_core.errors import FolderBusyError
    from airimu_core.io import folder_lock

    run = tmp_path / "run"
    with folder_lock(run):  # as a first `airimu train` holds it
        with pytest.raises(FolderBusyError, match=rf"{run}: another writer holds it \(process {os.getpid()} on "):
            train_run(with_epochs(TINY, 1), run, progress=False)
        assert not (run / "config.yaml").exists() and not (run / "last.pt").exists()  # nothing written
    assert train_run(with_epochs(TINY, 1), run, progress=False).epochs == 1  # free once the holder is gone


def test_weight_averaging_validates_and_ships_the_average_and_resumes_exactly(tmp_path):
    """train.ema_decay: the checkpoint's model is the exponential moving average of the stepped weights, the
    validation loss is the average's, and a run resumed from last.pt equals the uninterrupted one."""
    from learned_imu.training.experiment import build_windows, load_sequences, loss_weights
    from learned_imu.training.train import Trainer

    config = dataclasses.replace(TINY, train=dataclasses.replace(TINY.train, ema_decay=0.9, epochs=2))
    torch.manual_seed(0)
    model = TINY_MODEL()
    windows = build_windows(load_sequences(config.data.train, None), config, None)
    val = build_windows(load_sequences(config.data.val, None), config, None)
    trainer = Trainer(model, windows, val, batch_size=4, lr=3e-3, weights=loss_weights(config), ema_decay=0.9)
    expected = {k: v.clone() for k, v in model.state_dict().items()}
    step = trainer.optimiser.step

    steps = []

    def step_and_track(*args, **kwargs):  # the average by hand, after every optimiser step (with its warm-up)
        out = step(*args, **kwargs)
        steps.append(1)
        d = min(0.9, len(steps) / (len(steps) + 9))
        for k, v in model.state_dict().items():
            expected[k] = d * expected[k] + (1 - d) * v if v.is_floating_point() else v.clone()
        return out

    trainer.optimiser.step = step_and_track
    entry = trainer.epoch()
    state = trainer.state_dict()
    for k, v in expected.items():
        torch.testing.assert_close(state["model"][k], v, rtol=1e-6, atol=1e-7)
    assert any(not torch.equal(state["model"][k], state["training_weights"][k]) for k in expected)
    with trainer.averaged():
        assert trainer.validation_loss() == pytest.approx(entry.val_loss, rel=1e-6)
    assert trainer.validation_loss() != pytest.approx(entry.val_loss, rel=1e-6)  # the raw weights differ
    # through a run folder: resuming continues the average and the raw weights exactly
    train_run(config, tmp_path / "whole", progress=False)
    train_run(with_epochs(config, 1), tmp_path / "resumed", progress=False)
    train_run(config, tmp_path / "resumed", progress=False)
    a = load_checkpoint(tmp_path / "whole" / "last.pt").trainer
    b = load_checkpoint(tmp_path / "resumed" / "last.pt").trainer
    for key in ("model", "training_weights"):
        assert all(torch.equal(a[key][k], b[key][k]) for k in a[key])
    with pytest.raises(ConfigError, match="train.ema_decay"):
        dataclasses.replace(TINY.train, ema_decay=1.0)


def TINY_MODEL():
    from learned_imu.network.checkpoint import build_model

    return build_model(TINY.model)


def test_no_window_to_train_names_the_key_the_window_and_the_sequences(tmp_path):
    empty = dataclasses.replace(TINY, data=dataclasses.replace(TINY.data, train=()))
    with pytest.raises(ConfigError, match=r"data.train: no sequence listed"):
        train_run(empty, tmp_path / "empty", progress=False)
    long = dataclasses.replace(TINY, train=dataclasses.replace(TINY.train, window=5000, every=50))
    with pytest.raises(
        InputError,
        match=r"train.window = 5000 samples: no window .* in data.train: "
        r"sim_drone_consumer_seed1 \(3200 samples, 3200 with ground truth\)",
    ):
        train_run(long, tmp_path / "long", progress=False)
