"""GPS position factor with an antenna lever arm, on a ``gtsam.Pose3`` key (``X(i)``).

Measurement: the antenna position in the navigation (world) frame, m. Lever arm: the antenna's position in the
body (IMU) frame, m. Error ``t + R l - z`` (world frame, m), so with ``l = 0`` the error and its Jacobian equal
``gtsam.GPSFactor``'s. Noise is Gaussian with a per-axis standard deviation (m, not a variance), optionally
wrapped in a robust M-estimator (Huber or Cauchy) to survive outlier fixes.
"""

from __future__ import annotations

import gtsam
import numpy as np

ROBUST_LOSSES = ("huber", "cauchy")


def gps_noise(sigma_m, robust: str | None = None, robust_k: float = 1.345) -> gtsam.noiseModel.Base:
    """Diagonal Gaussian noise with standard deviations ``sigma_m`` (float or (3,), m), optionally robust.

    ``robust_k`` is the M-estimator's threshold on the whitened error (1.345 is Huber's 95 % efficiency value).
    """
    sigma = np.broadcast_to(np.asarray(sigma_m, dtype=float), (3,)).copy()
    if not np.all(np.isfinite(sigma)) or np.any(sigma <= 0):
        raise ValueError(f"GPS sigma must be positive and finite (m), got {sigma_m!r}")
    gaussian = gtsam.noiseModel.Diagonal.Sigmas(sigma)
    if robust is None:
        return gaussian
    if robust not in ROBUST_LOSSES:
        raise ValueError(f"unknown robust loss {robust!r}; known: {', '.join(ROBUST_LOSSES)}")
    estimator = gtsam.noiseModel.mEstimator.Huber if robust == "huber" else gtsam.noiseModel.mEstimator.Cauchy
    return gtsam.noiseModel.Robust.Create(estimator.Create(robust_k), gaussian)


class GpsFactor(gtsam.GPSFactorArm):
    """Antenna position measured in the world frame, on pose key ``key``: GTSAM's C++ ``GPSFactorArm`` (error
    ``t + R l - z``, Jacobians in GTSAM's Pose3 tangent order) with validated inputs.

    Deliberately not a Python ``gtsam.CustomFactor``: inside GTSAM's optimisers pybind11 hands a Python callback a
    *copy* of the whole ``Values`` (the optimiser's own values are not Python objects), so a Python factor costs
    O(graph size) per evaluation and a graph of them O(N^2) per iteration (measured: BENCHMARKS.md, "Design
    measurements").

    Args:
        key: the ``gtsam.Pose3`` key, e.g. ``gtsam.symbol_shorthand.X(i)``.
        position_m: (3,) measured antenna position, world frame, m.
        noise: a gtsam noise model of dimension 3 (see ``gps_noise``).
        lever_arm_m: (3,) antenna position in the body (IMU) frame, m.
    """

    def __init__(self, key: int, position_m, noise: gtsam.noiseModel.Base, lever_arm_m=(0.0, 0.0, 0.0)):
        self.position_m = _vector3("position_m", position_m)
        self.lever_arm_m = _vector3("lever_arm_m", lever_arm_m)
        if noise.dim() != 3:
            raise ValueError(f"GpsFactor noise must have dimension 3, got {noise.dim()}")
        super().__init__(key, self.position_m, self.lever_arm_m, noise)


def _vector3(name: str, value) -> np.ndarray:
    out = np.asarray(value, dtype=float)
    if out.shape != (3,) or not np.all(np.isfinite(out)):
        raise ValueError(f"GpsFactor {name} must be 3 finite numbers (m), got {value!r}")
    return out
