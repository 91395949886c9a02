"""Read an export (``learned_imu.export``, format version 1) and turn it into GTSAM factors.

The loader is numpy-only and validates every array's presence, shape and finiteness and the format version,
naming the file and the field on failure; it never unpickles (``allow_pickle=False``).
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

import gtsam
import numpy as np

from factors.checks import gravity_problem, preintegration_problem
from factors.imu import LearnedImuFactor
from factors.pim_from_deltas import pim_from_deltas

FORMAT_VERSION = 1


class ExportError(ValueError):
    """An export file is missing, of another format version, or malformed; the message names file and field."""


@dataclass(frozen=True, eq=False)
class ExportTruth:
    """An export's ground truth at its N samples: ``rot`` (N, 3, 3) world <- IMU, ``pos`` (N, 3) m, ``vel`` (N, 3)
    m/s (world frame), ``valid`` (N,) bool."""

    rot: np.ndarray
    pos: np.ndarray
    vel: np.ndarray
    valid: np.ndarray


@dataclass(frozen=True, eq=False)
class Export:
    """A loaded export; see ``learned_imu.export`` for every field's shape, unit and frame. Per sample (N): ``t`` s,
    ``gyro`` rad/s, ``acc`` m/s^2 (IMU frame; the corrected samples when a model ran), ``gyro_cov`` rad^2/s and
    ``acc_cov`` m^2/s^3 (sigma^2 densities); ``truth`` when the file has ground truth."""

    path: Path
    name: str
    gravity: np.ndarray
    keyframe_t: np.ndarray
    keyframe_index: np.ndarray
    delta_rot: np.ndarray
    delta_pos: np.ndarray
    delta_vel: np.ndarray
    delta_dt: np.ndarray
    delta_cov: np.ndarray
    bias_jacobian: np.ndarray
    t: np.ndarray
    gyro: np.ndarray
    acc: np.ndarray
    gyro_cov: np.ndarray
    acc_cov: np.ndarray
    truth: ExportTruth | None
    arrays: dict  # every array of the file as read (the fields above are the typed view)


_SHAPES = {  # field -> shape with "N" samples, "K" keyframes, "I" intervals
    "gravity": (3,),
    "t": ("N",),
    "gyro": ("N", 3),
    "acc": ("N", 3),
    "gyro_cov": ("N", 3),
    "acc_cov": ("N", 3),
    "keyframe_t": ("K",),
    "keyframe_index": ("K",),
    "delta_rot": ("I", 3, 3),
    "delta_pos": ("I", 3),
    "delta_vel": ("I", 3),
    "delta_dt": ("I",),
    "delta_cov": ("I", 9, 9),
    "bias_jacobian": ("I", 9, 6),
}


def load_export(path: str | Path) -> Export:
    """Load and validate an export file."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {key: data[key] for key in data.files}
    except FileNotFoundError:
        raise ExportError(f"{path}: file not found") from None
    except ValueError as err:  # numpy's text goes on to advise allow_pickle=True: not passed on
        problem = "it is not a zip of arrays, or holds object arrays that would need unpickling, which is refused"
        raise ExportError(f"{path}: not a readable .npz export ({problem})") from err
    except (OSError, zipfile.BadZipFile) as err:
        raise ExportError(f"{path}: not a readable .npz export ({err})") from None
    if "format_version" not in arrays:
        raise ExportError(f"{path}: field 'format_version' is missing: not an airimu export")
    version = int(arrays["format_version"])
    if version != FORMAT_VERSION:
        raise ExportError(f"{path}: field 'format_version' is {version}; this reader reads version {FORMAT_VERSION}")
    sizes = {"N": len(arrays.get("t", [])), "K": len(arrays.get("keyframe_t", []))}
    sizes["I"] = sizes["K"] - 1
    for field, shape in _SHAPES.items():
        if field not in arrays:
            raise ExportError(f"{path}: field '{field}' is missing")
        want = tuple(sizes[s] if isinstance(s, str) else s for s in shape)
        if arrays[field].shape != want:
            raise ExportError(f"{path}: field '{field}' has shape {arrays[field].shape}, expected {want}")
        if not np.all(np.isfinite(arrays[field])):
            raise ExportError(f"{path}: field '{field}' contains NaN or Inf")
    if sizes["I"] < 1:
        raise ExportError(f"{path}: field 'keyframe_t' needs at least two keyframes")
    _check_consistent(path, arrays, sizes["N"])
    return Export(
        path=path,
        name=str(arrays.get("name", path.stem)),
        arrays=arrays,
        truth=_truth(path, arrays, sizes["N"]),
        **{field: arrays[field] for field in Export.__dataclass_fields__ if field in _SHAPES},
    )


