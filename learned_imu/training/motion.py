"""Training data and loss of the motion model (``learned_imu.network.motion.MotionNet``): chunks of a sequence, the
body-frame velocity at every block end, one network pass per chunk.

A chunk is ``context + length`` consecutive samples (both whole numbers of blocks); the network reads all of them
from rest and is supervised at the block ends after the context (the context warms the GRUs up, as a stream's
history does at test time). The target at a block end is the ground-truth body-frame velocity ``R_gt^T v_gt``
(m/s). Chunks that cross a time gap or touch invalid ground truth are left out (``usable_windows``).

With ``frame_rotation_rad`` > 0, each training chunk is also seen from a randomly rotated IMU frame: one rotation Q
per chunk (random axis, angle ``N(0, frame_rotation_rad)``) applied to the gyro, the acc, the up axis and the target
alike (the same motion measured by an IMU mounted slightly differently), against over-fitting a few flights.

With ``time_reversal``, half the training chunks (drawn per chunk) are played backwards: the samples in reverse order,
the angular rate negated, the specific force and the attitude as they are, and the target the negated body-frame
velocity at the reversed chunk's block ends: the same path flown the other way, for which the body-frame kinematics
``dv_b/dt = f + R^T g - w x v_b`` hold exactly as for the original (every term keeps its sign).

The attitude the network reads is the ground truth's, perturbed while training: each chunk's attitude is tilted by
a random rotation about a horizontal world axis, of angle ``N(0, tilt_noise_rad)`` (roll/pitch error: what the up
axis ``R^T e_z`` is sensitive to), drawn from torch's global generator (part of a checkpoint, so a resumed run
continues exactly). That stands in for the estimator's attitude error at test time. Validation reads the
unperturbed truth.

Loss (a mean over the supervised block ends): ``|v - v_gt|^2`` (m/s)^2, plus ``covariance`` times the Gaussian
negative log-likelihood of the detached error under the predicted variance, ``0.5 (e^2 / var + log var)`` per
axis, so the variance learns the error without pulling the velocity (the selection criterion, validation, uses the
squared error alone). With ``drift`` > 0, plus ``drift`` times the squared world-frame mean velocity error since the
first supervised block end, at every block end (``|sum_j R_j e_j / k|^2``, (m/s)^2; the position error over the
chunk divided by its time): the slow part of the error, the one an integrated velocity turns into drift, weighed
at every horizon up to the chunk's length. ``axis_weights`` (3,) weigh each body axis's error in both terms, and so
in the validation loss that picks the checkpoint (a car's forward speed, which a causal window cannot know and the
graph may leave to the IMU, weighed low so that its over-fitting does not choose the epoch for the other two).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from airimu_core.errors import InputError
from airimu_core.sequence import ImuSequence
from learned_imu.network.motion import Motion, up_in_body
from learned_imu.training.windows import usable_windows


@dataclass(frozen=True, eq=False)
class MotionChunks:
    """B chunks of ``context + length`` samples. Shapes: ``gyro``, ``acc`` (B, S, 3) rad/s and m/s^2; ``rot``
    (B, S, 3, 3) ground-truth attitude world <- IMU; ``target`` (B, M, 3) body-frame velocity at the M block ends
    after the context, m/s; ``valid`` (B, M) which targets count (all of a usable chunk's); ``vel`` (B, S, 3) the
    body-frame velocity at every sample, m/s, kept only for ``time_reversal`` (module docstring)."""

    gyro: torch.Tensor
    acc: torch.Tensor
    rot: torch.Tensor
    target: torch.Tensor
    valid: torch.Tensor
    context_blocks: int
    tilt_noise_rad: float = 0.0
    frame_rotation_rad: float = 0.0
    mirror_axis: int | None = None
    spin_axis: int | None = None
    time_reversal: bool = False
    vel: torch.Tensor | None = None
    drift: float = 0.0
    axis_weights: tuple[float, float, float] = (1.0, 1.0, 1.0)

    def __len__(self) -> int:
        return self.gyro.shape[0]

    @property
    def windows(self) -> int:
        """How many targets count (the trainer weighs batches by it)."""
        return int(self.valid.sum())

    @property
    def mask(self) -> torch.Tensor:
        return self.valid

    def predict(self, model, perturb: bool) -> Motion:
        """The model's output at the supervised block ends; the attitude tilted (module docstring) if ``perturb``."""
        return self._predict(model, perturb)[0]

    def _predict(self, model, perturb: bool) -> tuple[Motion, torch.Tensor, torch.Tensor]:
        """The output and the target, both in the chunk's IMU frame (rotated by a random Q, module docstring, when
        ``perturb`` and ``frame_rotation_rad`` > 0), and (B, 1, 3, 3) the map from that frame to the world up to the
        ground-truth attitude, ``Q^-1`` (``R Q^-1`` takes the output to the world)."""
        gyro, acc, rot, target = self.gyro, self.acc, self.rot, self.target
        if perturb and self.time_reversal:
            gyro, acc, rot, target = self._reversed(torch.rand(len(self), device=gyro.device) < 0.5)
        truth = rot
        rot = _tilted(rot, self.tilt_noise_rad) if perturb and self.tilt_noise_rad > 0 else rot
        up = up_in_body(rot)
        back = torch.eye(3, dtype=gyro.dtype, device=gyro.device).expand(len(self), 3, 3)
        if perturb and self.frame_rotation_rad > 0:
            q = _random_rotations(len(self), self.frame_rotation_rad, gyro)  # new IMU frame <- old, per chunk
            gyro, acc, up, target = (torch.einsum("bij,bnj->bni", q, x) for x in (gyro, acc, up, target))
            back = back @ q.mT
        if perturb and (self.mirror_axis is not None or self.spin_axis is not None):
            q = _symmetry_maps(len(self), self.mirror_axis, self.spin_axis, gyro)
            acc, up, target = (torch.einsum("bij,bnj->bni", q, x) for x in (acc, up, target))
            # the angular rate is a pseudo-vector: a reflection (det -1) flips it once more
            gyro = torch.einsum("bij,bnj->bni", q, gyro) * torch.linalg.det(q)[:, None, None]
            back = back @ q.mT  # orthogonal: the inverse is the transpose
        out = model(gyro, acc, up)
        block = gyro.shape[1] // (self.target.shape[1] + self.context_blocks)
        world = truth[:, self.context_blocks * block + block - 1 :: block] @ back[:, None]
        return Motion(out.vel[:, self.context_blocks :], out.vel_var[:, self.context_blocks :]), target, world

    def _reversed(self, back: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """gyro, acc, rot and target with the chunks where ``back`` (B,) played backwards (module docstring)."""
        if self.vel is None or not bool(self.valid.all()):
            raise ValueError("MotionChunks: time_reversal needs the per-sample velocity and whole chunks")
        block = self.gyro.shape[1] // (self.target.shape[1] + self.context_blocks)
        reverse = (-self.gyro.flip(1), self.acc.flip(1), self.rot.flip(1))
        target = -self.vel.flip(1)[:, self.context_blocks * block + block - 1 :: block]
        pick = lambda new, old: torch.where(back.view(-1, *([1] * (old.ndim - 1))), new, old)  # noqa: E731
        return (
            *(pick(n, o) for n, o in zip(reverse, (self.gyro, self.acc, self.rot), strict=True)),
            pick(target, self.target),
        )

    def loss(self, model, covariance: float, use_covariance: bool = True) -> torch.Tensor:
        """Mean squared velocity error plus, with ``use_covariance``, ``covariance`` times the NLL of the detached
        error (module docstring); the attitude (and, with ``frame_rotation_rad``, the IMU frame) is perturbed while
        the model trains."""
        out, target, world = self._predict(model, perturb=model.training)
        err = out.vel - target
        weight = self.valid[..., None].to(err.dtype)
        count = weight.sum().clamp(min=1.0) * 3
        axes = torch.tensor(self.axis_weights, dtype=err.dtype, device=err.device)
        loss = (err.square() * weight * axes).sum() / count
        if self.drift > 0:
            drifting = err * weight * axes.sqrt()
            mean_err = (world @ drifting[..., None])[..., 0].cumsum(1) / weight.cumsum(1).clamp(min=1.0)
            loss = loss + self.drift * (mean_err.square() * weight).sum() / count
        if use_covariance and covariance > 0:
            nll = 0.5 * (err.detach().square() / out.vel_var + out.vel_var.log())
            loss = loss + covariance * (nll * weight).sum() / count
        return loss

    def to(self, device: str | torch.device) -> MotionChunks:
        return self._apply(lambda x: x.to(device))

    def double(self) -> MotionChunks:
        return self._apply(lambda x: x if x.dtype == torch.bool else x.double())

    def select(self, index: torch.Tensor) -> MotionChunks:
        index = index.to(self.gyro.device)
        return self._apply(lambda x: x[index])

    def _apply(self, op) -> MotionChunks:
        return MotionChunks(
            *(op(x) for x in (self.gyro, self.acc, self.rot, self.target, self.valid)),
            self.context_blocks,
            self.tilt_noise_rad,
            self.frame_rotation_rad,
            self.mirror_axis,
            self.spin_axis,
            self.time_reversal,
            None if self.vel is None else op(self.vel),
            self.drift,
            self.axis_weights,
        )


# below this, on every axis, the std of a model's velocities over the validation chunks against the truth's is a
# model whose output hardly depends on its input (KITTI's car model at 1 m/s per output unit: 0.0007-0.1)
COLLAPSED_SPREAD = 0.2


@torch.no_grad()
def output_spread(model, chunks: MotionChunks, batch_size: int = 64) -> np.ndarray:
    """(3,) per body axis: the std of the model's velocities over the valid targets of ``chunks`` (eval mode, the
    unperturbed attitude) divided by the std of the targets; about 1 for a model that follows the motion, near 0
    for one that gives the same velocity whatever it reads."""
    model.eval()
    predicted, target = [], []
    for first in range(0, len(chunks), batch_size):
        batch = chunks.select(torch.arange(first, min(first + batch_size, len(chunks))))
        out, truth, _ = batch._predict(model, perturb=False)
        predicted.append(out.vel[batch.valid])
        target.append(truth[batch.valid])
    predicted, target = torch.cat(predicted), torch.cat(target)
    return (predicted.std(0) / target.std(0).clamp(min=1e-9)).double().cpu().numpy()


def collapse_warning(spread: np.ndarray, where: str) -> str | None:
    """A message when every axis of ``output_spread`` is below ``COLLAPSED_SPREAD``, else None."""
    if np.all(spread < COLLAPSED_SPREAD):
        return (
            f"{where}: the motion model's velocities hardly vary: their std over the validation chunks is "
            f"{' / '.join(f'{x:.3g}' for x in spread)} of the truth's (x / y / z); its GRUs are likely saturated "
            "(motion.vel_scale_m_s well below the platform's speeds?)"
        )
    return None


def make_motion_chunks(
    sequence: ImuSequence,
    length: int,
    stride: int,
    context: int,
    block: int,
    tilt_noise_rad: float = 0.0,
    allow_empty: bool = False,
    frame_rotation_rad: float = 0.0,
    mirror_axis: int | None = None,
    spin_axis: int | None = None,
    time_reversal: bool = False,
    drift: float = 0.0,
    axis_weights: tuple[float, float, float] = (1.0, 1.0, 1.0),
) -> MotionChunks | None:
    """Chunks of ``sequence`` (module docstring) starting every ``stride`` samples; ``length`` and ``context`` whole
    numbers of ``block`` samples. None (``allow_empty``) or an ``InputError`` when no chunk is usable."""
    if sequence.gt is None:
        raise InputError(f"{sequence.name}: the motion model trains on ground truth; the sequence has none")
    for name, value in (("length", length), ("context", context)):
        if value % block or value < (block if name == "length" else 0):
            raise InputError(f"motion chunks: {name} must be a whole number of {block}-sample blocks, got {value}")
    if stride < 1:
        raise InputError(f"motion chunks: stride must be >= 1 sample, got {stride}")
    span = context + length
    starts = np.arange(0, len(sequence) - span, stride)
    starts = starts[usable_windows(sequence, starts, span - 1)] if len(starts) else starts
    if len(starts) == 0:
        if allow_empty:
            return None
        raise InputError(f"{sequence.name}: no chunk of {span} samples without a gap or invalid ground truth")
    take = starts[:, None] + np.arange(span)[None, :]
    gt = sequence.gt
    ends = take[:, context + block - 1 :: block]  # the block ends after the context
    target = np.einsum("bmji,bmj->bmi", gt.rot[ends], gt.vel[ends])  # R^T v
    vel = np.einsum("bsji,bsj->bsi", gt.rot[take], gt.vel[take]) if time_reversal else None
    as_tensor = lambda x: torch.as_tensor(np.ascontiguousarray(x), dtype=torch.float32)  # noqa: E731
    return MotionChunks(
        as_tensor(sequence.gyro[take]),
        as_tensor(sequence.acc[take]),
        as_tensor(gt.rot[take]),
        as_tensor(target),
        torch.ones(target.shape[:2], dtype=torch.bool),
        context // block,
        tilt_noise_rad,
        frame_rotation_rad,
        mirror_axis,
        spin_axis,
        time_reversal,
        None if vel is None else as_tensor(vel),
        drift,
        tuple(axis_weights),
    )


def concat_motion_chunks(parts: list[MotionChunks]) -> MotionChunks:
    first = parts[0]
    fields_ = zip(*((p.gyro, p.acc, p.rot, p.target, p.valid) for p in parts), strict=True)
    return MotionChunks(
        *(torch.cat(list(f)) for f in fields_),
        first.context_blocks,
        first.tilt_noise_rad,
        first.frame_rotation_rad,
        first.mirror_axis,
        first.spin_axis,
        first.time_reversal,
        None if first.vel is None else torch.cat([p.vel for p in parts]),
        first.drift,
        first.axis_weights,
    )


def _symmetry_maps(batch: int, mirror_axis: int | None, spin_axis: int | None, like: torch.Tensor) -> torch.Tensor:
    """(B, 3, 3) maps of the IMU frame, one per chunk: a rotation about ``spin_axis`` by a uniform angle, then
    (half the chunks) the reflection that flips ``mirror_axis``; None: that part left out."""
    q = torch.eye(3, dtype=like.dtype, device=like.device).repeat(batch, 1, 1)
    if mirror_axis is not None:
        flip = torch.rand(batch, device=like.device) < 0.5
        q[flip, mirror_axis, mirror_axis] = -1.0
    if spin_axis is not None:
        angle = torch.rand(batch, dtype=like.dtype, device=like.device) * (2 * math.pi)
        i, j = [a for a in range(3) if a != spin_axis]
        s = torch.eye(3, dtype=like.dtype, device=like.device).repeat(batch, 1, 1)
        s[:, i, i], s[:, i, j], s[:, j, i], s[:, j, j] = angle.cos(), -angle.sin(), angle.sin(), angle.cos()
        q = s @ q
    return q


def _random_rotations(batch: int, sigma_rad: float, like: torch.Tensor) -> torch.Tensor:
    """(B, 3, 3) rotations about uniformly random axes by angles N(0, sigma_rad), torch's global generator."""
    axis = torch.nn.functional.normalize(torch.randn(batch, 3, dtype=like.dtype, device=like.device), dim=-1)
    angle = torch.randn(batch, dtype=like.dtype, device=like.device) * sigma_rad
    k = torch.zeros(batch, 3, 3, dtype=like.dtype, device=like.device)
    k[:, 0, 1], k[:, 0, 2], k[:, 1, 2] = -axis[:, 2], axis[:, 1], -axis[:, 0]
    k = k - k.mT
    s, c = torch.sin(angle)[:, None, None], torch.cos(angle)[:, None, None]
    return torch.eye(3, dtype=like.dtype, device=like.device) + s * k + (1 - c) * (k @ k)  # Rodrigues


def _tilted(rot: torch.Tensor, sigma_rad: float) -> torch.Tensor:
    """(B, S, 3, 3) rotations, each chunk's tilted by one random rotation about a horizontal world axis."""
    batch = rot.shape[0]
    heading = torch.rand(batch, device=rot.device, dtype=rot.dtype) * (2 * math.pi)
    angle = torch.randn(batch, device=rot.device, dtype=rot.dtype) * sigma_rad
    axis = torch.stack([torch.cos(heading), torch.sin(heading), torch.zeros_like(heading)], dim=-1)
    k = torch.zeros(batch, 3, 3, dtype=rot.dtype, device=rot.device)
    k[:, 0, 2], k[:, 1, 2] = axis[:, 1], -axis[:, 0]
    k[:, 2, 0], k[:, 2, 1] = -axis[:, 1], axis[:, 0]
    s, c = torch.sin(angle)[:, None, None], torch.cos(angle)[:, None, None]
    tilt = torch.eye(3, dtype=rot.dtype, device=rot.device) + s * k + (1 - c) * (k @ k)  # Rodrigues
    return tilt[:, None] @ rot
