"""A learned body-frame velocity factor (``factors.motion.MotionFactor``) at every keyframe of a 1,000-keyframe
IMU + GPS graph: what it costs a Levenberg-Marquardt solve, by route.

    python benchmarks/motion_factor.py [--keyframes 1000] [--repeats 9] [--slow-repeats 3]

The graph: a curved path (5 m/s forward, yaw rate 0.05 rad/s, so a 100 m radius), keyframes every 0.1 s, a
``gtsam.ImuFactor`` per interval from ``PreintegratedImuMeasurements`` of constant samples (100 Hz), one shared bias
``B(0)`` with a prior, priors on the first pose and velocity, a ``gtsam.GPSFactor`` (sigma 0.5 m) every 10th
keyframe; initial values perturbed from the truth. Motion measurements: the true body-frame velocity plus noise of
sigma 0.05 m/s, with that variance. Variants (one ``run_variant``):

1. without: the IMU + GPS graph, ``gtsam.LevenbergMarquardtOptimizer`` -- the reference time;
2. MotionFactor, gtsam LM: + a ``MotionFactor`` per keyframe in GTSAM's optimiser;
3. callback floor, gtsam LM: + a Python ``CustomFactor`` per keyframe whose callback does nothing (zero error, zero
   Jacobians: the same steps as 1) -- the price of GTSAM's callback mechanism alone, dominated by the copy of the
   optimiser's whole ``Values`` pybind11 makes for every call;
4. without, Python-driven LM: ``factors.motion.solve_with_python_factors`` on graph 1 (the loop's own overhead);
5. MotionFactor, Python-driven LM: the same loop with the motion factors, which then get the ``Values`` by reference;
6. MotionTerms, Python-driven LM: the same loop with the motion factors evaluated together in numpy
   (``factors.motion.MotionTerms``, ``extra=``);
7. MotionFactor, fusion.graph.solve: graph 2 handed to the estimator's ``solve`` (what ``airimu fuse --motion`` runs),
   which takes the motion factors out of the graph into 6.

Reported: median solve time, ratio to 1, LM iterations, final error (of the graph with the motion factors where the
variant has them), velocity RMS error against the truth; and the per-call costs behind them. Variants 2, 5 and 6 reach
the same solution. There is no C++ route: no factor wrapped in gtsam 4.3's Python module has the error
``R^T v - v_body`` on (Pose3, Vector3) keys (``factors/motion.py``).

Measured (CPU, two runs, repeats interleaved): 1: 0.077 s; 2: 25.6x; 3: 24x (~0.2 ms a call, the copy of 2,001
values); 4: 1.35-1.41x (GTSAM 4.3's LM eliminates in place, which Python cannot call); 5: 2.37-2.44x; 6: 1.78x.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, V, X

from factors.motion import MotionTerms, motion_factors, solve_with_python_factors
from fusion.graph import solve

GRAVITY_M_S2 = 9.81
KEYFRAME_S = 0.1
IMU_HZ = 100
SPEED_M_S = 5.0
YAW_RATE_RAD_S = 0.05
GPS_EVERY = 10  # keyframes
GPS_SIGMA_M = 0.5
MOTION_SIGMA_M_S = 0.05
GYRO_COV = 1e-6  # rad^2/s, continuous-time (GTSAM's setGyroscopeCovariance)
ACC_COV = 1e-4  # m^2/s^3
INTEGRATION_COV = 1e-8  # m^2/s


@dataclass(frozen=True)
class Problem:
    base: gtsam.NonlinearFactorGraph  # IMU + GPS + priors
    motion: list  # one MotionFactor per keyframe
    initial: gtsam.Values
    truth: list  # gtsam.NavState per keyframe


@dataclass(frozen=True)
class Variant:
    name: str
    graph: Callable[[Problem], gtsam.NonlinearFactorGraph]
    solve: Callable[[gtsam.NonlinearFactorGraph, Problem], tuple[gtsam.Values, int]]
    with_motion: bool  # whether the solved cost includes the motion measurements


def simulate(keyframes: int, seed: int = 0) -> Problem:
    rng = np.random.default_rng(seed)
    params = gtsam.PreintegrationParams.MakeSharedU(GRAVITY_M_S2)
    params.setGyroscopeCovariance(np.eye(3) * GYRO_COV)
    params.setAccelerometerCovariance(np.eye(3) * ACC_COV)
    params.setIntegrationCovariance(np.eye(3) * INTEGRATION_COV)
    pim = gtsam.PreintegratedImuMeasurements(params, gtsam.imuBias.ConstantBias())
    specific_force = np.array([0.0, SPEED_M_S * YAW_RATE_RAD_S, GRAVITY_M_S2])  # centripetal + gravity, body frame
    for _ in range(round(KEYFRAME_S * IMU_HZ)):
        pim.integrateMeasurement(specific_force, np.array([0.0, 0.0, YAW_RATE_RAD_S]), 1.0 / IMU_HZ)
    truth = [gtsam.NavState(gtsam.Pose3(), np.array([SPEED_M_S, 0.0, 0.0]))]
    for _ in range(keyframes - 1):
        truth.append(pim.predict(truth[-1], gtsam.imuBias.ConstantBias()))
    base = gtsam.NonlinearFactorGraph()
    base.add(gtsam.PriorFactorPose3(X(0), truth[0].pose(), gtsam.noiseModel.Isotropic.Sigma(6, 0.01)))
    base.add(gtsam.PriorFactorVector(V(0), truth[0].velocity(), gtsam.noiseModel.Isotropic.Sigma(3, 0.1)))
    base.add(
        gtsam.PriorFactorConstantBias(B(0), gtsam.imuBias.ConstantBias(), gtsam.noiseModel.Isotropic.Sigma(6, 1e-3))
    )
    initial = gtsam.Values()
    initial.insert(B(0), gtsam.imuBias.ConstantBias())
    gps_noise = gtsam.noiseModel.Isotropic.Sigma(3, GPS_SIGMA_M)
    for k, state in enumerate(truth):
        initial.insert(X(k), state.pose().retract(np.r_[rng.normal(0, 0.01, 3), rng.normal(0, 0.5, 3)]))
        initial.insert(V(k), state.velocity() + rng.normal(0, 0.2, 3))
        if k + 1 < keyframes:
            base.add(gtsam.ImuFactor(X(k), V(k), X(k + 1), V(k + 1), B(0), pim))
        if k % GPS_EVERY == 0:
            base.add(gtsam.GPSFactor(X(k), state.position() + rng.normal(0, GPS_SIGMA_M, 3), gps_noise))
    v_body = np.array([s.bodyVelocity() for s in truth]) + rng.normal(0, MOTION_SIGMA_M_S, (keyframes, 3))
    motion = motion_factors(v_body, np.full((keyframes, 3), MOTION_SIGMA_M_S**2))
    return Problem(base, motion, initial, truth)


def with_factors(base: gtsam.NonlinearFactorGraph, extra: list) -> gtsam.NonlinearFactorGraph:
    graph = gtsam.NonlinearFactorGraph(base)
    for factor in extra:
        graph.add(factor)
    return graph


CALLS = [0]  # evaluations of the no-op callback


def noop_factors(keyframes: int) -> list[gtsam.CustomFactor]:
    """CustomFactors on (X(k), V(k)) that do nothing: zero error, zero Jacobians."""

    def evaluate(this, values, jacobians):
        CALLS[0] += 1
        if jacobians is not None:
            jacobians[0], jacobians[1] = np.zeros((3, 6)), np.zeros((3, 3))
        return np.zeros(3)

    unit = gtsam.noiseModel.Unit.Create(3)
    return [gtsam.CustomFactor(unit, [X(k), V(k)], evaluate) for k in range(keyframes)]


def gtsam_lm(graph: gtsam.NonlinearFactorGraph, problem: Problem) -> tuple[gtsam.Values, int]:
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, problem.initial)
    return optimizer.optimize(), optimizer.iterations()


def python_lm(graph: gtsam.NonlinearFactorGraph, problem: Problem) -> tuple[gtsam.Values, int]:
    solution = solve_with_python_factors(graph, problem.initial)
    return solution.values, solution.iterations


def fusion_solve(graph: gtsam.NonlinearFactorGraph, problem: Problem) -> tuple[gtsam.Values, int]:
    solution = solve(graph, problem.initial, np.arange(len(problem.truth), dtype=float))
    return solution.values, solution.iterations


def python_lm_terms(graph: gtsam.NonlinearFactorGraph, problem: Problem) -> tuple[gtsam.Values, int]:
    solution = solve_with_python_factors(graph, problem.initial, extra=(MotionTerms(problem.motion),))
    return solution.values, solution.iterations


VARIANTS = [
    Variant("without (gtsam LM)", lambda p: p.base, gtsam_lm, False),
    Variant("MotionFactor, gtsam LM", lambda p: with_factors(p.base, p.motion), gtsam_lm, True),
    Variant("callback floor, gtsam LM", lambda p: with_factors(p.base, noop_factors(len(p.truth))), gtsam_lm, False),
    Variant("without, Python-driven LM", lambda p: p.base, python_lm, False),
    Variant("MotionFactor, Python-driven LM", lambda p: with_factors(p.base, p.motion), python_lm, True),
    Variant("MotionTerms, Python-driven LM", lambda p: p.base, python_lm_terms, True),
    Variant("MotionFactor, fusion.graph.solve", lambda p: with_factors(p.base, p.motion), fusion_solve, True),
]


def run_variant(variant: Variant, problem: Problem, graph: gtsam.NonlinearFactorGraph) -> tuple[float, dict]:
    """One timed solve: (seconds, what it reached)."""
    CALLS[0] = 0
    start = time.perf_counter()
    values, iterations = variant.solve(graph, problem)
    seconds = time.perf_counter() - start
    velocity = np.array([values.atVector(V(k)) - s.velocity() for k, s in enumerate(problem.truth)])
    solved = with_factors(problem.base, problem.motion) if variant.with_motion else problem.base
    return seconds, {
        "iterations": iterations,
        "error": solved.error(values),
        "velocity_rms": float(np.sqrt(np.mean(np.sum(velocity**2, axis=1)))),
        "calls": CALLS[0],
    }


def per_call(fn: Callable[[], object], number: int = 2000) -> float:
    """Median over 5 runs of the time of one call, microseconds."""
    runs = []
    for _ in range(5):
        start = time.perf_counter()
        for _ in range(number):
            fn()
        runs.append((time.perf_counter() - start) / number)
    return statistics.median(runs) * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--keyframes", type=int, default=1000)
    parser.add_argument("--repeats", type=int, default=9)
    parser.add_argument("--slow-repeats", type=int, default=3, help="repeats of the gtsam-LM CustomFactor variants")
    args = parser.parse_args()
    problem = simulate(args.keyframes)
    print(
        f"{args.keyframes} keyframes, {problem.base.size()} IMU/GPS/prior factors, {len(problem.motion)} motion factors"
    )
    graphs = [variant.graph(problem) for variant in VARIANTS]
    times = {variant.name: [] for variant in VARIANTS}
    results = {}
    for repeat in range(args.repeats):  # round robin: a slow phase of the machine hits every variant alike
        for variant, graph in zip(VARIANTS, graphs, strict=True):
            slow = "gtsam LM" in variant.name and "without" not in variant.name
            if slow and repeat >= args.slow_repeats:
                continue
            seconds, results[variant.name] = run_variant(variant, problem, graph)
            times[variant.name].append(seconds)
    for name, result in results.items():
        result["seconds"] = statistics.median(times[name])
    reference = results[VARIANTS[0].name]["seconds"]
    print(f"{'variant':32s} {'median s':>9s} {'ratio':>7s} {'iters':>5s} {'error':>10s} {'vel RMS m/s':>11s}")
    for name, r in results.items():
        print(
            f"{name:32s} {r['seconds']:9.3f} {r['seconds'] / reference:6.2f}x {r['iterations']:5d} "
            f"{r['error']:10.2f} {r['velocity_rms']:11.4f}"
        )
    floor = results["callback floor, gtsam LM"]
    extra_us = (floor["seconds"] - reference) / floor["calls"] * 1e6
    factor, values = problem.motion[0], gtsam.Values(problem.initial)
    print(f"callback floor inside gtsam LM: {floor['calls']} calls per solve, {extra_us:.0f} us per call")
    print(f"copy of the graph's Values ({values.size()} values): {per_call(lambda: gtsam.Values(values), 200):.0f} us")
    error_us, linearize_us = per_call(lambda: factor.error(values)), per_call(lambda: factor.linearize(values))
    print(
        f"MotionFactor, Values owned by Python (by reference): error {error_us:.1f} us, linearize {linearize_us:.1f} us"
    )


if __name__ == "__main__":
    main()
