"""The AirIMU network: per-sample IMU corrections and their uncertainty, from a shared causal encoder.

Sizes follow the official model (``CodeNet`` in haleqiu/AirIMU ``model/code.py``): Conv1d 6 -> 32 -> 64 (kernel 7,
stride 3, each followed by BatchNorm, GELU and dropout 0.1), GRUs 64 -> 128 -> 256, and four decoders
(acc and gyro correction, acc and gyro noise), each Linear(256, 128) - GELU - Linear(128, 3); corrections are
scaled by 0.1 m/s^2 and 1 deg/s per unit of network output. ``use_gru=False`` drops the GRUs (the paper's CNN-only
model for KITTI's 10 Hz IMU and the helicopter); the decoders then read the 64 convolution channels.

Deliberate differences from the official model:

- Causal convolutions (left padding ``kernel - stride`` only, the official pads 3 on both sides), so every block of
  ``stride**layers`` = 9 samples gets one feature that depends only on samples up to the end of that block, and
  the feature is repeated to exactly the 9 samples of its block (the official spreads it over a window centred on
  the block and drops the first block). This makes streaming inference (``AirImuNet.stream``) exact.
- Noise is a continuous-time density, ``init_density * exp(z)`` with ``z`` the decoder output, clamped to
  +-``LOG_DENSITY_LIMIT``: the official's ``exp(z - 5)`` is a discrete per-sample variance (pypose's convention).
- Accelerometer input is divided by ``ACC_INPUT_SCALE_M_S2`` (the official feeds raw m/s^2).
- The last layer of every decoder starts at zero: an untrained model passes the raw IMU through with the initial
  noise densities exactly (the first optimiser step moves those layers, then gradients reach the encoder).

Conventions. Inputs ``gyro`` rad/s and ``acc`` m/s^2 (specific force), IMU frame. Outputs (``Correction``): the
corrected samples (raw + correction) in the same units and the per-sample diagonal noise as continuous-time
densities (``gyro_cov`` rad^2/s, ``acc_cov`` m^2/s^3), which ``learned_imu.preintegrate(gyro_cov=..., acc_cov=...)``
takes directly (one sample's variance is density / dt).

Streaming needs ``model.eval()``: in training mode BatchNorm normalises with each batch's own statistics and
dropout is random, so no chunking can match one pass; ``stream`` refuses training mode.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import torch
from torch import nn

from airimu_core.errors import InputError

ACC_INPUT_SCALE_M_S2 = 9.81  # acc is divided by this before the network: inputs of order 1, like gyro in rad/s
# Initial noise densities: EuRoC's ADIS16448 (datasheet white noise 1.6968e-4 rad/s/sqrt(Hz), 2.0e-3 m/s^2/sqrt(Hz)),
# the quiet end of consumer MEMS IMUs (phones and cheap boards reach ~1e-3 rad/s/sqrt(Hz), ~1e-2 m/s^2/sqrt(Hz)).
DEFAULT_GYRO_COV = 1.6968e-4**2  # noise density, sigma^2: rad^2/s
DEFAULT_ACC_COV = 2.0e-3**2  # m^2/s^3
LOG_DENSITY_LIMIT = 20.0  # |log(density / initial density)| is clamped to this: a factor e^20 ~ 5e8 either way


@dataclass(frozen=True, eq=False)
class Correction:
    """Network output for N samples.

    Shape:
        - gyro: (B, N, 3) corrected angular rate ``raw + d_gyro``, rad/s, IMU frame.
        - acc: (B, N, 3) corrected specific force ``raw + d_acc``, m/s^2, IMU frame.
        - d_gyro: (B, N, 3) gyro correction, rad/s.
        - d_acc: (B, N, 3) acc correction, m/s^2.
        - gyro_cov: (B, N, 3) diagonal gyro noise density, rad^2/s (continuous time), > 0.
        - acc_cov: (B, N, 3) diagonal acc noise density, m^2/s^3 (continuous time), > 0.
    """

    gyro: torch.Tensor
    acc: torch.Tensor
    d_gyro: torch.Tensor
    d_acc: torch.Tensor
    gyro_cov: torch.Tensor
    acc_cov: torch.Tensor


@dataclass(frozen=True, eq=False)
class StreamState:
    """What ``AirImuNet.stream`` carries from one chunk to the next (bounded: it does not grow with time).

    Shape:
        - conv_history: per convolution, its last ``kernel_size - stride`` inputs (B, C_in, kernel_size - stride).
        - gru_hidden: per GRU, its hidden state (1, B, H).
        - pending_gyro, pending_acc: raw samples of the not yet complete block (B, r, 3), r < ``model.block``.
    """

    conv_history: tuple[torch.Tensor, ...]
    gru_hidden: tuple[torch.Tensor, ...]
    pending_gyro: torch.Tensor
    pending_acc: torch.Tensor


class AirImuNet(nn.Module):
    """Correction and uncertainty network (see the module docstring). Plain typed arguments, no config object.

    Args:
        conv_channels: output channels of the convolutions (input has 6: acc, gyro).
        kernel_size: convolution kernel, samples (>= stride).
        stride: convolution stride; one feature summarises ``block = stride ** len(conv_channels)`` samples.
        gru_sizes: hidden sizes of the stacked GRUs (used if ``use_gru``).
        use_gru: False for the CNN-only model.
        decoder_hidden: width of each decoder's hidden layer.
        dropout: dropout probability after each convolution (training only).
        acc_scale_m_s2: acc correction per unit of network output, m/s^2.
        gyro_scale_rad_s: gyro correction per unit of network output, rad/s.
        init_gyro_cov: gyro noise density of the untrained model, sigma^2: rad^2/s.
        init_acc_cov: acc noise density of the untrained model, sigma^2: m^2/s^3.
        acc_input_scale_m_s2: acc is divided by this before the network.
    """

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
        init_gyro_cov: float = DEFAULT_GYRO_COV,
        init_acc_cov: float = DEFAULT_ACC_COV,
        acc_input_scale_m_s2: float = ACC_INPUT_SCALE_M_S2,
    ):
        super().__init__()
        if not 1 <= stride <= kernel_size:
            raise InputError(
                f"AirImuNet: need 1 <= stride <= kernel_size, got stride {stride} and kernel_size {kernel_size}"
            )
        if min(init_gyro_cov, init_acc_cov) <= 0:
            raise InputError("AirImuNet: init_gyro_cov and init_acc_cov must be > 0")
        self.stride, self.kernel_size = stride, kernel_size
        self.pad = kernel_size - stride  # left padding: each window ends on the last sample of its stride block
        self.block = stride ** len(conv_channels)  # input samples per feature step
        self.acc_input_scale_m_s2 = acc_input_scale_m_s2
        self.convs = causal_convs((6, *conv_channels), kernel_size, stride, dropout)
        sizes = (conv_channels[-1], *gru_sizes) if use_gru else (conv_channels[-1],)
        self.grus = nn.ModuleList(nn.GRU(a, b, batch_first=True) for a, b in zip(sizes[:-1], sizes[1:], strict=True))
        self.acc_decoder = _decoder(sizes[-1], decoder_hidden)
        self.gyro_decoder = _decoder(sizes[-1], decoder_hidden)
        self.acc_cov_decoder = _decoder(sizes[-1], decoder_hidden)
        self.gyro_cov_decoder = _decoder(sizes[-1], decoder_hidden)
        self.register_buffer("acc_scale", torch.tensor(acc_scale_m_s2))
        self.register_buffer("gyro_scale", torch.tensor(gyro_scale_rad_s))
        # buffer names kept from before the naming rule: they are checkpoint keys
        self.register_buffer("log_init_acc_density", torch.tensor(math.log(init_acc_cov)))
        self.register_buffer("log_init_gyro_density", torch.tensor(math.log(init_gyro_cov)))

    def forward(self, gyro: torch.Tensor, acc: torch.Tensor, gravity_imu: torch.Tensor | None = None) -> Correction:
        """Correct whole sequences in one pass, starting from rest (zero history and GRU states).

        ``gravity_imu`` (B, N, 3), m/s^2: gravity in the IMU frame from ground truth (``R_gt^T g``); when given,
        the network sees ``acc + gravity_imu`` (the official code's gravity removal; training and evaluation
        with ground truth only). The corrections still apply to ``acc``.

        A tail that does not fill a block is padded with copies of the last sample (as ``stream`` does with
        ``flush=True``), so its outputs depend on that last sample.

        Shape:
            - gyro: (B, N, 3) rad/s; acc: (B, N, 3) m/s^2; N >= 1.
            - Output: ``Correction`` with (B, N, 3) fields.
        """
        _check(gyro, acc)
        seen = acc if gravity_imu is None else acc + gravity_imu
        x = self._inputs(_pad_to_block(gyro, self.block), _pad_to_block(seen, self.block))
        return self._decode(encode(self.convs, self.grus, self.pad, x), gyro, acc)

    def initial_state(self, batch: int = 1) -> StreamState:
        """State before the first chunk: zero conv histories (the one-pass left padding), zero GRU states."""
        histories, hidden = initial_encoder_state(self.convs, self.grus, self.pad, batch)
        empty = histories[0].new_zeros(batch, 0, 3)
        return StreamState(histories, hidden, empty, empty)

    def stream(
        self, gyro: torch.Tensor, acc: torch.Tensor, state: StreamState, flush: bool = False
    ) -> tuple[Correction, StreamState]:
        """Process the next chunk of a stream: outputs for every sample whose block is now complete.

        Pending samples of the previous chunk come first in the output. ``flush=True`` ends the stream: a last
        partial block is padded with its last sample (as in ``forward``) and output; the returned state must not be
        continued. Requires eval mode (see the module docstring). No gradients are needed: wrap in ``no_grad``.

        Shape:
            - gyro: (B, M, 3) rad/s; acc: (B, M, 3) m/s^2; any M >= 0; B as in ``initial_state(B)``.
            - Output: ``Correction`` with (B, K, 3) fields, K = pending + M rounded down to a whole block (all of
              them if ``flush``), and the new ``StreamState``.
        """
        if self.training:
            raise InputError("AirImuNet.stream: call model.eval() first (BatchNorm and dropout differ in training)")
        _check(gyro, acc, min_samples=0)
        gyro = torch.cat([state.pending_gyro, gyro], dim=1)
        acc = torch.cat([state.pending_acc, acc], dim=1)
        ready = gyro.shape[1] if flush else gyro.shape[1] // self.block * self.block
        if ready == 0:  # not a whole block yet: keep the samples for the next chunk
            empty = gyro[:, :0]
            return Correction(*[empty] * 6), StreamState(state.conv_history, state.gru_hidden, gyro, acc)
        x = self._inputs(_pad_to_block(gyro[:, :ready], self.block), _pad_to_block(acc[:, :ready], self.block))
        features, histories, hidden = encode_stream(
            self.convs, self.grus, self.pad, x, state.conv_history, state.gru_hidden
        )
        out = self._decode(features, gyro[:, :ready], acc[:, :ready])
        return out, StreamState(histories, hidden, gyro[:, ready:], acc[:, ready:])

    def _inputs(self, gyro: torch.Tensor, acc: torch.Tensor) -> torch.Tensor:
        """(B, N, 3) raw samples -> (B, 6, N) network input [acc / scale, gyro]."""
        return torch.cat([acc / self.acc_input_scale_m_s2, gyro], dim=-1).mT

    def _decode(self, features: torch.Tensor, gyro: torch.Tensor, acc: torch.Tensor) -> Correction:
        """Decode (B, M, F) features once per block, then repeat each to the samples of its block."""
        n = gyro.shape[1]

        def per_sample(x: torch.Tensor) -> torch.Tensor:
            return x.repeat_interleave(self.block, dim=1)[:, :n]

        d_acc = per_sample(self.acc_decoder(features) * self.acc_scale)
        d_gyro = per_sample(self.gyro_decoder(features) * self.gyro_scale)
        log_acc = self.acc_cov_decoder(features).clamp(-LOG_DENSITY_LIMIT, LOG_DENSITY_LIMIT)
        log_gyro = self.gyro_cov_decoder(features).clamp(-LOG_DENSITY_LIMIT, LOG_DENSITY_LIMIT)
        return Correction(
            gyro=gyro + d_gyro,
            acc=acc + d_acc,
            d_gyro=d_gyro,
            d_acc=d_acc,
            gyro_cov=per_sample(torch.exp(log_gyro + self.log_init_gyro_density)),
            acc_cov=per_sample(torch.exp(log_acc + self.log_init_acc_density)),
        )


def causal_convs(channels: tuple[int, ...], kernel_size: int, stride: int, dropout: float) -> nn.ModuleList:
    """Conv1d(kernel, stride) - BatchNorm - GELU - Dropout per consecutive pair of ``channels`` (the encoder's
    convolutions; ``encode`` pads them on the left so that they are causal)."""
    return nn.ModuleList(
        nn.Sequential(
            nn.Conv1d(c_in, c_out, kernel_size, stride), nn.BatchNorm1d(c_out), nn.GELU(), nn.Dropout(dropout)
        )
        for c_in, c_out in zip(channels[:-1], channels[1:], strict=True)
    )


def encode(convs: nn.ModuleList, grus: nn.ModuleList, pad: int, x: torch.Tensor) -> torch.Tensor:
    """The causal encoder in one pass from rest: (B, C, N) inputs, N a whole number of blocks -> (B, N / block, F)
    features (each convolution left-padded by ``pad`` zeros, then the stacked GRUs from zero states)."""
    for conv in convs:
        x = conv(nn.functional.pad(x, (pad, 0)))
    features = x.mT
    for gru in grus:
        features, _ = gru(features)
    return features


def initial_encoder_state(convs: nn.ModuleList, grus: nn.ModuleList, pad: int, batch: int):
    """``encode_stream``'s state before the first chunk: zero convolution histories (the one-pass left padding)
    and zero GRU states."""
    p = next(convs.parameters())
    like = {"dtype": p.dtype, "device": p.device}
    histories = tuple(torch.zeros(batch, conv[0].in_channels, pad, **like) for conv in convs)
    hidden = tuple(torch.zeros(1, batch, gru.hidden_size, **like) for gru in grus)
    return histories, hidden


def encode_stream(convs: nn.ModuleList, grus: nn.ModuleList, pad: int, x: torch.Tensor, histories, hidden):
    """``encode`` continued from a stream state: the features of the next whole blocks, and the new convolution
    histories and GRU states (bounded: they do not grow with time)."""
    new_histories = []
    for conv, history in zip(convs, histories, strict=True):
        x = torch.cat([history, x], dim=-1)
        new_histories.append(x[..., x.shape[-1] - pad :].clone())
        x = conv(x)
    features, new_hidden = x.mT, []
    for gru, h in zip(grus, hidden, strict=True):
        features, h = gru(features, h)
        new_hidden.append(h)
    return features, tuple(new_histories), tuple(new_hidden)


def device_of(module: nn.Module) -> torch.device:
    """Where a module's first parameter (or buffer) lives; the CPU for a module with neither."""
    tensor = next(module.parameters(), None)
    if tensor is None:
        tensor = next(module.buffers(), None)
    return torch.device("cpu") if tensor is None else tensor.device


