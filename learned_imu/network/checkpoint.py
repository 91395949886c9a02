"""Checkpoints: one ``.pt`` per save, written atomically and read back with ``torch.load(weights_only=True)``.

Contents (plain tensors, numbers, strings, lists and dicts only, so the safe loader accepts them):

- ``format`` = ``"airimu-checkpoint"``, ``version`` = 1;
- ``config``: the resolved ``ExperimentConfig`` as a plain dict (``learned_imu.config.to_dict``), from which
  the model is rebuilt without the YAML file;
- ``trainer``: ``Trainer.state_dict()`` (model, optimiser, schedule, RNG states, epochs done);
- ``best``: the best validation record so far (``BestEpoch.to_dict()``: the epoch's metrics log entry plus what
  the calibration added; empty before the first epoch);
- ``trained_on`` (optional; absent in files written before it): ``rate_hz``, the median IMU rate of the training
  sequences, and ``datasets``, their reader names. ``model_from_checkpoint`` hands it to the model
  (``model.trained_on``), and ``learned_imu.network.inference.correct`` refuses data whose rate differs by more than
  ``MAX_RATE_MISMATCH``.
"""

from __future__ import annotations

import math
import pickle
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import torch

from learned_imu.config import ModelConfig, from_dict, renamed
from learned_imu.errors import DataError
from learned_imu.io import atomic_file
from learned_imu.network.model import AirImuNet


@dataclass(frozen=True)
class BestEpoch:
    """The best validation epoch of a run: its number (0-based), validation loss (the selection criterion), wall
    time since the run began (s) and the rest of its ``metrics.jsonl`` entry (``metrics``: ``train_loss``, ``lr``,
    ``val_roe_deg``, ...); then what the calibration of ``best.pt`` did: ``calibrated``, the second stage's final
    NLL, the (gyro, acc) noise scales. Checkpoints store it as a plain dict (``to_dict``), which older files are."""

    epoch: int
    val_loss: float
    seconds: float
    metrics: dict = field(default_factory=dict)
    calibrated: bool = False
    calibration_nll: float | None = None
    noise_scales: tuple[float, float] | None = None

    @classmethod
    def from_dict(cls, data: dict) -> BestEpoch | None:
        """The record of a stored dict (a checkpoint's ``best`` or a metrics entry); None for an empty one."""
        if not data:
            return None
        own = {"epoch", "val_loss", "seconds", *CALIBRATION_FIELDS}
        scales = data.get("noise_scales")
        return cls(
            epoch=int(data["epoch"]), val_loss=float(data["val_loss"]), seconds=float(data.get("seconds", math.nan)),
            metrics={k: v for k, v in data.items() if k not in own}, calibrated=bool(data.get("calibrated", False)),
            calibration_nll=data.get("calibration_nll"), noise_scales=None if scales is None else tuple(scales),
        )  # fmt: skip

    def to_dict(self) -> dict:
        """Flat and ``weights_only``-loadable: the metrics, the three fields, and the calibration keys once set."""
        out = {**self.metrics, "epoch": self.epoch, "val_loss": self.val_loss, "seconds": self.seconds}
        if self.calibrated:
            out["calibrated"] = True
        if self.calibration_nll is not None:
            out["calibration_nll"] = self.calibration_nll
        if self.noise_scales is not None:
            out["noise_scales"] = list(self.noise_scales)
        return out


CALIBRATION_FIELDS = ("calibrated", "calibration_nll", "noise_scales")  # what calibrating best.pt adds
FORMAT = "airimu-checkpoint"
VERSION = 1
_REQUIRED = ("format", "version", "config", "trainer", "best")


def save_checkpoint(
    path: str | Path, config: dict, trainer_state: dict, best: BestEpoch | dict | None, trained_on: dict | None = None
) -> Path:
    """Write a checkpoint atomically (a crash leaves the previous file intact); ``best`` a record, or a stored dict
    as read (hand-made files: ``{}``)."""
    best = best.to_dict() if isinstance(best, BestEpoch) else dict(best or {})
    payload = {"format": FORMAT, "version": VERSION, "config": config, "trainer": trainer_state, "best": best}
    if trained_on is not None:
        payload["trained_on"] = trained_on
    with atomic_file(path, "wb") as f:
        torch.save(payload, f)
    return Path(path)


def load_checkpoint(path: str | Path) -> dict:
    """Read and validate a checkpoint; a corrupt, foreign or other-version file is a ``DataError`` naming it."""
    path = Path(path)
    if not path.is_file():
        raise DataError(path, "file", "checkpoint not found")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except (RuntimeError, OSError, pickle.UnpicklingError, zipfile.BadZipFile, EOFError, ValueError) as error:
        first_line = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise DataError(path, "file", f"not a readable torch checkpoint ({first_line})") from error
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise DataError(path, "format", f"not an AirIMU checkpoint (expected format '{FORMAT}')")
    if payload.get("version") != VERSION:
        raise DataError(path, "version", f"checkpoint version {payload.get('version')!r}, this code reads {VERSION}")
    missing = [key for key in _REQUIRED if key not in payload]
    if missing:
        raise DataError(path, missing[0], "missing from the checkpoint")
    if isinstance(payload["config"], dict):  # files written before the naming rule keep loading
        payload["config"] = renamed(payload["config"])
    return payload


def model_from_checkpoint(path: str | Path) -> tuple[AirImuNet, dict]:
    """The trained model (eval mode) and the resolved config dict stored with it."""
    payload = load_checkpoint(path)
    config = payload["config"]
    model_config = from_dict(ModelConfig, config.get("model", {}), source=f"{path} (stored config)", where="model")
    model = build_model(model_config)
    try:
        model.load_state_dict(payload["trainer"]["model"])
    except (KeyError, RuntimeError) as error:
        raise DataError(path, "trainer.model", f"weights do not fit the stored model config ({error})") from error
    for name, tensor in model.state_dict().items():
        if tensor.is_floating_point() and not bool(torch.isfinite(tensor).all()):
            raise DataError(path, f"trainer.model.{name}", "holds NaN or Inf weights (a diverged or damaged model)")
    model.trained_on = payload.get("trained_on")
    return model.eval(), config


def build_model(config: ModelConfig) -> AirImuNet:
    """``AirImuNet`` from its config (the factory: the model itself takes plain arguments)."""
    return AirImuNet(
        conv_channels=config.conv_channels,
        kernel_size=config.kernel_size,
        stride=config.stride,
        gru_sizes=config.gru_sizes,
        use_gru=config.use_gru,
        decoder_hidden=config.decoder_hidden,
        dropout=config.dropout,
        acc_scale_m_s2=config.acc_scale_m_s2,
        gyro_scale_rad_s=config.gyro_scale_rad_s,
        init_gyro_cov=config.init_gyro_cov,
        init_acc_cov=config.init_acc_cov,
    )
