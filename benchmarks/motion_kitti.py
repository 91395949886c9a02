"""KITTI without GPS, AI-IMU's protocol: t_rel / r_rel of the KITTI odometry devkit on AI-IMU's ten sequences.

    python benchmarks/motion_kitti.py --fold 1 runs/kitti-motion-fold1/best.pt --fold 2 runs/kitti-motion-fold2/best.pt
        [--json F] [--outages]
    python benchmarks/motion_kitti.py --loo runs/kitti-loo    (leave-one-sequence-out models: motion_kitti_loo.py)

Each sequence is AI-IMU's sample range of its raw drive (the issue's table), read from ``../shared/data/kitti_raw``;
each is scored by the motion model of the fold that never saw it in training (``configs/kitti_motion_fold*.yaml``),
or with ``--loo`` by the model trained on every drive but its own (AI-IMU's leave-one-sequence-out).
Rows, every one from the ground-truth state at the range's first sample, without GPS, never aligned:

- ``imu``: the raw IMU integrated (``airimu fuse --no-gps --start ground-truth``: the graph of IMU factors alone);
- ``motion``: the same graph with a learned velocity factor every ``motion.keyframe_s`` (``airimu fuse --motion``);
  the model reads the graph's attitude, never the ground truth's.

The IMU factors use the raw samples with the noise densities of GTSAM's ``IMUKittiExampleGPS.py``
(1.75e-4 rad/s/sqrt(Hz), 0.01 m/s^2/sqrt(Hz)). Metric: ``learned_imu.evaluation.kitti_odometry`` (10 Hz,
segments of 100..800 m, t_rel %, r_rel deg/m). AI-IMU's table (t_rel %) is printed beside.

``--gtsam-drive``: GTSAM's example drive (seq 00 = 2011_10_03_drive_0027, fold 1's test drive) with GTSAM's own GPS
file (``kitti_gtsam/KittiGps_converted.txt``, mapped into the OXTS frame), one fix in ten fused, as
``IMUKittiExampleGPS.py`` runs it but in ``airimu fuse``'s batch graph (keyframes 1 s, raw IMU, the fuse config's
default noise), without and with fold 1's motion factor: RMSE of the keyframes (interpolated) against every fix,
ATE against the OXTS ground truth between the first and the last fused fix, unaligned.

``--outages``: GPS outages of 30 / 60 / 120 s at five places of each sequence (evenly spread over its middle), 1-Hz
fixes from the ground truth with 0.3 m noise elsewhere; the mean position error at the end of the outage (the log
solved up to then, ``airimu fuse --gps-outage``) for GTSAM's settings (raw IMU, its noise and bias states), the raw
IMU with its fixed noise, and that + the motion factor; with ``--correction N CHECKPOINT`` (fold N's AirIMU model,
``configs/kitti_fold*.yaml``) also its corrected samples with their learned covariance (``airimu``), and that + the
motion factor (``airimu_motion``), in these tables and ``--gtsam-drive``'s (fold 1's model); an outage row where
``airimu fuse`` refuses the model (its samples explain the GPS track far worse than the raw ones) says "refused".

``--online``: the motion row by ``fusion.online.OnlineFusion`` instead of the batch graph (``online_row``: a fixed-lag
smoother, keyframes every 0.18 s, the IMU's gaps held as a stream has them), to check what a live estimator gets.

``--start-sigmas ROT VEL``: the prior on the ground-truth start (default the fuse config's 0.01 rad, 0.1 m/s; the
reported LOO row: 1e-3 rad, 0.02 m/s, the ground truth's accuracy); ``--scale SIGMA WALK INTERVAL``: speed-scale
states on the motion factors (``motion.scale_sigma``); ``--imu-delay S``: ``FuseConfig.imu_delay_s``;
``--measure-delay``: only measure the IMU's delay on the LOO template's training drives that are no sequence.

``--velocity``: instead of the graphs, the motion model itself on each sequence, fed the ground-truth attitude: per
body axis (forward, left, up) its velocity RMSE and mean error (m/s), its median predicted sigma, its NEES (the mean
of error^2 / predicted variance: about 1 when the variances fit) and the correlation of its velocity with the truth's.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import time
from pathlib import Path

import numpy as np

from airimu.experiments.pgo import GTSAM_EXAMPLE, gps_for
from airimu.fuse import fuse, imu_rate_trajectory
from airimu_core.errors import DataError, InputError
from fusion.config import IMU_GAPS, FuseConfig, MotionSettings
from learned_imu.config import load_config
from learned_imu.evaluation.kitti_odometry import relative_errors, subsample_indices
from learned_imu.network.checkpoint import model_from_checkpoint, motion_from_checkpoint
from learned_imu.training.experiment import load_sequences

# AI-IMU (Brossard et al. 2020), Table I and its text: t_rel (%) per KITTI odometry sequence; and its ranges
SEQUENCES = {  # sequence: (drive, first row, last row of the 100 Hz drive), AI-IMU t_rel %
    "00": ("2011_10_03_drive_0027", 0, 45692, 6.81),
    "01": ("2011_10_03_drive_0042", 0, 12180, 1.56),
    "02": ("2011_10_03_drive_0034", 0, 47935, 3.37),
    "04": ("2011_09_30_drive_0016", 0, 2950, 1.22),
    "05": ("2011_09_30_drive_0018", 0, 28659, 3.05),
    "06": ("2011_09_30_drive_0020", 0, 11347, 1.57),
    "07": ("2011_09_30_drive_0027", 0, 11545, 1.32),
    "08": ("2011_09_30_drive_0028", 11231, 53650, 1.08),
    "09": ("2011_09_30_drive_0033", 0, 16589, 0.82),
    "10": ("2011_09_30_drive_0034", 0, 12744, 1.05),
}
GTSAM_NOISE = GTSAM_EXAMPLE.noise_density  # (gyro, acc) sigma densities of IMUKittiExampleGPS.py
OUTAGES_S = (30.0, 60.0, 120.0)
OUTAGE_PLACES = 5
GPS_SIGMA_M = 0.3
log = logging.getLogger("motion_kitti")


def sequence_range(seq, drive_csv: Path, first: int, last: int):
    """The drive ``seq`` cut to AI-IMU's rows [first, last] of the CSV (by time: the reader drops replayed rows),
    from its first sample with ground truth (the start state): a drive read with an IMU delay (``imu_delay_s``) has
    none on the samples restamped into a gap (2011_10_03_drive_0027 begins with a 1.9-s one)."""
    t = np.loadtxt(drive_csv, delimiter=",", comments="#", usecols=0)
    part = seq.between(t[first], t[min(last, len(t) - 1)])
    return part.between(part.t[int(np.argmax(part.gt.valid))], part.t[-1])


def truth_rows(seq, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows of ``seq`` at the times ``t`` and where they hold valid ground truth at exactly that time: a sample that
    ``imu_gaps: interpolate`` filled into a gap has none (its nearest later row is 1.6 s on)."""
    at = np.minimum(np.searchsorted(seq.t, t), len(seq.t) - 1)
    return at, seq.gt.valid[at] & (np.abs(seq.t[at] - t) < 1e-9)


