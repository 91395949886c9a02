"""GTSAM's ``IMUKittiExampleGPS.py`` pattern with learned factors: an ISAM2 loop over GTSAM's KITTI drive (the IMU
and GPS files that gtsam installs), a keyframe at every 1 Hz GPS time, every ``gps_skip``-th fix fused as a
position prior, a bias state per keyframe with the example's random walk, each interval preintegrated around the
latest bias estimate, the example's first state (position from the first fix, identity rotation, zero velocity
with a loose prior).

What changes with learned factors: each interval is ``factors.learned_pim`` of the model's corrected samples with
its per-sample noise (``--checkpoint``, e.g. ``runs/kitti/best.pt`` of ``configs/kitti.yaml``); without one, the raw
samples with the example's noise (``KittiEquivBiasedImu_metadata.txt``), i.e. GTSAM's example itself. ISAM2 runs QR
(GTSAM 4.3.0's example stops with an indeterminant system under its CHOLESKY setting).

    python examples/kitti_gps_learned.py [--checkpoint runs/kitti/best.pt] [--seconds 120] [--gps-skip 10]
"""

from __future__ import annotations

import argparse

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, V, X

from factors import learned_pim
from learned_imu.datasets import read_sequence

# KittiEquivBiasedImu_metadata.txt: continuous-time sigmas; the bias sigmas are per sample (times sqrt(samples))
GYRO_SIGMA, ACC_SIGMA, GYRO_BIAS_SIGMA, ACC_BIAS_SIGMA = 1.75e-4, 0.01, 2.91e-6, 1.67e-4
GPS_NOISE = gtsam.noiseModel.Diagonal.Precisions(np.array([0.0] * 3 + [1.0 / 0.07] * 3))


def run(seconds: float | None = None, checkpoint: str | None = None, gps_skip: int = 10) -> dict:
    """The loop; returns the RMSE (m) of the keyframe positions against every GPS fix, and the keyframe count."""
    seq = read_sequence("kitti")  # gtsam's copies of KittiEquivBiasedImu.txt and KittiGps_converted.txt
    gyro, acc = seq.gyro, seq.acc
    gyro_cov, acc_cov = np.full_like(gyro, GYRO_SIGMA**2), np.full_like(acc, ACC_SIGMA**2)
    if checkpoint:
        from learned_imu.network.inference import correct_from_checkpoint

        out = correct_from_checkpoint(checkpoint, seq)
        gyro, acc, gyro_cov, acc_cov = (x.numpy() for x in (out.gyro, out.acc, out.gyro_cov, out.acc_cov))
    fixes = seq.gps
    end = len(fixes.t) if seconds is None else int(np.searchsorted(fixes.t, fixes.t[0] + seconds))
    params = gtsam.PreintegrationParams(seq.gravity)
    isam_params = gtsam.ISAM2Params()
    isam_params.setFactorization("QR")
    isam_params.relinearizeSkip = 10
    isam = gtsam.ISAM2(isam_params)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    pose, vel, bias = gtsam.Pose3(gtsam.Rot3(), fixes.pos[0]), np.zeros(3), gtsam.imuBias.ConstantBias()
    values.insert(X(0), pose)
    values.insert(V(0), vel)
    values.insert(B(0), bias)
    position_only = gtsam.noiseModel.Diagonal.Precisions(np.array([0, 0, 0, 1, 1, 1.0]))
    graph.add(gtsam.PriorFactorPose3(X(0), pose, position_only))
    graph.add(gtsam.PriorFactorVector(V(0), vel, gtsam.noiseModel.Isotropic.Sigma(3, 1000.0)))
    bias_prior = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.1] * 3 + [5e-5] * 3))
    graph.add(gtsam.PriorFactorConstantBias(B(0), bias, bias_prior))
    sample = np.searchsorted(seq.t, fixes.t)  # the first IMU sample at or after each fix
    for k in range(1, end):
        take = slice(sample[k - 1], sample[k])
        n = take.stop - take.start
        pim = learned_pim(gyro[take], acc[take], seq.dt[take], gyro_cov[take], acc_cov[take], bias=bias, params=params)
        graph.add(gtsam.ImuFactor(X(k - 1), V(k - 1), X(k), V(k), B(k - 1), pim))
        walk = np.sqrt(n) * np.array([ACC_BIAS_SIGMA] * 3 + [GYRO_BIAS_SIGMA] * 3)
        graph.add(gtsam.BetweenFactorConstantBias(B(k - 1), B(k), gtsam.imuBias.ConstantBias(),
                                                  gtsam.noiseModel.Diagonal.Sigmas(walk)))  # fmt: skip
        if k % gps_skip == 0:
            fix = gtsam.Pose3(pose.rotation(), fixes.pos[k])
            graph.add(gtsam.PriorFactorPose3(X(k), fix, GPS_NOISE))
            values.insert(X(k), fix)
        else:
            values.insert(X(k), pose)
        values.insert(V(k), vel)
        values.insert(B(k), bias)
        if k > 2 * gps_skip:  # as the example: a few fixes first, so that the heading is observable
            isam.update(graph, values)
            graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
            estimate = isam.calculateEstimate()
            pose, vel, bias = estimate.atPose3(X(k)), estimate.atVector(V(k)), estimate.atConstantBias(B(k))
    estimate = isam.calculateEstimate()
    pos = np.array([estimate.atPose3(X(k)).translation() for k in range(end)])
    rmse = float(np.sqrt(np.mean(np.sum((pos - fixes.pos[:end]) ** 2, axis=1))))
    return {"rmse_to_gps_m": rmse, "keyframes": end}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoint", default=None, help="a trained model (default: GTSAM's example settings)")
    parser.add_argument("--seconds", type=float, default=None, help="only the first seconds of the drive")
    parser.add_argument("--gps-skip", type=int, default=10)
    args = parser.parse_args()
    result = run(args.seconds, args.checkpoint, args.gps_skip)
    print(f"keyframes: {result['keyframes']}")
    print(f"RMSE against every GPS fix: {result['rmse_to_gps_m']:.3f} m")


if __name__ == "__main__":
    main()
