"""Joint training of corrections and uncertainty through the differentiable preintegrator (AirIMU sec. III).

One step: the network corrects a batch of windows and predicts their noise densities; ``preintegrate`` turns
them into deltas and covariances at the supervised samples; the loss compares the deltas with the ground truth
in the covariance's chart (``learned_imu.training.losses``). Adam with weight decay, learning rate reduced on
plateaus of
the validation loss. Deterministic on CPU for a seed: the shuffling generator and torch's global RNG (dropout)
are part of ``Trainer.state_dict``, so a resumed run continues exactly where the interrupted one was. Under
``torchrun`` (``world``) each rank trains on its shard of every batch and rank 0 validates
(``learned_imu.training.distributed``).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import asdict, dataclass, fields

import numpy as np
import torch

from airimu_core.errors import InputError
from learned_imu.network.model import AirImuNet, Correction, device_of
from learned_imu.training.chunks import Chunks
from learned_imu.training.distributed import World, from_writer, global_loss, shard, wrap
from learned_imu.training.losses import (
    VARIANCE_FLOOR,
    LossWeights,
    normalised_squared_errors_of_variance,
    total_loss,
)
from learned_imu.training.motion import MotionChunks
from learned_imu.training.windows import Windows

TrainingData = Windows | Chunks | MotionChunks
"""What the trainer steps over: windows, each integrated on its own, or chunks whose windows come from one pass
(``learned_imu.training.chunks``), both offering ``len``, ``select``, ``to``, ``correct`` and ``errors``; or a
motion model's chunks (``learned_imu.training.motion``), which compute their own ``loss``."""

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class EpochLog:
    """One epoch: its number (0-based), mean training loss, validation loss, the learning rate used; in a run folder
    (``learned_imu.training.experiment.train_run``, one ``metrics.jsonl`` line each) also the wall time since the run
    began (s, summed over resumptions) and the validation metrics (means over the validation sequences)."""

    epoch: int
    train_loss: float
    val_loss: float
    lr: float
    seconds: float | None = None
    val_roe_deg: float | None = None
    val_rpe_rmse_m: float | None = None

    def to_dict(self) -> dict:
        """The JSON line's mapping: the fields that are set."""
        return {key: value for key, value in asdict(self).items() if value is not None}

    @classmethod
    def from_dict(cls, data: dict) -> EpochLog:
        """The record of a ``metrics.jsonl`` line (``KeyError``/``TypeError``/``ValueError`` when malformed)."""
        known = {f.name for f in fields(cls)}
        extra = sorted(set(data) - known)
        if extra:
            raise KeyError(f"unknown keys {extra}")
        return cls(**{key: (int if key == "epoch" else float)(value) for key, value in data.items()})


def stopped_early(last_epoch: int, best_epoch: int, patience: int) -> bool:
    """The early-stop rule (``train.early_stop_patience``): ``patience`` epochs past the best without a lower
    validation loss; 0 switches it off. ``training.experiment.train_run`` stops by it and ``airimu.viz.recording``
    marks a run so stopped."""
    return patience > 0 and last_epoch - best_epoch >= patience


def window_loss(
    model: torch.nn.Module, batch: TrainingData, weights: LossWeights, use_covariance: bool = True
) -> torch.Tensor:
    """Loss of ``model`` (an ``AirImuNet`` or its DDP wrapper) on a batch of windows or chunks, a mean over its
    windows (see the module docstring); a motion model's on its chunks (``learned_imu.training.motion``)."""
    if isinstance(batch, MotionChunks):
        return batch.loss(model, weights.covariance, use_covariance)
    out = batch.correct(model)
    densities = (out.gyro_cov, out.acc_cov) if use_covariance else (None, None)
    errors, variance = batch.errors(out, *densities)
    return total_loss(errors, variance, weights, batch.mask)


