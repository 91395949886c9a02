"""Typed config of the PGO ablation (``configs/pgo_*.yaml``); keys match the dataclasses one to one.

``experiment`` is the training config of the model (relative to this file); ``run`` the run folder holding its
checkpoints (relative to the working directory, trained there -- or resumed -- when ``best.pt`` is missing), or the
name of a shipped model (``airimu models``; used as it is); ``motion`` an optional motion model's checkpoint
(relative to the working directory, trained beforehand) or a shipped one's name.
``sequences`` default to the experiment's evaluation sequences (``data.evaluate``, else ``data.val``) and are
read relative to its data root.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from airimu_core.config import check_noise_density, config_path, from_dict, read_yaml
from airimu_core.errors import ConfigError
from fusion.config import BiasStates, FuseConfig, FusionSettings, MotionSettings
from learned_imu.config import SequenceConfig

ScoreSpan = Literal["keyframes", "gps"]
GpsSource = Literal["auto", "simulated", "recorded"]
Keyframes = Literal["interval", "fixes"]
SCORE_SPANS, GPS_SOURCES, KEYFRAMES = (typing.get_args(t) for t in (ScoreSpan, GpsSource, Keyframes))


@dataclass(frozen=True)
class PgoOptions:
    """Rates, noise and seeds of the ablation; fixed densities in rad/s/sqrt(Hz) and m/s^2/sqrt(Hz)."""

    gps_hz: tuple[float, ...] = (1.0, 0.1)
    gps_sigma_m: float = 0.1  # the simulated fixes' noise and the sigma they are fused with (recorded: their own)
    seeds: int = 10
    keyframe_interval_s: float = 0.1
    fixed_gyro_noise_density: float = FuseConfig.gyro_noise_density  # the fixed-covariance rows' IMU noise
    fixed_acc_noise_density: float = FuseConfig.acc_noise_density
    # where ATE is scored: "keyframes" (the whole keyframe span) or "gps" (from the first to the last fused fix:
    # past the last fix the graph dead-reckons, and how far depends on where the fixes fall, not on the setting)
    score_span: ScoreSpan = "keyframes"
    # "simulated" (from the ground truth), "recorded" (the sequence's own fixes) or "auto" (simulated where there is
    # ground truth, else recorded)
    gps_source: GpsSource = "auto"
    # "interval": a keyframe every keyframe_interval_s; "fixes": one at the sample of every recorded fix (within half
    # a sample period; fixes inside a gap of the IMU are not used), so that each fused fix has its keyframe
    keyframes: Keyframes = "interval"
    gtsam_example: bool = False  # add the GTSAM_EXAMPLE row
    # with bias states (fusion.graph.BiasStates: per-sample random walk and prior sigmas): each of the four settings
    # also runs with a bias state per keyframe, as a row "<setting> + bias states"
    bias_states: BiasStates | None = None
    # (gyro rad/s/sqrt(Hz), acc m/s^2/sqrt(Hz)) sigmas, at least, of a sample that is held across a time gap of the
    # IMU (longer than MAX_GAP_STEPS median steps: KITTI's dropped OXTS packets), in every setting; null: none
    gap_noise_density: tuple[float, float] | None = None

    def __post_init__(self):
        if self.score_span not in SCORE_SPANS:
            raise ConfigError(f"options.score_span must be one of {', '.join(SCORE_SPANS)}, got {self.score_span!r}")
        if self.keyframes not in KEYFRAMES:
            raise ConfigError(f"options.keyframes must be one of {', '.join(KEYFRAMES)}, got {self.keyframes!r}")
        if not (self.gps_hz and all(math.isfinite(r) and r > 0 for r in self.gps_hz)):
            raise ConfigError(f"options.gps_hz must be a list of positive rates (Hz), got {list(self.gps_hz)!r}")
        for key in ("gps_sigma_m", "keyframe_interval_s"):
            value = getattr(self, key)
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"options.{key} must be a positive number, got {value!r}")
        if self.seeds < 1:
            raise ConfigError(f"options.seeds must be a whole number >= 1, got {self.seeds!r}")
        check_noise_density("gyro", self.fixed_gyro_noise_density, "options.fixed_gyro_noise_density")
        check_noise_density("acc", self.fixed_acc_noise_density, "options.fixed_acc_noise_density")
        if self.gap_noise_density is not None:
            check_noise_density("gyro", self.gap_noise_density[0], "options.gap_noise_density[0]")
            check_noise_density("acc", self.gap_noise_density[1], "options.gap_noise_density[1]")
        if self.gps_source not in GPS_SOURCES:
            raise ConfigError(f"options.gps_source must be one of {', '.join(GPS_SOURCES)}, got {self.gps_source!r}")


@dataclass(frozen=True)
class PgoConfig:
    """The PGO ablation: which model, which sequences, GPS rates/noise/seeds, and the graph/solver settings."""

    name: str
    experiment: str
    run: str
    sequences: tuple[SequenceConfig, ...] = ()
    options: PgoOptions = field(default_factory=PgoOptions)
    fusion: FusionSettings = field(default_factory=FusionSettings)
    # a trained motion model (airimu train --model motion; its best.pt): adds the rows of
    # airimu.experiments.pgo.MOTION_SETTINGS (a learned velocity factor at every keyframe); null: none
    motion: str | None = None
    motion_settings: MotionSettings = field(default_factory=MotionSettings)  # passes and cov_scale (keyframe_s unused)


def load_pgo_config(path: str | Path) -> PgoConfig:
    """Read ``path`` (YAML; a shipped config by name too, ``airimu_core.config.config_path``); ``experiment`` is made
    absolute relative to the file's folder."""
    path = config_path(path)
    config = from_dict(PgoConfig, read_yaml(path), source=str(path))
    experiment = Path(config.experiment)
    if not experiment.is_absolute():
        experiment = (path.parent / experiment).resolve()
    return dataclasses.replace(config, experiment=str(experiment))
