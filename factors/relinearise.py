"""Bias re-linearisation on the export route, built in: solve, preintegrate every interval again around its solved
bias, solve again, until the biases stop moving.

``from_export`` corrects each interval for its bias key to first order (the export's bias Jacobians): on a
116-keyframe EuRoC graph with a 0.1-0.3 rad/s gyro bias that alone is 4.2-4.4 cm off GTSAM's re-preintegrated
solution. ``solve_relinearised(graph, values, export)`` is the loop users otherwise write themselves (GTSAM's
``IMUKittiExampleGPS.py`` does it inside its ISAM2 loop): Levenberg-Marquardt on ``graph``; then every
``gtsam.ImuFactor`` / ``gtsam.CombinedImuFactor`` of it is replaced by ``from_export(export, ..., bias=...)``'s factor
for the same interval, preintegrated by GTSAM from the export's corrected samples and learned noise around the bias
just solved (GTSAM's ``biasHat``); repeated until the largest change of any bias component is below ``tol`` (rad/s
and m/s^2 alike) or ``max_rounds``. Every other factor of ``graph`` is kept as it is. The result equals GTSAM's own
graph re-preintegrated from the samples at the converged biases (``tests/factors/test_bias_relinearisation.py``:
1e-6 m).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, V, X

from airimu_core.export import Export
from factors.checks import solve_or_explain
from factors.export_file import from_export

IMU_FACTORS = (gtsam.ImuFactor, gtsam.CombinedImuFactor)


@dataclass(frozen=True, eq=False)
class Relinearised:
    """The loop's result: the solved ``values``, the ``graph`` of the last solve (its IMU factors preintegrated around
    the biases before it), the solves run (``rounds``; 1 = no re-preintegration), and the largest bias change of the
    last one (inf when there was none)."""

    values: gtsam.Values
    graph: gtsam.NonlinearFactorGraph
    rounds: int
    bias_change: float


def solve_relinearised(
    graph: gtsam.NonlinearFactorGraph,
    values: gtsam.Values,
    export: Export,
    *,
    factor: str = "imu",
    params: gtsam.PreintegrationParams | None = None,
    pose_key=X,
    vel_key=V,
    bias_key=B,
    tol: float = 1e-6,
    max_rounds: int = 10,
    lm_params: gtsam.LevenbergMarquardtParams | None = None,
    optimize: Callable[[gtsam.NonlinearFactorGraph, gtsam.Values], gtsam.Values] | None = None,
) -> Relinearised:
    """Solve ``graph`` from ``values`` with its IMU factors re-preintegrated around the solved biases until they
    settle (module docstring).

    Args:
        graph: a graph whose IMU factors came from ``export`` (one per keyframe interval, keys ``pose_key(k)``,
            ``vel_key(k)``, ``bias_key(k)`` as ``from_export`` gives them), with bias states ``bias_key(k)``.
        values: the initial values, every ``bias_key(k)`` included.
        factor, params: as ``from_export`` (``"combined"`` needs a ``gtsam.PreintegrationCombinedParams``).
        tol: stop when no bias component moved more than this in a round (rad/s, m/s^2).
        max_rounds: at most this many solves.
        lm_params: Levenberg-Marquardt's settings (default GTSAM's).
        optimize: each solve, ``(graph, initial) -> solved values`` (default: GTSAM's LM with ``lm_params``); e.g.
            ``fusion.graph``'s route for graphs with Python factors, ``solve_with_python_factors``.
    """
    if max_rounds < 1 or not tol > 0:
        raise ValueError(f"solve_relinearised: need max_rounds >= 1 and tol > 0, got {max_rounds} and {tol}")
    others = gtsam.NonlinearFactorGraph()
    imu = 0
    for i in range(graph.size()):
        if isinstance(graph.at(i), IMU_FACTORS):
            imu += 1
        else:
            others.add(graph.at(i))
    intervals = len(export.keyframe_index) - 1
    if imu != intervals:
        raise ValueError(f"solve_relinearised: the graph has {imu} IMU factors, the export {intervals} intervals")
    lm_params = lm_params or gtsam.LevenbergMarquardtParams()
    if optimize is None:

        def optimize(graph, initial):
            return gtsam.LevenbergMarquardtOptimizer(graph, initial, lm_params).optimize()

    current, change, solves = graph, np.inf, 1
    solved = solve_or_explain(lambda: optimize(current, values))
    while solves < max_rounds:
        before = solved
        factors, _ = from_export(
            export,
            pose_key,
            vel_key,
            bias_key,
            factor=factor,
            params=params,
            bias=lambda k, at=before: at.atConstantBias(bias_key(k)),
        )
        current = gtsam.NonlinearFactorGraph()
        for item in [others.at(i) for i in range(others.size())] + factors:
            current.add(item)
        solved = solve_or_explain(lambda at=before, graph=current: optimize(graph, at))
        solves += 1
        change = max(_moved(solved, before, bias_key(k)) for k in range(intervals + 1))
        if change < tol:
            break
    return Relinearised(solved, current, solves, change)


def _moved(now: gtsam.Values, before: gtsam.Values, key) -> float:
    """The largest change of a bias component between two solutions."""
    return float(np.abs(now.atConstantBias(key).vector() - before.atConstantBias(key).vector()).max())