class Trainer:
    """Adam + ReduceLROnPlateau over shuffled mini-batches of windows or chunks (``batch_size`` of them a step);
    one ``epoch()`` at a time. With a ``world``, ``model`` is trained through a DDP wrapper (``self.net``) and
    ``batch_size`` is the global batch."""

    def __init__(
        self,
        model: AirImuNet,
        train: TrainingData,
        val: TrainingData,
        batch_size: int = 16,
        lr: float = 1e-3,
        weight_decay: float = 1e-4,
        weights: LossWeights | None = None,
        use_covariance: bool = True,
        plateau_factor: float = 0.5,
        plateau_patience: int = 2,
        seed: int = 0,
        world: World | None = None,
        device: str = "cpu",
        min_lr: float = 0.0,
        ema_decay: float = 0.0,
        val_covariance: bool = False,
    ):
        if batch_size < 1 or len(train) == 0 or len(val) == 0:
            raise InputError(f"Trainer: need batch_size >= 1 and windows to train and validate, got {batch_size}")
        # model (in place), windows and so every preintegration live on ``device``; the shuffling generator and
        # the RNG state kept in checkpoints are the CPU's (on a GPU dropout draws from the CUDA generator, so a
        # resumed GPU run is not bit-exact)
        self.model, self.train, self.val = model.to(device), train.to(device), val.to(device)
        self.batch_size, self.use_covariance = batch_size, use_covariance
        self.val_covariance = val_covariance and use_covariance
        self.weights = weights or LossWeights()
        self.world = world
        self.net = model if world is None else wrap(model, world, () if use_covariance else ("cov_decoder",))
        self.generator = torch.Generator().manual_seed(seed)
        self.optimiser = torch.optim.Adam(model.parameters(), lr=lr, weight_decay=weight_decay)
        self.scheduler = torch.optim.lr_scheduler.ReduceLROnPlateau(
            self.optimiser, factor=plateau_factor, patience=plateau_patience, min_lr=min_lr
        )
        self.epochs_done = 0
        if not 0.0 <= ema_decay < 1.0:
            raise InputError(f"Trainer: ema_decay must be in [0, 1), got {ema_decay}")
        self.ema_decay = ema_decay
        # the exponential moving average of the weights (Polyak averaging), updated after every step; what is
        # validated and what the checkpoint's "model" holds when ema_decay > 0 (the raw weights go on training)
        self.average = None if ema_decay == 0.0 else _copy(model.state_dict())
        self.averaged_steps = 0

    def epoch(self, on_batch: Callable[[float], None] | None = None) -> EpochLog:
        """Train one pass over the shuffled training windows (or chunks), validate, step the LR schedule."""
        self.model.train()
        order = torch.randperm(len(self.train), generator=self.generator)
        counts = None if self.train.mask is None else self.train.mask.sum(dim=1).cpu()  # windows in each chunk
        losses = []
        for first in range(0, len(self.train), self.batch_size):
            index, scale = shard(order[first : first + self.batch_size], self.world, counts)
            loss = window_loss(self.net, self.train.select(index), self.weights, self.use_covariance)
            self.optimiser.zero_grad()
            (loss if scale == 1.0 else loss * scale).backward()
            self.optimiser.step()
            self._update_average()
            losses.append(global_loss(loss.item(), scale, self.world))
            if on_batch is not None:
                on_batch(losses[-1])
        lr = self.optimiser.param_groups[0]["lr"]
        with self.averaged():
            val_loss = from_writer(self.validation_loss, self.world)
        self.scheduler.step(val_loss)
        entry = EpochLog(self.epochs_done, sum(losses) / len(losses), val_loss, lr)
        self.epochs_done += 1
        log.info("epoch %d: train %.5f, val %.5f, lr %.1e", entry.epoch, entry.train_loss, entry.val_loss, lr)
        return entry

    @torch.no_grad()
    def _update_average(self) -> None:
        if self.average is None:
            return
        self.averaged_steps += 1
        # warm-up (as timm's ModelEmaV2): the early average follows the weights instead of keeping the random init
        decay = min(self.ema_decay, self.averaged_steps / (self.averaged_steps + 9))
        for name, value in self.model.state_dict().items():
            if value.is_floating_point():
                self.average[name].lerp_(value, 1.0 - decay)
            else:
                self.average[name].copy_(value)

    @contextmanager
    def averaged(self):
        """Inside, ``self.model`` holds the averaged weights (no-op without ``ema_decay``); the training weights
        are back on exit."""
        if self.average is None:
            yield self.model
            return
        training = _copy(self.model.state_dict())
        self.model.load_state_dict(self.average)
        try:
            yield self.model
        finally:
            self.model.load_state_dict(training)

    @torch.no_grad()
    def validation_loss(self) -> float:
        """State loss on the validation windows in eval mode (batched like training, to bound memory).

        The model-selection criterion (best epoch, plateau, early stop) of every variant: the covariance's NLL is
        left out, so runs with and without the covariance loss pick their corrections by the same measure (the noise
        decoders are calibrated afterwards anyway, ``calibrate_uncertainty``); with ``val_covariance`` it is in, as
        the training loss has it (the official AirIMU's test loss)."""
        self.model.eval()
        total = 0.0
        for first in range(0, len(self.val), self.batch_size):
            batch = self.val.select(torch.arange(first, min(first + self.batch_size, len(self.val))))
            loss = window_loss(self.model, batch, self.weights, use_covariance=self.val_covariance)
            total += loss.item() * batch.windows
        return total / self.val.windows

    def state_dict(self) -> dict:
        """Everything needed to continue exactly: model, optimiser, schedule, RNG states, epochs done. With
        ``ema_decay``, "model" is the averaged weights (what inference loads) and "training_weights" the ones the
        optimiser steps."""
        state = {
            "model": self.model.state_dict() if self.average is None else _copy(self.average),
            "optimiser": self.optimiser.state_dict(),
            "scheduler": self.scheduler.state_dict(),
            "generator": self.generator.get_state(),
            "torch_rng": torch.get_rng_state(),
            "epochs_done": self.epochs_done,
        }
        if self.average is not None:
            state["training_weights"] = self.model.state_dict()
            state["averaged_steps"] = self.averaged_steps
        return state

    def load_state_dict(self, state: dict) -> None:
        if (self.average is None) != ("training_weights" not in state):
            raise InputError("Trainer: the checkpoint was trained with a different train.ema_decay (on or off)")
        if self.average is None:
            self.model.load_state_dict(state["model"])
        else:
            self.model.load_state_dict(state["training_weights"])
            self.average = _copy(state["model"])
            self.averaged_steps = int(state["averaged_steps"])
        self.optimiser.load_state_dict(state["optimiser"])
        self.scheduler.load_state_dict(state["scheduler"])
        self.generator.set_state(state["generator"])
        torch.set_rng_state(state["torch_rng"])
        self.epochs_done = int(state["epochs_done"])


