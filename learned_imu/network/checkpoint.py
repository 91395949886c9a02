"""Checkpoints: one ``.pt`` per save, written atomically and read back with ``torch.load(weights_only=True)``.

In code a checkpoint is a ``Checkpoint`` record (typed config, ``BestEpoch``, ``TrainedOn``); on disk it is a plain
dict of tensors, numbers, strings, lists and dicts only, so the safe loader accepts it:

- ``format`` = ``"airimu-checkpoint"``, ``version`` (``VERSION`` when written; ``READABLE`` are read);
- ``config``: the resolved ``ExperimentConfig`` as a plain dict (``airimu_core.config.to_dict``), from which
  the model is rebuilt without the YAML file;
- ``trainer``: ``Trainer.state_dict()`` (model weights under ``model``, optimiser, schedule, RNG states, epochs done);
- ``best``: the best validation record so far (``BestEpoch.to_dict()``; empty before the first epoch);
- ``trained_on``: ``rate_hz``, the median IMU rate of the training sequences, ``datasets``, their reader names, and
  (optional, newer files) ``speed_m_s``, the highest ground-truth speed among them; None when unknown.
  ``model_from_checkpoint`` hands it to the model (``model.trained_on``);
  ``learned_imu.network.inference.correct`` refuses data whose rate differs by more than ``MAX_RATE_MISMATCH``, and
  ``fusion.config.MotionSettings.speed_envelope`` reads the speed.
- ``written_by``: the versions of ``airimu`` and ``torch`` that wrote the file (a file from a newer toolkit is
  refused naming the version it needs).

Versions: 1 has no ``written_by``, and ``trained_on`` only in its later files; both read as absent
(tests/learned_imu/network/test_checkpoint.py). 2 always writes both keys.
"""

from __future__ import annotations

import dataclasses
import math
import pickle
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import torch

from airimu_core.config import from_dict, renamed, to_dict
from airimu_core.errors import ConfigError, DataError, InputError
from airimu_core.io import atomic_file
from learned_imu.config import ExperimentConfig, ModelConfig, MotionConfig
from learned_imu.network.model import AirImuNet
from learned_imu.network.motion import MotionNet


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
            epoch=int(data["epoch"]),
            val_loss=float(data["val_loss"]),
            seconds=float(data.get("seconds", math.nan)),
            metrics={k: v for k, v in data.items() if k not in own},
            calibrated=bool(data.get("calibrated", False)),
            calibration_nll=data.get("calibration_nll"),
            noise_scales=None if scales is None else tuple(scales),
        )

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
VERSION = 2
READABLE = (1, 2)
_REQUIRED = ("format", "version", "config", "trainer", "best")


@dataclass(frozen=True)
class TrainedOn:
    """What a model was trained on: the median IMU rate of its training sequences (Hz), their reader names, and
    ``speed_m_s``, the highest ground-truth speed among them (the largest of each sequence's 99.9th percentile of
    ``|v|``, m/s; None where unknown: files written before it was recorded). A motion model's forward velocity is
    not trusted above it (``fusion.config.MotionSettings.speed_envelope``). ``imu_delay_s``: the IMU delay (s)
    its training sequences were read with (the readers' ``imu_delay_s``, ``DataConfig.imu_delay_s`` of the stored
    config, not a key of the file); None where they differ. ``airimu fuse`` warns when a log is read
    with another (``learned_imu.network.rate.check_imu_delay``)."""

    rate_hz: float
    datasets: tuple[str, ...]
    speed_m_s: float | None = None
    imu_delay_s: float | None = 0.0

    def to_dict(self) -> dict:
        out = {"rate_hz": self.rate_hz, "datasets": list(self.datasets)}
        if self.speed_m_s is not None:
            out["speed_m_s"] = self.speed_m_s
        return out


