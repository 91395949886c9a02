"""The motion model: the IMU's body-frame velocity and its uncertainty, learned from body-frame IMU samples and the
attitude, causally (AirIO's representation, Qiu et al. RA-L 2025; our own network).

Inputs per sample: the IMU in its own frame (gyro rad/s, acc m/s^2 specific force, divided by
``ACC_INPUT_SCALE_M_S2``) and the attitude encoded as the world's up axis seen from the body, ``R^T e_z`` (the third
row of ``R``, world <- body): roll and pitch, which fix how gravity enters the accelerometer; heading does not
change the body-frame velocity and is left out, so the model cannot learn a room's layout. At test time the
attitude is the estimator's (integrated gyro from the last estimated state, or the graph's), never ground truth:
training perturbs the ground-truth attitude (``learned_imu.training.motion``) so that the model tolerates the
estimator's error.

Network: the correction model's causal encoder (``learned_imu.network.model.encode``: convolutions of stride
``stride`` whose left padding makes every block of ``block = stride ** layers`` samples see only samples up to
its own end, then stacked GRUs), 9 input channels; two decoders per block: the velocity ``v_body`` (m/s, times
``vel_scale_m_s`` per unit of output) and its per-axis variance ``init_var * exp(z)``, (m/s)^2, ``z`` clamped to
+-``LOG_VAR_LIMIT``. One output per block, the velocity at the block's last sample: with the default 2 layers of
stride 3, one every 9 samples (AirIO's rate, 1/9 of the IMU's). Streaming (``stream``) gives what one pass gives.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
import torch
from torch import nn

from airimu_core.errors import InputError
from airimu_core.motion import BodyVelocities
from learned_imu.network.model import (  # the correction model's encoder, decoder shape and padding
    ACC_INPUT_SCALE_M_S2,
    _decoder,
    _pad_to_block,
    causal_convs,
    encode,
    encode_stream,
    initial_encoder_state,
)
from learned_imu.network.rate import check_times_rate

LOG_VAR_LIMIT = 12.0  # |log(variance / initial variance)| is clamped to this: a factor e^12 ~ 1.6e5 either way
INPUT_CHANNELS = 9  # acc (3), gyro (3), up axis in the body frame (3)


@dataclass(frozen=True, eq=False)
class Motion:
    """Motion model output for M blocks.

    Shape:
        - vel: (B, M, 3) body-frame velocity at each block's last sample, m/s (``R^T v``, v world-frame).
        - vel_var: (B, M, 3) its per-axis variance, (m/s)^2, > 0.
    """

    vel: torch.Tensor
    vel_var: torch.Tensor


@dataclass(frozen=True, eq=False)
class MotionStreamState:
    """What ``MotionNet.stream`` carries between chunks: convolution histories, GRU states, and the samples of a
    block not yet complete ((B, r, 3) each, r < block)."""

    conv_history: tuple[torch.Tensor, ...]
    gru_hidden: tuple[torch.Tensor, ...]
    pending_gyro: torch.Tensor
    pending_acc: torch.Tensor
    pending_up: torch.Tensor


def up_in_body(rot: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) rotations world <- body -> (..., 3) the world's up axis in the body frame, ``R^T e_z``."""
    return rot[..., 2, :]


