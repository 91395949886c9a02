"""Trajectory metrics for IMU integration, as AirIMU measures them (haleqiu/AirIMU ``evaluation/evaluate_state.py``).

Definitions (over an interval of L IMU samples; ``interval_s`` = L x the median time step):
- Windows: the sequence is cut into non-overlapping windows of L samples, ``[s, s + L)``, s = 0, L, 2L, ...;
  a window is used only if the ground truth is valid on all its L + 1 states. In every window the IMU is
  integrated afresh from the ground-truth state (R, v, p) at s -- integration restarted at every window start,
  as the paper does -- giving predicted states after each of its samples. The official code also scores the
  shorter remainder of a sequence as one more window; here every window has exactly L samples (one of ~100
  windows at 1 s, a few tenths of a percent on the raw-IMU rows).
- Window-end errors: rotation angle of ``R_gt(s+L)^T R_pred(s+L)`` (deg) and ``|p_pred(s+L) - p_gt(s+L)|`` (m);
  since the start is exact they are the relative errors over the interval. Every metric of the paper's IMU tables
  is one statistic of these:

  ===================  =======================================  ====================================================
  field                statistic                                paper (official code)
  ===================  =======================================  ====================================================
  ``roe_deg``          mean of window-end rotation errors       "ROE" (``ROE``)
  ``roe_rmse_deg``     RMSE of window-end rotation errors       "RMSE" beside ROE; "R-RMSE" at 10 frames
                                                                (``RO_RMSE``)
  ``rpe_m``            mean of window-end position errors       (``RTE``)
  ``rpe_rmse_m``       RMSE of window-end position errors       "P-RMSE" over 1 s and at 10 frames (``RP_RMSE``)
  ===================  =======================================  ====================================================

  Checked against the paper's deterministic raw-IMU (Baseline) rows on MH_04, V1_03 and V2_02: within 0.5 % at
  1 s and at 10 frames (``tests/learned_imu/evaluation/test_paper_metrics.py``).
- ``rot_rmse_states_deg``, ``pos_rmse_states_m``, ``vel_rmse_states_m_s``: root mean square over *every*
  predicted state of every window (not a column of the paper; smaller than the window-end statistics, since
  errors grow within a window).
- ATE (m): RMSE of position over the whole sequence dead-reckoned from the first ground-truth state (no
  restart), without alignment and after the least-squares rigid (SE(3), no scale) alignment of Umeyama/Horn
  (evo's ``evo_ape --align``; cross-checked in the tests).
Orientation errors use ``Log`` angles in degrees; positions are world frame, metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from airimu_core.errors import InputError


@dataclass(frozen=True, eq=False)
class WindowErrors:
    """Per-window and per-state errors of restarted integration.

    Shapes: ``end_rot_deg``, ``end_pos_m`` (W,); ``rot_deg``, ``pos_m``, ``vel_m_s`` (W, L).
    """

    end_rot_deg: np.ndarray
    end_pos_m: np.ndarray
    rot_deg: np.ndarray
    pos_m: np.ndarray
    vel_m_s: np.ndarray


def rotation_angle_deg(rot_a: np.ndarray, rot_b: np.ndarray) -> np.ndarray:
    """Angle of ``rot_a^T rot_b`` in degrees, (...,) for (..., 3, 3) inputs; accurate near 0."""
    rel = np.einsum("...ji,...jk->...ik", rot_a, rot_b)
    sin = 0.5 * np.linalg.norm(
        np.stack(
            [rel[..., 2, 1] - rel[..., 1, 2], rel[..., 0, 2] - rel[..., 2, 0], rel[..., 1, 0] - rel[..., 0, 1]], -1
        ),
        axis=-1,
    )
    cos = 0.5 * (np.trace(rel, axis1=-2, axis2=-1) - 1)
    return np.degrees(np.arctan2(sin, cos))


def window_errors(pred_rot, pred_pos, pred_vel, gt_rot, gt_pos, gt_vel) -> WindowErrors:
    """Errors of predicted states (W, L, ...) against ground truth at the same states (W, L, ...)."""
    rot = rotation_angle_deg(gt_rot, pred_rot)
    pos = np.linalg.norm(pred_pos - gt_pos, axis=-1)
    vel = np.linalg.norm(pred_vel - gt_vel, axis=-1)
    return WindowErrors(end_rot_deg=rot[:, -1], end_pos_m=pos[:, -1], rot_deg=rot, pos_m=pos, vel_m_s=vel)


def rmse(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def umeyama_alignment(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation R and translation t minimising ``sum |R source_i + t - target_i|^2`` (Umeyama 1991, no scale).

    ``source``, ``target``: (N, 3) positions. Returns R (3, 3) and t (3,).
    """
    if source.shape != target.shape or source.ndim != 2 or source.shape[1] != 3 or len(source) < 3:
        raise InputError(f"alignment needs two (N, 3) arrays with N >= 3, got {source.shape} and {target.shape}")
    mu_s, mu_t = source.mean(axis=0), target.mean(axis=0)
    cov = (target - mu_t).T @ (source - mu_s) / len(source)
    u, _, vt = np.linalg.svd(cov)
    sign = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sign[2, 2] = -1
    rot = u @ sign @ vt
    return rot, mu_t - rot @ mu_s


def ate_m(est_pos: np.ndarray, gt_pos: np.ndarray, align: bool) -> float:
    """Absolute trajectory error (RMSE of position, m), optionally after rigid alignment of the estimate."""
    if align:
        rot, trans = umeyama_alignment(est_pos, gt_pos)
        est_pos = est_pos @ rot.T + trans
    return rmse(np.linalg.norm(est_pos - gt_pos, axis=-1))
