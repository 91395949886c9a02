"""Online fusion with bias states on GTSAM's KITTI drive: what ISAM2's built-in re-linearisation costs per keyframe.

    python benchmarks/online_bias.py [--data ../shared/data] [--tol 1e-1 1e-2 1e-3]

``kitti_gtsam`` (471 s of 100 Hz OXTS IMU, its 1 Hz GPS) streamed into ``fusion.online.OnlineFusion`` in blocks of 10
samples with 1-s keyframes, each fix once the IMU has passed it: first without bias states (the default noise 0.004
/ 0.08), then with GTSAM's example settings (its noise densities, its bias prior and cumulative walk:
``airimu.experiments.pgo.GTSAM_EXAMPLE``) at each ``bias_relinearize_tol``. Prints the wall time, ms per keyframe,
the intervals preintegrated again and the RMSE of the keyframes against every fix (the first state: identity
attitude at the first fix, as the drive has no ground truth here).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import gtsam
import numpy as np

from airimu.experiments.pgo import GTSAM_EXAMPLE
from fusion.config import FuseConfig, OnlineSettings
from fusion.online import OnlineFusion
from learned_imu.datasets import read_sequence

BLOCK = 10


def stream(seq, fusion: OnlineFusion) -> float:
    """Feed the drive and its fixes; returns the wall time, s."""
    gps, fix = seq.gps, 0
    start = time.perf_counter()
    for first in range(0, len(seq), BLOCK):
        block = slice(first, first + BLOCK)
        fusion.add_imu(seq.t[block], seq.gyro[block], seq.acc[block])
        while fix < len(gps.t) and gps.t[fix] <= seq.t[block][-1]:
            fusion.add_gps(gps.t[fix], gps.pos[fix], gps.sigma[fix])
            fix += 1
    fusion.flush()
    return time.perf_counter() - start


def rmse_to_gps(seq, fusion: OnlineFusion) -> float:
    trajectory = fusion.trajectory()
    inside = (seq.gps.t >= trajectory.t[0]) & (seq.gps.t <= trajectory.t[-1])
    error = trajectory.position_at(seq.gps.t[inside]) - seq.gps.pos[inside]
    return float(np.sqrt(np.mean(np.sum(error**2, axis=1))))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(Path(__file__).resolve().parents[2] / "shared" / "data"))
    parser.add_argument("--tol", type=float, nargs="+", default=[1e-1, 1e-2, 1e-3], help="bias_relinearize_tol values")
    args = parser.parse_args()
    seq = read_sequence("kitti", Path(args.data) / "kitti_gtsam")
    first = gtsam.NavState(gtsam.Pose3(gtsam.Rot3(), seq.gps.pos[0]), np.zeros(3))
    gyro, acc = GTSAM_EXAMPLE.noise_density
    runs = [("no bias states", FuseConfig())]
    runs += [
        (
            f"bias states, bias_relinearize_tol {tol:g}",
            FuseConfig(
                gyro, acc, estimate_bias=True, bias=GTSAM_EXAMPLE.bias, online=OnlineSettings(bias_relinearize_tol=tol)
            ),
        )
        for tol in args.tol
    ]
    for name, config in runs:
        fusion = OnlineFusion(None, seq.gravity, first, config)
        seconds = stream(seq, fusion)
        rmse = rmse_to_gps(seq, fusion)
        print(
            f"{name}: {seconds:.2f} s, {1e3 * seconds / fusion.keyframes:.1f} ms a keyframe ({fusion.keyframes}), "
            f"{fusion.reintegrated} intervals preintegrated again, RMSE against the GPS {rmse:.3f} m",
            flush=True,
        )


if __name__ == "__main__":
    main()
