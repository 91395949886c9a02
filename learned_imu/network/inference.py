"""Inference: a trained model applied to a sequence, from a model or straight from a checkpoint file.

- ``correct(model, sequence)``: the model's corrections and noise densities for a whole sequence (streamed; a model
  read from a checkpoint knows whether it was trained with ``train.remove_gravity``: ``model.removes_gravity``);
- ``correct_from_checkpoint(path, sequence)``: the same from a ``best.pt``;
- ``check_rate`` / ``check_times_rate``: a model whose checkpoint records its training rate refuses data sampled
  more than ``MAX_RATE_MISMATCH`` off it (its convolutions see time in samples).

Units: gyro rad/s, acc m/s^2, IMU frame; noise densities rad^2/s and m^2/s^3 (``*_cov``: sigma^2).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from airimu_core.errors import InputError
from airimu_core.sequence import ImuSequence
from learned_imu.network.model import AirImuNet, Correction, correct_sequence, device_of
from learned_imu.network.rate import MAX_RATE_MISMATCH, check_times_rate  # noqa: F401 (part of this API)


def correct(model: AirImuNet, sequence: ImuSequence, remove_gravity: bool | None = None) -> Correction:
    """The model's output for a whole sequence, (N, 3) fields in float64 on the CPU (streamed unless gravity removal
    needs the ground truth in one pass; computed on the model's device). A model read from a checkpoint that
    records its training rate (``model.trained_on``) refuses a sequence sampled more than ``MAX_RATE_MISMATCH`` off
    it. ``remove_gravity``: None takes the model's own (``model.removes_gravity``, set from its checkpoint; False
    for a model built in code); a value that contradicts the model's is an ``InputError``."""
    check_rate(model, sequence)
    own = getattr(model, "removes_gravity", None)
    if remove_gravity is not None and own is not None and remove_gravity != own:
        raise InputError(f"correct: remove_gravity={remove_gravity}, but the model was trained with {own}")
    remove_gravity = bool(own) if remove_gravity is None else remove_gravity
    model.eval()
    device = device_of(model)
    gyro = torch.as_tensor(sequence.gyro, dtype=torch.float32, device=device)
    acc = torch.as_tensor(sequence.acc, dtype=torch.float32, device=device)
    if remove_gravity:
        if sequence.gt is None:
            raise InputError(f"{sequence.name}: the model removes gravity with ground truth; the sequence has none")
        g_imu = np.einsum("nji,j->ni", sequence.gt.rot, sequence.gravity)
        g_imu = torch.as_tensor(g_imu, dtype=torch.float32, device=device)
        with torch.no_grad():
            out = model(gyro[None], acc[None], gravity_imu=g_imu[None])
        out = Correction(*(getattr(out, f)[0] for f in out.__dataclass_fields__))
    else:
        out = correct_sequence(model, gyro, acc)
    return Correction(*(getattr(out, f).cpu().double() for f in out.__dataclass_fields__))


def correct_from_checkpoint(checkpoint: str | Path, sequence: ImuSequence) -> Correction:
    """``correct`` with the model of ``checkpoint`` (which honours its stored ``train.remove_gravity``)."""
    from learned_imu.network.checkpoint import model_from_checkpoint

    return correct(model_from_checkpoint(checkpoint)[0], sequence)


def check_rate(model: AirImuNet, sequence: ImuSequence) -> None:
    """An ``InputError`` when ``sequence``'s median rate is more than ``MAX_RATE_MISMATCH`` off the rate the model
    was trained at (``model.trained_on``, from its checkpoint; nothing to check without it)."""
    check_times_rate(model, sequence.t, sequence.source or sequence.name)
