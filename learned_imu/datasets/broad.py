"""BROAD (Berlin Robust Orientation Estimation Assessment Dataset) trials, ``.mat`` or ``.hdf5`` files.

``.mat`` (MATLAB v5) is read with ``scipy.io.loadmat``, ``.hdf5``/``.h5`` with h5py: both copies hold the same
arrays under the same names (``sampling_rate`` may be a dataset or a file attribute in the HDF5 copy).

Conventions (from the dataset's ``info`` text and README, confirmed by the frame self-check on all 17 trials):

- ``imu_gyr`` (N, 3) rad/s, ``imu_acc`` (N, 3) m/s^2 specific force, IMU frame; ``imu_mag`` is not read.
- ``opt_quat`` (N, 4) (w, x, y, z): orientation of the IMU w.r.t. an ENU reference frame, already aligned to the
  IMU frame by the dataset authors, so it converts to world <- IMU directly. World = ENU, z-up.
- ``opt_pos`` (N, 3) **m** (not mm): position of the optical rigid body's origin in ENU, which is not
  necessarily the IMU centre (lever arm undocumented); velocity is differentiated from it (``_assemble``).
- Time: the file has no stamps; ``t = k / sampling_rate`` (285.714 Hz), starting at 0.
- Ground truth shares the IMU time grid: rows with NaN (marker occlusion) get ``valid=False`` exactly (the
  nearest GT row of each IMU sample is the same row; see ``_assemble``).
- Gravity: ``[0, 0, -9.81]`` m/s^2 (Berlin's normal gravity is 9.813; the difference is below IMU bias).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from airimu_core.errors import DataError
from airimu_core.sequence import ImuSequence
from learned_imu.datasets._assemble import GtSamples, ReadChecks, build_sequence

GRAVITY = 9.81
FIELDS = {"imu_gyr": 3, "imu_acc": 3, "opt_quat": 4, "opt_pos": 3}
UNUSED_CHECKS = ("on_duplicate",)  # ReadChecks fields refused unless at their defaults: stamps are never repeated


def read_broad(
    path: str | Path,
    *,
    ground_truth: bool = True,
    gravity: float = GRAVITY,
    checks: ReadChecks = ReadChecks(),
) -> ImuSequence:
    """Read one BROAD trial, ``.mat`` or ``.hdf5`` (see the module docstring for units and frames).

    Args:
        path: the ``.mat`` or ``.hdf5`` file.
        ground_truth: False to ignore the optical reference.
        gravity: magnitude of gravity, m/s^2 (world ENU z-up, gravity along -z).
        checks: gaps, crop, self-checks, velocity window (``_assemble.ReadChecks``); ``on_duplicate`` is refused
            unless left at its default (the stamps are the sample index over the rate).
    """
    checks.refuse(UNUSED_CHECKS, "read_broad", "its stamps are the sample index over the rate, never repeated")
    path = Path(path)
    if not path.is_file():
        raise DataError(path, "path", "file not found")
    mat = _load_hdf5(path) if path.suffix.lower() in (".hdf5", ".h5") else _load_mat(path)
    arrays = {name: _field(mat, name, width, path) for name, width in FIELDS.items()}
    n = arrays["imu_gyr"].shape[0]
    for name, value in arrays.items():
        if value.shape[0] != n:
            raise DataError(path, name, f"{value.shape[0]} rows, expected {n} like imu_gyr")
    for name in ("imu_gyr", "imu_acc"):
        bad = ~np.isfinite(arrays[name]).all(axis=1)
        if bad.any():
            raise DataError(path, name, f"non-finite value at sample {int(np.argmax(bad))}")
    rate = _sampling_rate(mat, path)
    t = np.arange(n) / rate
    gt = None
    if ground_truth:
        gt = GtSamples.from_quaternions(t, arrays["opt_quat"], "wxyz", arrays["opt_pos"], None, path, "opt_quat")
    return build_sequence(
        path.stem,
        path,
        t,
        arrays["imu_gyr"],
        arrays["imu_acc"],
        np.array([0.0, 0.0, -gravity]),
        gt=gt,
        checks=checks,
    )


def _load_mat(path: Path) -> dict:
    import scipy.io

    try:
        return scipy.io.loadmat(path, variable_names=[*FIELDS, "sampling_rate"])
    except (ValueError, OSError, NotImplementedError) as err:
        raise DataError(path, "path", f"not a readable MATLAB v5 file: {err}") from err


def _load_hdf5(path: Path) -> dict:
    import h5py

    try:
        with h5py.File(path, "r") as f:
            out = {name: f[name][()] for name in [*FIELDS, "sampling_rate"] if name in f}
            if "sampling_rate" not in out and "sampling_rate" in f.attrs:
                out["sampling_rate"] = np.asarray(f.attrs["sampling_rate"])
            return out
    except OSError as err:
        raise DataError(path, "path", f"not a readable HDF5 file: {err}") from err


def _field(mat: dict, name: str, width: int, path: Path) -> np.ndarray:
    if name not in mat:
        raise DataError(path, name, "missing from the file (is this a BROAD trial?)")
    value = np.asarray(mat[name], dtype=np.float64)
    if value.ndim != 2 or value.shape[1] != width:
        raise DataError(path, name, f"expected shape (N, {width}), got {value.shape}")
    return value


def _sampling_rate(mat: dict, path: Path) -> float:
    if "sampling_rate" not in mat:
        raise DataError(path, "sampling_rate", "missing from the file")
    rate = float(np.asarray(mat["sampling_rate"]).ravel()[0])
    if not np.isfinite(rate) or rate <= 0:
        raise DataError(path, "sampling_rate", f"expected a positive rate in Hz, got {rate}")
    return rate
