"""TUM-VI sequences (the TUM VI benchmark's ASL export, e.g. ``dataset-room2_512_16``), read unchanged.

Layout: ``<seq>/mav0/imu0/data.csv`` (the IMU as TUM-VI calibrated it: the official export's file) and the
motion-capture ground truth ``<seq>/mav0/mocap0/data.csv``; optionally ``<seq>/mav0/imu0/data_raw.csv``, the same
samples before TUM-VI's calibration (``imu="raw"``; the shared copy holds it, see ``../shared/data/tumvi/README.md``).
Anything else an official download holds (``cam0/``, ``cam1/``, ``dso/``) is ignored.

Conventions:

- IMU (both files): ``t [ns], w_RS_S (3) [rad/s], a_RS_S (3) [m/s^2]``, comma separated (the raw file's header
  has no ``#`` and ``", "`` separators; both read); IMU frame S = body frame. The IMU runs at 199.4 Hz: time steps
  are the stamps' (never a nominal 5 ms).
- Ground truth (``mocap0/data.csv``): ``t [ns], p_RS_R (3) [m], q_RS (w, x, y, z)`` at 120 Hz on the IMU's clock,
  ``q_RS`` world R <- IMU S; R is z-up, gravity ``[0, 0, -9.81007]`` m/s^2 (AirIMU's value; TUM-VI's calibrated
  accelerometer measures 9.77-9.80 m/s^2 at rest, README of the shared copy).
- Resampled to the IMU stamps (linear / slerp). An IMU sample is **valid** only when the mocap stamps on both
  sides of it are within ``max_gt_distance_s`` (10 ms, the rule of the official AirIMU loader, which keeps a sample
  when the next mocap stamp is < 10 ms away; here the previous one must be too, so no value interpolated across a
  hole counts). The mocap stream has holes (marker occlusions, up to 3.2 s); the IMU is cropped to the span of the
  ground truth; invalid samples stay in the sequence and no window uses them.
- Velocity: the mocap holds none. It is the derivative of a local cubic fitted to the positions over a centred
  window of ``vel_window_s`` (``TUMVI_VEL_WINDOW_S`` by default, a Savitzky-Golay filter on the actual stamps,
  ``_assemble.differentiate_positions``), chosen against the IMU: over 1 s, the velocity change of the ground truth
  matches the calibrated IMU's integrated specific force best at this window on every room
  (tests/learned_imu/datasets/test_tumvi.py; the plain 0.05 s window of the EuRoC reader follows the mocap's
  jitter).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Literal

import numpy as np

from airimu_core.errors import DataError
from airimu_core.sequence import ImuSequence
from learned_imu.datasets._assemble import VEL_WINDOW_S, ReadChecks, build_sequence, resolve
from learned_imu.datasets.euroc import GRAVITY, read_asl_imu, read_euroc_ground_truth

TumviImu = Literal["calibrated", "raw"]
IMU_FILES = {"calibrated": Path("mav0/imu0/data.csv"), "raw": Path("mav0/imu0/data_raw.csv")}
GT_FILE = Path("mav0/mocap0/data.csv")
MAX_GT_DISTANCE_S = 0.01  # s; a sample farther than this from a mocap stamp on either side is not ground truth
TUMVI_VEL_WINDOW_S = 0.2  # s; the velocity differentiation window used where vel_window_s is left at its default


def read_tumvi(
    path: str | Path,
    *,
    imu: TumviImu = "calibrated",
    imu_file: str | Path | None = None,
    gt_file: str | Path | None = None,
    ground_truth: bool = True,
    gravity: float = GRAVITY,
    max_gt_distance_s: float = MAX_GT_DISTANCE_S,
    checks: ReadChecks = ReadChecks(),
) -> ImuSequence:
    """Read one TUM-VI sequence folder (the one holding ``mav0/``).

    Args:
        path: the sequence folder.
        imu: ``"calibrated"`` (``mav0/imu0/data.csv``, TUM-VI's calibrated IMU) or ``"raw"``
            (``mav0/imu0/data_raw.csv``, the same samples uncalibrated).
        imu_file: an IMU csv relative to ``path`` (or absolute) in place of the one ``imu`` names.
        gt_file: the ground-truth file relative to ``path`` (or absolute); default ``mav0/mocap0/data.csv``.
        ground_truth: False to ignore the ground truth.
        gravity: magnitude of gravity, m/s^2 (world z-up, gravity along -z).
        max_gt_distance_s: s, the validity rule (module docstring).
        checks: duplicates, gaps, crop, self-checks, velocity window (``_assemble.ReadChecks``); its
            ``vel_window_s`` at ``ReadChecks``' default (0.05 s) means ``TUMVI_VEL_WINDOW_S``: an explicit 0.05 is
            taken for the default too (give e.g. 0.0501 for EuRoC's window).
    """
    root = Path(path)
    if not root.is_dir():
        raise DataError(root, "path", "not a directory (expected a TUM-VI sequence folder holding mav0/)")
    if imu not in IMU_FILES:
        raise DataError(root, "imu", f"expected one of {', '.join(IMU_FILES)}, got {imu!r}")
    if not (isinstance(max_gt_distance_s, int | float) and 0 < max_gt_distance_s <= 1.0):
        raise DataError(root, "max_gt_distance_s", f"expected seconds in (0, 1], got {max_gt_distance_s!r}")
    imu_path = resolve(root, imu_file or IMU_FILES[imu])
    raw_hint = imu == "raw" and imu_file is None
    samples = read_asl_imu(
        imu_path,
        checks.on_duplicate,
        "the official download has no raw csv: pass imu_file=... to a raw export" if raw_hint else "pass imu_file=...",
    )
    gt = None
    if ground_truth:
        gt_path = resolve(root, gt_file or GT_FILE)
        if not gt_path.is_file():
            problem = "ground-truth file not found (pass ground_truth=False to read the IMU alone)"
            raise DataError(gt_path, "gt_file", problem)
        gt = read_euroc_ground_truth(gt_path, on_duplicate=checks.on_duplicate)
    if checks.vel_window_s == VEL_WINDOW_S:
        checks = replace(checks, vel_window_s=TUMVI_VEL_WINDOW_S)
    return build_sequence(
        root.name,
        imu_path,
        samples.t,
        samples.gyro,
        samples.acc,
        np.array([0.0, 0.0, -gravity]),
        gt=gt,
        checks=checks,
        line_of=samples.line_of,
        max_gt_distance_s=float(max_gt_distance_s),
    )
