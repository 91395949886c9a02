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

from airimu_core.errors import InputError
from airimu_core.sequence import ImuSequence
from learned_imu.geometry import so3


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
        raise InputError(f"{sequence.name}: the average bias needs ground truth")
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
        raise InputError("average_bias: no sample with valid ground truth")
    return ConstantBias(gyro_err.mean(axis=0), acc_err.mean(axis=0))


@dataclass(frozen=True)
class LinearCalibration:
    """Per-sensor affine intrinsics: ``corrected = matrix @ raw - offset`` for gyro and for acc.

    ``gyro_matrix`` / ``acc_matrix`` (3, 3) hold the inverse of scale x misalignment (identity for a perfect
    sensor), ``gyro_offset_rad_s`` / ``acc_offset_m_s2`` (3,) the bias after that correction. This is the model of
    Kalibr-style IMU intrinsics (``raw = (scale * misalignment) true + bias``) solved for the true rates.
    """

    gyro_matrix: np.ndarray
    gyro_offset_rad_s: np.ndarray
    acc_matrix: np.ndarray
    acc_offset_m_s2: np.ndarray

    def correct(self, sequence: ImuSequence) -> tuple[np.ndarray, np.ndarray]:
        """(N, 3) corrected gyro and acc of ``sequence``."""
        gyro = sequence.gyro @ self.gyro_matrix.T - self.gyro_offset_rad_s
        acc = sequence.acc @ self.acc_matrix.T - self.acc_offset_m_s2
        return gyro, acc


CALIBRATION_BLOCK = 100  # samples averaged per least-squares row (0.5 s at EuRoC's 200 Hz)


def linear_calibration(sequences: list[ImuSequence], block: int = CALIBRATION_BLOCK) -> LinearCalibration:
    """Least squares of ``ground-truth sample ~ matrix @ raw - offset`` for each sensor (12 unknowns each) over
    the training ``sequences``; targets as in ``imu_from_ground_truth``.

    The rows are means over blocks of ``block`` consecutive valid samples, not single samples: the model is
    linear, so block means obey it too, while the raw samples' vibration (a drone's propellers put ~1 m/s^2 on
    EuRoC's accelerometer, absent from the smooth ground truth) averages out. Fitted per sample, that noise sits
    in the regressors and biases the slopes towards zero (errors in variables: an acc "scale" of 0.56 on EuRoC).
    """
    raw = {"gyro": [], "acc": []}
    truth = {"gyro": [], "acc": []}
    for seq in sequences:
        gyro, acc, ok = imu_from_ground_truth(seq)
        for name, target in (("gyro", gyro), ("acc", acc)):
            raw[name].append(_block_means(getattr(seq, name)[:-1], ok, block))
            truth[name].append(_block_means(target, ok, block))
    fitted = {}
    for name in ("gyro", "acc"):
        x, y = np.concatenate(raw[name]), np.concatenate(truth[name])
        if len(x) < 12:
            raise InputError(f"linear_calibration: {len(x)} blocks of {block} valid samples, need at least 12")
        design = np.hstack([x, -np.ones((len(x), 1))])
        solution, *_ = np.linalg.lstsq(design, y, rcond=None)  # (4, 3): rows matrix^T, then offset
        fitted[name] = (solution[:3].T.copy(), solution[3].copy())
    return LinearCalibration(*fitted["gyro"], *fitted["acc"])


def _block_means(values: np.ndarray, ok: np.ndarray, block: int) -> np.ndarray:
    """Means of ``values`` (N, 3) over consecutive blocks of ``block`` samples that are all ``ok``."""
    n = len(values) // block * block
    blocks = values[:n].reshape(-1, block, 3)
    whole = ok[:n].reshape(-1, block).all(axis=1)
    return blocks[whole].mean(axis=1)
