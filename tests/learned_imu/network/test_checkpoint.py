"""Checkpoints: typed in code (``Checkpoint``, ``BestEpoch``, ``TrainedOn``), plain ``weights_only``-loadable dicts on
disk; version-1 files (written before format version 2) still load, newer or damaged ones are named."""

from __future__ import annotations

import dataclasses
import re

import pytest
import torch

from airimu_core.config import to_dict
from airimu_core.errors import DataError
from learned_imu.config import ModelConfig
from learned_imu.network.checkpoint import (
    VERSION,
    BestEpoch,
    Checkpoint,
    TrainedOn,
    build_model,
    load_checkpoint,
    model_from_checkpoint,
    save_checkpoint,
)
from tests.helpers import write_checkpoint

SMALL = ModelConfig(conv_channels=(8, 16), gru_sizes=(16,), decoder_hidden=16)


def test_best_epoch_round_trips_through_a_weights_only_checkpoint(tmp_path):
    entry = {"epoch": 7, "train_loss": 0.5, "val_loss": 0.25, "lr": 1e-3, "seconds": 12.5, "val_roe_deg": 0.1}
    best = BestEpoch.from_dict(entry)
    fields = (best.epoch, best.val_loss, best.metrics["lr"], best.calibrated, best.noise_scales)
    assert fields == (7, 0.25, 1e-3, False, None)
    assert best.to_dict() == entry  # nothing added before calibration
    calibrated = BestEpoch.from_dict({**entry, "calibrated": True, "noise_scales": [0.5, 2.0]})
    assert calibrated.noise_scales == (0.5, 2.0) and calibrated.to_dict()["noise_scales"] == [0.5, 2.0]
    path = write_checkpoint(tmp_path / "c.pt", SMALL, build_model(SMALL).state_dict())
    path = save_checkpoint(path, Checkpoint(load_checkpoint(path).config, {"model": {}}, calibrated))
    assert load_checkpoint(path).best == calibrated  # torch.load(weights_only=True) underneath
    assert BestEpoch.from_dict({}) is None  # a file written before its first epoch
    assert torch.load(path, weights_only=True)["best"]["calibrated"] is True


def test_a_checkpoint_round_trips_as_records_and_says_what_wrote_it(tmp_path):
    model = build_model(SMALL)
    path = write_checkpoint(tmp_path / "c.pt", SMALL, model.state_dict(), remove_gravity=True)
    stored = load_checkpoint(path)
    on = TrainedOn(rate_hz=200.0, datasets=("euroc", "simulator"))
    save_checkpoint(path, Checkpoint(stored.config, stored.trainer, trained_on=on))
    again = load_checkpoint(path)
    assert again.version == VERSION == 2 and again.trained_on == on and again.best is None
    assert again.config == stored.config and again.config.train.remove_gravity and again.config.model == SMALL
    assert again.written_by == {"airimu": again.written_by["airimu"], "torch": torch.__version__}
    raw = torch.load(path, weights_only=True)
    assert raw["trained_on"] == {"rate_hz": 200.0, "datasets": ["euroc", "simulator"]}
    loaded, config = model_from_checkpoint(path)
    assert config == again.config and loaded.trained_on == on and not loaded.training
    for name, tensor in model.state_dict().items():
        assert torch.equal(loaded.state_dict()[name], tensor), name


def version_1(path, config: dict, weights: dict, **extra):
    """A checkpoint as format version 1 wrote it (no written_by; trained_on only in later version-1 files)."""
    payload = {"format": "airimu-checkpoint", "version": 1, "config": config, "trainer": {"model": weights}}
    torch.save({**payload, "best": {}, **extra}, path)
    return path


