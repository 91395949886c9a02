"""GTSAM factors from an export (``airimu_core.export.Export``, in memory or a ``.npz``): ``from_export``."""

from __future__ import annotations

from pathlib import Path

import gtsam
import numpy as np

from airimu_core.errors import ExportError
from airimu_core.export import Export, load_export
from factors.imu import LearnedImuFactor
from factors.pim_from_deltas import pim_from_deltas

BACKENDS = ("custom", "gtsam")
FACTORS = ("imu", "combined")


def from_export(
    export: Export | str | Path,
    pose_key=gtsam.symbol_shorthand.X,
    vel_key=gtsam.symbol_shorthand.V,
    bias_key=gtsam.symbol_shorthand.B,
    backend: str = "gtsam",
    *,
    factor: str = "imu",
    params: gtsam.PreintegrationParams | None = None,
    bias=None,
) -> tuple[list[gtsam.NonlinearFactor], np.ndarray]:
    """IMU factors between consecutive keyframes of an export (a path or an ``Export``), and the keyframe times
    (K,), s.

    Keys: ``pose_key(k)``, ``vel_key(k)`` and ``bias_key(k)`` for keyframe k (``X(k)``, ``V(k)``, ``B(k)`` by
    default; pass e.g. ``lambda k: X(k + 1)`` to number from 1 as GTSAM's KITTI example does, or ``lambda k: B(0)``
    for one shared bias). The export's samples are already corrected, so its deltas are preintegrated at zero bias
    and each factor corrects for its bias key to first order through the export's bias Jacobians.

    - ``backend="gtsam"`` (default): GTSAM's C++ ``gtsam.ImuFactor`` carrying the export's measurement
      (``pim_from_deltas``); ``"custom"``: ``LearnedImuFactor`` (Python; ``bias_key=None`` drops the bias), the same
      errors and Jacobians, ~10-30x slower to optimise.
    - ``factor="combined"``: ``gtsam.CombinedImuFactor`` (X(k), V(k), X(k+1), V(k+1), B(k), B(k+1)) from the
      export's per-sample corrected samples and learned noise through GTSAM's own preintegration
      (``learned_combined_pim``); needs ``params`` (a ``gtsam.PreintegrationCombinedParams``: gravity, the bias
      random walk, ``bodyPSensor``, ...).
    - ``params`` (a ``gtsam.PreintegrationParams``) with ``factor="imu"``: each interval is preintegrated again from
      the samples by GTSAM (``learned_pim``) so that everything in the params is honoured.
    - ``bias``: a ``gtsam.imuBias.ConstantBias``, or a function of k giving one, to preintegrate each interval around
      (GTSAM's ``biasHat``: re-linearisation, as ``IMUKittiExampleGPS.py`` re-preintegrates at its current bias
      estimate); GTSAM's own preintegration from the samples, with ``params`` or the export's gravity.

    The export's gravity must equal the params' (an error names both): the deltas were integrated with it.
    Whatever a route cannot honour raises: ``backend="custom"`` takes neither ``params`` nor ``bias``.
    """
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r}; known: {', '.join(BACKENDS)}")
    if factor not in FACTORS:
        raise ValueError(f"unknown factor {factor!r}; known: {', '.join(FACTORS)}")
    if backend == "gtsam" and bias_key is None:
        raise ValueError("backend='gtsam' builds gtsam.ImuFactor, which always has a bias key: pass bias_key")
    export = export if isinstance(export, Export) else load_export(export)
    if backend == "custom" and (params is not None or bias is not None or factor != "imu"):
        raise ValueError(
            "backend='custom' (LearnedImuFactor) uses the export's deltas as they are: params=, bias= "
            "and factor='combined' need backend='gtsam'"
        )
    if factor == "combined" and not isinstance(params, gtsam.PreintegrationCombinedParams):
        raise ValueError("factor='combined' needs params=gtsam.PreintegrationCombinedParams(...): the bias random walk")
    if params is not None:
        _check_gravity(export, params)
    if params is not None or bias is not None or factor == "combined":
        return _from_samples(export, pose_key, vel_key, bias_key, factor, params, bias), export.keyframe_t
    factors = []
    for k in range(len(export.delta_dt)):
        if backend == "gtsam":
            pim = pim_from_deltas(
                export.delta_rot[k],
                export.delta_pos[k],
                export.delta_vel[k],
                export.delta_dt[k],
                export.delta_cov[k],
                export.bias_jacobian[k],
                export.gravity,
            )
            factors.append(gtsam.ImuFactor(pose_key(k), vel_key(k), pose_key(k + 1), vel_key(k + 1), bias_key(k), pim))
            continue
        try:
            factors.append(
                LearnedImuFactor(
                    pose_key(k),
                    vel_key(k),
                    pose_key(k + 1),
                    vel_key(k + 1),
                    export.delta_rot[k],
                    export.delta_pos[k],
                    export.delta_vel[k],
                    export.delta_dt[k],
                    export.delta_cov[k],
                    gravity=export.gravity,
                    bias=None if bias_key is None else bias_key(k),
                    bias_jacobian=None if bias_key is None else export.bias_jacobian[k],
                )
            )
        except ValueError as err:
            raise ExportError(f"{export.path}: interval {k}: {err}") from None
    return factors, export.keyframe_t


def _check_gravity(export: Export, params) -> None:
    gravity = np.asarray(params.n_gravity, dtype=float)
    if not np.allclose(gravity, export.gravity, rtol=0, atol=1e-9):
        raise ValueError(
            f"{export.path}: the export was integrated with gravity {export.gravity.tolist()} m/s^2, the params hold "
            f"{gravity.tolist()}: build the params with the export's gravity"
        )


def _from_samples(export: Export, pose_key, vel_key, bias_key, factor: str, params, bias) -> list:
    """Factors from the export's per-sample data through GTSAM's own preintegration (``factors.learned_pim``)."""
    from factors.learned_pim import learned_combined_pim, learned_pim

    dt = np.diff(export.t)
    index = export.keyframe_index
    out = []
    for k in range(len(index) - 1):
        take = slice(int(index[k]), int(index[k + 1]))
        around = bias(k) if callable(bias) else bias
        samples = (export.gyro[take], export.acc[take], dt[take], export.gyro_cov[take], export.acc_cov[take])
        keys = (pose_key(k), vel_key(k), pose_key(k + 1), vel_key(k + 1))
        if factor == "combined":
            pim = learned_combined_pim(*samples, params=params, bias=around)
            out.append(gtsam.CombinedImuFactor(*keys, bias_key(k), bias_key(k + 1), pim))
        else:
            gravity = None if params is not None else export.gravity
            pim = learned_pim(*samples, gravity, bias=around, params=params)
            out.append(gtsam.ImuFactor(*keys, bias_key(k), pim))
    return out
