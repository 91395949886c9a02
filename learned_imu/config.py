"""Typed experiment configuration: frozen dataclasses whose fields match the YAML keys one to one.

``load_config(path)`` reads a YAML file with ``yaml.safe_load`` and builds an ``ExperimentConfig``; an unknown,
missing or ill-typed key is a ``ConfigError`` naming the file and the key's dotted path (``train.lr``).
Sequence paths are relative to ``data.root``, which is itself relative to the config file's folder unless
absolute; ``--data-root`` on the command line overrides it. The config stops at the factories
(``model_from_config`` etc. in ``learned_imu.training.experiment``): classes take plain arguments.

Units are in the field names or comments: seconds, samples, m/s^2, rad/s; noise densities are continuous-time
(rad^2/s, m^2/s^3) as in ``AirImuNet`` and GTSAM.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from airimu_core.config import config_path, from_dict, read_yaml, save_yaml
from airimu_core.errors import ConfigError

Device = Literal["cpu", "cuda", "auto"]
IntervalUnit = Literal["s", "frames"]  # learned_imu.evaluation.evaluate's
DEVICES = typing.get_args(Device)
INTERVAL_UNITS = typing.get_args(IntervalUnit)
WindowRule = Literal["valid", "end_valid"]  # learned_imu.evaluation.evaluate's ``windows``
WINDOW_RULES = typing.get_args(WindowRule)
TrainedModel = Literal["correction", "motion"]  # train.model: which network a run trains
TRAINED_MODELS = typing.get_args(TrainedModel)


def _check(record, key: str, ok, expected: str) -> None:
    """A ``ConfigError`` naming ``key`` (dotted) when ``ok(value)`` is false: range checks at load time."""
    value = getattr(record, key.split(".")[-1])
    try:
        good = bool(ok(value))
    except TypeError:
        good = False
    if not good:
        raise ConfigError(f"{key} must be {expected}, got {value!r}")


def _positive(x) -> bool:
    return math.isfinite(x) and x > 0


def _non_negative(x) -> bool:
    return math.isfinite(x) and x >= 0


@dataclass(frozen=True)
class SequenceConfig:
    """One sequence: a reader name (``learned_imu.datasets.READERS``) or ``"simulator"``.

    For a reader, ``path`` is relative to ``data.root`` and ``options`` are the reader's keyword arguments
    (e.g. ``imu_file`` for EuRoC). For ``"simulator"``, ``options`` are ``learned_imu.datasets.simulator.simulate``'s
    (``profile``, ``duration_s``, ``grade``, ``seed``, ...) and ``path`` is unused. ``span`` keeps the samples
    from one fraction of the sequence to another (``[0.0, 0.85]`` trains on the first 85 %, ``[0.85, 1.0]``
    validates on the rest: ``ImuSequence.part``).
    """

    dataset: str
    path: str = ""
    options: dict[str, Any] = field(default_factory=dict)
    span: tuple[float, ...] = (0.0, 1.0)

    def __post_init__(self):
        from learned_imu.datasets import check_options

        check_options(self.dataset, self.options, "options")
        if len(self.span) != 2 or not 0.0 <= self.span[0] < self.span[1] <= 1.0:
            raise ConfigError(
                f"span of {self.path or self.dataset}: need [start, stop] with 0 <= start < stop <= 1, "
                f"got {list(self.span)}"
            )


@dataclass(frozen=True)
class DataConfig:
    """Which sequences train, validate (best checkpoint, LR schedule) and are evaluated (ablation tables)."""

    train: tuple[SequenceConfig, ...]
    val: tuple[SequenceConfig, ...]
    evaluate: tuple[SequenceConfig, ...] = ()  # default: the validation sequences
    root: str = "."

    @property
    def imu_delay_s(self) -> float | None:
        """The IMU delay (s) every training sequence is read with (the readers' ``imu_delay_s`` option; 0 where
        none is given); None where they differ."""
        delays = {float(spec.options.get("imu_delay_s", 0.0)) for spec in self.train}
        return delays.pop() if len(delays) == 1 else None


@dataclass(frozen=True)
class ModelConfig:
    """``AirImuNet``'s arguments (see its docstring)."""

    conv_channels: tuple[int, ...] = (32, 64)
    kernel_size: int = 7
    stride: int = 3
    gru_sizes: tuple[int, ...] = (128, 256)
    use_gru: bool = True
    decoder_hidden: int = 128
    dropout: float = 0.1
    acc_scale_m_s2: float = 0.1
    gyro_scale_rad_s: float = 0.017453292519943295  # 1 deg/s
    init_gyro_cov: float = 1.6968e-4**2  # noise density of the untrained model, sigma^2: rad^2/s
    init_acc_cov: float = 2.0e-3**2  # m^2/s^3

    def __post_init__(self):
        for key in ("conv_channels", "gru_sizes"):
            _check(self, f"model.{key}", lambda v: all(int(c) >= 1 for c in v), "a list of positive sizes")
        _check(self, "model.conv_channels", lambda v: len(v) >= 1, "at least one convolution")
        for key in ("kernel_size", "stride", "decoder_hidden"):
            _check(self, f"model.{key}", lambda v: v >= 1, "a positive whole number")
        _check(self, "model.dropout", lambda v: 0.0 <= v < 1.0, "in [0, 1)")
        for key in ("acc_scale_m_s2", "gyro_scale_rad_s", "init_gyro_cov", "init_acc_cov"):
            _check(self, f"model.{key}", _positive, "a positive number")


