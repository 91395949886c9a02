"""Raw-IMU metrics on real EuRoC data, and the time to read and evaluate a sequence, beside evo.

    python benchmarks/evaluation.py [--data ../shared/data]

Prints ROE, RPE, R-RMSE, P-RMSE, V-RMSE and ATE of the raw IMU on MH_01_easy and the V1_02_medium excerpt at
intervals of 1 s and 10 frames (IMU samples), then times ``read_sequence`` + ``evaluate`` on MH_01_easy
(184 s at 200 Hz) against evo computing APE and RPE on a trajectory of the same length.
"""

from __future__ import annotations

import argparse
import copy
import statistics
import time
from pathlib import Path

import numpy as np
from evo.core import metrics as evo_metrics
from evo.core.trajectory import PoseTrajectory3D
from scipy.spatial.transform import Rotation

from learned_imu.datasets import read_sequence
from learned_imu.evaluate import evaluate

SEQUENCES = {
    "MH_01_easy": {},
    "V1_02_medium (first 40 s)": {"imu_file": "mav0/imu0/data_partial_first40s.csv"},
}
INTERVALS = ((1.0, "s"), (10, "frames"))


def evo_ape_rpe(rot: np.ndarray, pos: np.ndarray, est_pos: np.ndarray, delta: int) -> None:
    quat = Rotation.from_matrix(rot).as_quat()[:, [3, 0, 1, 2]]
    stamps = np.arange(len(pos)) * 0.005
    ref = PoseTrajectory3D(positions_xyz=pos, orientations_quat_wxyz=quat, timestamps=stamps)
    est = PoseTrajectory3D(positions_xyz=est_pos, orientations_quat_wxyz=quat, timestamps=stamps)
    aligned = copy.deepcopy(est)
    aligned.align(ref, correct_scale=False)
    for traj in (est, aligned):
        ape = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
        ape.process_data((ref, traj))
    rpe = evo_metrics.RPE(evo_metrics.PoseRelation.translation_part, delta=delta, delta_unit=evo_metrics.Unit.frames)
    rpe.process_data((ref, est))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", default=str(Path(__file__).resolve().parents[2] / "shared" / "data"))
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    euroc = Path(args.data) / "euroc"

    print(
        f"{'sequence':27s} {'interval':>9s} {'windows':>7s} {'ROE deg':>8s} {'RPE m':>7s} {'R-RMSE deg':>10s} "
        f"{'P-RMSE m':>9s} {'V-RMSE m/s':>10s} {'ATE m':>9s} {'ATE al. m':>9s}"
    )
    for name, options in SEQUENCES.items():
        seq = read_sequence("euroc", euroc / name.split()[0], **options)
        for interval, unit in INTERVALS:
            r = evaluate(seq, interval, unit)
            print(
                f"{name:27s} {f'{interval:g} {unit}':>9s} {r.n_windows:7d} {r.roe_deg:8.3f} {r.rpe_m:7.4f} "
                f"{r.r_rmse_deg:10.3f} {r.p_rmse_m:9.5f} {r.v_rmse_m_s:10.4f} {r.ate_m:9.4g} {r.ate_aligned_m:9.4g}"
            )

    path = euroc / "MH_01_easy"
    ours, peer = [], []
    for _ in range(args.repeats):
        start = time.perf_counter()
        seq = read_sequence("euroc", path)
        evaluate(seq, 1.0)
        ours.append(time.perf_counter() - start)
        start = time.perf_counter()
        evo_ape_rpe(seq.gt.rot, seq.gt.pos, seq.gt.pos + 0.01, delta=200)
        peer.append(time.perf_counter() - start)
    t_ours, t_peer = statistics.median(ours), statistics.median(peer)
    print(
        f"\nMH_01_easy ({len(seq)} samples): read + evaluate {t_ours:.2f} s; "
        f"evo APE (raw, aligned) + RPE on the same-length trajectory {t_peer:.2f} s ({t_peer / t_ours:.1f}x ours)"
    )


if __name__ == "__main__":
    main()
