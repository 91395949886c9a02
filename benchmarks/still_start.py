"""A still start without ground truth (issue 38): the raw gyro's bias from its mean rate and roll / pitch from
gravity (``fusion.still``), against the ground truth that ``airimu fuse`` never reads for them.

    python benchmarks/still_start.py

BROAD (every trial of ``../shared/data/broad``: a hand-held consumer IMU, 286 Hz, each starting still): the still
span, the bias found and its sigma, the tilt of the still gravity against the ground truth, and the RMS / final
attitude error of ``airimu fuse --no-gps --start ground-truth`` (raw IMU, keyframes 1 s) over the whole trial
without and with the bias taken out (``fuse.still_start``). KITTI drives that start parked: the keyframe position
RMSE with 1-Hz fixes (ground truth + 0.5 m noise) without and with it.
"""

from __future__ import annotations

import dataclasses
import glob
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from airimu.experiments.pgo import gps_for
from airimu.fuse import fuse, still_summary
from fusion.config import FuseConfig
from learned_imu.datasets import read_sequence

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
KITTI = ("2011_09_26_drive_0018", "2011_09_26_drive_0057", "2011_09_26_drive_0084", "2011_09_28_drive_0039")


def attitude_errors(seq, result) -> tuple[float, float]:
    """RMS and last keyframe attitude error against the ground truth, deg."""
    traj = result.solution.trajectory
    at = np.searchsorted(seq.t, traj.t)
    ok = seq.gt.valid[at]
    error = np.degrees(Rotation.from_matrix(np.einsum("nji,njk->nik", seq.gt.rot[at][ok], traj.rot[ok])).magnitude())
    return float(np.sqrt(np.mean(error**2))), float(error[-1])


def main() -> None:
    head = "| BROAD trial | still s | gyro bias mrad/s (sigma) | tilt error deg (sigma) | attitude RMS / end, kept |"
    print(head + " taken out | trial s |")
    print("|---|---|---|---|---|---|---|")
    for path in sorted(glob.glob(str(DATA / "broad" / "*.mat"))):
        seq = read_sequence("broad", path)
        runs = {
            on: fuse(seq, None, None, FuseConfig(keyframe_s=1.0, still_start=on), start="ground-truth")
            for on in (False, True)
        }
        still = runs[True].still
        if still is None:
            print(f"| {Path(path).stem} | none | | | | | |")
            continue
        summary = still_summary(runs[True])
        kept, out = attitude_errors(seq, runs[False]), attitude_errors(seq, runs[True])
        bias = ", ".join(f"{b * 1e3:.2f}" for b in still.gyro_bias)
        print(
            f"| {Path(path).stem} | {still.duration_s:.1f} | {bias} ({still.gyro_bias_sigma.max() * 1e3:.3f}) | "
            f"{summary['tilt_error_deg']:.2f} ({summary['tilt_sigma_deg']:.2f}) | {kept[0]:.1f} / {kept[1]:.1f} | "
            f"{out[0]:.1f} / {out[1]:.1f} | {seq.t[-1] - seq.t[0]:.0f} |",
            flush=True,
        )
    print(
        "\n| KITTI drive | still s | gyro bias mrad/s | keyframe RMSE m, bias kept | taken out |\n|---|---|---|---|---|"
    )
    for drive in KITTI:
        seq = read_sequence(
            "kitti_raw", DATA / "kitti_raw" / f"{drive}.csv", on_backward="drop", on_duplicate="drop", on_gap="keep"
        )
        fixes = gps_for(seq, 1.0, 0.5, seed=0, source="simulated")[0]
        blind = dataclasses.replace(seq, gps=None)
        rmse, still = {}, None
        for on in (False, True):
            result = fuse(blind, fixes, None, FuseConfig(keyframe_s=1.0, still_start=on))
            traj = result.solution.trajectory
            at = np.searchsorted(seq.t, traj.t)
            ok = seq.gt.valid[at]
            rmse[on] = float(np.sqrt(np.mean(np.sum((traj.pos[ok] - seq.gt.pos[at][ok]) ** 2, axis=1))))
            still = result.still if on else still
        span = f"{still.duration_s:.1f}" if still else "none"
        bias = ", ".join(f"{b * 1e3:.2f}" for b in still.gyro_bias) if still else ""
        print(f"| {drive} | {span} | {bias} | {rmse[False]:.3f} | {rmse[True]:.3f} |", flush=True)


if __name__ == "__main__":
    main()