def scores(seq, result) -> dict:
    """t_rel / r_rel of a fused result against the ground truth, at 10 Hz; and where they come from: the RMS of the
    heading error (deg) and the mean of the speed error (m/s, estimate minus truth) over the same samples."""
    dense = imu_rate_trajectory(result)
    at, keep = truth_rows(seq, dense.t)
    t, at = dense.t[keep], at[keep]
    pick = ticks_10hz(t)
    truth, est = at[pick], np.flatnonzero(keep)[pick]  # rows of the truth and of the estimate at the 10-Hz ticks
    errors = relative_errors(seq.gt.rot[truth], seq.gt.pos[truth], dense.rot[est], dense.pos[est])
    off = np.einsum("nij,nkj->nik", dense.rot[est], seq.gt.rot[truth])  # estimate truth^T: the world-frame error
    heading = np.degrees(np.arctan2(off[:, 1, 0], off[:, 0, 0]))
    speed = np.linalg.norm(dense.vel[est], axis=1) - np.linalg.norm(seq.gt.vel[truth], axis=1)
    return {
        "t_rel_percent": round(errors.t_rel_percent, 3),
        "r_rel_deg_per_m": round(errors.r_rel_deg_per_m, 5),
        "heading_rms_deg": round(float(np.sqrt(np.mean(heading**2))), 3),
        "speed_error_mean_m_s": round(float(speed.mean()), 3),
    }