def test_version_1_files_still_load(tmp_path):
    model = build_model(SMALL)
    whole = to_dict(load_checkpoint(write_checkpoint(tmp_path / "v2.pt", SMALL, model.state_dict())).config)
    best = {"epoch": 3, "train_loss": 0.4, "val_loss": 0.3, "lr": 1e-3, "seconds": 9.0, "calibrated": True}
    early = load_checkpoint(version_1(tmp_path / "early.pt", whole, model.state_dict(), best=best))
    assert early.version == 1 and early.trained_on is None and early.written_by == {}
    assert early.best.epoch == 3 and early.best.calibrated and early.config.model == SMALL
    on = {"rate_hz": 100.0, "datasets": ["kitti_raw"]}
    late = load_checkpoint(version_1(tmp_path / "late.pt", whole, model.state_dict(), trained_on=on))
    assert late.trained_on == TrainedOn(100.0, ("kitti_raw",))
    # a version-1 file written before the naming rule: its stored config has the old keys
    old = {**whole, "model": {**whole["model"], "init_gyro_density": 4e-8, "init_acc_density": 9e-6}}
    del old["model"]["init_gyro_cov"], old["model"]["init_acc_cov"]
    legacy = build_model(ModelConfig(**{**SMALL.__dict__, "init_gyro_cov": 4e-8, "init_acc_cov": 9e-6}))
    loaded, config = model_from_checkpoint(version_1(tmp_path / "old.pt", old, legacy.state_dict()))
    assert config.model.init_gyro_cov == 4e-8 and config.model.init_acc_cov == 9e-6
    with torch.no_grad():
        out = loaded(torch.zeros(1, 9, 3), torch.zeros(1, 9, 3))
    assert torch.allclose(out.gyro_cov, torch.full_like(out.gyro_cov, 4e-8), rtol=1e-5)


@pytest.mark.parametrize(
    ("change", "field", "message"),
    [
        ({"version": 3, "written_by": {"airimu": "9.0"}}, "version", r"version 3 \(written by airimu 9.0\).*1, 2"),
        ({"format": "lightning"}, "format", "not an AirIMU checkpoint"),
        ({"best": {"val_loss": 0.1}}, "best", "expected epoch and val_loss"),
        ({"best": [1, 2]}, "best", "expected a mapping"),
        ({"trained_on": {"rate_hz": -5.0, "datasets": []}}, "trained_on.rate_hz", "positive rate"),
        ({"trained_on": {"datasets": []}}, "trained_on", "expected rate_hz and datasets"),
        ({"config": {"name": "x"}}, "config", r"not readable by this version.*stored config: missing key 'data'"),
        ({"trainer": {"model": {}}}, "trainer.model", "weights do not fit"),
        ({"trainer": {"epochs_done": 3}}, "trainer.model", "the model weights are missing"),
    ],
)
def test_a_damaged_or_newer_checkpoint_is_named(tmp_path, change, field, message):
    path = write_checkpoint(tmp_path / "c.pt", SMALL, build_model(SMALL).state_dict())
    torch.save({**torch.load(path, weights_only=True), **change}, path)
    with pytest.raises(DataError, match=f"{re.escape(str(path))}: field '{field}': .*{message}"):
        model_from_checkpoint(path)


def test_a_model_that_removes_gravity_says_so_and_is_applied_that_way_or_refused(tmp_path):
    from airimu_core.errors import InputError
    from learned_imu.datasets.simulator import simulate
    from learned_imu.network.inference import correct, correct_from_checkpoint

    path = write_checkpoint(tmp_path / "g.pt", SMALL, build_model(SMALL).state_dict(), remove_gravity=True)
    model, _ = model_from_checkpoint(path)
    assert model.removes_gravity is True
    seq = simulate("drone", duration_s=2.0, seed=0)
    with_gt = correct(model, seq)  # the model's own setting: gravity from the ground truth
    torch.testing.assert_close(with_gt.gyro, correct(model, seq, remove_gravity=True).gyro)
    torch.testing.assert_close(with_gt.gyro, correct_from_checkpoint(path, seq).gyro)
    with pytest.raises(InputError, match="remove_gravity=False, but the model was trained with True"):
        correct(model, seq, remove_gravity=False)
    blind = dataclasses.replace(seq, gt=None)
    with pytest.raises(InputError, match="removes gravity with ground truth; the sequence has none"):
        correct(model, blind)
    plain, _ = model_from_checkpoint(write_checkpoint(tmp_path / "p.pt", SMALL, build_model(SMALL).state_dict()))
    assert plain.removes_gravity is False and correct(plain, blind).gyro.shape == (len(seq.t), 3)


def test_a_checkpoint_record_refuses_what_it_could_not_save(tmp_path):
    from airimu_core.errors import InputError

    config = load_checkpoint(write_checkpoint(tmp_path / "c.pt", SMALL, build_model(SMALL).state_dict())).config
    with pytest.raises(InputError, match="Checkpoint.config: expected an ExperimentConfig, got dict"):
        Checkpoint({"model": {}}, {"model": {}})
    with pytest.raises(InputError, match="Checkpoint.trainer: expected Trainer.state_dict"):
        Checkpoint(config, {"weights": {}})
    with pytest.raises(InputError, match="Checkpoint.best: expected a BestEpoch or None, got dict"):
        Checkpoint(config, {"model": {}}, best={"epoch": 1})
