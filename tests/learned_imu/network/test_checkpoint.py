"""The best-epoch record of a checkpoint: typed in code, a plain dict on disk (older files read the same)."""

from __future__ import annotations

import torch

from learned_imu.network.checkpoint import BestEpoch, load_checkpoint, save_checkpoint


def test_best_epoch_round_trips_through_a_weights_only_checkpoint(tmp_path):
    entry = {"epoch": 7, "train_loss": 0.5, "val_loss": 0.25, "lr": 1e-3, "seconds": 12.5, "val_roe_deg": 0.1}
    best = BestEpoch.from_dict(entry)
    fields = (best.epoch, best.val_loss, best.metrics["lr"], best.calibrated, best.noise_scales)
    assert fields == (7, 0.25, 1e-3, False, None)
    assert best.to_dict() == entry  # nothing added before calibration
    calibrated = BestEpoch.from_dict({**entry, "calibrated": True, "noise_scales": [0.5, 2.0]})
    assert calibrated.noise_scales == (0.5, 2.0) and calibrated.to_dict()["noise_scales"] == [0.5, 2.0]
    path = save_checkpoint(tmp_path / "c.pt", {}, {"model": {}}, calibrated)
    stored = load_checkpoint(path)["best"]  # torch.load(weights_only=True) underneath
    assert isinstance(stored, dict) and BestEpoch.from_dict(stored) == calibrated
    assert BestEpoch.from_dict({}) is None  # a file written before its first epoch
    assert torch.load(path, weights_only=True)["best"]["calibrated"] is True
