"""The first state ``airimu fuse`` starts from without ground truth (issue 38): roll and pitch from gravity, heading
from the GPS track (``fusion.initial.aligned_first_state``), against the ground truth that the fusion never read.

GPS at 1 Hz from the ground truth (EuRoC 0.1 m, KITTI 0.5 m per axis), raw IMU with the default noise (EuRoC:
``--euroc-checkpoint``'s AirIMU model, its raw gyro biases of up to 80 mrad/s tilt the whole solution), a keyframe
at every fix; the error of the graph's first-state prior mean: tilt (angle between the up axes) and heading. Run:

    python benchmarks/initial_alignment.py
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from gps_keyframes import CHECKS, DATA, gps_of  # noqa: E402

from airimu.fuse import fuse, initial_attitude_error  # noqa: E402
from learned_imu.datasets.euroc import read_euroc  # noqa: E402
from learned_imu.datasets.kitti_raw import read_kitti_raw  # noqa: E402

EUROC = DATA.parent / "euroc"
LOGS = [("euroc", f, 0.1) for f in ("MH_04_difficult", "V1_03_difficult", "V2_02_medium")] + [
    ("kitti_raw", d, 0.5) for d in ("2011_10_03_drive_0047", "2011_09_26_drive_0014", "2011_09_30_drive_0033")
]


def main() -> None:
    import argparse

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--euroc-checkpoint", default=None, help="an AirIMU model for the EuRoC rows (default: raw)")
    args = parser.parse_args()
    model = None
    if args.euroc_checkpoint:
        from learned_imu.network.checkpoint import model_from_checkpoint

        model = model_from_checkpoint(args.euroc_checkpoint)[0]
    print("| log | IMU | GPS sigma m | tilt error deg | heading error deg |")
    print("|---|---|---|---|---|")
    for kind, name, sigma in LOGS:
        use = model if kind == "euroc" else None
        if kind == "euroc":
            sequence = read_euroc(EUROC / name)
        else:
            sequence = read_kitti_raw(DATA / f"{name}.csv", on_backward="drop", checks=CHECKS)
        fixes = gps_of(sequence, 1.0, 0.0, sigma, seed=0)
        error = initial_attitude_error(fuse(sequence, fixes, use))
        imu = "raw" if use is None else "AirIMU"
        print(f"| {name} | {imu} | {sigma} | {error['tilt']:.2f} | {error['yaw']:.2f} |", flush=True)


if __name__ == "__main__":
    main()
