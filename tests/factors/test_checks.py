"""check_values names the missing or unconstrained key before the optimiser runs."""

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import V, X

from airimu_core.errors import GraphError
from factors import GpsFactor, gps_noise
from factors.checks import check_values, key_name


def graph_and_values():
    graph = gtsam.NonlinearFactorGraph()
    graph.add(GpsFactor(X(0), [0.0, 0.0, 0.0], gps_noise(0.1)))
    graph.add(gtsam.PriorFactorPose3(X(1), gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 0.1)))
    values = gtsam.Values()
    values.insert(X(0), gtsam.Pose3())
    values.insert(X(1), gtsam.Pose3())
    return graph, values


def test_consistent_graph_passes_and_names_are_readable():
    graph, values = graph_and_values()
    check_values(graph, values)
    assert key_name(X(12)) == "x12" and key_name(V(3)) == "v3"


def test_missing_key_is_named_with_its_factor():
    graph, values = graph_and_values()
    graph.add(gtsam.BetweenFactorPose3(X(1), X(2), gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 0.1)))
    with pytest.raises(GraphError, match=r"factor 2 \(BetweenFactorPose3\) needs a value for x2"):
        check_values(graph, values)


def test_unconstrained_value_is_named():
    graph, values = graph_and_values()
    values.insert(V(7), np.zeros(3))
    with pytest.raises(GraphError, match="v7 has an initial value but no factor constrains it"):
        check_values(graph, values)


def imu_chain(n: int) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """Poses X(0..n-1) linked by between factors, no anchor."""
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for k in range(n):
        values.insert(X(k), gtsam.Pose3(gtsam.Rot3(), np.array([k, 0.0, 0.0])))
        if k:
            step = gtsam.Pose3(gtsam.Rot3(), np.array([1.0, 0.0, 0.0]))
            graph.add(gtsam.BetweenFactorPose3(X(k - 1), X(k), step, gtsam.noiseModel.Isotropic.Sigma(6, 0.1)))
    return graph, values


def test_a_part_anchored_by_no_prior_or_fix_is_named():
    from factors.checks import check_anchored

    graph, _ = imu_chain(5)
    with pytest.raises(GraphError, match=r"5 states \(x0 ... x4\) are connected to no prior or GPS factor"):
        check_anchored(graph)
    graph.add(GpsFactor(X(2), [2.0, 0.0, 0.0], gps_noise(0.1)))
    check_anchored(graph)  # now anchored


def test_a_singular_system_is_explained_not_thrown_as_gtsam_exception():
    """One GPS fix anchors the chain structurally, but leaves its rotation free: GTSAM's indeterminate-system
    error becomes a GraphError naming the state."""
    from factors.checks import solve_or_explain

    graph, values = imu_chain(4)
    graph.add(GpsFactor(X(0), [0.5, 0.0, 0.0], gps_noise(0.1)))  # off the initial value: the solver must iterate
    optimiser = gtsam.GaussNewtonOptimizer(graph, values)
    with pytest.raises(GraphError, match=r"does not determine every state \(near x\d+\)"):
        solve_or_explain(optimiser.optimize)
