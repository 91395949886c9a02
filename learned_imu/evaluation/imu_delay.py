"""How late an IMU's samples are against its ground truth's clock: ``measure_imu_delay``.

The delay d is where the gyro, read d later, best matches the ground truth's body rate: the rate of each pair of
consecutive ground-truth rotations, ``Log(R_k^T R_k+1) / dt`` (rad/s, body frame), against the gyro at ``t_k + d``
(linear between samples): the sample that ``airimu_core.sequence.read_later`` puts at ``t_k``, which the
preintegration applies over [t_k, t_k+1] (so an IMU without delay measures d = dt / 2, the rectangle rule's best
sample). The score of a delay is the mean squared difference over every pair of
valid ground truth without a gap between them, pooled over the sequences (a drive that turns much weighs more: a
straight one hardly tells delays apart); searched on a 5-ms grid within ``+- max_s``, then to 0.5 ms around the best.
A delay > 0: the IMU is late (the readers' ``imu_delay_s`` takes it out of what is read, ``FuseConfig.imu_delay_s``
out of the preintegration).

Measured on the KITTI raw drives' OXTS stream (``benchmarks/motion_kitti.py --measure-delay``, BENCHMARKS.md): the
yaw rate lags the navigation solution of the same packet by ~60 ms on every drive that turns (x ~20, y ~50 ms).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from airimu_core.errors import InputError
from airimu_core.rotations import relative_rotvec
from airimu_core.sequence import MAX_GAP_STEPS, ImuSequence

COARSE_S, FINE_S = 0.005, 0.0005


@dataclass(frozen=True)
class ImuDelay:
    """``measure_imu_delay``'s result: ``delay_s`` (pooled), and per sequence (name, its own best delay s, the
    pooled delay's mean squared rate error and the zero delay's, (rad/s)^2)."""

    delay_s: float
    sequences: tuple[tuple[str, float, float, float], ...]


def measure_imu_delay(sequences: list[ImuSequence], max_s: float = 0.15) -> ImuDelay:
    """The IMU's delay against the ground truth of ``sequences`` (module docstring)."""
    if not (np.isfinite(max_s) and 0 < max_s <= 1.0):
        raise InputError(f"measure_imu_delay: max_s must be in (0, 1] s, got {max_s!r}")
    pairs = [_rate_pairs(seq) for seq in sequences]
    if not any(len(p[0]) for p in pairs):
        raise InputError("measure_imu_delay: no pair of consecutive valid ground-truth samples in the sequences")

    def scores(delays: np.ndarray) -> np.ndarray:  # (sequences, delays) summed squared errors
        return np.array([[_squared_error(seq, *p, d) for d in delays] for seq, p in zip(sequences, pairs, strict=True)])

    coarse = np.arange(-max_s, max_s + COARSE_S / 2, COARSE_S)
    coarse_scores = scores(coarse)
    centre = coarse[int(np.argmin(coarse_scores.sum(axis=0)))]
    fine = centre + np.arange(-COARSE_S, COARSE_S + FINE_S / 2, FINE_S)
    fine_scores = scores(fine)
    best = int(np.argmin(fine_scores.sum(axis=0)))
    delay = float(fine[best])
    at_zero = scores(np.zeros(1))[:, 0]
    rows = []
    for i, (seq, p) in enumerate(zip(sequences, pairs, strict=True)):
        count = max(len(p[0]), 1)
        own = float(coarse[int(np.argmin(coarse_scores[i]))])
        rows.append((seq.name, own, float(fine_scores[i, best]) / count, float(at_zero[i]) / count))
    return ImuDelay(delay, tuple(rows))


def _rate_pairs(seq: ImuSequence) -> tuple[np.ndarray, np.ndarray]:
    """(first times t_k (P,), ground-truth body rates (P, 3) rad/s) of the consecutive valid pairs without a gap."""
    if seq.gt is None:
        raise InputError(f"measure_imu_delay: {seq.source or seq.name} has no ground truth")
    step = np.diff(seq.t)
    ok = seq.gt.valid[:-1] & seq.gt.valid[1:] & (step <= MAX_GAP_STEPS * np.median(step))
    k = np.flatnonzero(ok)
    rates = relative_rotvec(seq.gt.rot[k], seq.gt.rot[k + 1]) / step[k, None]
    return seq.t[k], rates


def _squared_error(seq: ImuSequence, first: np.ndarray, rates: np.ndarray, delay: float) -> float:
    gyro = np.column_stack([np.interp(first + delay, seq.t, seq.gyro[:, i]) for i in range(3)])
    return float(np.sum((gyro - rates) ** 2))