def ticks_10hz(t: np.ndarray) -> np.ndarray:
    """``subsample_indices`` (the sample nearest each 10-Hz tick), where a gap of the drive leaves a tick without a
    sample within half a tick period: those ticks are left out (the drives with 1-2 s of missing data: 00, 02, 05)."""
    try:
        return subsample_indices(t)
    except InputError:
        ticks = t[0] + 0.1 * np.arange(int((t[-1] - t[0]) / 0.1) + 1)
        right = np.clip(np.searchsorted(t, ticks), 1, len(t) - 1)
        nearest = np.where(ticks - t[right - 1] <= t[right] - ticks, right - 1, right)
        return np.unique(nearest[np.abs(t[nearest] - ticks) < 0.05])


def outage_rows(seq, net, motion_config: FuseConfig, correction=None) -> list[dict]:
    """Mean error at the end of ``OUTAGE_PLACES`` outages of each length, per setting (module docstring);
    ``correction``: the fold's AirIMU model, for the two rows with its corrected samples and learned covariance."""
    span = float(seq.t[-1] - seq.t[0])
    fixes = gps_for(seq, 1.0, GPS_SIGMA_M, seed=0, source="simulated")[0]  # 1-Hz fixes from the ground truth
    raw = FuseConfig(
        gyro_noise_density=GTSAM_NOISE[0], acc_noise_density=GTSAM_NOISE[1], keyframe_s=1.0,
        imu_gaps=motion_config.imu_gaps,
    )  # fmt: skip
    gtsam_like = dataclasses.replace(raw, estimate_bias=True, bias=GTSAM_EXAMPLE.bias)
    settings = {"GTSAM settings": (gtsam_like, None), "raw IMU": (raw, None)}
    settings["raw IMU + motion"] = (dataclasses.replace(raw, motion=motion_config.motion), net)
    if correction is not None:
        learned = FuseConfig(keyframe_s=1.0, imu_gaps=motion_config.imu_gaps)  # the noise is the model's
        settings["AirIMU"] = (learned, None)
        settings["AirIMU + motion"] = (dataclasses.replace(learned, motion=motion_config.motion), net)
    rows = []
    for duration in OUTAGES_S:
        if span < duration + 20.0:
            continue
        starts = np.linspace(10.0, span - duration - 10.0, OUTAGE_PLACES)
        outages = tuple((float(s), duration) for s in starts)
        row = {"sequence": seq.name, "outage_s": duration}
        for name, (config, model) in settings.items():
            airimu = correction if name.startswith("AirIMU") else None
            try:
                result = fuse(seq, fixes, airimu, config, motion_model=model, start="ground-truth", outages=outages)
            except DataError as error:  # the model refused against the raw IMU (check_model_against_raw)
                row[name] = "refused"
                log.info("%s, %s: %s", seq.name, name, error)
                continue
            valid = seq.gt.valid  # an outage may end on a filled sample: the truth between its neighbours
            truth = [
                np.array([np.interp(t, seq.t[valid], seq.gt.pos[valid, i]) for i in range(3)])
                for t, _ in result.outage_ends
            ]
            ends = [np.linalg.norm(pos - at) for (_, pos), at in zip(result.outage_ends, truth, strict=True)]
            row[name] = round(float(np.mean(ends)), 3)
        rows.append(row)
        print(json.dumps(row), flush=True)
    return rows


