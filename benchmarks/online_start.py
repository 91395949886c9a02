"""A start without ground truth in ``OnlineFusion`` (issue 38, part 4): the first state found from the stream
(``fusion.align``: roll / pitch from gravity, the raw gyro's bias from a still start, heading by search once the
GPS track shows the platform accelerating) against the ground truth it never reads.

    python benchmarks/online_start.py

Raw IMU with ``FuseConfig``'s default densities (no model), keyframes every 1 s, ISAM2, 1-Hz fixes from the ground
truth with 0.3 m noise, fed as a driver would (blocks of 10 samples, each fix after the samples before it). Per
sequence: the IMU time the start waited for, the heading's sigma the search found, the error of the aligned first
state against the ground truth (tilt and heading, deg; velocity, m/s), and the keyframe position RMSE (m) of the
whole run from that start against the run started from the ground truth. Beside it, the batch estimator on the
same data (``airimu.fuse.fuse`` without ``start``: aligned to the GPS track by ``fusion.initial.aligned_first_state``,
then solved with all of it): the same errors of its first keyframe's solved state, and its RMSE.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import gtsam
import numpy as np

from airimu.experiments.pgo import gps_for
from airimu.fuse import fuse
from fusion.config import FuseConfig, OnlineSettings
from fusion.online import OnlineFusion
from learned_imu.datasets import read_sequence
from learned_imu.datasets.simulator import simulate

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
BLOCK = 10
SEQUENCES = (
    ("simulator", "drone", 1),
    ("simulator", "car", 1),
    ("simulator", "handheld", 1),
    ("euroc", "MH_04_difficult", 0),
    ("euroc", "V1_03_difficult", 0),
    ("euroc", "V2_02_medium", 0),
    ("kitti_raw", "2011_09_26_drive_0014", 0),
    ("kitti_raw", "2011_09_26_drive_0018", 0),
    ("kitti_raw", "2011_09_26_drive_0029", 0),
    ("kitti_raw", "2011_09_28_drive_0039", 0),
)


def sequence(kind: str, name: str, seed: int):
    if kind == "simulator":
        return simulate(name, duration_s=120.0, seed=seed)
    if kind == "euroc":
        return read_sequence("euroc", DATA / "euroc" / name)
    return read_sequence(
        "kitti_raw", DATA / "kitti_raw" / f"{name}.csv", on_backward="drop", on_duplicate="drop", on_gap="keep"
    )


def run(seq, gps, start) -> tuple[OnlineFusion, float]:
    fusion = OnlineFusion(None, seq.gravity, start, FuseConfig(online=OnlineSettings(keyframe_s=1.0)))
    fix, began = 0, time.perf_counter()
    for first in range(0, len(seq), BLOCK):
        block = slice(first, first + BLOCK)
        fusion.add_imu(seq.t[block], seq.gyro[block], seq.acc[block])
        while fix < len(gps.t) and gps.t[fix] <= seq.t[block][-1]:
            fusion.add_gps(gps.t[fix], gps.pos[fix], gps.sigma[fix])
            fix += 1
    fusion.flush()
    return fusion, time.perf_counter() - began


def rmse(seq, fusion: OnlineFusion) -> float:
    traj = fusion.trajectory()
    at = np.searchsorted(seq.t, traj.t)
    ok = seq.gt.valid[at]
    return float(np.sqrt(np.mean(np.sum((traj.pos[ok] - seq.gt.pos[at][ok]) ** 2, axis=1))))


def start_errors(seq, state: gtsam.NavState) -> tuple[float, float, float]:
    """Tilt and heading error (deg) of the aligned first state, and its velocity error (m/s)."""
    truth = seq.gt.rot[0]
    rot = state.pose().rotation().matrix()
    tilt = np.degrees(np.arccos(np.clip(rot[2] @ truth[2], -1.0, 1.0)))  # the up axis seen from the body
    relative = rot @ truth.T  # world error, heading about z
    heading = np.degrees(np.arctan2(relative[1, 0] - relative[0, 1], relative[0, 0] + relative[1, 1]))
    return float(tilt), float(abs(heading)), float(np.linalg.norm(state.velocity() - seq.gt.vel[0]))


def main() -> None:
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    print(
        "| sequence | s | waited s | still s | heading sigma deg | tilt / heading error deg | velocity error m/s |",
        end="",
    )
    print(" RMSE aligned / ground-truth start, m | stream s | batch `fuse`: tilt / heading error deg, RMSE m |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for kind, name, seed in SEQUENCES:
        seq = sequence(kind, name, seed)
        gps, _ = gps_for(seq, 1.0, 0.3, seed=0, source="simulated")
        truth_start = gtsam.NavState(gtsam.Pose3(gtsam.Rot3(seq.gt.rot[0]), seq.gt.pos[0]), seq.gt.vel[0])
        aligned, seconds = run(seq, gps, None)
        known, _ = run(seq, gps, truth_start)
        a = aligned.alignment
        batch = fuse(seq, gps, None, FuseConfig(keyframe_s=1.0)).solution.trajectory
        batch_tilt, batch_heading, _ = start_errors(
            seq, gtsam.NavState(gtsam.Pose3(gtsam.Rot3(batch.rot[0]), batch.pos[0]), batch.vel[0])
        )
        at = np.searchsorted(seq.t, batch.t)
        batch_rmse = float(np.sqrt(np.mean(np.sum((batch.pos - seq.gt.pos[at]) ** 2, axis=1))))
        if a is None:
            print(f"| {kind} {name} | {seq.t[-1] - seq.t[0]:.0f} | none | | | | | | {seconds:.1f} | |")
            continue
        tilt, heading, vel = start_errors(seq, a.state)
        still = f"{a.still.duration_s:.1f}" if a.still is not None else "-"
        forced = " (forced)" if a.forced else ""
        print(
            f"| {kind} {name} | {seq.t[-1] - seq.t[0]:.0f} | {a.waited_s:.1f}{forced} | {still} | "
            f"{np.degrees(a.yaw_sigma_rad):.2f} | {tilt:.2f} / {heading:.2f} | {vel:.2f} | "
            f"{rmse(seq, aligned):.3f} / {rmse(seq, known):.3f} | {seconds:.1f} | "
            f"{batch_tilt:.2f} / {batch_heading:.2f}, {batch_rmse:.3f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
