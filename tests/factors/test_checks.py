"""check_values names the missing or unconstrained key before the optimiser runs."""

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import V, X

from factors import GpsFactor, gps_noise
from factors.checks import GraphError, check_values, key_name


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