def gtsam_drive_rows(
    net, root: Path, motion: MotionSettings, correction=None, every: int = 10, imu_gaps: str = "hold"
) -> list[dict]:
    """The ``--gtsam-drive`` rows (module docstring); ``motion``: the motion factors' settings (``--cov-scale``);
    ``correction``: fold 1's AirIMU model, for two more rows with its corrected samples and learned noise; ``every``:
    one fix in this many fused; ``imu_gaps``: ``FuseConfig.imu_gaps``."""
    from learned_imu.datasets import read_sequence

    seq = read_sequence(
        "kitti_raw", root / "kitti_raw/2011_10_03_drive_0027.csv", on_backward="drop", on_duplicate="drop",
        on_gap="keep", gps_file=root / "kitti_gtsam/KittiGps_converted.txt",
    )  # fmt: skip
    gps = seq.gps
    fused = gps[np.arange(len(gps.t)) % every == 0]
    rows = []
    settings = [("raw IMU", None, None), ("raw IMU + motion", None, net)]
    if correction is not None:
        settings += [("AirIMU", correction, None), ("AirIMU + motion", correction, net)]
    for name, airimu, model in settings:
        config = FuseConfig(keyframe_s=1.0, imu_gaps=imu_gaps, motion=motion)
        result = fuse(seq, fused, airimu, config, motion_model=model)
        keyframes = result.solution.trajectory
        inside = (gps.t >= keyframes.t[0]) & (gps.t <= keyframes.t[-1])
        at_fix = np.column_stack([np.interp(gps.t[inside], keyframes.t, keyframes.pos[:, i]) for i in range(3)])
        row = {
            "row": name,
            "rmse_to_gps_m": round(float(np.sqrt(np.mean(np.sum((at_fix - gps.pos[inside]) ** 2, 1)))), 3),
            "ate_m": ate_between_fixes(seq, result, fused),
        }
        rows.append(row)
        print(json.dumps(row), flush=True)
    return rows


def online_row(seq, net, motion: MotionSettings) -> dict:
    """``--online``'s scores: ``OnlineFusion`` (fixed-lag smoother, 5 s, a keyframe every 0.18 s: two model blocks)
    over the sequence from the ground-truth start, no GPS, the samples delivered 100 at a time; t_rel / r_rel of its
    keyframes (``learned_imu.evaluation.kitti_odometry``), and how many factors the speed envelope freed."""
    import gtsam

    from fusion.config import OnlineSettings
    from fusion.online import OnlineFusion

    config = FuseConfig(
        gyro_noise_density=GTSAM_NOISE[0],
        acc_noise_density=GTSAM_NOISE[1],
        online=OnlineSettings(keyframe_s=0.18, smoother="fixed_lag", lag_s=5.0),
        motion=motion,
    )
    gt = seq.gt
    start = gtsam.NavState(gtsam.Pose3(gtsam.Rot3(gt.rot[0]), gt.pos[0]), gt.vel[0])
    fusion = OnlineFusion(None, seq.gravity, start, config, motion_model=net)
    for first in range(0, len(seq.t), 100):
        fusion.add_imu(seq.t[first : first + 100], seq.gyro[first : first + 100], seq.acc[first : first + 100])
    fusion.flush()
    track = fusion.trajectory()
    at = np.searchsorted(seq.t, track.t)
    errors = relative_errors(gt.rot[at], gt.pos[at], track.rot, track.pos)
    return {
        "t_rel_percent": round(errors.t_rel_percent, 3),
        "r_rel_deg_per_m": round(errors.r_rel_deg_per_m, 5),
        "keyframes": len(track.t),
        "beyond_envelope": fusion.beyond_envelope,
    }


def velocity_row(seq, net) -> dict:
    """``--velocity``'s row for one sequence (module docstring): the model at every block end with a valid truth."""
    import torch

    from learned_imu.network.motion import block_ends, motion_sequence, up_in_body

    ends = block_ends(len(seq), net.block).numpy()
    valid = seq.gt.valid[ends]
    truth = np.einsum("nji,nj->ni", seq.gt.rot[ends], seq.gt.vel[ends])[valid]
    raw = [torch.as_tensor(x, dtype=torch.float32) for x in (seq.gyro, seq.acc)]
    out = motion_sequence(net, *raw, up_in_body(torch.as_tensor(seq.gt.rot, dtype=torch.float32)))
    vel, var = out.vel.double().numpy()[valid], out.vel_var.double().numpy()[valid]
    err = vel - truth
    return {
        "rmse_m_s": np.sqrt(np.mean(err**2, axis=0)).round(3).tolist(),
        "mean_error_m_s": err.mean(axis=0).round(3).tolist(),
        "median_sigma_m_s": np.sqrt(np.median(var, axis=0)).round(3).tolist(),
        "nees": np.mean(err**2 / var, axis=0).round(2).tolist(),
        "correlation": [round(float(np.corrcoef(vel[:, i], truth[:, i])[0, 1]), 2) for i in range(3)],
    }


