"""EuRoC without GPS, AirIO's protocol: the motion model beside AirIMU integration and the graph with both.

    python benchmarks/motion_euroc.py --checkpoint runs/euroc/best.pt --motion runs/euroc-motion/best.pt [--json F]

Per test flight (MH_04_difficult, V1_03_difficult, V2_02_medium): every estimate starts at the ground-truth state
of the first IMU sample and is never aligned; ATE is the position RMSE over every IMU sample of the flight (m), RTE
the RMSE of the 5-s displacement error over windows starting every second (m). Rows:

- ``airimu``: the AirIMU-corrected IMU integrated (strapdown) from the first state;
- ``motion, est. attitude``: the motion model's body-frame velocity, fed with the attitude of the integrated
  corrected gyro and rotated into the world by it, integrated (each velocity held until the next, causal);
- ``graph, est. attitude``: ``airimu.fuse.fuse`` without GPS from the ground-truth start (``airimu fuse --no-gps
  --start ground-truth --motion``): AirIMU preintegration factors between keyframes every ``motion.keyframe_s``, a
  motion factor at each (``factors.MotionFactor``), a prior on the first state, Levenberg-Marquardt; the motion
  model reads the attitude of the previous solution (``motion.passes``), never ground truth;
- ``motion, GT attitude``: the motion row with the ground-truth attitude in and for the rotation into the world
  (AirIO's ground-truth-attitude variant).

Also printed: the motion model's velocity RMSE per axis and its NEES per axis (about 1 when the variance fits).
AirIO's EKF on the same flights, its table: 2.308 / 3.05 / 4.206 m ATE.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from airimu.fuse import fuse, imu_rate_trajectory
from fusion.config import FuseConfig, MotionSettings
from learned_imu.config import load_config
from learned_imu.evaluation.evaluate import dead_reckoning
from learned_imu.geometry.preintegration import preintegrate
from learned_imu.network.checkpoint import model_from_checkpoint, motion_from_checkpoint
from learned_imu.network.inference import correct
from learned_imu.network.motion import block_ends, motion_sequence, up_in_body
from learned_imu.training.experiment import load_sequences

sys.path.insert(0, str(Path(__file__).resolve().parent))
from motion_kitti import add_start_and_scale_arguments, with_start_and_scale  # noqa: E402

AIRIO_EKF_ATE_M = {"MH_04_difficult": 2.308, "V1_03_difficult": 3.05, "V2_02_medium": 4.206}
RTE_WINDOW_S = 5.0


def attitude(seq, gyro: np.ndarray) -> np.ndarray:
    """(N, 3, 3) world <- IMU: the gyro integrated from the ground-truth attitude at sample 0 (the state before each
    sample)."""
    pre = preintegrate(torch.as_tensor(gyro), torch.zeros(len(seq), 3, dtype=torch.float64), torch.as_tensor(seq.dt))
    rot = seq.gt.rot[0] @ pre.rot.numpy()
    return np.concatenate([seq.gt.rot[:1], rot[:-1]])


def integrated_velocity(seq, rot: np.ndarray, vel_body: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Positions from the ground-truth start, each block's velocity held from its end sample to the next (causal;
    before the first output, the ground-truth start velocity)."""
    which = np.searchsorted(ends, np.arange(len(seq)), side="right") - 1
    world = np.where((which >= 0)[:, None], np.einsum("nij,nj->ni", rot, vel_body[np.maximum(which, 0)]), seq.gt.vel[0])
    moved = np.cumsum(world[:-1] * np.diff(seq.t)[:, None], axis=0)  # each sample's velocity over its step
    return seq.gt.pos[0] + np.concatenate([np.zeros((1, 3)), moved])


def graph_solution(seq, model, net, config: FuseConfig) -> np.ndarray:
    """Positions at every sample from ``airimu.fuse.fuse`` without GPS (module docstring)."""
    result = fuse(seq, None, model, config, motion_model=net, start="ground-truth")
    dense = imu_rate_trajectory(result)
    return np.stack([np.interp(seq.t, dense.t, dense.pos[:, i]) for i in range(3)], axis=1)


