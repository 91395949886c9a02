"""Training windows: fixed-length stretches of a sequence, each starting from its ground-truth state.

A window of L samples starting at sample s carries the IMU samples s .. s+L-1, the ground-truth state at s, and
the ground-truth states after every ``every``-th sample (AirIMU supervises every k-th; the official default is
50 of 1000). Only windows whose ground truth is valid throughout and that bridge no time gap are kept
(``usable_windows``, which ``learned_imu.evaluation.evaluate`` uses too).

``context`` samples before each window are fed to the network but neither integrated nor supervised
(``Windows.correct``): without them the first block of every window is computed from the network's zero padding,
an input it never sees inside a long sequence, and the covariance loss, which only sees the sum over a window,
lets the network park nearly all of a window's predicted variance there, so that streamed over a whole drive its
densities come out orders of magnitude too small (measured on KITTI: BENCHMARKS.md, "Design measurements").
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
import torch

from airimu_core.errors import InputError
from airimu_core.sequence import ImuSequence, gap_indices
from learned_imu.geometry.preintegration import NavState, preintegrate
from learned_imu.network.model import Correction
from learned_imu.training.losses import delta_errors


@dataclass(frozen=True, eq=False)
class Windows:
    """M windows of L samples. Shapes: ``gyro``/``acc`` (M, L, 3) rad/s and m/s^2, ``dt`` (M, L) s; ``start``
    states (M, ...); ``targets`` states after the supervised samples (M, K, ...); ``gravity`` (3,) world;
    ``gravity_imu`` (M, L, 3) the gravity vector in the IMU frame from ground truth, ``R_gt^T g`` (only when
    the network's input has gravity removed, ``make_windows(remove_gravity=True)``), else None. ``context``: the
    first ``context`` samples of ``gyro``, ``acc`` and ``gravity_imu`` (then (M, context + L, 3)) precede the
    window's start state: network input only."""

    gyro: torch.Tensor
    acc: torch.Tensor
    dt: torch.Tensor
    start: NavState
    targets: NavState
    gravity: torch.Tensor
    at: slice
    gravity_imu: torch.Tensor | None = None
    context: int = 0

    def __len__(self) -> int:
        return self.gyro.shape[0]

    def correct(self, model) -> Correction:
        """``model``'s output (an ``AirImuNet`` or its DDP wrapper) on the windows' samples, the context cut off:
        (M, L, 3) fields."""
        out = model(self.gyro, self.acc, gravity_imu=self.gravity_imu)
        if not self.context:
            return out
        return Correction(*(getattr(out, f.name)[:, self.context :] for f in fields(Correction)))

    def errors(self, out: Correction, gyro_cov=None, acc_cov=None) -> tuple[torch.Tensor, torch.Tensor | None]:
        """(M, K, 9) delta errors [theta, p, v] of each window at its K supervised states, and their variances
        (M, K, 9), the covariance's diagonal, when densities (M, L, 3) are given (one ``preintegrate`` per window;
        ``Chunks.errors`` reads the same from one pass over a chunk)."""
        pre = preintegrate(out.gyro, out.acc, self.dt, gyro_cov, acc_cov, at=self.at)
        variance = None if pre.cov is None else torch.diagonal(pre.cov, dim1=-2, dim2=-1)
        return delta_errors(pre, self.start, self.targets, self.gravity), variance

    def to(self, device: str | torch.device) -> Windows:
        """The same windows on ``device`` (every tensor moved; ``self`` when nothing moves)."""
        if self.gyro.device == torch.device(device):
            return self

        def move(state: NavState) -> NavState:
            return NavState(rot=state.rot.to(device), vel=state.vel.to(device), pos=state.pos.to(device))

        return Windows(
            self.gyro.to(device),
            self.acc.to(device),
            self.dt.to(device),
            move(self.start),
            move(self.targets),
            self.gravity.to(device),
            self.at,
            None if self.gravity_imu is None else self.gravity_imu.to(device),
            self.context,
        )

    @property
    def windows(self) -> int:
        """How many windows (``len``; ``Chunks.windows`` counts the windows inside its chunks)."""
        return len(self)

    mask = None  # every window counts in a loss (``Chunks.mask`` marks the windows of its chunks that do)

    def double(self) -> Windows:
        """The same windows in float64."""

        def cast(state: NavState) -> NavState:
            return NavState(rot=state.rot.double(), vel=state.vel.double(), pos=state.pos.double())

        return Windows(
            self.gyro.double(),
            self.acc.double(),
            self.dt.double(),
            cast(self.start),
            cast(self.targets),
            self.gravity.double(),
            self.at,
            None if self.gravity_imu is None else self.gravity_imu.double(),
            self.context,
        )

    def select(self, index: torch.Tensor) -> Windows:
        """The windows at ``index`` (a 1-D index tensor)."""
        index = index.to(self.gyro.device)
        pick = _pick(index)
        return Windows(
            self.gyro[index],
            self.acc[index],
            self.dt[index],
            pick(self.start),
            pick(self.targets),
            self.gravity,
            self.at,
            None if self.gravity_imu is None else self.gravity_imu[index],
            self.context,
        )


def usable_windows(sequence: ImuSequence, starts: np.ndarray, length: int, need_valid: bool = True) -> np.ndarray:
    """(W,) bool: windows ``[s, s + length)`` with valid ground truth on all their states (unless not
    ``need_valid``) and no time gap (``airimu_core.sequence.gap_indices``: e.g. KITTI's dropped OXTS packets,
    read with ``on_gap="keep"``), so that integration restarts after a gap instead of bridging it."""
    gap = np.zeros(len(sequence), dtype=bool)
    gap[gap_indices(sequence.t)] = True  # sample i is followed by a gap
    gaps_before = np.concatenate([[0], np.cumsum(gap)])  # gaps after samples [0, k)
    invalid_before = np.concatenate([[0], np.cumsum(~sequence.gt.valid)])
    no_gap = gaps_before[starts + length] - gaps_before[starts] == 0
    if not need_valid:
        return no_gap
    all_valid = invalid_before[starts + length + 1] - invalid_before[starts] == 0
    return no_gap & all_valid


def make_windows(
    sequence: ImuSequence,
    length: int = 1000,
    every: int = 50,
    stride: int | None = None,
    dtype=torch.float32,
    remove_gravity: bool = False,
    allow_empty: bool = False,
    context: int = 0,
) -> Windows | None:
    """Cut ``sequence`` into windows of ``length`` samples every ``stride`` samples (default: ``length``).

    ``remove_gravity`` adds ``gravity_imu`` (the official code's option: the network sees ``acc + R_gt^T g``).
    ``allow_empty``: return None instead of raising when no window is usable (gaps or invalid ground truth).
    ``context``: samples of network input before each window (module docstring); the first window starts there,
    and the context too must be free of gaps and invalid ground truth."""
    if sequence.gt is None:
        raise InputError(f"{sequence.name}: training windows need ground truth")
    if context < 0:
        raise InputError(f"{sequence.name}: context must be >= 0 samples, got {context}")
    if not 1 <= every <= length or context + length >= len(sequence):
        raise InputError(
            f"{sequence.name}: need 1 <= every <= length and context + length < {len(sequence)}, "
            f"got every {every}, length {length}, context {context}"
        )
    stride = stride or length
    gt = sequence.gt
    starts = np.arange(context, len(sequence) - length, stride)
    starts = starts[usable_windows(sequence, starts - context, context + length)]
    if len(starts) == 0 and allow_empty:
        return None
    if len(starts) == 0:
        raise InputError(f"{sequence.name}: no window of {length} samples with valid ground truth")
    take = starts[:, None] + np.arange(length)
    fed = starts[:, None] + np.arange(-context, length)  # network input: the context, then the window
    at = slice(every - 1, None, every)
    after = (take + 1)[:, at]

    def t(x):
        return torch.as_tensor(x, dtype=dtype)

    return Windows(
        gyro=t(sequence.gyro[fed]),
        acc=t(sequence.acc[fed]),
        dt=t(sequence.dt[take]),
        start=NavState(rot=t(gt.rot[starts]), vel=t(gt.vel[starts]), pos=t(gt.pos[starts])),
        targets=NavState(rot=t(gt.rot[after]), vel=t(gt.vel[after]), pos=t(gt.pos[after])),
        gravity=t(sequence.gravity),
        at=at,
        gravity_imu=t(np.einsum("mlji,j->mli", gt.rot[fed], sequence.gravity)) if remove_gravity else None,
        context=context,
    )


def _pick(index: torch.Tensor):
    def pick(state: NavState) -> NavState:
        return NavState(rot=state.rot[index], vel=state.vel[index], pos=state.pos[index])

    return pick


def concat_windows(parts: list[Windows]) -> Windows:
    """Windows of several sequences as one set (same length, supervision and gravity required)."""
    if not parts:
        raise InputError("concat_windows: no windows given")
    first = parts[0]
    for other in parts[1:]:
        if other.gyro.shape[1] != first.gyro.shape[1] or other.at != first.at or other.context != first.context:
            raise InputError("concat_windows: windows differ in length, context or supervised samples")
        if not torch.equal(other.gravity, first.gravity):
            raise InputError("concat_windows: sequences have different gravity vectors")
    if len(parts) == 1:
        return first

    def cat(name: str):
        return torch.cat([getattr(p, name) for p in parts])

    def cat_state(name: str) -> NavState:
        states = [getattr(p, name) for p in parts]
        return NavState(**{f: torch.cat([getattr(s, f) for s in states]) for f in ("rot", "vel", "pos")})

    gravity_imu = None if first.gravity_imu is None else cat("gravity_imu")
    return Windows(
        cat("gyro"),
        cat("acc"),
        cat("dt"),
        cat_state("start"),
        cat_state("targets"),
        first.gravity,
        first.at,
        gravity_imu,
        first.context,
    )
