"""The second noise stage after training: ``scale_checkpoint_noise(path, sequence, out)`` fits one noise scale per
sensor by maximum likelihood on a held-out sequence's windows (``train.noise_residuals``) and writes a new
checkpoint (``airimu scale-noise``). Noise densities rad^2/s and m^2/s^3 (``*_cov``: sigma^2); a scale multiplies
them."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from airimu_core.errors import DataError, InputError
from airimu_core.sequence import ImuSequence


@dataclass(frozen=True)
class NoiseScaling:
    """What ``scale_checkpoint_noise`` did: the (gyro, acc) scales applied, the held-out NSE (rotation, position,
    velocity; 1 = calibrated) before and after, and the checkpoint written."""

    scales: tuple[float, float]
    nse_before: np.ndarray
    nse_after: np.ndarray
    path: Path


def scale_checkpoint_noise(checkpoint: str | Path, sequence: ImuSequence, out: str | Path) -> NoiseScaling:
    """Scale ``checkpoint``'s noise densities (one factor per sensor) to ``sequence``'s windows by maximum likelihood
    and write the result to ``out`` (may be ``checkpoint`` itself; the scales accumulate in ``best.noise_scales``).
    ``sequence`` must have ground truth and be held out (neither trained nor evaluated on)."""
    from learned_imu.network.checkpoint import load_checkpoint, save_checkpoint
    from learned_imu.training.experiment import build_windows
    from learned_imu.training.train import noise_residuals, scale_noise

    if sequence.gt is None:
        where = sequence.source or sequence.name
        raise InputError(f"{where}: the sequence has no ground truth; scaling the noise needs it")
    stored = load_checkpoint(checkpoint)
    if stored.best is None:  # the scales are kept in the best-epoch record
        raise DataError(checkpoint, "best", "the checkpoint has no trained epoch; scale the noise of a trained one")
    model = stored.model(checkpoint)
    residuals = noise_residuals(model, build_windows([sequence], stored.config, None))
    scales = residuals.best_scales()
    before, after = residuals.nse(), residuals.nse(*scales)
    scale_noise(model, *scales)
    previous = stored.best.noise_scales or (1.0, 1.0)
    best = replace(stored.best, noise_scales=(previous[0] * float(scales[0]), previous[1] * float(scales[1])))
    written = save_checkpoint(out, replace(stored, best=best).with_weights(model.state_dict()))
    return NoiseScaling((float(scales[0]), float(scales[1])), before, after, Path(written))
