"""Online fusion latency: a simulated 200 Hz IMU and 1 Hz GPS fed to ``fusion.online.OnlineFusion`` as a driver
delivers them (blocks of ``--block`` samples, each fix after the IMU block that passes its time), timing every call.

    python benchmarks/online.py [--minutes 10] [--keyframe 0.1 1.0] [--checkpoint runs/demo/best.pt] [--threads 1]

Reports per keyframe interval the median and p99 wall time of: IMU blocks that only buffer, IMU blocks that add a
keyframe (model inference over the interval, preintegration, factor, ISAM2 update), GPS fixes, and the
``current_state()`` query; and the real-time factor (processing time / data time) and its inverse, the margin
(target: >= 10 at 200 Hz IMU and 1 Hz GPS). Without a checkpoint a default-size untrained AirImuNet runs (the
inference cost does not depend on the weights).
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def run(seq, gps, model, keyframe_s: float, block: int, smoother: str, lag_s: float) -> tuple[dict, object]:
    """Feed the whole sequence; wall times (s) per call kind, and the fusion's final trajectory."""
    import gtsam

    from fusion.online import OnlineFusion

    first = gtsam.NavState(gtsam.Pose3(gtsam.Rot3(seq.gt.rot[0]), seq.gt.pos[0]), seq.gt.vel[0])
    from fusion.config import FuseConfig, OnlineSettings

    online = OnlineSettings(keyframe_s=keyframe_s, smoother=smoother, lag_s=lag_s)
    fusion = OnlineFusion(model, seq.gravity, first, FuseConfig(1e-3, 1e-2, online=online))
    times: dict[str, list[float]] = {"imu (buffer only)": [], "imu + keyframe update": [], "gps": [], "state": []}
    fix = 0
    clock = time.perf_counter
    for start in range(0, len(seq), block):
        part = slice(start, start + block)
        began = clock()
        added = fusion.add_imu(seq.t[part], seq.gyro[part], seq.acc[part])
        times["imu + keyframe update" if added else "imu (buffer only)"].append(clock() - began)
        if added:
            began = clock()
            fusion.current_state()
            times["state"].append(clock() - began)
        while fix < len(gps.t) and gps.t[fix] <= seq.t[part][-1]:
            began = clock()
            fusion.add_gps(gps.t[fix], gps.pos[fix], gps.sigma[fix])
            times["gps"].append(clock() - began)
            fix += 1
    began = clock()
    fusion.flush()
    times["imu + keyframe update"].append(clock() - began)
    return times, fusion.trajectory()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--keyframe", type=float, nargs="+", default=[0.1, 1.0], help="keyframe intervals, s")
    parser.add_argument("--block", type=int, default=10, help="IMU samples per add_imu call")
    parser.add_argument("--checkpoint", default=None)
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads (0: torch's default)")
    parser.add_argument("--smoother", default="isam2", choices=["isam2", "fixed_lag"])
    parser.add_argument("--lag", type=float, default=10.0, help="fixed-lag window, s")
    args = parser.parse_args()

    import torch

    from airimu.experiments.pgo import ate_m, gps_for
    from fusion.graph import Solution
    from learned_imu.datasets.simulator import simulate
    from learned_imu.network.checkpoint import model_from_checkpoint
    from learned_imu.network.model import AirImuNet

    if args.threads:
        torch.set_num_threads(args.threads)
    seq = simulate("drone", duration_s=args.minutes * 60, grade="consumer", seed=0)
    gps, truth = gps_for(seq, 1.0, 0.1, seed=0)
    # untrained: noise densities of the fused raw IMU (consumer grade, inflated for its biases)
    model = (
        model_from_checkpoint(args.checkpoint)[0]
        if args.checkpoint
        else AirImuNet(init_gyro_cov=1e-6, init_acc_cov=1e-4).eval()
    )
    data_s = seq.t[-1] - seq.t[0]
    print(
        f"{args.minutes:g} min at 200 Hz ({len(seq):,} samples, blocks of {args.block}), {len(gps.t)} GPS fixes, "
        f"{args.smoother}, torch threads {torch.get_num_threads()}"
    )
    for keyframe_s in args.keyframe:
        times, trajectory = run(seq, gps, model, keyframe_s, args.block, args.smoother, args.lag)
        total = sum(sum(v) for v in times.values())
        print(f"\nkeyframes every {keyframe_s:g} s ({len(trajectory.t)} keyframes)")
        print(f"  {'call':<24}{'count':>8}{'median ms':>12}{'p99 ms':>10}{'max ms':>10}")
        for kind, values in times.items():
            ms = np.array(values) * 1e3
            print(f"  {kind:<24}{len(ms):>8}{np.median(ms):>12.3f}{np.percentile(ms, 99):>10.3f}{ms.max():>10.1f}")
        updates = np.array(times["imu + keyframe update"]) * 1e3
        tenth = max(1, len(updates) // 10)
        print(
            f"  keyframe update median, first vs last tenth of the run: {np.median(updates[:tenth]):.2f} ms, "
            f"{np.median(updates[-tenth:]):.2f} ms"
        )
        print(
            f"  processing {total:.1f} s for {data_s:.0f} s of data: real-time factor {total / data_s:.4f}, "
            f"margin {data_s / total:.1f}x (target >= 10x)"
        )
        print(f"  ATE {ate_m(Solution(trajectory, None, None, 0, 0.0), truth):.3f} m")


if __name__ == "__main__":
    main()
