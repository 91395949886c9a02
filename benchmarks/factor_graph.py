"""The same IMU + GPS graph solved by Levenberg-Marquardt four ways, side by side.

    python benchmarks/factor_graph.py [--keyframes 300] [--repeats 5]

(Not named factors.py: run as a script, that name would shadow the ``factors`` package.)

1. built-in: ``gtsam.ImuFactor`` from ``PreintegratedImuMeasurements`` with a constant noise density;
2. learned_pim: ``gtsam.ImuFactor`` from ``factors.learned_pim`` (per-sample noise; C++ factor);
3. LearnedImuFactor: our Python ``CustomFactor`` built from the same deltas and covariance;
4. pim_from_deltas: ``gtsam.ImuFactor`` rebuilt from those deltas and covariance (the export's fast route);
5. callback floor: a Python ``CustomFactor`` whose callback only asks the built-in C++ factor for its whitened
   error and Jacobians -- the cost of GTSAM's Python callback mechanism itself (the call, and the copy of the
   optimiser's whole ``Values`` that pybind11 makes for every call), with no math in Python.
A simulated drone flight at 200 Hz with white noise only (industrial grade; no bias, so the three graphs model
the data exactly), keyframes every 0.5 s, GPS (sigma 0.5 m) at every keyframe. Reported: median LM solve
time, ratio to the built-in, and error+Jacobian evaluations per second of one IMU factor (``linearize``).
"""

from __future__ import annotations

import argparse
import statistics
import time

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, V, X

from factors import LearnedImuFactor, learned_pim
from factors.pim_from_deltas import pim_from_deltas
from learned_imu.datasets.simulator import ImuErrorModel, simulate

KEYFRAME_S = 0.5
GPS_SIGMA_M = 0.5


def build_graphs(keyframes: int, seed: int = 0):
    grade = ImuErrorModel.from_grade("industrial")
    white_only = ImuErrorModel(grade.gyro_noise_density_rad_s_sqrthz, grade.acc_noise_density_m_s2_sqrthz, 0, 0, 0, 0)
    seq = simulate("drone", duration_s=keyframes * KEYFRAME_S + 1.0, seed=seed, error_model=white_only)
    gyro_density, acc_density = white_only.noise_densities()
    per = int(round(KEYFRAME_S / np.median(seq.dt)))
    gravity = float(-seq.gravity[2])
    params = gtsam.PreintegrationParams.MakeSharedU(gravity)
    params.setGyroscopeCovariance(np.diag(gyro_density))
    params.setAccelerometerCovariance(np.diag(acc_density))
    params.setIntegrationCovariance(np.zeros((3, 3)))
    names = ("built-in", "learned_pim", "LearnedImuFactor", "pim_from_deltas", "callback floor")
    graphs = {name: gtsam.NonlinearFactorGraph() for name in names}
    initial = gtsam.Values()
    rng = np.random.default_rng(seed)
    for k in range(keyframes + 1):
        i = k * per
        pose = gtsam.Pose3(gtsam.Rot3(seq.gt.rot[i]), seq.gt.pos[i])
        initial.insert(X(k), pose.retract(rng.normal(0, 0.05, 6)))
        initial.insert(V(k), seq.gt.vel[i] + rng.normal(0, 0.1, 3))
        gps = seq.gt.pos[i] + rng.normal(0, GPS_SIGMA_M, 3)  # one noisy fix, the same in every graph
        for graph in graphs.values():
            graph.add(gtsam.GPSFactor(X(k), gps, gtsam.noiseModel.Isotropic.Sigma(3, GPS_SIGMA_M)))
        if k == keyframes:
            break
        sl = slice(i, i + per)
        pim = gtsam.PreintegratedImuMeasurements(params, gtsam.imuBias.ConstantBias())
        for a, w, h in zip(seq.acc[sl], seq.gyro[sl], seq.dt[sl], strict=True):
            pim.integrateMeasurement(a, w, h)
        graphs["built-in"].add(gtsam.ImuFactor(X(k), V(k), X(k + 1), V(k + 1), B(0), pim))
        graphs["callback floor"].add(callback_floor(gtsam.ImuFactor(X(k), V(k), X(k + 1), V(k + 1), B(0), pim)))
        lpim = learned_pim(seq.gyro[sl], seq.acc[sl], seq.dt[sl], gyro_density, acc_density, gravity_m_s2=gravity)
        graphs["learned_pim"].add(gtsam.ImuFactor(X(k), V(k), X(k + 1), V(k + 1), B(0), lpim))
        rebuilt = pim_from_deltas(
            pim.deltaRij().matrix(),
            pim.deltaPij(),
            pim.deltaVij(),
            pim.deltaTij(),
            pim.preintMeasCov(),
            np.zeros((9, 6)),
            seq.gravity,
        )
        graphs["pim_from_deltas"].add(gtsam.ImuFactor(X(k), V(k), X(k + 1), V(k + 1), B(0), rebuilt))
        graphs["LearnedImuFactor"].add(
            LearnedImuFactor(
                X(k),
                V(k),
                X(k + 1),
                V(k + 1),
                pim.deltaRij().matrix(),
                pim.deltaPij(),
                pim.deltaVij(),
                pim.deltaTij(),
                pim.preintMeasCov(),
                gravity=seq.gravity,
            )
        )
    bias_prior = gtsam.PriorFactorConstantBias(
        B(0), gtsam.imuBias.ConstantBias(), gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)
    )
    for name in ("built-in", "learned_pim", "pim_from_deltas", "callback floor"):
        graphs[name].add(bias_prior)
    initial_with_bias = gtsam.Values(initial)
    initial_with_bias.insert(B(0), gtsam.imuBias.ConstantBias())
    return graphs, initial, initial_with_bias


