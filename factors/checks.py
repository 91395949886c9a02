"""Checks of what enters a graph, and checks to run before an optimiser.

Measurements (``preintegration_problem``, ``gravity_problem``): deltas, their covariances and the world gravity,
shared by ``LearnedImuFactor`` and ``load_export`` so every backend refuses the same inputs.

Graphs: every key a factor uses must have a value, every value must be constrained,
and every connected part of the graph must be anchored by a unary factor (a prior or a GPS fix); and a readable
error instead of GTSAM's ``IndeterminantLinearSystemException`` when the solver finds the system singular."""

from __future__ import annotations

import re
from collections.abc import Callable

import gtsam
import numpy as np

ROTATION_TOL = 1e-5  # max |R^T R - I| entry of a delta rotation
SYMMETRY_TOL = 1e-9  # max |C - C^T| relative to max |C| of a covariance
# The world frame is z-up (learned_imu.datasets.sequence): gravity points along -z with Earth's magnitude; 9.78-9.83
# m/s^2
# anywhere on the surface, the range leaves room for rounded values (9.8, 10).
GRAVITY_RANGE_M_S2 = (9.5, 10.5)
GRAVITY_MAX_TILT_RAD = 0.02  # angle between gravity and world -z


def preintegration_problem(delta_rot, delta_dt, delta_cov) -> tuple[int, str] | None:
    """The first interval whose measurement is unusable and why, or None. ``delta_rot`` (I, 3, 3), ``delta_dt``
    (I,) s, ``delta_cov`` (I, 9, 9): a non-rotation, a non-positive or non-finite time, a covariance that is not
    symmetric positive definite (zero, negative or NaN variances included)."""
    rot = np.asarray(delta_rot, dtype=float)
    dt = np.asarray(delta_dt, dtype=float)
    cov = np.asarray(delta_cov, dtype=float)
    bad_dt = ~(np.isfinite(dt) & (dt > 0))
    ortho = np.abs(np.swapaxes(rot, -1, -2) @ rot - np.eye(3)).max(axis=(-2, -1))
    bad_rot = ~(ortho <= ROTATION_TOL) | ~(np.linalg.det(rot) > 0)
    scale = np.abs(cov).max(axis=(-2, -1))
    asym = np.abs(cov - np.swapaxes(cov, -1, -2)).max(axis=(-2, -1))
    finite = np.isfinite(cov).all(axis=(-2, -1))
    smallest = np.full(len(cov), -np.inf)
    smallest[finite] = np.linalg.eigvalsh(0.5 * (cov[finite] + np.swapaxes(cov[finite], -1, -2))).min(axis=-1)
    bad_cov = ~finite | ~(asym <= SYMMETRY_TOL * scale) | ~(smallest > 0)
    for bad, why in (
        (bad_dt, lambda k: f"delta_dt must be positive and finite (s), got {dt[k]!r}"),
        (bad_rot, lambda k: "delta_rot is not a rotation matrix"),
        (bad_cov, lambda k: f"delta_cov must be symmetric positive definite (9x9), min eigenvalue {smallest[k]:.3g}"),
    ):
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            return k, why(k)
    return None


def gravity_problem(gravity) -> str | None:
    """Why ``gravity`` (3,) m/s^2 cannot be the world frame's (z-up) gravity vector, or None."""
    g = np.asarray(gravity, dtype=float)
    norm = float(np.linalg.norm(g))
    low, high = GRAVITY_RANGE_M_S2
    if not (np.isfinite(norm) and low <= norm <= high):
        return f"gravity {g.tolist()} m/s^2 has magnitude {norm:.4g}, expected Earth's, in [{low:g}, {high:g}]"
    if np.arccos(np.clip(-g[2] / norm, -1.0, 1.0)) > GRAVITY_MAX_TILT_RAD:
        return f"gravity {g.tolist()} m/s^2 does not point down the world's -z axis (the world frame is z-up)"
    return None


class GraphError(ValueError):
    """A factor graph and its initial values do not fit together; the message names the key and the factor."""


def key_name(key: int) -> str:
    """``x3``-style name of a symbol key (``gtsam.symbol_shorthand``), else the integer."""
    symbol = gtsam.Symbol(key)
    char = symbol.chr()
    return f"{chr(char) if isinstance(char, int) else char}{symbol.index()}" if char else str(key)


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


def solve_or_explain(optimise: Callable[[], gtsam.Values]) -> gtsam.Values:
    """Run ``optimise`` (e.g. ``optimizer.optimize``); GTSAM's indeterminate-system error becomes a ``GraphError``
    that names the state and the usual causes."""
    try:
        return optimise()
    except RuntimeError as error:
        if "Indeterminate" not in str(error) and "Indeterminant" not in str(error):
            raise
        near = re.search(r"Symbol: (\w+)\)", str(error))
        where = f"near {near.group(1)}" if near else "somewhere in the graph"
        raise GraphError(
            f"the graph does not determine every state ({where}): its linear system is singular. Usual causes: "
            "too few GPS fixes for the unknown heading (at least 2 well-separated fixes per connected stretch), "
            "a keyframe without an IMU factor to its neighbours, or a zero-information noise model"
        ) from None