@dataclass(frozen=True)
class MotionConfig:
    """The motion model (``learned_imu.network.motion.MotionNet``'s arguments) and its training chunks
    (``learned_imu.training.motion``), trained when ``train.model`` is ``motion``. Sizes in IMU samples, each of
    ``chunk``, ``context``, ``stride`` and ``val_stride`` a whole number of blocks (``stride ** len(conv_channels)``,
    9 by default: one velocity every 9 samples)."""

    conv_channels: tuple[int, ...] = (32, 64)
    kernel_size: int = 7
    stride: int = 3
    gru_sizes: tuple[int, ...] = (128, 128)
    decoder_hidden: int = 64
    dropout: float = 0.1
    init_var: float = 0.1  # (m/s)^2, the untrained model's velocity variance
    # m/s per unit of the velocity decoder's output: about the platform's typical speed. A car's 10-30 m/s read at
    # 1 m/s per unit drove the GRUs into saturation in the first epoch (KITTI: a constant output; BENCHMARKS.md)
    vel_scale_m_s: float = 1.0
    chunk: int = 1800  # samples supervised per chunk
    context: int = 180  # samples before them that warm the GRUs up, unsupervised
    chunk_stride: int = 450  # distance between training chunk starts
    val_chunk_stride: int = 1800  # between validation chunk starts
    tilt_noise_deg: float = 2.0  # one-sigma tilt of each training chunk's attitude (learned_imu.training.motion)
    # one-sigma angle of a random rotation of each training chunk's IMU frame (inputs and target alike: the same
    # motion seen by an IMU mounted a little differently); 0: none
    frame_rotation_deg: float = 0.0
    # symmetries of the platform the training chunks are also seen through (IMU axes 0 / 1 / 2; null: none): half the
    # chunks reflected so that this IMU axis flips (a mirrored flight), and every chunk rotated about that IMU axis by
    # a uniform angle (a vehicle whose dynamics do not care about its heading about its thrust axis)
    mirror_axis: int | None = None
    spin_axis: int | None = None
    # half the training chunks played backwards (angular rate and velocity negated): the same path flown the other way
    time_reversal: bool = False
    covariance: float = 0.1  # weight of the variance's negative log-likelihood in the loss
    # weight of the drift term: the squared world-frame mean velocity error over every prefix of a chunk
    # (learned_imu.training.motion); 0: none
    drift: float = 0.0
    # weight of each IMU axis's velocity error in the loss (both terms, validation too): a car's forward axis low
    axis_weights: tuple[float, float, float] = (1.0, 1.0, 1.0)

    @property
    def block(self) -> int:
        return self.stride ** len(self.conv_channels)

    def __post_init__(self):
        for key in ("conv_channels", "gru_sizes"):
            _check(self, f"motion.{key}", lambda v: len(v) >= 1 and all(int(c) >= 1 for c in v), "positive sizes")
        for key in ("kernel_size", "stride", "decoder_hidden"):
            _check(self, f"motion.{key}", lambda v: v >= 1, "a positive whole number")
        _check(self, "motion.stride", lambda v: v <= self.kernel_size, "at most motion.kernel_size")
        _check(self, "motion.dropout", lambda v: 0.0 <= v < 1.0, "in [0, 1)")
        _check(self, "motion.init_var", _positive, "a positive variance, (m/s)^2")
        _check(self, "motion.vel_scale_m_s", _positive, "a positive speed, m/s")
        for key in ("chunk", "chunk_stride", "val_chunk_stride"):
            _check(
                self,
                f"motion.{key}",
                lambda v: v >= self.block and v % self.block == 0,
                f"a positive multiple of {self.block}",
            )
        _check(self, "motion.context", lambda v: v >= 0 and v % self.block == 0, f"a multiple of {self.block} >= 0")
        _check(self, "motion.tilt_noise_deg", lambda v: 0.0 <= v <= 45.0, "in [0, 45] degrees")
        _check(self, "motion.frame_rotation_deg", lambda v: 0.0 <= v <= 45.0, "in [0, 45] degrees")
        for key in ("mirror_axis", "spin_axis"):
            _check(self, f"motion.{key}", lambda v: v is None or v in (0, 1, 2), "null or an IMU axis 0, 1 or 2")
        _check(self, "motion.time_reversal", lambda v: isinstance(v, bool), "true or false")
        _check(self, "motion.covariance", _non_negative, "a weight >= 0")
        _check(self, "motion.drift", _non_negative, "a weight >= 0")
        _check(
            self,
            "motion.axis_weights",
            lambda v: len(v) == 3 and all(math.isfinite(w) and w >= 0 for w in v) and max(v) > 0,
            "three weights >= 0, one per IMU axis, not all 0",
        )


