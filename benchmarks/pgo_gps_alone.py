"""GPS alone, scored as the PGO ablation scores its rows: the fused fixes of each rate and seed interpolated by a
straight line and by a cubic spline (no IMU), ATE against the same reference over the same span.

    python benchmarks/pgo_gps_alone.py --config configs/pgo_kitti.yaml

Says how much of a fused result the GPS explains by itself (on KITTI's drive 0027 at 1 Hz: all of it).
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.interpolate import CubicSpline

from airimu.experiments.pgo import fixes_on_samples, gps_for, recorded_phases
from airimu.experiments.pgo_config import load_pgo_config
from learned_imu.config import load_config
from learned_imu.training.experiment import load_sequences


def rmse(pos: np.ndarray, truth: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((pos - truth) ** 2, axis=1))))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="configs/pgo_kitti.yaml")
    args = parser.parse_args()
    config = load_pgo_config(args.config)
    experiment = load_config(config.experiment)
    options = config.options
    sequences = load_sequences(config.sequences or experiment.data.evaluate, experiment.data.root)
    for sequence in sequences:
        recorded = options.gps_source == "recorded" or (options.gps_source == "auto" and sequence.gt is None)
        if options.keyframes == "fixes":
            sequence = fixes_on_samples(sequence)
        for rate in options.gps_hz:
            seeds = min(options.seeds, recorded_phases(sequence, rate)) if recorded else options.seeds
            line, spline = [], []
            for seed in range(seeds):
                fuse, truth = gps_for(sequence, rate, options.gps_sigma_m, seed, options.gps_source)
                inside = (truth.t >= fuse.t[0]) & (truth.t <= fuse.t[-1])
                t = truth.t[inside]
                line.append(
                    rmse(np.column_stack([np.interp(t, fuse.t, fuse.pos[:, i]) for i in range(3)]), truth.pos[inside])
                )
                spline.append(rmse(CubicSpline(fuse.t, fuse.pos)(t), truth.pos[inside]))
            print(
                f"{sequence.name} GPS {rate:g} Hz ({seeds} draws): straight line {np.mean(line):.3f} +- "
                f"{np.std(line):.3f} m, cubic spline {np.mean(spline):.3f} +- {np.std(spline):.3f} m"
            )


if __name__ == "__main__":
    main()
