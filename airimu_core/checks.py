"""Checks of IMU measurements that every backend shares, numpy only: preintegrated deltas and their covariances
(``preintegration_problem``) and the world gravity (``gravity_problem``). ``airimu_core.export`` and
``factors.LearnedImuFactor`` refuse the same inputs through them."""

from __future__ import annotations

import numpy as np

ROTATION_TOL = 1e-5  # max |R^T R - I| entry of a delta rotation
SYMMETRY_TOL = 1e-9  # max |C - C^T| relative to max |C| of a covariance
# The world frame is z-up (airimu_core.sequence): gravity points along -z with Earth's magnitude; 9.78-9.83
# m/s^2
# anywhere on the surface, the range leaves room for rounded values (9.8, 10).
GRAVITY_RANGE_M_S2 = (9.5, 10.5)
GRAVITY_MAX_TILT_RAD = 0.02  # angle between gravity and world -z


def preintegration_problem(delta_rot, delta_dt, delta_cov) -> tuple[int, str] | None:
    """The first interval whose measurement is unusable and why, or None. ``delta_rot`` (I, 3, 3), ``delta_dt``
    (I,) s, ``delta_cov`` (I, 9, 9): a non-rotation, a non-positive or non-finite time, a covariance that is not
    symmetric positive definite (zero, negative or NaN variances included)."""
    rot = np.asarray(delta_rot, dtype=float)
    dt = np.asarray(delta_dt, dtype=float)
    cov = np.asarray(delta_cov, dtype=float)
    bad_dt = ~(np.isfinite(dt) & (dt > 0))
    ortho = np.abs(np.swapaxes(rot, -1, -2) @ rot - np.eye(3)).max(axis=(-2, -1))
    bad_rot = ~(ortho <= ROTATION_TOL) | ~(np.linalg.det(rot) > 0)
    scale = np.abs(cov).max(axis=(-2, -1))
    asym = np.abs(cov - np.swapaxes(cov, -1, -2)).max(axis=(-2, -1))
    finite = np.isfinite(cov).all(axis=(-2, -1))
    smallest = np.full(len(cov), -np.inf)
    smallest[finite] = np.linalg.eigvalsh(0.5 * (cov[finite] + np.swapaxes(cov[finite], -1, -2))).min(axis=-1)
    bad_cov = ~finite | ~(asym <= SYMMETRY_TOL * scale) | ~(smallest > 0)
    for bad, why in (
        (bad_dt, lambda k: f"delta_dt must be positive and finite (s), got {dt[k]!r}"),
        (bad_rot, lambda k: "delta_rot is not a rotation matrix"),
        (bad_cov, lambda k: f"delta_cov must be symmetric positive definite (9x9), min eigenvalue {smallest[k]:.3g}"),
    ):
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            return k, why(k)
    return None


def gravity_problem(gravity) -> str | None:
    """Why ``gravity`` (3,) m/s^2 cannot be the world frame's (z-up) gravity vector, or None."""
    g = np.asarray(gravity, dtype=float)
    norm = float(np.linalg.norm(g))
    low, high = GRAVITY_RANGE_M_S2
    if not (np.isfinite(norm) and low <= norm <= high):
        return f"gravity {g.tolist()} m/s^2 has magnitude {norm:.4g}, expected Earth's, in [{low:g}, {high:g}]"
    if np.arccos(np.clip(-g[2] / norm, -1.0, 1.0)) > GRAVITY_MAX_TILT_RAD:
        return f"gravity {g.tolist()} m/s^2 does not point down the world's -z axis (the world frame is z-up)"
    return None