def _copy(state: dict) -> dict:
    return {name: value.detach().clone() for name, value in state.items()}


def fit(
    model: AirImuNet,
    train: TrainingData,
    val: TrainingData,
    epochs: int = 10,
    batch_size: int = 16,
    lr: float = 1e-3,
    weight_decay: float = 1e-4,
    weights: LossWeights | None = None,
    use_covariance: bool = True,
    seed: int = 0,
) -> list[EpochLog]:
    """Train ``model`` in place for ``epochs``; returns one ``EpochLog`` per epoch (no run folder)."""
    trainer = Trainer(model, train, val, batch_size, lr, weight_decay, weights, use_covariance, seed=seed)
    return [trainer.epoch() for _ in range(epochs)]


def calibrate_uncertainty(
    model: AirImuNet, windows: TrainingData, steps: int = 200, batch_size: int = 16, lr: float = 1e-3, seed: int = 0
) -> float:
    """Second stage: fit only the noise decoders by the covariance NLL, the rest of the network frozen, in eval
    mode (as at inference). Returns the mean NLL of the last 20 steps.

    ``windows`` are moved to the model's device.

    Why: in joint training the first epochs see errors of the raw, uncorrected IMU (hundreds of sigmas), and Adam's
    second-moment memory of those gradients then shrinks the noise decoders' steps by orders of magnitude, so their
    output lags behind the corrections' improvement and over-predicts the noise (several-fold on EuRoC: BENCHMARKS.md,
    "Design measurements"). A fresh optimiser on the final errors fixes it.
    """
    from learned_imu.training.losses import variance_nll

    heads = [p for name, p in model.named_parameters() if "cov_decoder" in name]
    if not heads:
        raise InputError("calibrate_uncertainty: the model has no noise decoders ('*cov_decoder*' parameters)")
    frozen = [(p, p.requires_grad) for p in model.parameters()]
    for p, _ in frozen:
        p.requires_grad_(False)
    for p in heads:
        p.requires_grad_(True)
    optimiser = torch.optim.Adam(heads, lr=lr)
    generator = torch.Generator().manual_seed(seed)
    windows = windows.to(heads[0].device)
    model.eval()
    losses = []
    try:
        for _ in range(steps):
            pick = torch.randint(0, len(windows), (min(batch_size, len(windows)),), generator=generator)
            batch = windows.select(pick)
            out = batch.correct(model)
            errors, variance = batch.errors(out, out.gyro_cov, out.acc_cov)
            loss = variance_nll(errors.detach(), variance, batch.mask)
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            losses.append(loss.item())
    finally:
        for p, flag in frozen:
            p.requires_grad_(flag)
    return sum(losses[-20:]) / max(1, len(losses[-20:]))


