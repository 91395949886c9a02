"""Scale: a 2-hour 200 Hz simulated sequence (1.44 M samples) through inference + export, then the IMU + GPS graph
at 1 Hz GPS with keyframes every second (7,200 states) solved by Levenberg-Marquardt.

    python benchmarks/fusion_scale.py [--hours 2] [--checkpoint runs/demo/best.pt] [--no-graph]

Reports wall time and peak resident memory (``ru_maxrss``) of each stage. Without a checkpoint an untrained
AirImuNet (same size as the paper's) does the inference: the cost does not depend on the weights. Targets:
inference + export under 60 s with peak memory under 2 GB; the graph solved in under 30 s.
"""

from __future__ import annotations

import argparse
import resource
import time

import torch


def peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--hours", type=float, default=2.0)
    parser.add_argument("--checkpoint", default=None)
    parser.add_argument("--no-graph", action="store_true", help="stop after inference + export")
    args = parser.parse_args()

    from airimu.experiments.pgo import ate_m, gps_for
    from fusion.config import FusionSettings
    from fusion.graph import build_graph, solve
    from learned_imu.datasets.simulator import simulate
    from learned_imu.export import keyframes_every, preintegration_export
    from learned_imu.network.checkpoint import model_from_checkpoint
    from learned_imu.network.model import AirImuNet, correct_sequence

    clock = time.perf_counter()
    seq = simulate("drone", duration_s=args.hours * 3600, grade="consumer", seed=0, device_seed=7)
    print(f"simulated {len(seq):,} samples in {time.perf_counter() - clock:.1f} s (peak {peak_mb():.0f} MB)")
    model = model_from_checkpoint(args.checkpoint)[0] if args.checkpoint else AirImuNet().eval()

    clock = time.perf_counter()
    out = correct_sequence(
        model, torch.as_tensor(seq.gyro, dtype=torch.float32), torch.as_tensor(seq.acc, dtype=torch.float32)
    )
    inference = time.perf_counter() - clock
    noise = (out.gyro_cov.double().numpy(), out.acc_cov.double().numpy())
    export = preintegration_export(
        seq, keyframes_every(seq, 1.0), *noise, out.gyro.double().numpy(), out.acc.double().numpy()
    )
    total = time.perf_counter() - clock
    print(
        f"inference {inference:.1f} s + export {total - inference:.1f} s = {total:.1f} s "
        f"(target < 60 s), peak memory {peak_mb():.0f} MB (target < 2048 MB)"
    )

    if args.no_graph:
        return
    fuse, truth = gps_for(seq, 1.0, 0.1, seed=0)
    settings = FusionSettings()
    clock = time.perf_counter()
    graph, values = build_graph(export, fuse, settings)
    built = time.perf_counter() - clock
    solution = solve(graph, values, export.keyframe_t, settings)
    total = time.perf_counter() - clock
    print(
        f"graph: {len(export.keyframe_t):,} states, {graph.size():,} factors; build {built:.1f} s + solve "
        f"{total - built:.1f} s = {total:.1f} s (target < 30 s), {solution.iterations} LM iterations, "
        f"ATE {ate_m(solution, truth):.3f} m"
    )


if __name__ == "__main__":
    main()
