"""Initial values and the first state of the IMU + GPS pose graph (``fusion.graph.build_graph`` calls these).

Initial values: of two guesses, the one with the lower graph error -- positions interpolated between the GPS fixes
with rotations dead-reckoned from the deltas (robust for a strongly biased IMU over short spans), or a solution
window by window (``FusionSettings.init_window`` keyframes, each window started from the previous one's solution
and predicted through the IMU deltas: robust after hours, where the dead-reckoned attitude drifts by hundreds of
degrees).

Without a known first state (no ground truth, as on KITTI) the first state comes from an initial alignment to the
GPS track: position and velocity from the fixes, roll and pitch from gravity, yaw by search (``YAW_STEP_DEG``),
with a loose prior (``ALIGNED_PRIOR_SIGMAS``).
"""

from __future__ import annotations

import gtsam
import numpy as np

from airimu_core.errors import InputError
from factors import Export

X, V, B = gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.V, gtsam.symbol_shorthand.B
MIN_FIXES_PER_WINDOW = 3  # GPS fixes per window of the sequential initialisation
YAW_STEP_DEG = 30.0  # heading grid of the initial alignment (sequences without ground truth)
ALIGNED_PRIOR_SIGMAS = (0.2, 1.0, 1.0)  # rad, m, m/s: prior on an aligned (not known) first state


def first_state(initial_state, where: str) -> tuple[gtsam.Pose3, np.ndarray]:
    """(pose, velocity) of a ``gtsam.NavState`` given as the first state (world <- IMU pose, world velocity m/s);
    anything else is an ``InputError`` showing how to build one (the old ``(rot, pos, vel)`` tuple read in another
    order than ``learned_imu``'s keyword-only ``NavState(rot=, vel=, pos=)``, so it is no longer taken)."""
    if not isinstance(initial_state, gtsam.NavState):
        raise InputError(
            f"{where}: initial_state must be a gtsam.NavState, e.g. gtsam.NavState(gtsam.Pose3(gtsam.Rot3(rot), pos), "
            f"vel) with rot (3, 3) world <- IMU, pos (3,) m, vel (3,) m/s; got {type(initial_state).__name__}"
        )
    pose, vel = initial_state.pose(), np.asarray(initial_state.velocity(), dtype=float)
    if not (np.all(np.isfinite(pose.matrix())) and np.all(np.isfinite(vel))):
        raise InputError(f"{where}: initial_state holds NaN or Inf")
    return pose, vel


def known_first_state(export: Export, initial_state) -> tuple[gtsam.Pose3, np.ndarray] | None:
    """The prior's state: ``initial_state`` (a ``gtsam.NavState``), else the export's ground truth at the first
    keyframe, else None."""
    if initial_state is not None:
        return first_state(initial_state, "build_graph")
    if export.truth is None:
        return None
    first, truth = int(export.keyframe_index[0]), export.truth
    return gtsam.Pose3(gtsam.Rot3(truth.rot[first]), truth.pos[first]), np.asarray(truth.vel[first], float)