class MotionNet(nn.Module):
    """Body-frame velocity and its variance (module docstring). Plain typed arguments, no config object.

    Args:
        conv_channels: output channels of the causal convolutions (input: 9).
        kernel_size, stride: of each convolution; one output per ``stride ** len(conv_channels)`` samples.
        gru_sizes: hidden sizes of the stacked GRUs.
        decoder_hidden: width of each decoder's hidden layer.
        dropout: after each convolution (training only).
        vel_scale_m_s: velocity per unit of decoder output, m/s.
        init_var: variance of the untrained model, (m/s)^2.
        acc_input_scale_m_s2: acc is divided by this before the network.
    """

    def __init__(
        self,
        conv_channels: tuple[int, ...] = (32, 64),
        kernel_size: int = 7,
        stride: int = 3,
        gru_sizes: tuple[int, ...] = (128, 128),
        decoder_hidden: int = 64,
        dropout: float = 0.1,
        vel_scale_m_s: float = 1.0,
        init_var: float = 0.1,
        acc_input_scale_m_s2: float = ACC_INPUT_SCALE_M_S2,
    ):
        super().__init__()
        if not 1 <= stride <= kernel_size:
            raise InputError(f"MotionNet: need 1 <= stride <= kernel_size, got {stride} and {kernel_size}")
        if not init_var > 0 or not vel_scale_m_s > 0:
            raise InputError(f"MotionNet: init_var and vel_scale_m_s must be > 0, got {init_var}, {vel_scale_m_s}")
        self.stride, self.kernel_size = stride, kernel_size
        self.pad = kernel_size - stride
        self.block = stride ** len(conv_channels)
        self.acc_input_scale_m_s2 = acc_input_scale_m_s2
        self.convs = causal_convs((INPUT_CHANNELS, *conv_channels), kernel_size, stride, dropout)
        sizes = (conv_channels[-1], *gru_sizes)
        self.grus = nn.ModuleList(nn.GRU(a, b, batch_first=True) for a, b in zip(sizes[:-1], sizes[1:], strict=True))
        self.vel_decoder = _decoder(sizes[-1], decoder_hidden)
        self.var_decoder = _decoder(sizes[-1], decoder_hidden)
        self.register_buffer("vel_scale", torch.tensor(float(vel_scale_m_s)))
        self.register_buffer("log_init_var", torch.tensor(float(init_var)).log())

    def forward(self, gyro: torch.Tensor, acc: torch.Tensor, up: torch.Tensor) -> Motion:
        """Whole sequences in one pass from rest. A tail that does not fill a block is padded with its last
        sample, so the last output is the velocity at the last sample.

        Shape:
            - gyro: (B, N, 3) rad/s; acc: (B, N, 3) m/s^2; up: (B, N, 3) ``up_in_body(R)``; N >= 1.
            - Output: ``Motion`` with (B, ceil(N / block), 3) fields.
        """
        _check(gyro, acc, up)
        x = self._inputs(*(_pad_to_block(v, self.block) for v in (gyro, acc, up)))
        return self._decode(encode(self.convs, self.grus, self.pad, x))

    def initial_state(self, batch: int = 1) -> MotionStreamState:
        """State before the first chunk of a stream."""
        histories, hidden = initial_encoder_state(self.convs, self.grus, self.pad, batch)
        empty = histories[0].new_zeros(batch, 0, 3)
        return MotionStreamState(histories, hidden, empty, empty, empty)

    def stream(
        self, gyro: torch.Tensor, acc: torch.Tensor, up: torch.Tensor, state: MotionStreamState, flush: bool = False
    ) -> tuple[Motion, MotionStreamState]:
        """The next chunk of a stream: one output per block completed by it (``flush``: the last partial block
        too, padded as in ``forward``; the state must then not be continued). Needs eval mode; wrap in
        ``torch.no_grad``."""
        if self.training:
            raise InputError("MotionNet.stream: call model.eval() first (BatchNorm and dropout differ in training)")
        _check(gyro, acc, up, min_samples=0)
        gyro, acc, up = (
            torch.cat([old, new], dim=1)
            for old, new in ((state.pending_gyro, gyro), (state.pending_acc, acc), (state.pending_up, up))
        )
        ready = gyro.shape[1] if flush else gyro.shape[1] // self.block * self.block
        if ready == 0:
            empty = gyro.new_zeros(gyro.shape[0], 0, 3)
            return Motion(empty, empty), MotionStreamState(state.conv_history, state.gru_hidden, gyro, acc, up)
        x = self._inputs(*(_pad_to_block(v[:, :ready], self.block) for v in (gyro, acc, up)))
        features, histories, hidden = encode_stream(
            self.convs, self.grus, self.pad, x, state.conv_history, state.gru_hidden
        )
        rest = MotionStreamState(histories, hidden, gyro[:, ready:], acc[:, ready:], up[:, ready:])
        return self._decode(features), rest

    def _inputs(self, gyro: torch.Tensor, acc: torch.Tensor, up: torch.Tensor) -> torch.Tensor:
        return torch.cat([acc / self.acc_input_scale_m_s2, gyro, up], dim=-1).mT

    def _decode(self, features: torch.Tensor) -> Motion:
        log_var = self.var_decoder(features).clamp(-LOG_VAR_LIMIT, LOG_VAR_LIMIT)
        return Motion(self.vel_decoder(features) * self.vel_scale, torch.exp(log_var + self.log_init_var))


