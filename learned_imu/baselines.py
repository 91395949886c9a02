"""Non-learned baselines of the paper's IMU ablation: the raw IMU and a constant ("average") bias.

The average bias is the mean, over every training sample with valid ground truth, of the measured sample minus
the sample implied by the ground truth under the discrete integrator (the simulator's exact discretisation):

    gyro_gt_k = Log(R_k^T R_{k+1}) / dt_k,    acc_gt_k = R_k^T ((v_{k+1} - v_k) / dt_k - g)

(rad/s and m/s^2, IMU frame). Ground-truth velocity noise averages out in the mean.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from learned_imu import so3
from learned_imu.sequence import ImuSequence


@dataclass(frozen=True)
class ConstantBias:
    """A constant IMU bias, subtracted from the samples: ``gyro_rad_s`` (3,), ``acc_m_s2`` (3,)."""

    gyro_rad_s: np.ndarray
    acc_m_s2: np.ndarray

    def correct(self, sequence: ImuSequence) -> tuple[np.ndarray, np.ndarray]:
        """(N, 3) corrected gyro and acc of ``sequence``."""
        return sequence.gyro - self.gyro_rad_s, sequence.acc - self.acc_m_s2


def imu_from_ground_truth(sequence: ImuSequence) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The IMU samples implied by the ground truth: gyro (N-1, 3), acc (N-1, 3) and a valid mask (N-1,)."""
    if sequence.gt is None:
        raise ValueError(f"{sequence.name}: the average bias needs ground truth")
    gt, dt = sequence.gt, sequence.dt[:-1, None]
    rot = torch.as_tensor(gt.rot)
    gyro = so3.log(rot[:-1].mT @ rot[1:]).numpy() / dt
    acc = np.einsum("nji,nj->ni", gt.rot[:-1], (gt.vel[1:] - gt.vel[:-1]) / dt - sequence.gravity)
    return gyro, acc, gt.valid[:-1] & gt.valid[1:]


def average_bias(sequences: list[ImuSequence]) -> ConstantBias:
    """The mean bias over the valid samples of ``sequences`` (see the module docstring)."""
    gyro_err, acc_err = [], []
    for seq in sequences:
        gyro, acc, ok = imu_from_ground_truth(seq)
        gyro_err.append(seq.gyro[:-1][ok] - gyro[ok])
        acc_err.append(seq.acc[:-1][ok] - acc[ok])
    gyro_err, acc_err = np.concatenate(gyro_err), np.concatenate(acc_err)
    if len(gyro_err) == 0:
        raise ValueError("average_bias: no sample with valid ground truth")
    return ConstantBias(gyro_err.mean(axis=0), acc_err.mean(axis=0))
