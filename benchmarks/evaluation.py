"""Raw-IMU metrics on real EuRoC data, and the time to read and evaluate a sequence, beside evo.

    python benchmarks/evaluation.py [--data ../shared/data]

Prints the paper's metrics of the raw IMU (``learned_imu.evaluation.metrics``: ROE, its RMSE, P-RMSE) and the ATE on
the three
EuRoC test flights of the shared data at intervals of 1 s and 10 frames (IMU samples), beside the paper's Baseline
values (``learned_imu.evaluation.paper``) and their ratio, then times ``read_sequence`` + ``evaluate`` on MH_01_easy
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
from learned_imu.evaluation import paper
from learned_imu.evaluation.evaluate import evaluate

SEQUENCES = ("MH_04_difficult", "V1_03_difficult", "V2_02_medium")
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

    print(f"{'sequence':16s} {'interval':>9s} {'windows':>7s}  metric: ours / paper (ratio)")
    for name in SEQUENCES:
        seq = read_sequence("euroc", euroc / name)
        for interval, unit in INTERVALS:
            r = evaluate(seq, interval, unit)
            fields = ("roe_deg", "roe_rmse_deg", "rpe_rmse_m") if unit == "s" else ("roe_rmse_deg", "rpe_rmse_m")
            cells = []
            for field in fields:
                key = field if unit == "s" else field.replace("_deg", "_10f_deg").replace("_m", "_10f_m")
                ref = paper.reference(paper.EUROC_IMU, name, "Baseline", key)
                cells.append(f"{field} {getattr(r, field):.4g} / {ref:.4g} ({getattr(r, field) / ref:.3f})")
            print(
                f"{name:16s} {f'{interval:g} {unit}':>9s} {r.n_windows:7d}  "
                + "; ".join(cells)
                + f"; ATE {r.ate_m:.4g}"
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