_TRUTH_SHAPES = {"gt_rot": (3, 3), "gt_pos": (3,), "gt_vel": (3,), "gt_valid": ()}  # per sample


def _truth(path: Path, arrays: dict, n: int) -> ExportTruth | None:
    """The ground truth of the file, all four fields or none; shapes checked (NaN allowed where not valid)."""
    present = [field for field in _TRUTH_SHAPES if field in arrays]
    if not present:
        return None
    for field, shape in _TRUTH_SHAPES.items():
        if field not in arrays:
            raise ExportError(f"{path}: field '{field}' is missing (the file has {', '.join(present)})")
        if arrays[field].shape != (n, *shape):
            raise ExportError(f"{path}: field '{field}' has shape {arrays[field].shape}, expected {(n, *shape)}")
    return ExportTruth(arrays["gt_rot"], arrays["gt_pos"], arrays["gt_vel"], arrays["gt_valid"].astype(bool))


def _check_consistent(path: Path, arrays: dict, n: int) -> None:
    """The checks every backend needs (``factors.checks``): measurements, gravity, keyframes that index the
    samples in order, positive noise densities."""
    problem = preintegration_problem(arrays["delta_rot"], arrays["delta_dt"], arrays["delta_cov"])
    if problem is not None:
        k, why = problem
        field = why.split(" ", 1)[0]
        raise ExportError(f"{path}: field '{field}', interval {k}: {why}")
    why = gravity_problem(arrays["gravity"])
    if why:
        raise ExportError(f"{path}: field 'gravity': {why}")
    index, kt, t = arrays["keyframe_index"], arrays["keyframe_t"], arrays["t"]
    if not np.issubdtype(index.dtype, np.integer) or np.any(np.diff(index) <= 0) or index[0] < 0 or index[-1] >= n:
        raise ExportError(f"{path}: field 'keyframe_index' must be strictly increasing sample indices in [0, {n - 1}]")
    if np.any(np.diff(t) <= 0):
        raise ExportError(f"{path}: field 't' must be strictly increasing")
    if np.abs(kt - t[index]).max() > 1e-6:
        raise ExportError(f"{path}: field 'keyframe_t' differs from t[keyframe_index] (s)")
    if np.abs(arrays["delta_dt"] - np.diff(kt)).max() > 1e-6:
        raise ExportError(f"{path}: field 'delta_dt' differs from the keyframe times' differences (s)")
    for field in ("gyro_cov", "acc_cov"):
        if not np.all(arrays[field] > 0):
            raise ExportError(f"{path}: field '{field}' must hold positive noise densities (sigma^2)")


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
        raise ValueError("backend='custom' (LearnedImuFactor) uses the export's deltas as they are: params=, bias= "
                         "and factor='combined' need backend='gtsam'")  # fmt: skip
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
                export.delta_rot[k], export.delta_pos[k], export.delta_vel[k], export.delta_dt[k],
                export.delta_cov[k], export.bias_jacobian[k], export.gravity,
            )  # fmt: skip
            factors.append(gtsam.ImuFactor(pose_key(k), vel_key(k), pose_key(k + 1), vel_key(k + 1), bias_key(k), pim))
            continue
        try:
            factors.append(
                LearnedImuFactor(
                    pose_key(k), vel_key(k), pose_key(k + 1), vel_key(k + 1),
                    export.delta_rot[k], export.delta_pos[k], export.delta_vel[k], export.delta_dt[k],
                    export.delta_cov[k], gravity=export.gravity,
                    bias=None if bias_key is None else bias_key(k),
                    bias_jacobian=None if bias_key is None else export.bias_jacobian[k],
                )
            )  # fmt: skip
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