@dataclass(frozen=True)
class LossConfig:
    """``LossWeights``: Huber weights per block and epsilon for the covariance NLL (paper 1e-3)."""

    rotation: float = 1.0
    position: float = 1.0
    velocity: float = 1.0
    covariance: float = 1e-3
    huber_delta: float = 0.005
    covariance_trains_corrections: bool = False
    covariance_by_block: bool = False  # each block's NLL weighted by its block weight too (the official loss)

    def __post_init__(self):
        for key in ("rotation", "position", "velocity", "covariance"):
            _check(self, f"loss.{key}", _non_negative, "a weight >= 0")
        _check(self, "loss.huber_delta", _positive, "a positive number")


@dataclass(frozen=True)
class TrainConfig:
    """Windows, optimiser and schedule. ``window`` and ``every`` and ``stride`` are in IMU samples."""

    # which network the run trains: "correction" (AirImuNet: corrections and noise, the windows below) or "motion"
    # (MotionNet: body-frame velocity, the chunks of the motion section); the optimiser and schedule are shared
    model: TrainedModel = "correction"

    window: int = 1000
    every: int = 50  # supervise every k-th sample of a window (official default 50)
    stride: int = 0  # distance between training window starts; 0 = window (no overlap)
    # samples of network input before each window, neither integrated nor supervised (windows.py: without them the
    # network can park a window's predicted variance on its zero-padded first block); at least the network's
    # receptive field (18 samples, two blocks, for the default CNN) so that no window output sees the padding
    context: int = 0
    # every-window training (learned_imu.training.chunks): the network and the preintegrator run once over a chunk
    # of this many samples, and every window inside it (starting every ``stride`` samples) is read off that pass;
    # batch_size then counts chunks. 0: each window corrected and integrated on its own (batch_size counts windows)
    chunk: int = 0
    val_stride: int = 0  # distance between validation window starts; 0 = window (no overlap)
    # integrate velocity and position with the ground truth's rotation (the official AirIMU's gtrot; chunk only):
    # the gyro correction is then trained by the rotation loss alone, the acc correction by errors free of it
    gt_rotation: bool = False
    batch_size: int = 16
    epochs: int = 100
    lr: float = 1e-3
    weight_decay: float = 1e-4
    plateau_factor: float = 0.5  # ReduceLROnPlateau on the validation loss
    plateau_patience: int = 5
    min_lr: float = 0.0  # the plateau schedule's floor (the official AirIMU schedule: 1e-5)
    # exponential moving average of the weights, updated every step (0 = off): validation, best.pt and inference
    # use the average, the optimiser steps the raw weights; the horizon is about 1 / (1 - ema_decay) steps
    ema_decay: float = 0.0
    early_stop_patience: int = 0  # stop after this many epochs without a better validation loss; 0 = never
    # the validation loss (plateau schedule, best epoch, early stop) with the covariance's likelihood term, as the
    # training loss has it: the official AirIMU's test loss (train.py steps its scheduler and picks best_model on
    # get_loss, cov term included). False: the state loss alone, so that runs with and without the covariance loss
    # are chosen by the same measure
    val_covariance: bool = False
    calibration_steps: int = 200  # second stage: noise decoders alone on the NLL (0 = off; see train.py)
    # then one scale per sensor's noise fitted on the validation windows (train.fit_noise_scales); only where the
    # validation sequences are not the ones evaluated
    scale_noise_on_val: bool = False
    remove_gravity: bool = False  # network input acc + R_gt^T g (official option; needs ground truth)
    seed: int = 0
    # where model, windows and preintegration live while training: cpu, cuda (an error without one) or auto
    # (cuda when torch sees one); checkpoints are read back on the CPU either way
    device: Device = "cpu"

    def __post_init__(self):
        _check(self, "train.device", lambda v: v in DEVICES, f"one of {', '.join(DEVICES)}")
        _check(self, "train.model", lambda v: v in TRAINED_MODELS, f"one of {', '.join(TRAINED_MODELS)}")
        _check(self, "train.window", lambda v: v >= 2, "at least 2 samples")
        _check(self, "train.every", lambda v: 1 <= v <= self.window, f"in [1, train.window = {self.window}]")
        for key in ("stride", "val_stride", "context", "plateau_patience", "early_stop_patience", "calibration_steps"):
            _check(self, f"train.{key}", lambda v: v >= 0, "a whole number >= 0")
        for key in ("batch_size", "epochs"):
            _check(self, f"train.{key}", lambda v: v >= 1, "a whole number >= 1")
        _check(self, "train.lr", _positive, "a positive number")
        _check(self, "train.weight_decay", _non_negative, "a number >= 0")
        _check(self, "train.plateau_factor", lambda v: 0.0 < v < 1.0, "in (0, 1)")
        _check(self, "train.ema_decay", lambda v: 0.0 <= v < 1.0, "in [0, 1) (0 = no weight averaging)")
        _check(self, "train.min_lr", lambda v: 0.0 <= v <= self.lr, f"in [0, train.lr = {self.lr}]")
        _check(
            self,
            "train.chunk",
            lambda v: v == 0 or v >= self.window,
            f"0 (windows one by one) or at least train.window = {self.window} samples",
        )
        _check(self, "train.gt_rotation", lambda v: not v or self.chunk > 0, "false unless train.chunk is set")


