"""Shared test builders (evo's ``test/helpers.py`` habit): test modules import these, never each other.

- ``REPO``, ``shared_data_dir()``: the checkout and the real-data folder beside it (a missing folder fails loudly).
- ``error_jacobian``: the numerical derivative of a factor's unwhitened error in float64, by GTSAM's own
  ``gtsam.utils.numerical_derivative`` (central differences in the value's tangent chart: Pose3 ``retract``,
  vectors ``+``, ``imuBias.ConstantBias`` ``retract``).
- ``gtsam_pim``, ``factor_from_pim``, ``factor_with_bias_from_samples``: IMU measurements built by GTSAM and by
  ``learned_imu.preintegrate`` for the factor tests.
"""

from __future__ import annotations

import os
from pathlib import Path

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, V, X
from gtsam.utils.numerical_derivative import numericalDerivative11

from factors.imu import LearnedImuFactor

REPO = Path(__file__).resolve().parents[1]
GRAVITY = 9.81  # m/s^2, the factor tests' world
JACOBIAN_STEP = 1e-6  # central-difference step on each tangent coordinate (float64)


def shared_data_dir() -> Path:
    """The real-data folder: ``$AIRIMU_SHARED_DATA`` or ``<repo>/../shared/data``. Raises if it is missing."""
    path = Path(os.environ.get("AIRIMU_SHARED_DATA", REPO.parent / "shared" / "data"))
    if not (path / "README.md").is_file():
        raise FileNotFoundError(
            f"real data folder not found at {path}: tests that prove the method on real data need it "
            "(set AIRIMU_SHARED_DATA or place shared/data beside the checkout)"
        )
    return path


_VALUE_AT = {"x": "atPose3", "v": "atVector", "b": "atConstantBias", "m": "atRot3", "s": "atVector"}  # (X, V, B, M, S)


def error_jacobian(factor: gtsam.NonlinearFactor, values: gtsam.Values, key: int, step: float = JACOBIAN_STEP):
    """d unwhitenedError / d tangent of the value at ``key`` (an X, V or B key), central differences in float64."""
    value = getattr(values, _VALUE_AT[chr(gtsam.Symbol(key).chr())])(key)

    def error_at(x) -> np.ndarray:
        moved = gtsam.Values(values)
        moved.update(key, x)
        return factor.unwhitenedError(moved)

    return numericalDerivative11(error_at, value, step)


def gtsam_pim(seed: int, n: int = 200, dt: float = 0.005) -> gtsam.PreintegratedImuMeasurements:
    """GTSAM's preintegration of ``n`` random samples (acc about gravity, gyro up to 1.5 rad/s)."""
    rng = np.random.default_rng(seed)
    params = gtsam.PreintegrationParams.MakeSharedU(GRAVITY)
    params.setGyroscopeCovariance(np.eye(3) * 1e-4)
    params.setAccelerometerCovariance(np.eye(3) * 1e-3)
    params.setIntegrationCovariance(np.eye(3) * 1e-8)
    pim = gtsam.PreintegratedImuMeasurements(params, gtsam.imuBias.ConstantBias())
    for _ in range(n):
        pim.integrateMeasurement(rng.normal(0, 2, 3) + [0, 0, GRAVITY], rng.uniform(-1.5, 1.5, 3), dt)
    return pim


def factor_from_pim(pim) -> LearnedImuFactor:
    """Our factor on GTSAM's deltas and covariance (no bias key)."""
    return LearnedImuFactor(
        X(0),
        V(0),
        X(1),
        V(1),
        pim.deltaRij().matrix(),
        pim.deltaPij(),
        pim.deltaVij(),
        pim.deltaTij(),
        pim.preintMeasCov(),
        gravity=[0.0, 0.0, -GRAVITY],
    )


def factor_with_bias_from_samples(seed: int, n: int = 200, dt: float = 0.005):
    """Our factor built from learned_imu.preintegrate (deltas, covariance, bias Jacobian), and GTSAM's pim of the
    same samples."""
    import torch

    from learned_imu import preintegrate

    rng = np.random.default_rng(seed)
    gyro = rng.uniform(-1.0, 1.0, (n, 3))
    acc = rng.normal(0, 2, (n, 3)) + [0, 0, GRAVITY]
    pre = preintegrate(torch.tensor(gyro), torch.tensor(acc), dt, 1e-4, 1e-3, at=-1, bias_jacobian=True)
    ours = LearnedImuFactor(
        X(0),
        V(0),
        X(1),
        V(1),
        pre.rot[0].numpy(),
        pre.pos[0].numpy(),
        pre.vel[0].numpy(),
        pre.dt[0].item(),
        pre.cov[0].numpy(),
        gravity=[0.0, 0.0, -GRAVITY],
        bias=B(0),
        bias_jacobian=pre.bias_jacobian[0].numpy(),
    )
    params = gtsam.PreintegrationParams.MakeSharedU(GRAVITY)
    params.setGyroscopeCovariance(np.eye(3) * 1e-4)
    params.setAccelerometerCovariance(np.eye(3) * 1e-3)
    params.setIntegrationCovariance(np.zeros((3, 3)))
    pim = gtsam.PreintegratedImuMeasurements(params, gtsam.imuBias.ConstantBias())
    for k in range(n):
        pim.integrateMeasurement(acc[k], gyro[k], dt)
    return ours, pim


def write_checkpoint(path, model_config, weights: dict, remove_gravity: bool = False) -> Path:
    """A hand-made checkpoint (current format): ``weights`` of a model built from ``model_config``, inside a minimal
    whole config (one simulated sequence to train and validate on)."""
    from learned_imu.config import DataConfig, ExperimentConfig, SequenceConfig, TrainConfig
    from learned_imu.network.checkpoint import Checkpoint, save_checkpoint

    simulated = (SequenceConfig("simulator"),)
    config = ExperimentConfig(
        "hand-made",
        DataConfig(train=simulated, val=simulated),
        model=model_config,
        train=TrainConfig(remove_gravity=remove_gravity),
    )
    return save_checkpoint(path, Checkpoint(config, {"model": weights}))
