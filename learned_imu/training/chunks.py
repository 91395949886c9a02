"""Training chunks: every window of a long stretch of a sequence from one network pass and one preintegration.

A chunk is ``chunk`` consecutive samples (plus ``context`` samples of network input before them). Inside it a
window of ``length`` samples starts at every ``stride``-th sample and is supervised at every ``every``-th, exactly
the windows ``make_windows(sequence, length, every, stride, context=context)`` cuts, each starting from its own
ground-truth state. The network runs once over the chunk (its GRU carries its state through, as in streamed
inference) and ``learned_imu.geometry.windowed.preintegrate_windows`` reads every window's deltas and covariance
off one pass: no sample is corrected or integrated once per window that contains it.

Consecutive chunks overlap by ``length - stride`` samples, so that every window lies in exactly one chunk; the
last chunk of a sequence is moved back to end on its last usable sample, and windows it shares with the chunk
before it are counted once (``Chunks.valid``). Windows that cross a time gap, or touch invalid ground truth
(their context included), are left out exactly as ``make_windows`` leaves them out (``usable_windows``).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
import torch

from airimu_core.errors import InputError
from airimu_core.sequence import ImuSequence
from learned_imu.geometry.preintegration import NavState, Preintegrated
from learned_imu.geometry.windowed import preintegrate_windows, window_ends
from learned_imu.network.model import Correction
from learned_imu.training.losses import errors_against, truth_deltas
from learned_imu.training.windows import usable_windows


@dataclass(frozen=True, eq=False)
class Chunks:
    """B chunks of N samples with M window starts each, K supervised states a window. Shapes: ``gyro``/``acc``
    (B, context + N, 3) rad/s and m/s^2 (network input: the context, then the chunk), ``dt`` (B, N) s; ``truth``
    the ground-truth deltas (Forster's, gravity removed: ``learned_imu.training.losses.truth_deltas``) of every
    window to its supervised states, fields (B, M, K, ...); ``valid`` (B, M) which windows are trained on (the
    others hold identity deltas); ``starts`` (M,) window starts within a chunk; ``gravity_imu``
    (B, context + N, 3) or None, as in ``Windows``; ``rotation`` (B, N, 3, 3) world <- IMU from ground truth at
    each sample, or None: velocity and position are then integrated with it (``preintegrate_windows``'s
    ``rotation``, the official AirIMU's ``gtrot``)."""

    gyro: torch.Tensor
    acc: torch.Tensor
    dt: torch.Tensor
    truth: Preintegrated
    valid: torch.Tensor
    starts: torch.Tensor
    length: int
    every: int
    gravity_imu: torch.Tensor | None = None
    context: int = 0
    rotation: torch.Tensor | None = None

    def __len__(self) -> int:
        return self.gyro.shape[0]

    @property
    def windows(self) -> int:
        """How many windows the chunks train on."""
        return int(self.valid.sum())

    @property
    def mask(self) -> torch.Tensor:
        """(B, M) the windows that count in a loss (``valid``)."""
        return self.valid

    def correct(self, model) -> Correction:
        """``model``'s output on the chunks' samples, the context cut off: (B, N, 3) fields."""
        out = model(self.gyro, self.acc, gravity_imu=self.gravity_imu)
        if not self.context:
            return out
        return Correction(*(getattr(out, f.name)[:, self.context :] for f in fields(Correction)))

    def errors(self, out: Correction, gyro_cov=None, acc_cov=None) -> tuple[torch.Tensor, torch.Tensor | None]:
        """(B, M, K, 9) delta errors [theta, p, v] of every window at its K supervised states, and their variances
        (B, M, K, 9), the covariance's diagonal, when densities (B, N, 3) are given (float64); only the windows of
        ``mask`` count."""
        pre = preintegrate_windows(
            out.gyro,
            out.acc,
            self.dt,
            self.starts,
            self.length,
            self.every,
            gyro_cov,
            acc_cov,
            self.rotation,
            diagonal=True,
        )
        return errors_against(pre, self.truth), pre.variance

    def to(self, device: str | torch.device) -> Chunks:
        """The same chunks on ``device``."""
        if self.gyro.device == torch.device(device):
            return self
        return _apply(lambda x: x.to(device))(self, self.starts.to(device))

    def double(self) -> Chunks:
        """The same chunks in float64 (``valid`` stays bool)."""
        return _apply(lambda x: x if x.dtype == torch.bool else x.double())(self, self.starts)

    def select(self, index: torch.Tensor) -> Chunks:
        """The chunks at ``index`` (a 1-D index tensor)."""
        index = index.to(self.gyro.device)
        return _apply(lambda x: x[index])(self, self.starts)


def _apply(op):
    """Apply ``op`` to every per-chunk tensor of a ``Chunks``."""

    def apply(c: Chunks, starts: torch.Tensor) -> Chunks:
        truth = Preintegrated(op(c.truth.rot), op(c.truth.vel), op(c.truth.pos), op(c.truth.dt))
        gravity_imu = None if c.gravity_imu is None else op(c.gravity_imu)
        rotation = None if c.rotation is None else op(c.rotation)
        return Chunks(
            op(c.gyro),
            op(c.acc),
            op(c.dt),
            truth,
            op(c.valid),
            starts,
            c.length,
            c.every,
            gravity_imu,
            c.context,
            rotation,
        )

    return apply


def chunk_offsets(n: int, chunk: int, length: int, stride: int, context: int) -> tuple[np.ndarray, np.ndarray]:
    """Where the chunks of a sequence of ``n`` samples begin, and the first window start each of them owns
    (``chunk - length`` a multiple of ``stride``).

    Window starts are the grid ``context, context + stride, ...`` (``make_windows``'s); chunk i holds the starts
    ``offset_i + stride * [0, M)`` and owns those from ``owned_i`` on (the last chunk, moved back to fit, shares
    some with the one before it). Returns (offsets, owned), both (C,) sample indices; empty if no chunk fits."""
    if chunk < length or (chunk - length) % stride:
        raise InputError(f"chunk_offsets: need chunk - length a multiple of stride; got {chunk}, {length}, {stride}")
    per_chunk = (chunk - length) // stride + 1  # M
    last = n - 1 - chunk  # the chunk's last state (after its last sample) must exist: offset + chunk <= n - 1
    if last < context:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    step = per_chunk * stride
    offsets = np.arange(context, last + 1, step)
    grid_end = context + ((n - 1 - length - context) // stride) * stride  # the last window start that fits
    covered = offsets[-1] + (per_chunk - 1) * stride
    owned = offsets.copy()
    if covered < grid_end:  # a tail of windows no chunk holds: one more chunk, ending on the last grid start
        tail = context + ((grid_end - (per_chunk - 1) * stride - context) // stride) * stride
        offsets = np.append(offsets, tail)
        owned = np.append(owned, covered + stride)
    return offsets, owned


def make_chunks(
    sequence: ImuSequence,
    chunk: int,
    length: int = 1000,
    every: int = 50,
    stride: int = 10,
    dtype=torch.float32,
    remove_gravity: bool = False,
    allow_empty: bool = False,
    context: int = 0,
    gt_rotation: bool = False,
) -> Chunks | None:
    """Cut ``sequence`` into chunks of ``chunk`` samples holding every window of ``length`` samples that starts every
    ``stride`` samples (module docstring). ``allow_empty``: None instead of an error when no chunk fits or no
    window in them is usable. ``gt_rotation``: integrate velocity and position with the ground truth's rotation
    (``Chunks.rotation``)."""
    if sequence.gt is None:
        raise InputError(f"{sequence.name}: training chunks need ground truth")
    if not 1 <= every <= length or stride < 1 or context < 0:
        raise InputError(
            f"{sequence.name}: need 1 <= every <= length, stride >= 1 and context >= 0; got every {every}, "
            f"length {length}, stride {stride}, context {context}"
        )
    if chunk < length:
        raise InputError(f"{sequence.name}: a chunk of {chunk} samples cannot hold a window of {length}")
    per_chunk = (chunk - length) // stride + 1
    chunk = length + (per_chunk - 1) * stride  # the samples its windows use (rounded down to the stride grid)
    offsets, owned = chunk_offsets(len(sequence), chunk, length, stride, context)
    local = np.arange(per_chunk) * stride
    starts = offsets[:, None] + local  # (C, M) window starts in the sequence
    valid = np.zeros(starts.shape, dtype=bool)
    if len(offsets):
        usable = usable_windows(sequence, (starts - context).ravel(), context + length).reshape(starts.shape)
        valid = usable & (starts >= owned[:, None])
    if not valid.any():
        if allow_empty:
            return None
        raise InputError(
            f"{sequence.name}: no window of {length} samples with valid ground truth in chunks of {chunk} samples "
            f"(the sequence has {len(sequence)})"
        )
    keep = valid.any(axis=1)
    offsets, starts, valid = offsets[keep], starts[keep], valid[keep]
    fed = offsets[:, None] + np.arange(-context, chunk)
    truth = _truth_deltas(sequence, starts, length, every, valid)

    def t(x):
        return torch.as_tensor(x, dtype=dtype)

    rot = _finite_rotations(sequence.gt.rot)
    return Chunks(
        gyro=t(sequence.gyro[fed]),
        acc=t(sequence.acc[fed]),
        dt=t(sequence.dt[offsets[:, None] + np.arange(chunk)]),
        truth=truth,  # float64, like the deltas preintegrate_windows computes
        valid=torch.as_tensor(valid),
        starts=torch.as_tensor(local, dtype=torch.long),
        length=length,
        every=every,
        gravity_imu=t(np.einsum("mlji,j->mli", rot[fed], sequence.gravity)) if remove_gravity else None,
        context=context,
        rotation=t(rot[offsets[:, None] + np.arange(chunk)]) if gt_rotation else None,
    )


def _finite_rotations(rot: np.ndarray) -> np.ndarray:
    """Rotations with any non-finite one (invalid ground truth, in windows that are left out) set to identity."""
    bad = ~np.isfinite(rot).all(axis=(1, 2))
    return np.where(bad[:, None, None], np.eye(3), rot) if bad.any() else rot


def _truth_deltas(sequence: ImuSequence, starts: np.ndarray, length: int, every: int, valid: np.ndarray):
    """Ground-truth deltas (float64) of the windows starting at the sequence indices ``starts`` (C, M) to their K
    supervised states; windows not ``valid`` get identity deltas (their ground truth may be invalid, even NaN)."""
    gt = sequence.gt
    ends = starts[..., None] + window_ends(torch.zeros(1, dtype=torch.long), length, every)[0].numpy()  # (C, M, K)
    elapsed = np.concatenate([[0.0], np.cumsum(sequence.dt)])
    fields = ("rot", "vel", "pos")
    states = [NavState(**{k: torch.as_tensor(getattr(gt, k)[i]) for k in fields}) for i in (starts, ends)]
    truth = truth_deltas(*states, torch.as_tensor(elapsed[ends] - elapsed[starts][..., None]), sequence.gravity)
    keep = torch.as_tensor(valid)[..., None]
    eye = torch.eye(3, dtype=torch.float64)
    return Preintegrated(
        rot=torch.where(keep[..., None, None], truth.rot, eye),
        vel=torch.where(keep[..., None], truth.vel, 0.0),
        pos=torch.where(keep[..., None], truth.pos, 0.0),
        dt=truth.dt,
    )


def concat_chunks(parts: list[Chunks]) -> Chunks:
    """Chunks of several sequences as one set (same chunk length, windows and context required)."""
    if not parts:
        raise InputError("concat_chunks: no chunks given")
    first = parts[0]
    for other in parts[1:]:
        same = (other.gyro.shape[1], other.length, other.every, other.context) == (
            first.gyro.shape[1],
            first.length,
            first.every,
            first.context,
        )
        if not same or not torch.equal(other.starts, first.starts):
            raise InputError("concat_chunks: chunks differ in length, windows, context or supervised samples")
        for name, option in (("gravity_imu", "remove_gravity"), ("rotation", "gt_rotation")):
            if (getattr(other, name) is None) != (getattr(first, name) is None):
                raise InputError(f"concat_chunks: some chunks were made with {option} and some without")
    if len(parts) == 1:
        return first

    def cat(get):
        return torch.cat([get(p) for p in parts])

    truth = Preintegrated(*(cat(lambda p, f=f: getattr(p.truth, f)) for f in ("rot", "vel", "pos", "dt")))
    gravity_imu = None if first.gravity_imu is None else cat(lambda p: p.gravity_imu)
    rotation = None if first.rotation is None else cat(lambda p: p.rotation)
    return Chunks(
        cat(lambda p: p.gyro),
        cat(lambda p: p.acc),
        cat(lambda p: p.dt),
        truth,
        cat(lambda p: p.valid),
        first.starts,
        first.length,
        first.every,
        gravity_imu,
        first.context,
        rotation,
    )
