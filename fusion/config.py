"""Typed config of the PGO ablation (``configs/pgo_*.yaml``); keys match the dataclasses one to one.

``experiment`` is the training config of the model (relative to this file); ``run`` the run folder holding its
checkpoints (relative to the working directory, trained there -- or resumed -- when ``best.pt`` is missing).
``sequences`` default to the experiment's evaluation sequences (``data.evaluate``, else ``data.val``) and are
read relative to its data root.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from fusion.graph import FusionSettings
from fusion.pgo import PgoOptions
from learned_imu.config import SequenceConfig, config_path, from_dict, read_yaml
from learned_imu.errors import ConfigError


@dataclass(frozen=True)
class PgoConfig:
    """The PGO ablation: which model, which sequences, GPS rates/noise/seeds, and the graph/solver settings."""

    name: str
    experiment: str
    run: str
    sequences: tuple[SequenceConfig, ...] = ()
    options: PgoOptions = field(default_factory=PgoOptions)
    fusion: FusionSettings = field(default_factory=FusionSettings)


def load_pgo_config(path: str | Path) -> PgoConfig:
    """Read ``path`` (YAML; a shipped config by name too, ``learned_imu.config.config_path``); ``experiment`` is made
    absolute relative to the file's folder."""
    path = config_path(path)
    config = from_dict(PgoConfig, read_yaml(path), source=str(path))
    experiment = Path(config.experiment)
    if not experiment.is_absolute():
        experiment = (path.parent / experiment).resolve()
    if config.fusion.backend not in ("gtsam", "custom"):
        raise ConfigError(f"{path}: key 'fusion.backend': expected 'gtsam' or 'custom', got {config.fusion.backend!r}")
    if config.fusion.gps_robust not in (None, "huber", "cauchy"):
        raise ConfigError(f"{path}: key 'fusion.gps_robust': expected null, 'huber' or 'cauchy'")
    return PgoConfig(config.name, str(experiment), config.run, config.sequences, config.options, config.fusion)