@torch.no_grad()
def correct_sequence(model: AirImuNet, gyro: torch.Tensor, acc: torch.Tensor, chunk: int = 4096) -> Correction:
    """Correct one whole sequence by streaming it through ``model`` (eval mode) in chunks of ``chunk`` samples.

    The result equals ``model(gyro[None], acc[None])[0]`` up to float round-off; the network's working memory is
    bounded by the chunk (the outputs themselves are O(N)). The tail is padded as in ``AirImuNet.forward``.

    Shape:
        - gyro: (N, 3) rad/s; acc: (N, 3) m/s^2; N >= 1.
        - Output: ``Correction`` with (N, 3) fields (no batch axis).
    """
    if gyro.ndim != 2 or gyro.shape[-1] != 3 or acc.shape != gyro.shape or gyro.shape[0] == 0:
        raise InputError(
            "correct_sequence: gyro and acc must both be (N, 3) with N >= 1; "
            f"got {tuple(gyro.shape)} and {tuple(acc.shape)}"
        )
    if chunk < 1:
        raise InputError(f"correct_sequence: chunk must be >= 1 sample, got {chunk}")
    state = model.initial_state(1)
    parts = []
    n = gyro.shape[0]
    for start in range(0, n, chunk):
        last = start + chunk >= n
        out, state = model.stream(gyro[None, start : start + chunk], acc[None, start : start + chunk], state, last)
        parts.append(out)
    return Correction(**{f.name: torch.cat([getattr(p, f.name) for p in parts], dim=1)[0] for f in fields(Correction)})