def aligned_first_state(export: Export, times, gps, imu_factors, gps_factors, settings, still=None):
    """Initial alignment without ground truth: position and velocity from the GPS track, roll and pitch from the
    first interval's mean specific force (gravity; a still start's, ``fusion.still.StillStart``, when there is one,
    and zero velocity then), yaw by search: the heading whose first-window solution (``solve_window`` with loose
    priors) has the lowest graph error. No assumption about the platform's motion."""
    pos = np.array([np.interp(times[:2], gps.t, gps.pos[:, i]) for i in range(3)]).T
    later = min(len(gps.t) - 1, 1)
    vel = (gps.pos[later] - gps.pos[0]) / max(gps.t[later] - gps.t[0], 1e-9) if later else np.zeros(3)
    up = -export.gravity / np.linalg.norm(export.gravity)  # world up
    force = export.delta_vel[0] / export.delta_dt[0]  # body frame, ~ -gravity when not accelerating hard
    if still is not None:
        force, vel = still.up, np.zeros(3)
    level = _rotation_between(force / np.linalg.norm(force), up)  # world <- body, yaw arbitrary
    end = min(len(imu_factors), _window_length(gps_factors, len(imu_factors), settings))
    best = None
    for yaw in np.deg2rad(np.arange(0.0, 360.0, YAW_STEP_DEG)):
        pose = gtsam.Pose3(gtsam.Rot3.AxisAngle(up, yaw).compose(gtsam.Rot3(level)), pos[0])
        priors = priors_on_first(pose, vel, *ALIGNED_PRIOR_SIGMAS)
        window, solved = solve_window(export, imu_factors, gps_factors, priors, 0, end, pose, vel, settings)
        error = window.error(solved)
        if best is None or error < best[0]:
            best = (error, solved.atPose3(X(0)), solved.atVector(V(0)))
    return best[1], best[2]


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vector ``a`` to unit vector ``b``."""
    axis, cos = np.cross(a, b), float(np.dot(a, b))
    if np.linalg.norm(axis) < 1e-12:
        return np.eye(3) if cos > 0 else gtsam.Rot3.AxisAngle(_orthogonal(a), np.pi).matrix()
    return gtsam.Rot3.AxisAngle(axis / np.linalg.norm(axis), np.arctan2(np.linalg.norm(axis), cos)).matrix()


def _orthogonal(a: np.ndarray) -> np.ndarray:
    other = np.eye(3)[int(np.argmin(np.abs(a)))]
    v = np.cross(a, other)
    return v / np.linalg.norm(v)


def priors_on_first(pose: gtsam.Pose3, vel: np.ndarray, rot_sigma: float, pos_sigma: float, vel_sigma: float) -> list:
    return [
        gtsam.PriorFactorPose3(X(0), pose, sigmas([rot_sigma] * 3 + [pos_sigma] * 3)),
        gtsam.PriorFactorVector(V(0), vel, sigmas([vel_sigma] * 3)),
    ]


def interpolated_values(export: Export, times: np.ndarray, gps, first, settings) -> gtsam.Values:
    """Positions interpolated between the GPS fixes, velocities their differences, rotations dead-reckoned."""
    pos = np.column_stack([np.interp(times, gps.t, gps.pos[:, i]) for i in range(3)])
    vel = np.gradient(pos, times, axis=0)
    pos[0], vel[0] = first[0].translation(), first[1]
    rot = first[0].rotation()
    values = gtsam.Values()
    for k in range(len(times)):
        values.insert(X(k), gtsam.Pose3(rot, pos[k]))
        values.insert(V(k), vel[k])
        if k < len(export.delta_rot):
            rot = rot.compose(gtsam.Rot3(export.delta_rot[k]))
    if settings.backend == "gtsam":
        values.insert(B(0), gtsam.imuBias.ConstantBias())
    return values


def motion_values(export: Export, times: np.ndarray, motion, first, settings) -> gtsam.Values:
    """Rotations dead-reckoned through the IMU deltas from ``first``, velocities the learned body-frame ones
    (``motion``, an ``airimu_core.motion.BodyVelocities``) rotated into the world (the IMU's prediction outside its
    span), positions their trapezoidal integral."""
    body, _, inside = motion.at(times)
    pose, vel = first
    rot, rots, vels = pose.rotation(), [], []
    for k in range(len(times)):
        matrix = rot.matrix()
        vel = matrix @ body[k] if inside[k] else vel
        rots.append(rot)
        vels.append(np.asarray(vel, dtype=float))
        if k < len(export.delta_rot):
            if not inside[k]:  # the IMU's velocity change over the interval
                vel = vel + export.gravity * export.delta_dt[k] + matrix @ export.delta_vel[k]
            rot = rot.compose(gtsam.Rot3(export.delta_rot[k]))
    vels[0] = np.asarray(first[1], dtype=float)
    steps = np.diff(times)[:, None] * 0.5 * (np.array(vels[:-1]) + np.array(vels[1:]))
    pos = pose.translation() + np.concatenate([np.zeros((1, 3)), np.cumsum(steps, axis=0)])
    values = gtsam.Values()
    for k in range(len(times)):
        values.insert(X(k), gtsam.Pose3(rots[k], pos[k]))
        values.insert(V(k), vels[k])
    if settings.backend == "gtsam":
        values.insert(B(0), gtsam.imuBias.ConstantBias())
    return values


def sequential_initial_values(export: Export, imu_factors, gps_factors, priors, first, settings) -> gtsam.Values:
    """Initial values solved window by window (``settings.init_window`` keyframes, or more so that a window holds
    ``MIN_FIXES_PER_WINDOW`` GPS fixes): each window starts from the previous one's solved end state, predicts
    through its IMU deltas, and is solved with its GPS factors and a prior on its first state. The global LM then
    starts close to its solution even after hours of drift."""
    n = len(imu_factors) + 1
    values = gtsam.Values()
    pose, vel = first
    length = _window_length(gps_factors, n, settings)
    start = 0
    while start < n - 1:
        end = min(start + length, n - 1)
        if start > 0:  # hold the window's first state near the previous window's solution
            priors = [
                gtsam.PriorFactorPose3(X(start), pose, sigmas([1e-3] * 6)),
                gtsam.PriorFactorVector(V(start), vel, sigmas([1e-3] * 3)),
            ]
        _, solved = solve_window(export, imu_factors, gps_factors, priors, start, end, pose, vel, settings)
        for k in range(start, end + 1):
            if not values.exists(X(k)):
                values.insert(X(k), solved.atPose3(X(k)))
                values.insert(V(k), solved.atVector(V(k)))
        pose, vel = solved.atPose3(X(end)), solved.atVector(V(end))
        start = end
    if settings.backend == "gtsam":
        values.insert(B(0), gtsam.imuBias.ConstantBias())
    return values


def _window_length(gps_factors, n: int, settings) -> int:
    """Keyframes per initialisation window: ``settings.init_window``, or enough for ``MIN_FIXES_PER_WINDOW`` fixes
    at the median spacing of the keyframes that hold a fix (``n`` when at most one does)."""
    fixed = sorted(gps_factors)
    spacing = int(np.median(np.diff(fixed))) if len(fixed) > 1 else n
    return max(settings.init_window, MIN_FIXES_PER_WINDOW * spacing)


def solve_window(export: Export, imu_factors, gps_factors, priors, start, end, pose, vel, settings):
    """Keyframes ``start..end``: states predicted through the IMU deltas from (``pose``, ``vel``) at ``start``,
    then solved by LM with the window's IMU and GPS factors and ``priors`` (unsolved if it holds no fix).
    Returns the window's graph and its values."""
    g = export.gravity
    window, guess = gtsam.NonlinearFactorGraph(), gtsam.Values()
    guess.insert(X(start), pose)
    guess.insert(V(start), vel)
    for k in range(start, end):  # predict: the IMU deltas from the window's first state
        dt, rot = export.delta_dt[k], pose.rotation().matrix()
        p = pose.translation() + vel * dt + 0.5 * g * dt**2 + rot @ export.delta_pos[k]
        vel = vel + g * dt + rot @ export.delta_vel[k]
        pose = gtsam.Pose3(pose.rotation().compose(gtsam.Rot3(export.delta_rot[k])), p)
        guess.insert(X(k + 1), pose)
        guess.insert(V(k + 1), vel)
        window.add(imu_factors[k])
    fixes = [f for k in range(start, end + 1) for f in gps_factors.get(k, [])]
    for factor in [*fixes, *priors]:
        window.add(factor)
    if settings.backend == "gtsam":
        window.add(gtsam.NonlinearEqualityConstantBias(B(0), gtsam.imuBias.ConstantBias()))
        guess.insert(B(0), gtsam.imuBias.ConstantBias())
    if not fixes:
        return window, guess
    return window, gtsam.LevenbergMarquardtOptimizer(window, guess, lm_params(settings)).optimize()


def lm_params(settings) -> gtsam.LevenbergMarquardtParams:
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(settings.max_iterations)
    params.setRelativeErrorTol(settings.relative_error_tol)
    params.setAbsoluteErrorTol(settings.absolute_error_tol)
    if settings.backend == "custom":
        # GTSAM's default multifrontal Cholesky declares the linearised graph of Python LearnedImuFactors
        # indeterminate (near its last keyframes) although its Jacobian is well conditioned (cond ~4e5) and equals
        # the C++ ImuFactor graph's; LM then only succeeds at large damping and crawls (1000 iterations). QR
        # solves the same system: 3 iterations, the C++ graph's optimum to 1e-12. Cause inside GTSAM not found.
        params.setLinearSolverType("MULTIFRONTAL_QR")
    return params


def sigmas(values) -> gtsam.noiseModel.Diagonal:
    return gtsam.noiseModel.Diagonal.Sigmas(np.asarray(values, dtype=float))
