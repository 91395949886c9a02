"""GTSAM's ``IMUKittiExampleGPS.py`` as shipped (its IMU and GPS files, its ISAM2 loop, keyframes at every 1 Hz fix,
every ``gps_skip``-th fix fused; phases whose ISAM2 update fails are reported as failed), scored as
``configs/pgo_kitti.yaml`` scores its rows: ATE (RMSE, no alignment) against the OXTS ground truth of
``kitti_raw/2011_10_03_drive_0027.csv`` at every raw sample between the first and the last fused fix. The reference
for the GTSAM row of ``airimu ablate-pgo --config configs/pgo_kitti.yaml``, which keeps the example's noise, bias
model and GPS noise but shares the other rows' graph, samples and solver.

    python benchmarks/kitti_gtsam_example.py [--data ../shared/data] [--gps-skip 10] [--factorization QR]

The loop is the example's (first fix 1, identity first rotation with no rotation prior, zero first velocity with
sigma 1000 m/s, 2 * gps_skip fixes before the first ISAM2 update, each interval re-preintegrated at the latest bias
estimate); GTSAM 4.3.0 stops with an indeterminant system under its CHOLESKY setting, so QR is the default here.
The solution lives in the GPS file's frame; it is mapped into the ground truth's ENU frame by the per-axis scale and
offset that ``read_kitti_raw(gps_file=...)`` fits. Every phase of the fused fixes (0 .. gps_skip - 1) is run.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, V, X

from fusion.graph import Trajectory
from learned_imu.datasets import read_sequence

DRIVE = "kitti_raw/2011_10_03_drive_0027.csv"
REPAIR = {"on_backward": "drop", "on_duplicate": "drop", "on_gap": "keep"}


def load(data: Path):
    meta = np.loadtxt(data / "kitti_gtsam" / "KittiEquivBiasedImu_metadata.txt", skiprows=1)
    imu = np.loadtxt(data / "kitti_gtsam" / "KittiEquivBiasedImu.txt", skiprows=1)
    gps = np.loadtxt(data / "kitti_gtsam" / "KittiGps_converted.txt", delimiter=",", skiprows=1)
    return meta, imu, gps


def run_example(meta, imu, gps, gps_skip: int, phase: int, factorization: str) -> Trajectory:
    """The example's main loop with the fused fixes ``i % gps_skip == phase``; the final ISAM2 estimate."""
    acc_sigma, gyro_sigma, integration_sigma, acc_bias_sigma, gyro_bias_sigma = meta[6:11]
    params = gtsam.PreintegrationParams.MakeSharedU(9.8)
    params.setAccelerometerCovariance(np.eye(3) * acc_sigma**2)
    params.setGyroscopeCovariance(np.eye(3) * gyro_sigma**2)
    params.setIntegrationCovariance(np.eye(3) * integration_sigma**2)
    isam_params = gtsam.ISAM2Params()
    isam_params.setFactorization(factorization)
    isam_params.relinearizeSkip = 10
    isam = gtsam.ISAM2(isam_params)
    factors, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    gps_noise = gtsam.noiseModel.Diagonal.Precisions(np.array([0.0] * 3 + [1.0 / 0.07] * 3))
    first = 1
    pose, vel, bias = gtsam.Pose3(gtsam.Rot3(), gps[first, 1:]), np.zeros(3), gtsam.imuBias.ConstantBias()
    j = 0
    for i in range(first, len(gps)):
        t = gps[i, 0]
        if i == first:
            values.insert(X(i), pose)
            values.insert(V(i), vel)
            values.insert(B(i), bias)
            factors.addPriorPose3(X(i), pose, gtsam.noiseModel.Diagonal.Precisions(np.array([0, 0, 0, 1, 1, 1.0])))
            factors.addPriorVector(V(i), vel, gtsam.noiseModel.Diagonal.Sigmas(np.ones(3) * 1000.0))
            factors.addPriorConstantBias(B(i), bias, gtsam.noiseModel.Diagonal.Sigmas(np.array([0.1] * 3 + [5e-5] * 3)))
            continue
        pim = gtsam.PreintegratedImuMeasurements(params, bias)
        count = 0
        while j < len(imu) and imu[j, 0] <= t:
            if imu[j, 0] >= gps[i - 1, 0]:
                pim.integrateMeasurement(imu[j, 2:5], imu[j, 5:8], imu[j, 1])
                count += 1
            j += 1
        factors.push_back(gtsam.ImuFactor(X(i - 1), V(i - 1), X(i), V(i), B(i - 1), pim))
        walk = np.sqrt(count) * np.array([acc_bias_sigma] * 3 + [gyro_bias_sigma] * 3)
        factors.push_back(gtsam.BetweenFactorConstantBias(
            B(i - 1), B(i), gtsam.imuBias.ConstantBias(), gtsam.noiseModel.Diagonal.Sigmas(walk)))  # fmt: skip
        if i % gps_skip == phase:
            fix = gtsam.Pose3(pose.rotation(), gps[i, 1:])
            factors.addPriorPose3(X(i), fix, gps_noise)
            values.insert(X(i), fix)
        else:
            values.insert(X(i), pose)
        values.insert(V(i), vel)
        values.insert(B(i), bias)
        if i > first + 2 * gps_skip:
            isam.update(factors, values)
            factors.resize(0)
            values.clear()
            result = isam.calculateEstimate()
            pose, vel, bias = result.atPose3(X(i)), result.atVector(V(i)), result.atConstantBias(B(i))
    result = isam.calculateEstimate()
    keys = range(first, len(gps))
    return Trajectory(
        t=gps[first:, 0],
        rot=np.array([result.atPose3(X(k)).rotation().matrix() for k in keys]),
        pos=np.array([result.atPose3(X(k)).translation() for k in keys]),
        vel=np.array([result.atVector(V(k)) for k in keys]),
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(Path(__file__).resolve().parents[2] / "shared" / "data"))
    parser.add_argument("--gps-skip", type=int, default=10)
    parser.add_argument("--factorization", default="QR", choices=("QR", "CHOLESKY"))
    args = parser.parse_args()
    data = Path(args.data)
    meta, imu, gps = load(data)
    truth = read_sequence("kitti_raw", data / DRIVE, **REPAIR)
    as_is = read_sequence("kitti_raw", data / DRIVE, **REPAIR, gps_file="../kitti_gtsam/KittiGps_converted.txt",
                          gps_frame="as_is").gps  # fmt: skip
    fitted = read_sequence("kitti_raw", data / DRIVE, **REPAIR, gps_file="../kitti_gtsam/KittiGps_converted.txt").gps
    scale = np.array([np.polyfit(as_is.pos[:, a], fitted.pos[:, a], 1) for a in range(3)])  # file -> ENU per axis
    ates = []
    for phase in range(args.gps_skip):
        start = time.perf_counter()
        try:
            traj = run_example(meta, imu, gps, args.gps_skip, phase, args.factorization)
        except RuntimeError as error:  # gtsam's IndeterminantLinearSystemException
            print(f"phase {phase}: failed: {str(error).strip().splitlines()[0]} {str(error).strip().splitlines()[1]}")
            continue
        pos = traj.pos * scale[:, 0] + scale[:, 1]
        traj = Trajectory(traj.t, traj.rot, pos, traj.vel * scale[:, 0])
        fused = gps[1:, 0][(np.arange(1, len(gps)) % args.gps_skip) == phase]
        inside = (truth.t >= max(fused[0], traj.t[0])) & (truth.t <= min(fused[-1], traj.t[-1]))
        err = traj.position_at(truth.t[inside]) - truth.gt.pos[inside]
        ates.append(float(np.sqrt(np.mean(np.sum(err**2, axis=1)))))
        print(f"phase {phase}: ATE {ates[-1]:.3f} m ({time.perf_counter() - start:.1f} s)", flush=True)
    rate = 1.0 / args.gps_skip
    print(f"GTSAM IMUKittiExampleGPS as shipped ({args.factorization}), {rate:g} Hz: ATE {np.mean(ates):.3f} +- "
          f"{np.std(ates):.3f} m over the {len(ates)} of {args.gps_skip} phases that solved")  # fmt: skip


if __name__ == "__main__":
    main()
