"""GTSAM's ``CombinedImuFactorExample.py`` pattern with learned factors: a ``gtsam.CombinedImuFactor`` per keyframe
interval with its own bias states ``B(k)``, ``B(k+1)`` and the bias random walk of
``gtsam.PreintegrationCombinedParams``, here with 1 Hz GPS fixes; Levenberg-Marquardt.

What changes with learned factors: the factors come from an airimu export (corrected samples and per-sample noise;
without ``--checkpoint`` the raw samples with constant noise) through ``factors.from_export(export,
factor="combined", params=params)``, GTSAM's own combined preintegration fed with the learned noise; everything
else in ``params`` (gravity, the bias random walk) is honoured.

    python examples/combined_imu_factor_learned.py [--checkpoint runs/demo/best.pt]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, V, X

from airimu.experiments.pgo import gps_for
from factors import GpsFactor, from_export, gps_noise
from learned_imu.datasets.simulator import ImuErrorModel, simulate
from learned_imu.export import export_preintegration, keyframes_every

# white noise, bias random walk (rad/s^2/sqrt(Hz), m/s^3/sqrt(Hz)) and turn-on biases
ERRORS = ImuErrorModel(1e-4, 1e-3, 1e-4, 1e-3, 0.05, 0.1)
NOISE_COV = (1e-4**2, 1e-3**2)  # without a model: the simulated white noise, sigma^2
GPS_SIGMA_M = 0.3


def run(seconds: float = 30.0, checkpoint: str | None = None, seed: int = 5) -> dict:
    """Solve; returns the ATE (m) at the keyframes, the GPS's own error, and the bias estimate against the truth
    at the first keyframe (rad/s)."""
    seq = simulate("car", duration_s=seconds, error_model=ERRORS, seed=seed)
    noise, samples = NOISE_COV, (None, None)
    if checkpoint:
        from learned_imu.network.inference import correct_from_checkpoint

        out = correct_from_checkpoint(checkpoint, seq)
        noise, samples = (out.gyro_cov.numpy(), out.acc_cov.numpy()), (out.gyro.numpy(), out.acc.numpy())
    path = Path(tempfile.mkdtemp()) / "learned.npz"
    index = keyframes_every(seq, 0.5)
    export_preintegration(path, seq, index, *noise, *samples)

    params = gtsam.PreintegrationCombinedParams(seq.gravity)
    params.setIntegrationCovariance(np.zeros((3, 3)))
    params.setBiasOmegaCovariance(np.eye(3) * ERRORS.gyro_bias_rw_rad_s2_sqrthz**2)
    params.setBiasAccCovariance(np.eye(3) * ERRORS.acc_bias_rw_m_s3_sqrthz**2)
    imu_factors, times = from_export(path, X, V, B, factor="combined", params=params)

    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for factor in imu_factors:
        graph.add(factor)
    first = gtsam.Pose3(gtsam.Rot3(seq.gt.rot[0]), seq.gt.pos[0])
    graph.add(gtsam.PriorFactorPose3(X(0), first, gtsam.noiseModel.Isotropic.Sigma(6, 0.01)))
    graph.add(gtsam.PriorFactorVector(V(0), seq.gt.vel[0], gtsam.noiseModel.Isotropic.Sigma(3, 0.1)))
    loose = gtsam.noiseModel.Isotropic.Sigma(6, 1.0)
    graph.add(gtsam.PriorFactorConstantBias(B(0), gtsam.imuBias.ConstantBias(), loose))
    fixes, _ = gps_for(seq, 1.0, GPS_SIGMA_M, seed=0)
    for t, pos in zip(fixes.t, fixes.pos, strict=True):
        graph.add(GpsFactor(X(int(np.argmin(np.abs(times - t)))), pos, gps_noise(GPS_SIGMA_M)))
    for k, i in enumerate(index):  # initial values: the truth disturbed
        values.insert(X(k), gtsam.Pose3(gtsam.Rot3(seq.gt.rot[i]), seq.gt.pos[i] + 1.0))
        values.insert(V(k), seq.gt.vel[i] + 0.5)
        values.insert(B(k), gtsam.imuBias.ConstantBias())
    result = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()

    pos = np.array([result.atPose3(X(k)).translation() for k in range(len(times))])
    ate = float(np.sqrt(np.mean(np.sum((pos - seq.gt.pos[index]) ** 2, axis=1))))
    gps_error = float(np.sqrt(np.mean(np.sum((fixes.pos - seq.gt.pos[np.searchsorted(seq.t, fixes.t)]) ** 2, 1))))
    return {"ate_m": ate, "gps_error_m": gps_error, "gyro_bias_0": result.atConstantBias(B(0)).gyroscope()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoint", default=None, help="a trained model (default: the raw IMU, constant noise)")
    parser.add_argument("--seconds", type=float, default=30.0)
    args = parser.parse_args()
    result = run(args.seconds, args.checkpoint)
    print(f"GPS alone error: {result['gps_error_m']:.3f} m")
    print(f"fused ATE: {result['ate_m']:.3f} m")
    print(f"gyro bias at the first keyframe: {np.array2string(result['gyro_bias_0'], precision=4)} rad/s")


if __name__ == "__main__":
    main()
