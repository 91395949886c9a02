"""KITTI raw IMU + GPS as GTSAM ships it for ``IMUKittiExampleGPS.py`` (``KittiEquivBiasedImu.txt`` and
``KittiGps_converted.txt``).

Conventions (those of gtsam's ``IMUKittiExampleGPS.py`` loaders):

- IMU file, space separated, one header line ``Time dt accelX accelY accelZ omegaX omegaY omegaZ``: time of day
  of the OXTS clock [s], dt [s] since the previous sample (not used: recomputed from ``Time``), then **accel
  first** (specific force, m/s^2), then gyro (rad/s), in the IMU/body frame (body <- IMU is identity per the
  metadata file; z-up, OXTS forward-left-up).
- The first IMU row has no predecessor (its ``dt`` equals its absolute time) and comes 1.92 s before the second
  one; it is dropped by default (``skip_first=True``), so the remaining stream has no gap.
- GPS file, comma separated, header ``Time,X,Y,Z``: time on the IMU clock [s], position [m] in a local z-up
  (east/north/up-like) frame. Fixes outside the IMU time span are dropped (that is the first fix, 2.9 s before
  the others; gtsam's example also starts at fix 1). ``sigma`` = sqrt(0.07) m per axis, the example's GPS noise
  (``noiseModel.Diagonal.Precisions([0, 0, 0] + [1/0.07] * 3)``: precision 1/0.07, i.e. variance 0.07 m^2).
- Gravity ``[0, 0, -9.8]`` m/s^2 (``PreintegrationParams.MakeSharedU(9.8)`` in the example).
- No ground truth (``gt=None``): the KITTI odometry poses in the shared data are not aligned in time or frame.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from airimu_core.errors import DataError
from airimu_core.sequence import GpsFixes, ImuSequence
from airimu_core.table import read_table
from learned_imu.datasets._assemble import ReadChecks, build_sequence
from learned_imu.datasets._checks import check_timestamps

GRAVITY = 9.8  # m/s^2, as gtsam's IMUKittiExampleGPS.py
GPS_SIGMA = float(np.sqrt(0.07))  # m per axis, from the example's GPS precision 1/0.07
IMU_FILE = "KittiEquivBiasedImu.txt"
GPS_FILE = "KittiGps_converted.txt"
IMU_COLUMNS = ("Time", "dt", "accelX", "accelY", "accelZ", "omegaX", "omegaY", "omegaZ")
GPS_COLUMNS = ("Time", "X", "Y", "Z")
UNUSED_CHECKS = ("crop_to_gt", "check_frame", "vel_window_s")  # ReadChecks fields without ground truth: refused


def read_kitti(
    path: str | Path | None = None,
    *,
    imu_file: str = IMU_FILE,
    gps_file: str | None = GPS_FILE,
    skip_first: bool = True,
    gps_sigma: float = GPS_SIGMA,
    gravity: float = GRAVITY,
    checks: ReadChecks = ReadChecks(),
) -> ImuSequence:
    """Read the GTSAM KITTI IMU (+ GPS) example (see the module docstring for units and frames).

    Args:
        path: folder holding the two files; None: the copies installed with gtsam
            (``gtsam.findExampleDataFile``).
        imu_file, gps_file: file names inside ``path``; ``gps_file=None`` reads the IMU only.
        skip_first: drop the first IMU row (no predecessor, 1.92 s before the second row).
        gps_sigma: one-sigma GPS position noise per axis, m.
        gravity: magnitude of gravity, m/s^2 (world z-up, gravity along -z).
        checks: duplicates, gaps and the units check (``_assemble.ReadChecks``); the fields about ground truth
            (``UNUSED_CHECKS``) are refused unless left at their defaults.
    """
    checks.refuse(UNUSED_CHECKS, "read_kitti", "the files hold no ground truth")
    imu_path = _locate(path, imu_file)
    table = read_table(imu_path, delimiter=None, min_columns=len(IMU_COLUMNS), field="imu")
    raw = table.columns(IMU_COLUMNS if table.header else range(len(IMU_COLUMNS)), "imu")
    table.require_finite(raw, "imu")
    rows = np.arange(raw.shape[0])[1 if skip_first else 0 :]
    unique = check_timestamps(
        raw[rows, 0],
        imu_path,
        "Time",
        on_duplicate=checks.on_duplicate,
        line_of=lambda row: table.line_of(int(rows[row])),
    )
    keep = rows[unique]
    t, acc, gyro = raw[keep, 0], raw[keep, 2:5], raw[keep, 5:8]
    gps = read_gps(_locate(path, gps_file), gps_sigma) if gps_file is not None else None
    return build_sequence(
        "kitti_gtsam",
        imu_path,
        t,
        gyro,
        acc,
        np.array([0.0, 0.0, -gravity]),
        gps=gps,
        checks=checks,
        line_of=lambda row: table.line_of(int(keep[row])),
        gps_source=_locate(path, gps_file) if gps_file is not None else None,
    )


def _locate(path: str | Path | None, name: str) -> Path:
    if path is not None:
        return Path(path) / name
    import importlib.util

    spec = importlib.util.find_spec("gtsam")  # located, not imported: learned_imu never imports gtsam
    found = Path(spec.origin).parent / "Data" / name if spec and spec.origin else None
    if found is None or not found.is_file():
        raise DataError(name, "path", "no path given and gtsam's example data (gtsam/Data) not found; pass path=")
    return found


def read_gps(path: Path, sigma: float) -> GpsFixes:
    """Fixes of a ``Time,X,Y,Z`` file (GTSAM's ``KittiGps_converted.txt``) with ``sigma`` m per axis."""
    if not sigma > 0:
        raise DataError(path, "gps_sigma", f"must be positive, got {sigma}")
    table = read_table(path, delimiter=",", min_columns=len(GPS_COLUMNS), field="gps")
    raw = table.columns(GPS_COLUMNS if table.header else range(len(GPS_COLUMNS)), "gps")
    table.require_finite(raw, "gps")
    keep = check_timestamps(raw[:, 0], path, "Time", line_of=table.line_of)
    return GpsFixes(t=raw[keep, 0], pos=raw[keep, 1:4], sigma=np.full((keep.size, 3), float(sigma)))
