"""What a sample held across a time gap of KITTI's OXTS stream gets wrong: the preintegration error of that one
sample against the ground truth, on the training drives of ``configs/kitti.yaml`` (so that the PGO's
``options.gap_noise_density`` is not tuned on its evaluation drive).

    python benchmarks/kitti_gaps.py [--config configs/kitti.yaml]

Prints, per gap length class, the number of gaps and the noise density (sigma, per axis) that would make the
observed rotation and velocity errors one sigma: sqrt(mean(error^2) / mean(gap length)).
"""

from __future__ import annotations

import argparse

import gtsam
import numpy as np

from learned_imu.config import load_config
from learned_imu.training.experiment import load_sequences


def gap_errors(sequences, min_gap_s: float = 0.05):
    """(rotation errors (G, 3) rad, velocity errors (G, 3) m/s, gap lengths (G,) s) of every sample followed by
    a step over ``min_gap_s``, integrated over that step as it is."""
    rot, vel, length = [], [], []
    for s in sequences:
        steps = np.diff(s.t)
        for i in np.flatnonzero(steps > min_gap_s):
            h = steps[i]
            r_i, r_j = s.gt.rot[i], s.gt.rot[i + 1]
            held = gtsam.Rot3.Expmap(s.gyro[i] * h).matrix()
            rot.append(gtsam.Rot3.Logmap(gtsam.Rot3(held.T @ r_i.T @ r_j)))
            vel.append(r_i.T @ (s.gt.vel[i + 1] - s.gt.vel[i] - s.gravity * h) - s.acc[i] * h)
            length.append(h)
    return np.array(rot), np.array(vel), np.array(length)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="configs/kitti.yaml")
    args = parser.parse_args()
    config = load_config(args.config)
    rot, vel, length = gap_errors(load_sequences(config.data.train, config.data.root))
    for low, high in ((0.05, 0.5), (0.5, 3.0)):
        pick = (length > low) & (length <= high)
        if not pick.any():
            continue
        mean_length = float(length[pick].mean())
        gyro = np.sqrt((rot[pick] ** 2).mean(axis=0) / mean_length)
        acc = np.sqrt((vel[pick] ** 2).mean(axis=0) / mean_length)
        print(
            f"gaps {low}-{high} s: {int(pick.sum())} (mean {mean_length:.2f} s); gyro density "
            f"{np.array2string(gyro, precision=4)} rad/s/sqrt(Hz) (rms {np.sqrt(np.mean(gyro**2)):.3f}), acc "
            f"{np.array2string(acc, precision=3)} m/s^2/sqrt(Hz) (rms {np.sqrt(np.mean(acc**2)):.2f})"
        )


if __name__ == "__main__":
    main()
