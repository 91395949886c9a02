"""The preintegration handed from torch to GTSAM: an ``Export`` (keyframe deltas, their 9x9 covariances and bias
Jacobians, the samples and their noise), built in memory by ``learned_imu.export.preintegration_export`` and turned
into factors by ``factors.from_export``; between processes the same arrays travel as a ``.npz``
(``save_export`` / ``load_export``, never unpickled). Numpy only.

Format version 1 (every array named as in the ``.npz``):

- ``format_version`` () int; ``name`` () str; ``gravity`` (3,) world-frame gravity vector, m/s^2.
- per sample (N): ``t`` s; ``gyro`` rad/s and ``acc`` m/s^2 (the samples used: corrected ones when a model
  ran), IMU frame; ``gyro_cov`` rad^2/s and ``acc_cov`` m^2/s^3, continuous-time noise densities (diagonal).
- per keyframe (K): ``keyframe_t`` s and ``keyframe_index`` (the sample at which the keyframe's state is taken).
- per keyframe interval (K - 1): ``delta_rot`` (3, 3), ``delta_pos`` (3,) m, ``delta_vel`` (3,) m/s, ``delta_dt``
  s: the preintegrated deltas from keyframe k to k + 1; ``delta_cov`` (9, 9) in GTSAM's tangent order
  [rotation, position, velocity] and noise convention (``preintMeasCov``); ``bias_jacobian`` (9, 6) w.r.t. a
  bias [acc, gyro] subtracted from the samples.
- ground truth when known: ``gt_rot`` (N, 3, 3) world <- IMU, ``gt_pos`` (N, 3), ``gt_vel`` (N, 3), ``gt_valid``.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from airimu_core.checks import gravity_problem, preintegration_problem
from airimu_core.errors import ExportError

FORMAT_VERSION = 1


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

    path: Path | None  # the file it was read from; None for one built in memory
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
    """Load and validate an export file (``.npz``, never unpickled)."""
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
    return export_from_arrays(arrays, path)


def export_from_arrays(arrays: dict, path: Path | None = None) -> Export:
    """An ``Export`` from the arrays of the format (module docstring), validated as ``load_export`` validates a
    file: every field's presence, shape and finiteness, the format version, the measurements and the keyframes.
    ``path`` names the file in errors (None: the export is named by its ``name`` field)."""
    where = path if path is not None else f"export {str(arrays.get('name', '?'))!r}"
    if "format_version" not in arrays:
        raise ExportError(f"{where}: field 'format_version' is missing: not an airimu export")
    version = int(arrays["format_version"])
    if version != FORMAT_VERSION:
        raise ExportError(f"{where}: field 'format_version' is {version}; this reader reads version {FORMAT_VERSION}")
    sizes = {"N": len(arrays.get("t", [])), "K": len(arrays.get("keyframe_t", []))}
    sizes["I"] = sizes["K"] - 1
    for field, shape in _SHAPES.items():
        if field not in arrays:
            raise ExportError(f"{where}: field '{field}' is missing")
        want = tuple(sizes[s] if isinstance(s, str) else s for s in shape)
        if arrays[field].shape != want:
            raise ExportError(f"{where}: field '{field}' has shape {arrays[field].shape}, expected {want}")
        if not np.all(np.isfinite(arrays[field])):
            raise ExportError(f"{where}: field '{field}' contains NaN or Inf")
    if sizes["I"] < 1:
        raise ExportError(f"{where}: field 'keyframe_t' needs at least two keyframes")
    _check_consistent(where, arrays, sizes["N"])
    return Export(
        path=path,
        name=str(arrays.get("name", path.stem if path is not None else "export")),
        arrays=arrays,
        truth=_truth(where, arrays, sizes["N"]),
        **{field: arrays[field] for field in Export.__dataclass_fields__ if field in _SHAPES},
    )


def save_export(export: Export, path: str | Path) -> Path:
    """Write ``export`` as a ``.npz`` (its ``arrays``), atomically: the route between processes."""
    from airimu_core.io import atomic_file

    with atomic_file(path, "wb") as f:
        np.savez(f, **export.arrays)
    return Path(path)


_TRUTH_SHAPES = {"gt_rot": (3, 3), "gt_pos": (3,), "gt_vel": (3,), "gt_valid": ()}  # per sample


def _truth(path, arrays: dict, n: int) -> ExportTruth | None:
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


def _check_consistent(path, arrays: dict, n: int) -> None:
    """The checks every backend needs (``airimu_core.checks``): measurements, gravity, keyframes that index the
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
