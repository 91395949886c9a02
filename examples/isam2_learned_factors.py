"""Learned IMU factors in an existing ISAM2 loop.

A GTSAM user already runs ISAM2 over keyframes ``X(k)`` with factors of their own (here: 1 Hz GPS fixes on the
nearest keyframe). An airimu export (``airimu export``, or ``learned_imu.export.export_preintegration``) holds per
keyframe interval the learned preintegrated deltas, their 9x9 covariance and bias Jacobian;
``factors.from_export(..., backend="gtsam")`` turns them into GTSAM's own C++ ``ImuFactor``s. The loop gains one
factor per keyframe, a velocity key ``V(k)`` and one bias key ``B(0)`` held at zero (the learned samples are already
corrected); the factor's ``predict`` gives the new keyframe's initial value.

Runs on the simulator, no files needed:

    python examples/isam2_learned_factors.py [--checkpoint runs/demo/best.pt]

(``fusion.online.OnlineFusion`` does the same from raw samples as they arrive, the model in streaming mode.)
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import gtsam
import numpy as np

from airimu.experiments.pgo import gps_for
from factors import GpsFactor, from_export, gps_noise
from learned_imu.datasets.simulator import simulate
from learned_imu.export import export_preintegration, keyframes_every

X, V, B = gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.V, gtsam.symbol_shorthand.B
GPS_SIGMA_M = 0.5
# without a model: the raw samples with the paper's fixed noise (VINS-Mono's EuRoC setting, rad^2/s and m^2/s^3)
RAW_DENSITIES = (0.004**2, 0.08**2)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoint", default=None, help="a trained model (default: raw IMU, fixed noise)")
    args = parser.parse_args()

    # the data: 60 s of a simulated drone with an ADIS16448-class IMU (EuRoC's) at 200 Hz, and GPS fixes at 1 Hz
    seq = simulate("drone", duration_s=60.0, grade="industrial", seed=4)
    gps, truth = gps_for(seq, 1.0, GPS_SIGMA_M, seed=0)
    noise, samples = RAW_DENSITIES, (None, None)
    if args.checkpoint:
        from learned_imu.network.inference import correct_from_checkpoint

        out = correct_from_checkpoint(args.checkpoint, seq)
        noise, samples = (out.gyro_cov.numpy(), out.acc_cov.numpy()), (out.gyro.numpy(), out.acc.numpy())
    path = Path(tempfile.mkdtemp()) / "learned.npz"
    export_preintegration(path, seq, keyframes_every(seq, 0.5), *noise, *samples)

    # the learned factors: factor k joins keyframes k and k + 1
    imu_factors, times = from_export(path, X, V, lambda k: B(0), backend="gtsam")

    # the user's ISAM2 loop, one keyframe per step
    isam = gtsam.ISAM2()
    zero_bias = gtsam.imuBias.ConstantBias()
    fix_at = dict(zip(np.searchsorted(times, gps.t).tolist(), gps.pos, strict=True))  # fixes lie on keyframes here
    for k in range(len(times)):
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        if k == 0:  # the user's prior, plus the zero bias the learned factors share
            pose = gtsam.Pose3(gtsam.Rot3(seq.gt.rot[0]), seq.gt.pos[0])
            graph.add(gtsam.PriorFactorPose3(X(0), pose, gtsam.noiseModel.Isotropic.Sigma(6, 0.1)))
            graph.add(gtsam.PriorFactorVector(V(0), seq.gt.vel[0], gtsam.noiseModel.Isotropic.Sigma(3, 0.1)))
            graph.add(gtsam.NonlinearEqualityConstantBias(B(0), zero_bias))
            values.insert(B(0), zero_bias)
            state = gtsam.NavState(pose, seq.gt.vel[0])
        else:  # NEW: the learned IMU factor into this keyframe, and its prediction as the initial value
            graph.add(imu_factors[k - 1])
            previous = gtsam.NavState(isam.calculateEstimatePose3(X(k - 1)), isam.calculateEstimateVector(V(k - 1)))
            state = imu_factors[k - 1].preintegratedMeasurements().predict(previous, zero_bias)
        values.insert(X(k), state.pose())
        values.insert(V(k), state.velocity())
        if k in fix_at:  # the user's own factor
            graph.add(GpsFactor(X(k), fix_at[k], gps_noise(GPS_SIGMA_M)))
        isam.update(graph, values)

    # how well it did: keyframe positions against the ground truth
    estimate = isam.calculateEstimate()
    fused = np.array([estimate.atPose3(X(k)).translation() for k in range(len(times))])
    fused_error = fused - truth.pos[np.searchsorted(truth.t, times)]
    gps_error = gps.pos - truth.pos[np.searchsorted(truth.t, gps.t)]
    print(f"keyframes: {len(times)}")
    print(f"GPS alone error: {np.sqrt(np.mean(np.sum(gps_error**2, axis=1))):.3f} m (RMSE at the fixes)")
    print(f"fused ATE: {np.sqrt(np.mean(np.sum(fused_error**2, axis=1))):.3f} m (RMSE at every keyframe)")


if __name__ == "__main__":
    main()
