"""GTSAM's own preintegration fed with the learned model: corrected samples and their per-sample noise.

``gtsam.PreintegratedImuMeasurements`` keeps a shared pointer to its ``PreintegrationParams``, so setting the
gyroscope and accelerometer covariance before each ``integrateMeasurement`` applies that sample's learned noise.
The result drives ``gtsam.ImuFactor`` (and, from ``PreintegratedCombinedMeasurements``, ``CombinedImuFactor``)
at C++ speed with the learned covariance.

Conventions: gyro rad/s and acc m/s^2 (specific force) in the IMU frame; noise given as continuous-time
densities (rad^2/s, m^2/s^3) exactly as ``PreintegrationParams.setGyroscopeCovariance`` takes them; gravity as
the magnitude for ``MakeSharedU`` (z-up world, gravity along -z).
"""

from __future__ import annotations

import gtsam
import numpy as np


def learned_pim(
    gyro,
    acc,
    dt,
    gyro_density,
    acc_density,
    gravity_m_s2=9.81,
    integration_density: float = 0.0,
    bias: gtsam.imuBias.ConstantBias | None = None,
) -> gtsam.PreintegratedImuMeasurements:
    """Preintegrate corrected samples with per-sample learned noise into GTSAM's tangent preintegration.

    Args:
        gyro, acc: (N, 3) corrected samples, rad/s and m/s^2, IMU frame.
        dt: (N,) or float, seconds per sample.
        gyro_density, acc_density: (N, 3) per-sample diagonal noise densities (or (3,) / float for constant).
        gravity_m_s2: gravity magnitude for ``PreintegrationParams.MakeSharedU`` (z-up world), or the (3,)
            world-frame gravity vector, m/s^2.
        integration_density: GTSAM's integration covariance (m^2/s), 0 to match ``learned_imu.preintegrate``.
        bias: the bias estimate to preintegrate around (zero by default; the learned samples are corrected).
    """
    gyro = _samples("gyro", gyro)
    acc = _samples("acc", acc)
    n = len(gyro)
    if acc.shape != gyro.shape:
        raise ValueError(f"learned_pim: gyro {gyro.shape} and acc {acc.shape} must both be (N, 3)")
    dt = np.broadcast_to(np.asarray(dt, dtype=float), (n,))
    if not np.all(np.isfinite(dt)) or np.any(dt <= 0):
        raise ValueError("learned_pim: dt must be positive and finite for every sample")
    gyro_density = _densities("gyro_density", gyro_density, n)
    acc_density = _densities("acc_density", acc_density, n)

    if np.ndim(gravity_m_s2) == 0:
        params = gtsam.PreintegrationParams.MakeSharedU(float(gravity_m_s2))
    else:
        params = gtsam.PreintegrationParams(np.asarray(gravity_m_s2, dtype=float).reshape(3))
    params.setIntegrationCovariance(np.eye(3) * integration_density)
    pim = gtsam.PreintegratedImuMeasurements(params, bias or gtsam.imuBias.ConstantBias())
    for k in range(n):
        params.setGyroscopeCovariance(np.diag(gyro_density[k]))
        params.setAccelerometerCovariance(np.diag(acc_density[k]))
        pim.integrateMeasurement(acc[k], gyro[k], dt[k])
    return pim


def _samples(name: str, value) -> np.ndarray:
    out = np.asarray(value, dtype=float)
    if out.ndim != 2 or out.shape[1] != 3 or len(out) == 0:
        raise ValueError(f"learned_pim: {name} must be (N, 3) with N >= 1, got shape {out.shape}")
    if not np.all(np.isfinite(out)):
        raise ValueError(f"learned_pim: {name} contains NaN or Inf")
    return out


def _densities(name: str, value, n: int) -> np.ndarray:
    try:
        out = np.broadcast_to(np.asarray(value, dtype=float), (n, 3))
    except ValueError:
        raise ValueError(f"learned_pim: {name} must be a float, (3,) or (N, 3); got {np.shape(value)}") from None
    if not np.all(np.isfinite(out)) or np.any(out < 0):
        raise ValueError(f"learned_pim: {name} must be finite and non-negative (a noise density)")
    return out