@dataclass(frozen=True, eq=False)
class Checkpoint:
    """A checkpoint's contents (see the module docstring). ``trainer`` is ``Trainer.state_dict()``, the weights
    under ``"model"``; ``version`` and ``written_by`` are the file's as read (saving writes this code's)."""

    config: ExperimentConfig
    trainer: dict
    best: BestEpoch | None = None
    trained_on: TrainedOn | None = None
    version: int = VERSION
    written_by: dict[str, str] = field(default_factory=dict)

    def __post_init__(self):
        if not isinstance(self.config, ExperimentConfig):
            raise InputError(f"Checkpoint.config: expected an ExperimentConfig, got {type(self.config).__name__}")
        if not isinstance(self.trainer, dict) or not isinstance(self.trainer.get("model"), dict):
            raise InputError("Checkpoint.trainer: expected Trainer.state_dict(), a dict with the weights under 'model'")
        if self.best is not None and not isinstance(self.best, BestEpoch):
            raise InputError(f"Checkpoint.best: expected a BestEpoch or None, got {type(self.best).__name__}")

    def with_weights(self, weights: dict) -> Checkpoint:
        """This checkpoint with other model weights (a calibrated or rescaled model), the rest of the trainer kept."""
        return dataclasses.replace(self, trainer={**self.trainer, "model": weights})

    @property
    def kind(self) -> str:
        """Which network it holds: ``"correction"`` (``AirImuNet``) or ``"motion"`` (``MotionNet``)."""
        return self.config.train.model

    def model(self, source: str | Path = "checkpoint") -> AirImuNet:
        """The network of the stored config with the stored weights, in eval mode, with ``trained_on`` and
        ``removes_gravity`` (``train.remove_gravity``) attached for ``learned_imu.network.inference.correct``;
        weights that do not fit the config or hold NaN/Inf are a ``DataError`` naming ``source`` (the file), and so
        is a motion model's checkpoint (``motion_model``)."""
        self._expect("correction", source)
        model = self._loaded(build_model(self.config.model), source)
        model.removes_gravity = self.config.train.remove_gravity
        return model

    def motion_model(self, source: str | Path = "checkpoint") -> MotionNet:
        """The motion model (``learned_imu.network.motion``) of a ``train.model: motion`` checkpoint, in eval mode,
        ``trained_on`` attached; checked as ``model`` is."""
        self._expect("motion", source)
        model = self._loaded(build_motion_model(self.config.motion), source)
        model.warmup_samples = self.config.motion.context  # its outputs before then were never trained
        return model

    def _expect(self, kind: str, source) -> None:
        if self.kind != kind:
            use = "motion_from_checkpoint (airimu fuse --motion)" if self.kind == "motion" else "model_from_checkpoint"
            raise DataError(
                source, "config.train.model", f"holds a {self.kind} model, not a {kind} model: load it with {use}"
            )

    def _loaded(self, model, source):
        try:
            model.load_state_dict(self.trainer["model"])
        except (KeyError, RuntimeError) as error:
            raise DataError(source, "trainer.model", f"weights do not fit the stored model config ({error})") from error
        for name, tensor in model.state_dict().items():
            if tensor.is_floating_point() and not bool(torch.isfinite(tensor).all()):
                raise DataError(
                    source, f"trainer.model.{name}", "holds NaN or Inf weights (a diverged or damaged model)"
                )
        model.trained_on = self.trained_on
        return model.eval()


def save_checkpoint(path: str | Path, checkpoint: Checkpoint) -> Path:
    """Write ``checkpoint`` atomically (a crash leaves the previous file intact) in format ``VERSION``."""
    payload = {
        "format": FORMAT,
        "version": VERSION,
        "config": to_dict(checkpoint.config),
        "trainer": checkpoint.trainer,
        "best": checkpoint.best.to_dict() if checkpoint.best is not None else {},
        "trained_on": checkpoint.trained_on.to_dict() if checkpoint.trained_on is not None else None,
        "written_by": _software(),
    }
    with atomic_file(path, "wb") as f:
        torch.save(payload, f)
    return Path(path)


def load_checkpoint(path: str | Path) -> Checkpoint:
    """Read and validate a checkpoint (any version in ``READABLE``); a corrupt, foreign or newer file, or one whose
    stored config this code cannot read, is a ``DataError`` naming it and the field. ``path`` may name a model
    installed with the package (``learned_imu.network.shipped``: ``"euroc"``) where no file of that name exists."""
    path = Path(path)
    if not path.is_file():
        from learned_imu.network.shipped import shipped_path

        path = shipped_path(str(path)) or path
    if not path.is_file():
        from learned_imu.network.shipped import shipped_models

        names = ", ".join(shipped_models()) or "none"
        raise DataError(path, "file", f"checkpoint not found (nor a shipped model of that name; shipped: {names})")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as error:  # torch's message goes on to advise weights_only=False: not repeated
        problem = (
            "torch's safe loader refuses what it holds (objects other than tensors and plain data, or no "
            "pickle at all); nothing was unpickled"
        )
        raise DataError(path, "file", f"not a readable torch checkpoint: {problem}") from error
    except (RuntimeError, OSError, zipfile.BadZipFile, EOFError, ValueError, KeyError, IndexError) as error:
        # KeyError / IndexError: what the legacy (non-zip) reader raises on a text or other non-checkpoint file
        problem = f"{type(error).__name__}: {str(error).strip().splitlines()[0]}" if str(error).strip() else ""
        raise DataError(path, "file", f"not a readable torch checkpoint ({problem or type(error).__name__})") from error
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise DataError(path, "format", f"not an AirIMU checkpoint (expected format '{FORMAT}')")
    version = payload.get("version")
    if version not in READABLE:
        written_by = payload.get("written_by")
        writer = written_by.get("airimu", "unknown") if isinstance(written_by, dict) else "unknown"
        readable = ", ".join(map(str, READABLE))
        raise DataError(
            path,
            "version",
            f"checkpoint version {version!r} (written by airimu {writer}); this code "
            f"(airimu {_software()['airimu']}) reads versions {readable}: upgrade airimu to read it",
        )
    missing = [key for key in _REQUIRED if key not in payload]
    if missing:
        raise DataError(path, missing[0], "missing from the checkpoint")
    config = _stored_config(payload["config"], path)
    trained_on = _trained_on(payload.get("trained_on"), path)
    if trained_on is not None:
        trained_on = dataclasses.replace(trained_on, imu_delay_s=config.data.imu_delay_s)
    return Checkpoint(
        config=config,
        trainer=_trainer(payload["trainer"], path),
        best=_best(payload["best"], path),
        trained_on=trained_on,
        version=int(version),
        written_by=dict(payload.get("written_by") or {}),
    )