def ate_between_fixes(seq, result, fused) -> float:
    """ATE (m, unaligned) of a fused result's IMU-rate track against the ground truth between the first and the last
    fused fix."""
    dense = imu_rate_trajectory(result)
    at, keep = truth_rows(seq, dense.t)
    keep &= (dense.t >= fused.t[0]) & (dense.t <= fused.t[-1])
    return round(float(np.sqrt(np.mean(np.sum((dense.pos[keep] - seq.gt.pos[at[keep]]) ** 2, 1)))), 3)


def gtsam_validation_rows(net, fold_config, motion: MotionSettings) -> list[dict]:
    """``--gtsam-drive --validate``: the ``--gtsam-drive`` rows on fold 1's validation drives (which its model never
    saw), 1-Hz fixes simulated from the truth (``GPS_SIGMA_M``), one in ten fused, from the ground-truth start: ATE
    between the first and the last fused fix, for choosing the motion settings of that row without its drive."""
    rows = []
    for seq in load_sequences(fold_config.data.val, fold_config.data.root):
        fixes = gps_for(seq, 1.0, GPS_SIGMA_M, seed=0, source="simulated")[0]
        fused = fixes[np.arange(len(fixes.t)) % 10 == 0]
        row = {"sequence": seq.name, "validation": True}
        config = FuseConfig(keyframe_s=1.0, motion=motion)
        for name, model in (("raw IMU", None), ("raw IMU + motion", net)):
            result = fuse(seq, fused, None, config, motion_model=model, start="ground-truth")
            row[name] = ate_between_fixes(seq, result, fused)
        rows.append(row)
        print(json.dumps(row), flush=True)
    return rows


def add_start_and_scale_arguments(parser: argparse.ArgumentParser) -> None:
    """``--scale`` and ``--start-sigmas`` (this script's and ``motion_euroc.py``'s; ``with_start_and_scale``)."""
    parser.add_argument(
        "--scale",
        type=float,
        nargs=3,
        metavar=("SIGMA", "WALK", "INTERVAL_S"),
        help="motion.scale_sigma, scale_walk (per sqrt(s)), scale_interval_s: speed-scale states",
    )
    parser.add_argument(
        "--start-sigmas",
        type=float,
        nargs=2,
        metavar=("ROT_RAD", "VEL_M_S"),
        help="the prior on the ground-truth start (graph.prior_rot_sigma_rad, prior_vel_sigma_m_s; default the "
        "fuse config's 0.01 rad, 0.1 m/s; AI-IMU's KITTI filter starts at 1e-3 rad, 0.316 m/s: cov_Rot0 1e-6, "
        "cov_v0 1e-1)",
    )


def with_start_and_scale(config: FuseConfig, args: argparse.Namespace) -> FuseConfig:
    """``config`` with ``--scale``'s speed-scale states and ``--start-sigmas``' start prior, where given."""
    if args.scale:
        sigma, walk, interval = args.scale
        motion = dataclasses.replace(config.motion, scale_sigma=sigma, scale_walk=walk, scale_interval_s=interval)
        config = dataclasses.replace(config, motion=motion)
    if args.start_sigmas:
        rot, vel = args.start_sigmas
        graph = dataclasses.replace(config.graph, prior_rot_sigma_rad=rot, prior_vel_sigma_m_s=vel)
        config = dataclasses.replace(config, graph=graph)
    return config