def callback_floor(factor: gtsam.NoiseModelFactor) -> gtsam.CustomFactor:
    """A Python CustomFactor equal to ``factor`` whose callback does no math of its own (unit noise: the C++
    factor returns whitened error and Jacobians)."""
    keys = list(factor.keys())
    edges = np.cumsum([0, 6, 3, 6, 3, 6])  # columns of the linearised ImuFactor: X_i, V_i, X_j, V_j, B

    def evaluate(this, values, jacobians):
        if jacobians is None:
            return factor.whitenedError(values)
        a, b = factor.linearize(values).jacobian()  # whitened: A and b = -error
        for i in range(len(keys)):
            jacobians[i] = a[:, edges[i] : edges[i + 1]]
        return -b

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(9), keys, evaluate)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--keyframes", type=int, default=300)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    graphs, initial, initial_with_bias = build_graphs(args.keyframes)
    params = gtsam.LevenbergMarquardtParams()
    times, errors, evals = {}, {}, {}
    for name, graph in graphs.items():
        values = initial if name == "LearnedImuFactor" else initial_with_bias
        runs = []
        for _ in range(args.repeats):
            start = time.perf_counter()
            optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
            result = optimizer.optimize()
            runs.append(time.perf_counter() - start)
        times[name] = statistics.median(runs)
        errors[name] = (graph.error(result), optimizer.iterations())
        imu = next(graph.at(i) for i in range(graph.size()) if not isinstance(graph.at(i), gtsam.GPSFactor))
        count, start = 0, time.perf_counter()
        while time.perf_counter() - start < 0.5:
            imu.linearize(values)
            count += 1
        evals[name] = count / (time.perf_counter() - start)
    print(f"{args.keyframes} keyframes ({args.keyframes} IMU factors, {args.keyframes + 1} GPS factors), LM:")
    for name in graphs:
        final_error, iterations = errors[name]
        print(
            f"  {name:17s} {times[name] * 1e3:8.1f} ms  {times[name] / times['built-in']:5.2f}x built-in  "
            f"{iterations} iterations, final error {final_error:.3f}; "
            f"{evals[name]:,.0f} IMU-factor linearisations/s"
        )


if __name__ == "__main__":
    main()
