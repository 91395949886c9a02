"""One call from an export and GPS fixes to a solved, checked graph: ``solve_export(export, fixes, config)``.

The graph is ``fusion.graph.build_graph``'s (GPS factors with the config's robust loss, a keyframe state per export
keyframe, optional bias states and learned motion factors) solved by Levenberg-Marquardt; with bias states and
GTSAM's factors it is re-linearised (``factors.solve_relinearised``: every interval preintegrated again around its
solved bias until the biases move less than 1e-6). The result is then checked against its own noise model
(``fusion.consistency``): chi-square per degree of freedom of each kind of factor, warned about when the inputs
contradict their sigmas.
"""

from __future__ import annotations

import logging

from airimu_core.export import Export
from airimu_core.motion import BodyVelocities
from airimu_core.sequence import GpsFixes
from factors import solve_relinearised
from fusion import consistency
from fusion.config import FuseConfig
from fusion.graph import (
    Solution,
    build_graph,
    combined_params,
    has_motion_factors,
    solve,
    solve_motion_graph,
    trajectory_of,
)
from fusion.initial import lm_params

log = logging.getLogger(__name__)


def solve_export(
    export: Export,
    fixes: GpsFixes | None,
    config: FuseConfig | None = None,
    initial_state=None,
    motion: BodyVelocities | None = None,
    guess=None,
    still=None,
) -> tuple[Solution, dict]:
    """The solution and its ``fusion.consistency.residuals`` (module docstring); inconsistencies are logged as
    warnings naming the export. ``fixes`` None: no GPS (``initial_state``, a ``gtsam.NavState`` at the first
    keyframe, or the export's ground truth then anchors the graph); ``motion``: learned body-frame velocities, a
    motion factor at every keyframe inside their span (``fusion.graph.build_graph``); ``guess``: an earlier
    solution's values, one more candidate for the initial values; ``still``: the log's still start
    (``fusion.still.StillStart``) for an aligned first state."""
    config = config or FuseConfig()
    settings, bias = config.graph, config.bias_states
    graph, values = build_graph(
        export, fixes, settings, initial_state, bias=bias, motion=motion, guess=guess, still=still,
        mount_sigma_rad=config.motion.mount_sigma_rad, speed_scale=config.motion.speed_scale(),
    )  # fmt: skip
    if bias is None or settings.backend != "gtsam":
        solution = solve(graph, values, export.keyframe_t, settings)
    else:
        combined = bias.factor == "combined"
        done = solve_relinearised(
            graph,
            values,
            export,
            factor="combined" if combined else "imu",
            params=combined_params(export, bias) if combined else None,
            lm_params=lm_params(settings),
            optimize=fast_route(graph, settings),
        )
        log.info(
            "%s: bias re-linearisation: %d solves, last bias change %.2g", export.name, done.rounds, done.bias_change
        )
        trajectory = trajectory_of(done.values, export.keyframe_t)
        solution = Solution(trajectory, done.graph, done.values, done.rounds, done.graph.error(done.values))
    found = consistency.residuals(solution.graph, solution.values)
    for message in consistency.check(found):
        log.warning("%s: %s", export.name, message)
    return solution, found


def fast_route(graph, settings):
    """``solve_relinearised``'s solver for a graph with motion factors: ``fusion.graph.solve_motion_graph`` (10-25x
    faster than GTSAM's LM calling them back, BENCHMARKS.md "Motion factor"), with QR. With bias states Cholesky
    calls about half of LM's damped systems indeterminate (stiff bias walks: whitened Jacobians ~1e6) and LM crawls
    at large damping to its iteration limit; QR solves them (KITTI seq 04 without GPS, gyro bias walk 2.9e-7 rad/s
    per sample: 1,648 of 3,248 tries failed, 100 iterations a solve, 25 s; with QR 2 iterations, 1.2 s, a lower
    final error). None (GTSAM's LM) for a graph without motion factors."""
    if not has_motion_factors(graph):
        return None
    params = lm_params(settings)
    params.setLinearSolverType("MULTIFRONTAL_QR")
    return lambda rebuilt, initial: solve_motion_graph(rebuilt, initial, params).values
