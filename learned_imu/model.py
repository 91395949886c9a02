"""The AirIMU network: per-sample IMU corrections and their uncertainty, from a shared causal encoder.

Shape of the official model (``CodeNet``): Conv1d 6 -> 32 -> 64 (kernel 7, stride 3, BatchNorm, GELU, dropout
0.1), GRUs 64 -> 128 -> 256, and two decoders. Deliberate differences: the convolutions are causal (left padding
only), so that every block of ``stride**2`` = 9 samples gets a feature that depends only on samples up to the end
of that block; features are repeated back to the 9 samples of their block; and the last decoder layers start at
zero, so an untrained model passes the raw IMU through with the initial noise. This makes streaming inference
(``stream``) exact: chunk by chunk with carried state it gives the same output as one pass.

Conventions. Inputs: ``gyro`` (B, N, 3) rad/s and ``acc`` (B, N, 3) m/s^2 specific force, IMU frame. Outputs
(``Correction``): corrected samples (raw + correction) in the same units, and per-sample diagonal noise as
continuous-time densities (``gyro_cov`` rad^2/s, ``acc_cov`` m^2/s^3), what ``learned_imu.preintegrate`` takes.
Streaming needs ``model.eval()`` (BatchNorm statistics and dropout are per batch in training mode).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import nn

ACC_INPUT_SCALE_M_S2 = 9.81  # acc is divided by this before the network (inputs of order 1)
DEFAULT_GYRO_DENSITY = 1.6968e-4**2  # rad^2/s: initial gyro noise (EuRoC's ADIS16448 datasheet density)
DEFAULT_ACC_DENSITY = 2.0e-3**2  # m^2/s^3: initial acc noise
LOG_DENSITY_LIMIT = 20.0  # the network's log-density offset is clamped to +-this (e^20 ~ 5e8)


@dataclass(frozen=True, eq=False)
class Correction:
    """Network output. Shapes (B, N, 3); units in the module docstring."""

    gyro: torch.Tensor
    acc: torch.Tensor
    d_gyro: torch.Tensor
    d_acc: torch.Tensor
    gyro_cov: torch.Tensor
    acc_cov: torch.Tensor


@dataclass(frozen=True, eq=False)
class StreamState:
    """What ``AirImuNet.stream`` carries between chunks: conv input histories, GRU hidden states, and the raw
    samples of the incomplete block (B, r, 3) each, r < 9."""

    conv_history: tuple[torch.Tensor, ...]
    gru_hidden: tuple[torch.Tensor, ...]
    pending_gyro: torch.Tensor
    pending_acc: torch.Tensor


class AirImuNet(nn.Module):
    """Correction and uncertainty network (see the module docstring). Plain typed arguments, no config object."""

    def __init__(
        self,
        conv_channels: tuple[int, ...] = (32, 64),
        kernel_size: int = 7,
        stride: int = 3,
        gru_sizes: tuple[int, ...] = (128, 256),
        use_gru: bool = True,
        decoder_hidden: int = 128,
        dropout: float = 0.1,
        acc_scale_m_s2: float = 0.1,
        gyro_scale_rad_s: float = math.radians(1.0),
        init_gyro_density: float = DEFAULT_GYRO_DENSITY,
        init_acc_density: float = DEFAULT_ACC_DENSITY,
    ):
        super().__init__()
        if kernel_size < stride:
            raise ValueError(f"kernel_size ({kernel_size}) must be at least the stride ({stride})")
        self.stride, self.kernel_size = stride, kernel_size
        self.pad = kernel_size - stride  # left padding: a window ends at the last sample of its stride block
        self.block = stride ** len(conv_channels)  # samples per feature step
        channels = (6, *conv_channels)
        self.convs = nn.ModuleList(
            nn.Sequential(
                nn.Conv1d(c_in, c_out, kernel_size, stride), nn.BatchNorm1d(c_out), nn.GELU(), nn.Dropout(dropout)
            )
            for c_in, c_out in zip(channels[:-1], channels[1:], strict=True)
        )
        sizes = (channels[-1], *gru_sizes) if use_gru else (channels[-1],)
        self.grus = nn.ModuleList(nn.GRU(a, b, batch_first=True) for a, b in zip(sizes[:-1], sizes[1:], strict=True))
        self.correction = _decoder(sizes[-1], decoder_hidden)
        self.uncertainty = _decoder(sizes[-1], decoder_hidden)
        self.register_buffer("scale", torch.tensor([acc_scale_m_s2] * 3 + [gyro_scale_rad_s] * 3))
        self.register_buffer("init_density", torch.tensor([init_acc_density] * 3 + [init_gyro_density] * 3))

    def forward(self, gyro: torch.Tensor, acc: torch.Tensor) -> Correction:
        """One pass over whole sequences (B, N, 3); the tail that does not fill a block is padded with the last
        sample (as ``stream`` does at ``flush``)."""
        _check(gyro, acc)
        n = gyro.shape[1]
        padded_gyro, padded_acc = _pad_to_block(gyro, self.block), _pad_to_block(acc, self.block)
        x = torch.cat([padded_acc / ACC_INPUT_SCALE_M_S2, padded_gyro], dim=-1).mT  # (B, 6, N')
        for conv in self.convs:
            x = conv(nn.functional.pad(x, (self.pad, 0)))
        features = x.mT
        for gru in self.grus:
            features, _ = gru(features)
        return self._decode(features, gyro, acc, n)

    def initial_state(self, batch: int = 1) -> StreamState:
        """State before the first chunk: zero histories (the one-pass left padding) and zero GRU states."""
        p = next(self.parameters())
        histories = [torch.zeros(batch, conv[0].in_channels, self.pad, dtype=p.dtype) for conv in self.convs]
        hidden = [torch.zeros(1, batch, gru.hidden_size, dtype=p.dtype) for gru in self.grus]
        empty = torch.zeros(batch, 0, 3, dtype=p.dtype)
        return StreamState(tuple(histories), tuple(hidden), empty, empty)

    def stream(
        self, gyro: torch.Tensor, acc: torch.Tensor, state: StreamState, flush: bool = False
    ) -> tuple[Correction, StreamState]:
        """Process a chunk (B, M, 3). Returns the output for every sample that completes a block (earlier
        pending samples first) and the new state; ``flush=True`` also completes a last partial block."""
        _check(gyro, acc)
        gyro = torch.cat([state.pending_gyro, gyro], dim=1)
        acc = torch.cat([state.pending_acc, acc], dim=1)
        ready = gyro.shape[1] // self.block * self.block
        if flush and ready < gyro.shape[1]:
            n = gyro.shape[1]
            gyro, acc, ready = _pad_to_block(gyro, self.block), _pad_to_block(acc, self.block), n
        done = self.block * (gyro.shape[1] // self.block)
        if done == 0:  # not a whole block yet: keep the samples for the next chunk
            empty = gyro[:, :0]
            out = Correction(empty, empty, empty, empty, empty, empty)
            return out, StreamState(state.conv_history, state.gru_hidden, gyro, acc)
        x = torch.cat([acc[:, :done] / ACC_INPUT_SCALE_M_S2, gyro[:, :done]], dim=-1).mT
        histories = []
        for conv, history in zip(self.convs, state.conv_history, strict=True):
            x = torch.cat([history, x], dim=-1)
            histories.append(x[..., x.shape[-1] - self.pad :])
            x = conv(x)
        features, hidden = x.mT, []
        for gru, h in zip(self.grus, state.gru_hidden, strict=True):
            features, h = gru(features, h)
            hidden.append(h)
        out = self._decode(features, gyro[:, :ready], acc[:, :ready], ready)
        return out, StreamState(tuple(histories), tuple(hidden), gyro[:, done:], acc[:, done:])

    def _decode(self, features: torch.Tensor, gyro: torch.Tensor, acc: torch.Tensor, n: int) -> Correction:
        per_sample = features.repeat_interleave(self.block, dim=1)[:, :n]
        delta = self.correction(per_sample) * self.scale
        log_offset = self.uncertainty(per_sample).clamp(-LOG_DENSITY_LIMIT, LOG_DENSITY_LIMIT)
        density = self.init_density * torch.exp(log_offset)
        return Correction(
            gyro=gyro + delta[..., 3:],
            acc=acc + delta[..., :3],
            d_gyro=delta[..., 3:],
            d_acc=delta[..., :3],
            gyro_cov=density[..., 3:],
            acc_cov=density[..., :3],
        )


@torch.no_grad()
def correct_sequence(model: AirImuNet, gyro: torch.Tensor, acc: torch.Tensor, chunk: int = 4096) -> Correction:
    """Run a whole (N, 3) sequence through ``model`` in chunks (bounded memory), returning all N samples."""
    state = model.initial_state(1)
    parts = []
    n = gyro.shape[0]
    for start in range(0, n, chunk):
        last = start + chunk >= n
        out, state = model.stream(gyro[None, start : start + chunk], acc[None, start : start + chunk], state, last)
        parts.append(out)
    fields = Correction.__dataclass_fields__
    return Correction(**{f: torch.cat([getattr(p, f) for p in parts], dim=1)[0] for f in fields})


def _decoder(width: int, hidden: int) -> nn.Sequential:
    last = nn.Linear(hidden, 6)
    nn.init.zeros_(last.weight)  # start from the raw IMU and the initial noise
    nn.init.zeros_(last.bias)
    return nn.Sequential(nn.Linear(width, hidden), nn.GELU(), last)


def _pad_to_block(x: torch.Tensor, block: int) -> torch.Tensor:
    missing = (-x.shape[1]) % block
    return torch.cat([x, x[:, -1:].expand(-1, missing, -1)], dim=1) if missing else x


def _check(gyro: torch.Tensor, acc: torch.Tensor) -> None:
    if gyro.ndim != 3 or gyro.shape[-1] != 3 or acc.shape != gyro.shape:
        raise ValueError(f"AirImuNet: gyro and acc must both be (B, N, 3); got {tuple(gyro.shape)}, {tuple(acc.shape)}")