@dataclass(frozen=True, eq=False)
class NoiseResiduals:
    """A model's delta errors on windows (M, K, 9) and the diagonal variances (M, K, 9) that its gyro noise and its
    acc noise contribute to their covariance, float64 (``noise_residuals``).

    The propagated covariance is linear in the densities, so densities scaled by (s_g, s_a) have exactly the
    variances ``s_g gyro_var + s_a acc_var``: the calibration under any scaling follows without running the model
    again."""

    errors: torch.Tensor
    gyro_var: torch.Tensor
    acc_var: torch.Tensor

    def nse(self, gyro_scale: float = 1.0, acc_scale: float = 1.0) -> np.ndarray:
        """(3,) mean e^2 / sigma^2 of rotation, position, velocity with the densities scaled as given."""
        variance = gyro_scale * self.gyro_var + acc_scale * self.acc_var
        return normalised_squared_errors_of_variance(self.errors, variance).numpy()

    def best_scales(self) -> tuple[float, float]:
        """The (gyro, acc) density scales of maximum likelihood: a two-parameter fit of the diagonal Gaussian NLL
        (the covariance loss's)."""
        squared = self.errors.square()
        log_scales = torch.zeros(2, dtype=torch.float64, requires_grad=True)
        optimiser = torch.optim.LBFGS([log_scales], max_iter=100, line_search_fn="strong_wolfe")

        def nll():
            optimiser.zero_grad()
            scales = torch.exp(log_scales)
            variance = scales[0] * self.gyro_var + scales[1] * self.acc_var + VARIANCE_FLOOR
            loss = (torch.log(variance) + squared / variance).mean()
            loss.backward()
            return loss

        optimiser.step(nll)
        gyro_scale, acc_scale = torch.exp(log_scales.detach()).tolist()
        return gyro_scale, acc_scale


@torch.no_grad()
def noise_residuals(model: AirImuNet, windows: TrainingData, batch_size: int = 64) -> NoiseResiduals:
    """The model (eval mode) on ``windows``: its errors and its two noise variances (see ``NoiseResiduals``),
    from two float64 preintegrations per batch, one with each sensor's noise alone (on the model's device; the
    result on the CPU)."""
    model.eval()
    windows = windows.to(device_of(model))
    errors, gyro_var, acc_var = [], [], []
    for first in range(0, len(windows), batch_size):
        batch = windows.select(torch.arange(first, min(first + batch_size, len(windows))))
        out = batch.correct(model)
        out = Correction(*(getattr(out, f.name).double() for f in fields(Correction)))
        batch = batch.double()
        error, from_gyro = batch.errors(out, out.gyro_cov, torch.zeros_like(out.acc_cov))
        _, from_acc = batch.errors(out, torch.zeros_like(out.gyro_cov), out.acc_cov)
        keep = slice(None) if batch.mask is None else batch.mask  # the windows that count, (M, K, ...) each
        errors.append(error[keep])
        gyro_var.append(from_gyro[keep])
        acc_var.append(from_acc[keep])
    return NoiseResiduals(*(torch.cat(x).cpu() for x in (errors, gyro_var, acc_var)))


def fit_noise_scales(model: AirImuNet, windows: TrainingData) -> tuple[float, float]:
    """Scales (gyro, acc) of the model's noise densities that maximise the likelihood of ``windows``' errors
    (``noise_residuals(...).best_scales()``). Meant for windows the corrections were not fitted to (the validation
    set): residuals there are larger than on the training windows, where the noise decoders learned them, and one
    global scale per sensor is what a few held-out windows can pin down without overfitting (variance scaling, as
    temperature scaling for classifiers)."""
    return noise_residuals(model, windows).best_scales()


def scale_noise(model: AirImuNet, gyro_scale: float, acc_scale: float) -> None:
    """Multiply the model's output noise densities by the given factors (in place, through its buffers)."""
    if not (gyro_scale > 0 and acc_scale > 0):
        raise InputError(f"scale_noise: scales must be positive, got {gyro_scale}, {acc_scale}")
    with torch.no_grad():
        model.log_init_gyro_density += math.log(gyro_scale)
        model.log_init_acc_density += math.log(acc_scale)