def model_from_checkpoint(path: str | Path) -> tuple[AirImuNet, ExperimentConfig]:
    """The trained model (eval mode, ``trained_on`` attached) and the resolved config stored with it."""
    checkpoint = load_checkpoint(path)
    return checkpoint.model(path), checkpoint.config


def motion_from_checkpoint(path: str | Path) -> tuple[MotionNet, ExperimentConfig]:
    """The trained motion model (eval mode, ``trained_on`` attached) and the resolved config stored with it."""
    checkpoint = load_checkpoint(path)
    return checkpoint.motion_model(path), checkpoint.config


def _stored_config(data, path: Path) -> ExperimentConfig:
    if not isinstance(data, dict):
        raise DataError(path, "config", f"expected a mapping, got {type(data).__name__}")
    try:  # renamed: files written before the naming rule keep loading
        return from_dict(ExperimentConfig, renamed(data), source="stored config")
    except ConfigError as error:
        raise DataError(path, "config", f"not readable by this version of airimu ({error})") from None


def _mapping(data, path: Path, key: str) -> dict:
    if not isinstance(data, dict):
        raise DataError(path, key, f"expected a mapping, got {type(data).__name__}")
    return data


def _trainer(data, path: Path) -> dict:
    if not isinstance(_mapping(data, path, "trainer").get("model"), dict):
        raise DataError(path, "trainer.model", "the model weights are missing")
    return data


def _best(data, path: Path) -> BestEpoch | None:
    try:
        return BestEpoch.from_dict(_mapping(data, path, "best"))
    except (TypeError, KeyError, ValueError) as error:
        raise DataError(path, "best", f"expected epoch and val_loss ({error!r})") from None


def _trained_on(data, path: Path) -> TrainedOn | None:
    if data is None:
        return None
    try:
        rate, datasets = float(data["rate_hz"]), tuple(str(name) for name in data["datasets"])
    except (TypeError, KeyError, ValueError) as error:
        raise DataError(path, "trained_on", f"expected rate_hz and datasets ({error!r})") from None
    if not (math.isfinite(rate) and rate > 0):
        raise DataError(path, "trained_on.rate_hz", f"must be a positive rate in Hz, got {rate!r}")
    speed = data.get("speed_m_s")
    if speed is not None:
        try:
            speed = float(speed)
        except (TypeError, ValueError):
            speed = math.nan
        if not (math.isfinite(speed) and speed >= 0):
            raise DataError(path, "trained_on.speed_m_s", f"must be a speed >= 0 in m/s, got {data['speed_m_s']!r}")
    return TrainedOn(rate, datasets, speed)


def _software() -> dict[str, str]:
    from importlib.metadata import PackageNotFoundError, version

    try:
        airimu = version("airimu")
    except PackageNotFoundError:  # a source tree that is not installed
        airimu = "unknown"
    return {"airimu": airimu, "torch": str(torch.__version__)}  # a str subclass the safe loader refuses


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


def build_motion_model(config: MotionConfig) -> MotionNet:
    """``MotionNet`` from its config."""
    return MotionNet(
        conv_channels=config.conv_channels,
        kernel_size=config.kernel_size,
        stride=config.stride,
        gru_sizes=config.gru_sizes,
        decoder_hidden=config.decoder_hidden,
        dropout=config.dropout,
        vel_scale_m_s=config.vel_scale_m_s,
        init_var=config.init_var,
    )