def measured_delay() -> dict:
    """``--measure-delay``: the IMU's delay against the ground truth, pooled over the LOO template's training drives
    that are none of the ten sequences (so no sequence's score chose it), and each drive's own."""
    from learned_imu.evaluation.imu_delay import measure_imu_delay

    template = load_config("configs/kitti_motion_loo.yaml")
    drives = {drive for drive, *_ in SEQUENCES.values()}
    specs = [spec for spec in template.data.train if not any(drive in spec.path for drive in drives)]
    found = measure_imu_delay(load_sequences(specs, template.data.root))
    return {
        "imu_delay_s": round(found.delay_s, 4),
        "drives": [
            {"drive": name, "own_delay_s": round(own, 4), "rate_mse_at_delay": mse, "rate_mse_at_zero": zero}
            for name, own, mse, zero in found.sequences
        ],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fold", nargs=2, action="append", default=[], metavar=("N", "CHECKPOINT"))
    parser.add_argument(
        "--loo", help="leave-one-sequence-out models instead: DIR/seqS/best.pt scores S (motion_kitti_loo.py)"
    )
    parser.add_argument(
        "--correction", nargs=2, action="append", default=[], metavar=("N", "CHECKPOINT"),
        help="fold N's AirIMU model (configs/kitti_fold*.yaml): adds its rows",
    )  # fmt: skip
    parser.add_argument("--only", nargs="*", help="sequences to run (default: all of the folds given)")
    parser.add_argument("--keyframe-s", type=float, default=MotionSettings.keyframe_s, help="motion.keyframe_s")
    parser.add_argument("--passes", type=int, default=MotionSettings.passes, help="motion.passes")
    parser.add_argument(
        "--cov-scale", type=float, nargs="+", default=[MotionSettings.cov_scale], help="motion.cov_scale: 1 or 3"
    )
    parser.add_argument(
        "--mount-sigma", type=float, nargs="+", help="motion.mount_sigma_rad: a mounting-rotation state (1 or 3, rad)"
    )
    add_start_and_scale_arguments(parser)
    parser.add_argument("--imu-delay", type=float, default=0.0, help="FuseConfig.imu_delay_s of every row (s)")
    parser.add_argument(
        "--measure-delay",
        action="store_true",
        help="only measure the IMU's delay (learned_imu.evaluation.imu_delay) on the LOO template's training drives "
        "that are no sequence (configs/kitti_motion_loo.yaml)",
    )
    parser.add_argument(
        "--imu-gaps",
        choices=IMU_GAPS,
        default="hold",
        help="FuseConfig.imu_gaps of every row: how a gap of the IMU is integrated",
    )
    parser.add_argument(
        "--speed-envelope",
        type=lambda v: None if v.lower() in ("none", "null") else float(v),
        default=MotionSettings.speed_envelope,
        help="motion.speed_envelope: a factor on the model's training speed, or none",
    )
    parser.add_argument(
        "--estimate-bias", action="store_true", help="FuseConfig.estimate_bias: bias states in the no-GPS graphs"
    )
    parser.add_argument(
        "--online", action="store_true", help="the motion row by OnlineFusion instead (fixed lag, raw IMU held gaps)"
    )
    parser.add_argument("--outages", action="store_true", help="also the GPS-outage rows")
    parser.add_argument("--gtsam-drive", action="store_true", help="only GTSAM's drive, one fix in ten (fold 1)")
    parser.add_argument(
        "--validate", action="store_true", help="score the folds' validation drives (whole) instead: for settings"
    )
    parser.add_argument("--fix-every", type=int, default=10, help="--gtsam-drive: one fix in this many (default 10)")
    parser.add_argument(
        "--velocity", action="store_true", help="the motion model's velocity error and NEES instead of the graphs"
    )
    parser.add_argument("--json", help="write the rows here")
    args = parser.parse_args()
    if args.measure_delay:
        print(json.dumps(measured_delay()))
        return
    if bool(args.fold) == bool(args.loo):
        parser.error("give --fold N CHECKPOINT (once or twice) or --loo DIR")
    logging.basicConfig(level=logging.ERROR)
    mount = None if args.mount_sigma is None else tuple(args.mount_sigma)
    motion = MotionSettings(args.keyframe_s, args.passes, tuple(args.cov_scale), mount, args.speed_envelope)
    config = FuseConfig(
        gyro_noise_density=GTSAM_NOISE[0],
        acc_noise_density=GTSAM_NOISE[1],
        keyframe_s=1.0,
        imu_gaps=args.imu_gaps,
        imu_delay_s=args.imu_delay,
        motion=motion,
        estimate_bias=args.estimate_bias,
    )
    config = with_start_and_scale(config, args)
    motion = config.motion
    rows, outages = [], []
    if args.gtsam_drive:
        net = motion_from_checkpoint(dict(args.fold)["1"])[0]
        fold_config = load_config("configs/kitti_motion_fold1.yaml")
        if args.validate:
            rows = gtsam_validation_rows(net, fold_config, motion)
        else:
            correction = None
            if "1" in dict(args.correction):
                correction, corrected_by = model_from_checkpoint(dict(args.correction)["1"])
                if any("2011_10_03_drive_0027" in spec.path for spec in corrected_by.data.train):
                    raise SystemExit(f"{dict(args.correction)['1']} was trained on GTSAM's drive")
            root = Path(fold_config.data.root)
            rows = gtsam_drive_rows(net, root, motion, correction, args.fix_every, args.imu_gaps)
        args.fold = []
    runs = [(fold, checkpoint, False) for fold, checkpoint in args.fold]
    if args.loo:  # each sequence by its own model; the drive to score is the one its run held out
        held = [s for s in sorted(SEQUENCES) if not args.only or s in args.only]
        runs = [(f"loo {s}", str(Path(args.loo) / f"seq{s}" / "best.pt"), True) for s in held]
    for fold, checkpoint, loo in runs:
        net, trained = motion_from_checkpoint(checkpoint)
        trained_on = {spec.path for spec in trained.data.train}
        correction = None
        if fold in dict(args.correction):
            correction, corrected_by = model_from_checkpoint(dict(args.correction)[fold])
            trained_on |= {spec.path for spec in corrected_by.data.train}
        fold_config = trained if loo else load_config(f"configs/kitti_motion_fold{fold}.yaml")
        if args.validate:
            for seq in load_sequences(fold_config.data.val, fold_config.data.root):
                part = dataclasses.replace(seq, gps=None)
                row = {"sequence": seq.name, "fold": fold, "validation": True}
                row["imu"] = scores(part, fuse(part, None, None, config, start="ground-truth"))
                row["motion"] = scores(part, fuse(part, None, None, config, motion_model=net, start="ground-truth"))
                rows.append(row)
                print(json.dumps(row), flush=True)
            continue
        drives = load_sequences(fold_config.data.evaluate, fold_config.data.root)
        for spec, seq in zip(fold_config.data.evaluate, drives, strict=True):
            name = next(k for k, v in SEQUENCES.items() if v[0] in spec.path)
            if args.only and name not in args.only:
                continue
            if spec.path in trained_on:
                raise SystemExit(f"{checkpoint} was trained on {spec.path}: not a test drive of fold {fold}")
            drive, first, last, ai_imu = SEQUENCES[name]
            part = sequence_range(seq, Path(fold_config.data.root) / spec.path, first, last)
            part = dataclasses.replace(part, name=f"seq {name} ({drive})", gps=None)
            start = time.perf_counter()
            row = {"sequence": name, "drive": drive, "fold": fold, "ai_imu_t_rel_percent": ai_imu}
            if args.velocity:
                row |= velocity_row(part, net)
                rows.append(row)
                print(json.dumps(row), flush=True)
                continue
            if args.online:
                row["online_motion"] = online_row(part, net, motion)
                rows.append(row)
                print(json.dumps(row), flush=True)
                continue
            row["imu"] = scores(part, fuse(part, None, None, config, start="ground-truth"))
            row["motion"] = scores(part, fuse(part, None, None, config, motion_model=net, start="ground-truth"))
            if correction is not None:
                learned = FuseConfig(keyframe_s=1.0, imu_gaps=args.imu_gaps, motion=motion)
                row["airimu"] = scores(part, fuse(part, None, correction, learned, start="ground-truth"))
                row["airimu_motion"] = scores(
                    part, fuse(part, None, correction, learned, motion_model=net, start="ground-truth")
                )
            row["seconds"] = round(time.perf_counter() - start, 1)
            rows.append(row)
            print(json.dumps(row), flush=True)
            if args.outages:
                outages += outage_rows(part, net, config, correction)
    if args.json:
        Path(args.json).write_text(json.dumps({"t_rel": rows, "outages": outages}, indent=1))


if __name__ == "__main__":
    main()
