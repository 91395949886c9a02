"""Joint training of corrections and uncertainty through the differentiable preintegrator (AirIMU sec. III).

One step: the network corrects a batch of windows and predicts their noise densities; ``preintegrate`` turns
them into deltas and covariances at the supervised samples; the loss compares the deltas with the ground truth
in the covariance's chart (``learned_imu.losses``). Adam with weight decay, learning rate reduced on plateaus of
the validation loss. Deterministic on CPU for a seed.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import torch

from learned_imu.losses import LossWeights, delta_errors, total_loss
from learned_imu.model import AirImuNet
from learned_imu.preintegration import preintegrate
from learned_imu.windows import Windows

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class EpochLog:
    """Mean training loss and validation loss of one epoch, and the learning rate used."""

    epoch: int
    train_loss: float
    val_loss: float
    lr: float


def window_loss(model: AirImuNet, windows: Windows, weights: LossWeights, use_covariance: bool = True) -> torch.Tensor:
    """Loss of ``model`` on ``windows`` (see the module docstring)."""
    out = model(windows.gyro, windows.acc)
    densities = (out.gyro_cov, out.acc_cov) if use_covariance else (None, None)
    pre = preintegrate(out.gyro, out.acc, windows.dt, *densities, at=windows.at)
    errors = delta_errors(pre, windows.start, windows.targets, windows.gravity)
    return total_loss(errors, pre.cov, weights)


def fit(
    model: AirImuNet,
    train: Windows,
    val: Windows,
    epochs: int = 10,
    batch_size: int = 16,
    lr: float = 1e-3,
    weight_decay: float = 1e-4,
    weights: LossWeights | None = None,
    use_covariance: bool = True,
    seed: int = 0,
) -> list[EpochLog]:
    """Train ``model`` in place; returns one ``EpochLog`` per epoch."""
    weights = weights or LossWeights()
    generator = torch.Generator().manual_seed(seed)
    optimiser = torch.optim.Adam(model.parameters(), lr=lr, weight_decay=weight_decay)
    scheduler = torch.optim.lr_scheduler.ReduceLROnPlateau(optimiser, factor=0.5, patience=2)
    history = []
    for epoch in range(epochs):
        model.train()
        order = torch.randperm(len(train), generator=generator)
        losses = []
        for first in range(0, len(train), batch_size):
            loss = window_loss(model, train.select(order[first : first + batch_size]), weights, use_covariance)
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            losses.append(loss.item())
        model.eval()
        with torch.no_grad():
            val_loss = window_loss(model, val, weights, use_covariance).item()
        scheduler.step(val_loss)
        entry = EpochLog(epoch, sum(losses) / len(losses), val_loss, optimiser.param_groups[0]["lr"])
        log.info("epoch %d: train %.5f, val %.5f, lr %.1e", entry.epoch, entry.train_loss, entry.val_loss, entry.lr)
        history.append(entry)
    return history
