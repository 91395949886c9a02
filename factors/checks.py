"""Checks of what enters a graph, and checks to run before an optimiser.

Graphs: every key a factor uses must have a value, every value must be constrained,
and every connected part of the graph must be anchored by a unary factor (a prior or a GPS fix); and a readable
error instead of GTSAM's ``IndeterminantLinearSystemException`` when the solver finds the system singular."""

from __future__ import annotations

import re
from collections.abc import Callable

import gtsam
import numpy as np

from airimu_core.errors import GraphError


def key_name(key: int) -> str:
    """``x3``-style name of a symbol key (``gtsam.symbol_shorthand``), else the integer."""
    symbol = gtsam.Symbol(key)
    char = symbol.chr()
    return f"{chr(char) if isinstance(char, int) else char}{symbol.index()}" if char else str(key)


def key_rows(available: np.ndarray, wanted: np.ndarray, kind: str, where: str) -> np.ndarray:
    """Positions of ``wanted`` keys (uint64) in the sorted ``available`` ones; a ``GraphError`` from ``where`` names
    the first missing one."""
    rows = np.minimum(np.searchsorted(available, wanted), max(len(available) - 1, 0))
    missing = available[rows] != wanted if len(available) else np.ones(len(wanted), bool)
    if missing.any():
        key = int(wanted[np.flatnonzero(missing)[0]])
        raise GraphError(f"{where}: the values have no {kind} for {key_name(key)}")
    return rows


def poses_of(values: gtsam.Values, keys: np.ndarray, where: str) -> np.ndarray:
    """The ``Pose3`` values at ``keys`` read in bulk: (K, 12) rows of ``gtsam.utilities.extractPose3``, the rotation
    row-major then the translation (one ``atPose3`` call per key costs ~4x more)."""
    held = np.array(gtsam.utilities.allPose3s(values).keys(), dtype=np.uint64)  # sorted, as extractPose3's rows
    rows = key_rows(held, np.asarray(keys, dtype=np.uint64), "Pose3", where)
    return gtsam.utilities.extractPose3(values)[rows] if len(rows) else np.zeros((0, 12))


def check_values(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> None:
    """Raise ``GraphError`` naming the first missing key and the factor that needs it; and the first key that
    no factor uses (an unconstrained variable makes the linear system indeterminate)."""
    used = set()
    for i in range(graph.size()):
        factor = graph.at(i)
        if factor is None:
            continue
        for key in factor.keys():
            used.add(key)
            if not values.exists(key):
                raise GraphError(
                    f"factor {i} ({type(factor).__name__}) needs a value for {key_name(key)}, "
                    "which the initial values do not have"
                )
    unused = [key for key in values.keys() if key not in used]
    if unused:
        raise GraphError(f"{key_name(unused[0])} has an initial value but no factor constrains it")


def check_anchored(graph: gtsam.NonlinearFactorGraph) -> None:
    """Raise ``GraphError`` if a connected part of the graph has no unary factor (prior, GPS fix, equality):
    nothing then fixes those states in the world frame and the linear system is singular."""
    parent: dict[int, int] = {}

    def root(key: int) -> int:
        while parent.setdefault(key, key) != key:
            parent[key] = parent[parent[key]]
            key = parent[key]
        return key

    anchored_keys = set()
    for i in range(graph.size()):
        factor = graph.at(i)
        if factor is None:
            continue
        keys = list(factor.keys())
        if len(keys) == 1:
            anchored_keys.add(keys[0])
        for key in keys:
            parent[root(key)] = root(keys[0])
    anchored = {root(key) for key in anchored_keys}
    loose = sorted((key for key in parent if root(key) not in anchored), key=lambda k: (root(k), k))
    if loose:
        part = [key for key in loose if root(key) == root(loose[0])]
        raise GraphError(
            f"{len(part)} states ({key_name(part[0])} ... {key_name(part[-1])}) are connected to no prior or GPS "
            "factor: nothing fixes them in the world frame (add a prior on one of them or a GPS fix)"
        )


def is_indeterminate(error: RuntimeError) -> bool:
    """GTSAM's ``IndeterminantLinearSystemException`` as Python sees it (a ``RuntimeError``, by its message)."""
    return "Indeterminate" in str(error) or "Indeterminant" in str(error)


def solve_or_explain(optimise: Callable[[], gtsam.Values]) -> gtsam.Values:
    """Run ``optimise`` (e.g. ``optimizer.optimize``); GTSAM's indeterminate-system error becomes a ``GraphError``
    that names the state and the usual causes."""
    try:
        return optimise()
    except RuntimeError as error:
        if not is_indeterminate(error):
            raise
        near = re.search(r"Symbol: (\w+)\)", str(error))
        where = f"near {near.group(1)}" if near else "somewhere in the graph"
        raise GraphError(
            f"the graph does not determine every state ({where}): its linear system is singular. Usual causes: "
            "too few GPS fixes for the unknown heading (at least 2 well-separated fixes per connected stretch), "
            "a keyframe without an IMU factor to its neighbours, or a zero-information noise model"
        ) from None
