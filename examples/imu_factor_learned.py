"""GTSAM's ``ImuFactorExample.py`` pattern with learned factors: one ``gtsam.ImuFactor`` per second, one bias key
``B(0)`` for the whole run, priors on the first state only, noisy initial values, Levenberg-Marquardt.

What changes with learned factors: each second's preintegration is ``factors.learned_pim`` (GTSAM's own, fed
sample by sample with the per-sample noise a model predicts; without ``--checkpoint`` a constant noise), and
because the IMU here has large biases (gyro 0.1-0.3 rad/s, as in GTSAM's example) the factors are preintegrated
again around the solver's bias estimate until it settles (GTSAM's ``biasHat``): the first-order bias correction
alone leaves the solution metres off at such biases.

    python examples/imu_factor_learned.py [--checkpoint runs/demo/best.pt] [--seconds 12]
"""

from __future__ import annotations

import argparse

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, V, X

from factors import learned_pim
from learned_imu.datasets.simulator import ImuErrorModel, simulate

BIAS_KEY = B(0)
# GTSAM's example: acc bias (-0.3, 0.1, 0.2) m/s^2, gyro bias (0.1, 0.3, -0.1) rad/s; here drawn at that scale
ERRORS = ImuErrorModel(1e-4, 1e-3, 0.0, 0.0, 0.2, 0.2)
NOISE_COV = (1e-4**2, 1e-3**2)  # without a model: the simulated white noise, sigma^2


def run(seconds: float = 12.0, checkpoint: str | None = None, relinearise: int = 4, seed: int = 3) -> dict:
    """Solve the example; returns the final position error (m), the true and estimated bias, and iterations."""
    seq = simulate("car", duration_s=seconds + 0.5, error_model=ERRORS, seed=seed)
    gyro, acc, gyro_cov, acc_cov = seq.gyro, seq.acc, *NOISE_COV
    if checkpoint:  # the learned model's corrected samples and per-sample noise
        from learned_imu.network.inference import correct_from_checkpoint

        out = correct_from_checkpoint(checkpoint, seq)
        gyro, acc, gyro_cov, acc_cov = (x.numpy() for x in (out.gyro, out.acc, out.gyro_cov, out.acc_cov))
    per_second = int(round(1.0 / float(np.median(seq.dt))))
    starts = np.arange(0, int(seconds) * per_second + 1, per_second)  # keyframe k at sample starts[k]

    rng = np.random.default_rng(0)
    initial = gtsam.Values()
    for k, i in enumerate(starts):  # noisy initial values around the truth, as the example
        truth = gtsam.Pose3(gtsam.Rot3(seq.gt.rot[i]), seq.gt.pos[i])
        initial.insert(X(k), truth.compose(gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(0, 0.1, 3)), rng.normal(0, 1, 3))))
        initial.insert(V(k), seq.gt.vel[i] + rng.normal(0, 0.1, 3))
    initial.insert(BIAS_KEY, gtsam.imuBias.ConstantBias())

    estimate, bias = initial, gtsam.imuBias.ConstantBias()
    for _ in range(relinearise):  # preintegrate around the current bias estimate, solve, repeat
        graph = gtsam.NonlinearFactorGraph()
        graph.add(
            gtsam.PriorFactorPose3(
                X(0), gtsam.Pose3(gtsam.Rot3(seq.gt.rot[0]), seq.gt.pos[0]), gtsam.noiseModel.Isotropic.Sigma(6, 0.1)
            )
        )
        graph.add(gtsam.PriorFactorVector(V(0), seq.gt.vel[0], gtsam.noiseModel.Isotropic.Sigma(3, 0.1)))
        for k in range(len(starts) - 1):
            take = slice(starts[k], starts[k + 1])
            cov = [c[take] if np.ndim(c) else c for c in (gyro_cov, acc_cov)]
            pim = learned_pim(gyro[take], acc[take], seq.dt[take], *cov, seq.gravity, bias=bias)
            graph.add(gtsam.ImuFactor(X(k), V(k), X(k + 1), V(k + 1), BIAS_KEY, pim))
        estimate = gtsam.LevenbergMarquardtOptimizer(graph, estimate).optimize()
        bias = estimate.atConstantBias(BIAS_KEY)
    last = len(starts) - 1
    error = np.linalg.norm(estimate.atPose3(X(last)).translation() - seq.gt.pos[starts[last]])
    true_gyro_bias = np.median(seq.gyro - _true_rates(seq), axis=0)
    return {"final_error_m": float(error), "gyro_bias": bias.gyroscope(), "true_gyro_bias": true_gyro_bias}


def _true_rates(seq) -> np.ndarray:
    """Body rates from consecutive ground-truth attitudes (the simulator's gyro without its errors)."""
    rel = np.einsum("nji,njk->nik", seq.gt.rot[:-1], seq.gt.rot[1:])
    rates = np.array([gtsam.Rot3.Logmap(gtsam.Rot3(r)) for r in rel]) / seq.dt[:-1, None]
    return np.concatenate([rates, rates[-1:]])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoint", default=None, help="a trained model (default: the raw IMU, constant noise)")
    parser.add_argument("--seconds", type=float, default=12.0)
    args = parser.parse_args()
    result = run(args.seconds, args.checkpoint)
    print(f"gyro bias estimated: {np.array2string(result['gyro_bias'], precision=4)} rad/s")
    print(f"gyro bias true: {np.array2string(result['true_gyro_bias'], precision=4)} rad/s")
    print(f"final position error: {result['final_error_m']:.3f} m")


if __name__ == "__main__":
    main()