@dataclass(frozen=True)
class EvaluationConfig:
    """Interval of the paper's metrics (``learned_imu.evaluation.evaluate``) and keyframe spacing of exports, s;
    ``frames``:
    the short interval of the paper's 10-frame table, in IMU samples (0 = not scored)."""

    interval: float = 1.0
    interval_unit: IntervalUnit = "s"
    frames: int = 10
    # which windows are scored: "valid" (every sample of the window has ground truth) or "end_valid" (its end sample
    # has; the official AirIMU evaluation's --mask, which its TUM-VI table uses: a window may start inside a hole of
    # the ground truth, from the values interpolated across it)
    windows: WindowRule = "valid"

    def __post_init__(self):
        _check(self, "evaluation.interval_unit", lambda v: v in INTERVAL_UNITS, f"one of {', '.join(INTERVAL_UNITS)}")
        _check(self, "evaluation.windows", lambda v: v in WINDOW_RULES, f"one of {', '.join(WINDOW_RULES)}")
        _check(self, "evaluation.interval", _positive, "a positive number")
        _check(self, "evaluation.frames", lambda v: v >= 0, "a whole number >= 0 (0: not scored)")


@dataclass(frozen=True)
class ExperimentConfig:
    """A whole experiment: data, model, loss, training and evaluation."""

    name: str
    data: DataConfig
    model: ModelConfig = ModelConfig()
    motion: MotionConfig = MotionConfig()
    loss: LossConfig = LossConfig()
    train: TrainConfig = TrainConfig()
    evaluation: EvaluationConfig = EvaluationConfig()


def resolve_device(device: str) -> str:
    """``train.device`` as a torch device name: ``auto`` is ``cuda`` when torch sees a GPU, else ``cpu``; ``cuda``
    without one is a ``ConfigError``."""
    import torch

    if device not in DEVICES:
        raise ConfigError(f"train.device must be one of {', '.join(DEVICES)}, got {device!r}")
    if device == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if device == "cuda" and not torch.cuda.is_available():
        raise ConfigError("train.device is 'cuda' but torch sees no CUDA device (use 'cpu' or 'auto')")
    return device


def load_config(path: str | Path, data_root: str | Path | None = None) -> ExperimentConfig:
    """Read ``path`` (YAML; a shipped config by name too, ``config_path``) into an ``ExperimentConfig``;
    ``data.root`` is made absolute (``data_root`` wins)."""
    path = config_path(path)
    config = from_dict(ExperimentConfig, read_yaml(path), source=str(path))
    root = Path(data_root) if data_root is not None else Path(config.data.root)
    if not root.is_absolute():
        root = (Path.cwd() if data_root is not None else path.parent) / root
    return dataclasses.replace(config, data=dataclasses.replace(config.data, root=str(root.resolve())))


def save_config(path: str | Path, config: ExperimentConfig) -> None:
    """Write the resolved config as YAML, atomically."""
    save_yaml(path, config)