@torch.no_grad()
def motion_sequence(model: MotionNet, gyro: torch.Tensor, acc: torch.Tensor, up: torch.Tensor, chunk: int = 4096):
    """One whole sequence streamed through ``model`` (eval mode) in chunks: equal to ``model(...)`` on the whole
    sequence up to round-off, with bounded working memory.

    Shape:
        - gyro, acc, up: (N, 3); output: ``Motion`` with (ceil(N / block), 3) fields (no batch axis).
    """
    if gyro.ndim != 2 or gyro.shape[0] == 0:
        raise InputError(f"motion_sequence: gyro must be (N, 3) with N >= 1, got {tuple(gyro.shape)}")
    state, parts, n = model.initial_state(1), [], gyro.shape[0]
    for start in range(0, n, chunk):
        part = slice(start, start + chunk)
        out, state = model.stream(gyro[None, part], acc[None, part], up[None, part], state, start + chunk >= n)
        parts.append(out)
    return Motion(**{f.name: torch.cat([getattr(p, f.name) for p in parts], dim=1)[0] for f in fields(Motion)})


def block_ends(n: int, block: int) -> torch.Tensor:
    """Sample index of each output of an N-sample sequence: the last sample of every block (the last one padded:
    the sequence's last sample)."""
    ends = torch.arange(block - 1, n, block)
    if n % block:
        ends = torch.cat([ends, torch.tensor([n - 1])])
    return ends


def _check(gyro: torch.Tensor, acc: torch.Tensor, up: torch.Tensor, min_samples: int = 1) -> None:
    if gyro.ndim != 3 or gyro.shape[-1] != 3 or acc.shape != gyro.shape or up.shape != gyro.shape:
        raise InputError(
            "MotionNet: gyro, acc and up must all be (B, N, 3); got "
            f"{tuple(gyro.shape)}, {tuple(acc.shape)} and {tuple(up.shape)}"
        )
    if gyro.shape[1] < min_samples:
        raise InputError(f"MotionNet: need at least {min_samples} sample(s), got N = {gyro.shape[1]}")


def predict_velocities(model: MotionNet, sequence, rot: np.ndarray) -> BodyVelocities:
    """The motion model over a whole ``sequence`` (an ``ImuSequence``: its raw body-frame IMU) with the attitude
    ``rot`` (N, 3, 3) world <- IMU that the estimator believes at each sample (never ground truth at test time):
    one ``airimu_core.motion.BodyVelocities`` row per block end, at that sample's time. A model whose checkpoint
    records another sample rate is refused (``learned_imu.network.inference.check_rate``, naming both). Outputs
    inside the model's warm-up (``warmup_samples``) are left out."""
    check_times_rate(model, sequence.t, sequence.source or sequence.name)
    rot = np.asarray(rot, dtype=float)
    if rot.shape != (len(sequence.t), 3, 3) or not np.all(np.isfinite(rot)):
        raise InputError(
            f"{sequence.name}: the motion model's attitude must be {len(sequence.t)} finite rotations (N, 3, 3), "
            f"got {rot.shape}"
        )
    as_input = lambda x: torch.as_tensor(np.ascontiguousarray(x), dtype=torch.float32)  # noqa: E731
    out = motion_sequence(model, as_input(sequence.gyro), as_input(sequence.acc), as_input(up_in_body(rot)))
    ends = block_ends(len(sequence.t), model.block).numpy()
    warm = ends >= warmup_samples(model)
    if not warm.any():
        raise InputError(
            f"{sequence.name}: {len(sequence.t)} samples do not outlast the motion model's warm-up "
            f"({warmup_samples(model)} samples)"
        )
    vel, var = out.vel.double().numpy(), out.vel_var.double().numpy()
    return BodyVelocities(sequence.t[ends[warm]], vel[warm], var[warm])


def warmup_samples(model) -> int:
    """Samples a stream must have seen before the model's outputs count: its training chunks' unsupervised context
    (``motion.context``, set on a model read from a checkpoint; 0 for one built in code). Before then the GRUs are
    still filling and neither velocity nor variance was ever trained."""
    return int(getattr(model, "warmup_samples", 0))
