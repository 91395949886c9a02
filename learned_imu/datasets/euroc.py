"""EuRoC MAV sequences in the ASL folder layout, read unchanged (TUM-VI exports: ``learned_imu.datasets.tumvi``).

Layout: ``<seq>/mav0/imu0/data.csv`` and, optionally, ground truth in ``<seq>/mav0/state_groundtruth_estimate0/``
as the official ``data.csv`` or a TUM-format ``groundtruth_tum.txt`` (the official file wins when both exist).

Conventions:

- IMU ``data.csv``: ``t [ns], w_RS_S (3) [rad/s], a_RS_S (3) [m/s^2]``, comma separated; gyro and specific force
  in the IMU frame S (= body frame, T_BS = identity). Time becomes seconds (``ns * 1e-9``, absolute, float64:
  ~0.25 us resolution, fine for the time steps; spreadsheet-rounded stamps are accepted as they are).
- Official ground truth (``.csv``): 17 columns ``t [ns], p_RS_R (3) [m], q_RS (w, x, y, z), v_RS_R (3) [m/s],
  b_w (3), b_a (3)``; the file velocity is used, biases are ignored. An 8-column ASL pose file (no velocity) is
  accepted too and its velocity differentiated. ``q_RS`` rotates S-vectors into R: it is world <- IMU directly.
- TUM ground truth (``.txt``): ``t [s], p (3) [m], q (x, y, z, w)``, space separated, no velocity: velocity is
  differentiated from the positions (local cubic fit over 0.05 s, see ``_assemble``; 3.2 mm/s rms against the
  official velocity on V1_02).
- World R (Leica / Vicon frame) is z-up; gravity ``[0, 0, -9.81007]`` m/s^2 as AirIMU uses.
- The IMU is cropped to the ground-truth span (``crop_to_gt=True``; ground truth starts ~1 s after the IMU);
  ground truth is resampled to the IMU stamps (linear / slerp), gaps longer than 5 GT steps -> ``valid=False``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from airimu_core.errors import DataError
from airimu_core.sequence import ImuSequence
from airimu_core.table import read_table
from learned_imu.datasets._assemble import GtSamples, ReadChecks, build_sequence, resolve
from learned_imu.datasets._checks import OnDuplicate, check_timestamps

log = logging.getLogger(__name__)
GRAVITY = 9.81007  # m/s^2, the value AirIMU uses for EuRoC
NS = 1e-9
IMU_FILE = Path("mav0/imu0/data.csv")
GT_DIR = Path("mav0/state_groundtruth_estimate0")
GT_FILES = (GT_DIR / "data.csv", GT_DIR / "groundtruth_tum.txt")
ASL_POSE_COLUMNS = 8  # t, p(3), q_wxyz(4)
ASL_STATE_COLUMNS = 11  # ... + v(3); the official file has 17 (+ b_w, b_a)
TUM_COLUMNS = 8  # t, p(3), q_xyzw(4)


def read_euroc(
    path: str | Path,
    *,
    imu_file: str | Path | None = None,
    gt_file: str | Path | None = None,
    ground_truth: bool = True,
    gravity: float = GRAVITY,
    checks: ReadChecks = ReadChecks(),
) -> ImuSequence:
    """Read one EuRoC / TUM-VI sequence folder (the one holding ``mav0/``).

    Args:
        path: the sequence folder.
        imu_file: IMU csv relative to ``path`` (or absolute); default ``mav0/imu0/data.csv``.
        gt_file: ground-truth file relative to ``path`` (or absolute); ``.txt`` is read as TUM, anything else as
            ASL. Default: the official ``data.csv``, else ``groundtruth_tum.txt``, else no ground truth.
        ground_truth: False to ignore any ground truth.
        gravity: magnitude of gravity, m/s^2 (world z-up, gravity along -z).
        checks: duplicates, gaps, crop, self-checks, velocity window (``_assemble.ReadChecks``); ``on_duplicate``
            applies to the IMU and the ground truth.
    """
    root = Path(path)
    if not root.is_dir():
        raise DataError(root, "path", "not a directory (expected a EuRoC sequence folder holding mav0/)")
    imu_path = resolve(root, imu_file or IMU_FILE)
    imu = read_asl_imu(imu_path, checks.on_duplicate)
    gt = None
    if ground_truth:
        gt_path = (
            resolve(root, gt_file)
            if gt_file is not None
            else next((root / f for f in GT_FILES if (root / f).is_file()), None)
        )
        if gt_path is not None:
            gt = read_euroc_ground_truth(gt_path, on_duplicate=checks.on_duplicate)
        elif (root / GT_DIR).is_dir():
            there = sorted(p.name for p in (root / GT_DIR).iterdir())
            log.warning(
                "%s: no ground truth read: the folder holds %s, not %s (pass gt_file=...)",
                root / GT_DIR,
                there or "nothing",
                " or ".join(f.name for f in GT_FILES),
            )
    return build_sequence(
        root.name,
        imu_path,
        imu.t,
        imu.gyro,
        imu.acc,
        np.array([0.0, 0.0, -gravity]),
        gt=gt,
        checks=checks,
        line_of=imu.line_of,
    )


@dataclass(frozen=True, eq=False)
class AslImu:
    """An ASL ``imu0/data.csv`` as read: time (N,) s, gyro and acc (N, 3), and the file line of each sample."""

    t: np.ndarray
    gyro: np.ndarray
    acc: np.ndarray
    line_of: Callable[[int], int | None]


def read_asl_imu(path: Path, on_duplicate: OnDuplicate = "error", hint: str = "pass imu_file=...") -> AslImu:
    """``t [ns], gyro (3), acc (3)`` rows of an ASL IMU csv (EuRoC, TUM-VI), finite, time stamps checked; a
    missing file names the files beside it and ``hint``."""
    if not path.is_file():
        folder = path.parent
        there = sorted(p.name for p in folder.iterdir()) if folder.is_dir() else []
        raise DataError(path, "imu_file", f"IMU file not found (files in {folder}: {there or 'none'}; {hint})")
    table = read_table(path, delimiter=",", min_columns=7, field="imu")
    raw = table.data[:, :7]
    table.require_finite(raw, "imu")
    keep = check_timestamps(raw[:, 0] * NS, path, "t", on_duplicate=on_duplicate, line_of=table.line_of)
    raw = raw[keep]
    return AslImu(raw[:, 0] * NS, raw[:, 1:4], raw[:, 4:7], lambda row: table.line_of(int(keep[row])))


def read_euroc_ground_truth(path: str | Path, *, on_duplicate: OnDuplicate = "error") -> GtSamples:
    """Ground truth at its own stamps from an ASL ``data.csv`` or a TUM ``.txt`` (see the module docstring)."""
    path = Path(path)
    if not path.is_file():
        raise DataError(path, "gt_file", "ground-truth file not found")
    tum = path.suffix == ".txt"
    if tum:
        table = read_table(path, delimiter=None, min_columns=TUM_COLUMNS, field="gt")
        t, pos, quat, order, vel = table.data[:, 0], table.data[:, 1:4], table.data[:, 4:8], "xyzw", None
    else:
        table = read_table(path, delimiter=",", min_columns=ASL_POSE_COLUMNS, field="gt")
        t, pos, quat, order = table.data[:, 0] * NS, table.data[:, 1:4], table.data[:, 4:8], "wxyz"
        vel = table.data[:, 8:11] if table.data.shape[1] >= ASL_STATE_COLUMNS else None
    table.require_finite(t[:, None], "gt.t")
    keep = check_timestamps(t, path, "gt.t", on_duplicate=on_duplicate, line_of=table.line_of)
    vel = vel[keep] if vel is not None else None
    return GtSamples.from_quaternions(t[keep], quat[keep], order, pos[keep], vel, path)