def ate(seq, pos: np.ndarray) -> float:
    ok = seq.gt.valid
    return float(np.sqrt(np.mean(np.sum((pos[ok] - seq.gt.pos[ok]) ** 2, axis=1))))


def rte(seq, pos: np.ndarray) -> float:
    rate = 1.0 / float(np.median(seq.dt))
    span, step = int(round(RTE_WINDOW_S * rate)), int(round(rate))
    starts = np.arange(0, len(seq) - span, step)
    ok = seq.gt.valid[starts] & seq.gt.valid[starts + span]
    starts = starts[ok]
    err = (pos[starts + span] - pos[starts]) - (seq.gt.pos[starts + span] - seq.gt.pos[starts])
    return float(np.sqrt(np.mean(np.sum(err**2, axis=1))))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", required=True, help="the AirIMU correction model")
    parser.add_argument("--motion", required=True, help="the motion model")
    parser.add_argument("--config", default="configs/euroc.yaml", help="its data.evaluate are the test flights")
    parser.add_argument("--json", help="write the rows here")
    add_start_and_scale_arguments(parser)
    parser.add_argument("--keyframe-s", type=float, default=MotionSettings.keyframe_s, help="motion.keyframe_s")
    parser.add_argument("--passes", type=int, default=MotionSettings.passes, help="motion.passes")
    parser.add_argument(
        "--cov-scale", type=float, nargs="+", default=[MotionSettings.cov_scale], help="motion.cov_scale: 1 or 3"
    )
    parser.add_argument(
        "--estimate-bias", action="store_true", help="FuseConfig.estimate_bias: bias states in the graph"
    )
    args = parser.parse_args()
    motion = MotionSettings(args.keyframe_s, args.passes, tuple(args.cov_scale))
    fuse_config = with_start_and_scale(FuseConfig(motion=motion, estimate_bias=args.estimate_bias), args)
    model, _ = model_from_checkpoint(args.checkpoint)
    net, _ = motion_from_checkpoint(args.motion)
    config = load_config(args.config)
    rows = []
    for seq in load_sequences(config.data.evaluate, config.data.root):
        start = time.perf_counter()
        correction = correct(model, seq)
        gyro, acc = correction.gyro.double().numpy(), correction.acc.double().numpy()
        ends = block_ends(len(seq), net.block).numpy()
        truth_body = np.einsum("nji,nj->ni", seq.gt.rot[ends], seq.gt.vel[ends])
        est_rot = attitude(seq, gyro)
        result = {"sequence": seq.name, "airio_ekf_ate_m": AIRIO_EKF_ATE_M.get(seq.name)}
        tracks = {"airimu": dead_reckoning(seq, gyro, acc)}
        raw = [torch.as_tensor(x, dtype=torch.float32) for x in (seq.gyro, seq.acc)]
        for name, rot in (("est", est_rot), ("gt", seq.gt.rot)):
            out = motion_sequence(net, *raw, up_in_body(torch.as_tensor(rot, dtype=torch.float32)))
            vel, var = out.vel.double().numpy(), out.vel_var.double().numpy()
            err = vel - truth_body
            result[f"vel_rmse_m_s_{name}"] = np.sqrt(np.mean(err**2, axis=0)).round(4).tolist()
            result[f"nees_per_axis_{name}"] = np.mean(err**2 / var, axis=0).round(3).tolist()
            tracks[f"motion, {name} attitude"] = integrated_velocity(seq, rot, vel, ends)
        tracks["graph, est attitude"] = graph_solution(seq, model, net, fuse_config)
        for name, pos in tracks.items():
            result[name] = {"ate_m": round(ate(seq, pos), 3), "rte_5s_m": round(rte(seq, pos), 3)}
        result["seconds"] = round(time.perf_counter() - start, 1)
        rows.append(result)
        print(json.dumps(result), flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
