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

from factors.imu import LearnedImuFactor
from factors.pim_from_deltas import pim_from_deltas

FORMAT_VERSION = 1


class ExportError(ValueError):
    """An export file is missing, of another format version, or malformed; the message names file and field."""


@dataclass(frozen=True, eq=False)
class Export:
    """A loaded export; see ``learned_imu.export`` for every field's shape, unit and frame."""

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
    arrays: dict  # every array of the file, including per-sample data and ground truth when present


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
    except (OSError, ValueError, zipfile.BadZipFile) as err:  # ValueError: object arrays (pickle) refused
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
    return Export(
        path=path,
        name=str(arrays.get("name", path.stem)),
        arrays=arrays,
        **{field: arrays[field] for field in Export.__dataclass_fields__ if field in _SHAPES},
    )


BACKENDS = ("custom", "gtsam")


def from_export(
    path: str | Path,
    pose_key=gtsam.symbol_shorthand.X,
    vel_key=gtsam.symbol_shorthand.V,
    bias_key=None,
    backend: str = "custom",
) -> tuple[list[gtsam.NonlinearFactor], np.ndarray]:
    """IMU factors between consecutive keyframes of an export, and the keyframe times (K,), s.

    Keys are ``pose_key(k)`` and ``vel_key(k)`` for keyframe k (``X(k)``, ``V(k)`` by default); with ``bias_key``
    (e.g. ``gtsam.symbol_shorthand.B``, or ``lambda k: B(0)`` for one shared bias) each factor also corrects for
    the bias ``bias_key(k)``. ``backend="custom"`` gives ``LearnedImuFactor`` (Python); ``"gtsam"`` gives the
    built-in C++ ``gtsam.ImuFactor`` carrying the same measurement (``pim_from_deltas``): identical errors and
    Jacobians, ~10x faster to optimise, and it always needs ``bias_key``.
    """
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r}; known: {', '.join(BACKENDS)}")
    if backend == "gtsam" and bias_key is None:
        raise ValueError("backend='gtsam' builds gtsam.ImuFactor, which always has a bias key: pass bias_key")
    export = load_export(path)
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
