"""Quaternion <-> matrix conversion and slerp in float64 numpy (Hamilton quaternions, as EuRoC/ROS/BROAD use).

Order is always explicit: ``"wxyz"`` (scalar first: EuRoC ASL, BROAD, GTSAM ``Quaternion(w, x, y, z)``) or
``"xyzw"`` (scalar last: TUM files, ROS messages, scipy). Matrices are (N, 3, 3) and rotate vectors of the
frame the quaternion describes into its reference frame (for the readers: world <- IMU).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from airimu_core.errors import DataError

QUAT_ORDERS = ("wxyz", "xyzw")
# |q| must be within this of 1: files round to ~6 decimals (error ~1e-6); a wrong column gives a norm far from 1
UNIT_NORM_TOL = 1e-2


def to_xyzw(q: np.ndarray, order: str) -> np.ndarray:
    """(N, 4) quaternions reordered to scalar-last."""
    if order == "wxyz":
        return q[:, [1, 2, 3, 0]]
    if order == "xyzw":
        return q
    raise ValueError(f"quaternion order must be one of {QUAT_ORDERS}, got {order!r}")


def quat_to_matrix(q: np.ndarray, order: str, source: object = "", field: str = "quaternion") -> np.ndarray:
    """(N, 3, 3) rotation matrices of (N, 4) quaternions in ``order``; non-unit input raises a DataError."""
    norm = np.linalg.norm(q, axis=1)
    bad = np.abs(norm - 1.0) > UNIT_NORM_TOL
    if bad.any():
        row = int(np.argmax(bad))
        raise DataError(
            source, field, f"quaternion at sample {row} has norm {norm[row]:.4f}, expected 1 (wrong columns?)"
        )
    return Rotation.from_quat(to_xyzw(q, order)).as_matrix()


def matrix_to_quat_wxyz(rot: np.ndarray) -> np.ndarray:
    """(..., 4) unit quaternions (w, x, y, z), w >= 0, of (..., 3, 3) rotation matrices, in float64 (scipy's
    conversion; ``learned_imu.geometry.so3.matrix_to_quaternion_wxyz`` is its torch twin for autograd)."""
    rot = np.asarray(rot, dtype=np.float64)
    xyzw = Rotation.from_matrix(rot.reshape(-1, 3, 3)).as_quat()
    wxyz = xyzw[:, [3, 0, 1, 2]]
    wxyz = np.where(wxyz[:, :1] < 0, -wxyz, wxyz)
    return wxyz.reshape(*rot.shape[:-2], 4)


def relative_rotvec(rot_a: np.ndarray, rot_b: np.ndarray) -> np.ndarray:
    """(N, 3) rotation vectors ``Log(rot_a^T rot_b)``, rad, expressed in frame a."""
    rel = np.einsum("nji,njk->nik", rot_a, rot_b)
    return Rotation.from_matrix(rel).as_rotvec()


def slerp(rot_a: np.ndarray, rot_b: np.ndarray, frac: np.ndarray) -> np.ndarray:
    """(N, 3, 3) ``rot_a Exp(frac Log(rot_a^T rot_b))``: constant-rate rotation from a (frac 0) to b (frac 1)."""
    step = Rotation.from_rotvec(frac[:, None] * relative_rotvec(rot_a, rot_b)).as_matrix()
    return rot_a @ step
