"""GPS fixes at their own times (issue 37): ``airimu fuse`` with a keyframe at every fix, with ``--keyframes 1s``
(a keyframe at every fix and every second between them), and what ``--keyframes 1s`` did before (each fix applied
at the nearest keyframe of a 1-s grid: emulated by moving each fix's time to that keyframe's).

KITTI raw drives read from ``../shared/data/kitti_raw`` (100 Hz OXTS IMU, raw samples, fixed noise), GPS at 1 Hz
from the ground truth with 0.5 m noise per axis, the first fix ``--phase`` s after the first sample (so fixes lie
between the 1-s keyframes, as a user's GPS clock does). ATE: RMSE over every IMU sample, no alignment (the GPS
frame is the ground truth's). Run:

    python benchmarks/gps_keyframes.py --drive 2011_10_03_drive_0047 --drive 2011_09_30_drive_0028
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np

from airimu.fuse import fuse, imu_rate_trajectory
from airimu_core.sequence import GpsFixes
from fusion.config import FuseConfig
from learned_imu.datasets._assemble import ReadChecks
from learned_imu.datasets.kitti_raw import read_kitti_raw
from learned_imu.evaluation.metrics import ate_m

CHECKS = ReadChecks(on_duplicate="drop", on_gap="keep")  # as configs/kitti.yaml reads the drives
DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "kitti_raw"


def gps_of(sequence, rate_hz: float, phase_s: float, sigma_m: float, seed: int) -> GpsFixes:
    """Fixes every 1 / rate s from ``phase_s`` after the first sample, on the nearest samples, from the truth."""
    times = np.arange(sequence.t[0] + phase_s, sequence.t[-1], 1.0 / rate_hz)
    index = np.unique(np.clip(np.searchsorted(sequence.t, times), 0, len(sequence.t) - 1))
    index = index[sequence.gt.valid[index]]
    noisy = sequence.gt.pos[index] + np.random.default_rng(seed).normal(0.0, sigma_m, (len(index), 3))
    return GpsFixes(sequence.t[index], noisy, np.full((len(index), 3), sigma_m))


def snapped(sequence, fixes: GpsFixes, interval_s: float) -> GpsFixes:
    """The fixes with their times moved to the nearest keyframe of an ``interval_s`` grid (the old behaviour)."""
    step = int(round(interval_s / float(np.median(sequence.dt))))
    grid = sequence.t[np.arange(0, len(sequence.t), step)]
    nearest = np.clip(np.searchsorted(grid, fixes.t), 1, len(grid) - 1)
    nearest = np.where(np.abs(grid[nearest - 1] - fixes.t) <= np.abs(grid[nearest] - fixes.t), nearest - 1, nearest)
    return dataclasses.replace(fixes, t=grid[nearest])


def run(sequence, fixes: GpsFixes, keyframe_s: float | None) -> tuple[float, int, float]:
    config = FuseConfig(keyframe_s=keyframe_s)
    began = time.perf_counter()
    result = fuse(dataclasses.replace(sequence, gps=None), fixes, None, config)
    seconds = time.perf_counter() - began
    dense = imu_rate_trajectory(result)
    sample = np.searchsorted(sequence.t, dense.t)
    keep = sequence.gt.valid[sample]
    ate = ate_m(sequence.gt.pos[sample[keep]], dense.pos[keep], align=False)
    return ate, len(result.solution.trajectory.t), seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--drive", action="append", default=None, help="kitti_raw drive (repeatable)")
    parser.add_argument("--phase", type=float, default=0.42, help="first fix, s after the first sample")
    parser.add_argument("--sigma", type=float, default=0.5, help="GPS noise per axis, m")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    drives = args.drive or ["2011_10_03_drive_0047"]
    print("| drive | keyframes | ATE m | keyframes solved | solve s |")
    print("|---|---|---|---|---|")
    for drive in drives:
        sequence = read_kitti_raw(DATA / f"{drive}.csv", on_backward="drop", checks=CHECKS)
        fixes = gps_of(sequence, 1.0, args.phase, args.sigma, args.seed)
        rows = [
            ("one at every fix", fixes, None),
            ("every fix + every 1 s (--keyframes 1s)", fixes, 1.0),
            ("before: fixes moved to the 1-s grid", snapped(sequence, fixes, 1.0), 1.0),
        ]
        for name, gps, keyframe_s in rows:
            ate, keyframes, seconds = run(sequence, gps, keyframe_s)
            print(f"| {drive} | {name} | {ate:.3f} | {keyframes} | {seconds:.1f} |", flush=True)


if __name__ == "__main__":
    main()