def _decoder(width: int, hidden: int) -> nn.Sequential:
    """Linear(width, hidden) - GELU - Linear(hidden, 3), the last layer zero (untrained: no correction, initial
    noise)."""
    last = nn.Linear(hidden, 3)
    nn.init.zeros_(last.weight)
    nn.init.zeros_(last.bias)
    return nn.Sequential(nn.Linear(width, hidden), nn.GELU(), last)


def _pad_to_block(x: torch.Tensor, block: int) -> torch.Tensor:
    """(B, N, 3) -> (B, N', 3), N' the next multiple of ``block``, padded with copies of the last sample."""
    missing = (-x.shape[1]) % block
    return torch.cat([x, x[:, -1:].expand(-1, missing, -1)], dim=1) if missing else x


def _check(gyro: torch.Tensor, acc: torch.Tensor, min_samples: int = 1) -> None:
    if gyro.ndim != 3 or gyro.shape[-1] != 3 or acc.shape != gyro.shape:
        raise InputError(
            f"AirImuNet: gyro and acc must both be (B, N, 3); got {tuple(gyro.shape)} and {tuple(acc.shape)}"
        )
    if gyro.shape[1] < min_samples:
        raise InputError(f"AirImuNet: need at least {min_samples} sample(s), got N = {gyro.shape[1]}")
