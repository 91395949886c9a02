"""IMU + GPS pose graph: keyframe states, learned preintegration factors, GPS factors, a prior; solved by LM.

Pipeline (each step one call): load the export (``factors.load_export``) -> preintegration factors between
consecutive keyframes -> GPS factors at the keyframes nearest to each fix (warned about when a fix lies between
keyframes: export with a keyframe at every fix) -> a prior on the first state ->
initial values -> ``gtsam.LevenbergMarquardtOptimizer`` -> a typed ``Trajectory``.

Keys: ``X(k)`` (``Pose3``, world <- IMU), ``V(k)`` (world-frame velocity, m/s) for keyframe k, as
``gtsam.ImuFactor`` uses them. The exported deltas are already corrected, so by default no bias state is estimated:
with the default ``backend="gtsam"`` every ``gtsam.ImuFactor`` (C++, the same residual as
``factors.LearnedImuFactor``) shares one bias key ``B(0)`` held at zero by a ``NonlinearEquality`` (a hard
constraint, not a tight prior that would ill-condition the marginals); ``backend="custom"`` uses ``LearnedImuFactor``
without a bias key. With ``bias=BiasStates(...)`` (raw samples, as GTSAM's ``IMUKittiExampleGPS.py``) each interval
k has its own bias ``B(k)`` ([acc m/s^2, gyro rad/s], ``gtsam.imuBias.ConstantBias``), corrected to first order by
the export's bias Jacobians, linked by a random walk and held near zero by a prior on ``B(0)``.

Initial values (``fusion.initial``): of two guesses, the one with the lower graph error -- GPS-interpolated
positions, or a window-by-window solution; without a known first state, an initial alignment to the GPS track.
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from pathlib import Path

import gtsam
import numpy as np

from airimu_core.errors import GraphError, InputError
from airimu_core.io import atomic_file
from airimu_core.motion import BodyVelocities
from airimu_core.rotations import matrix_to_quat_wxyz
from airimu_core.sequence import GpsFixes
from factors import (
    Export,
    GpsFactor,
    MotionFactor,
    MotionTerms,
    check_anchored,
    check_values,
    from_export,
    gps_noise,
    load_export,
    motion_factors,
    poses_of,
    solve_or_explain,
    solve_with_python_factors,
)
from fusion.align import aligned_prior
from fusion.config import BiasStates, FusionSettings
from fusion.initial import (
    ALIGNED_PRIOR_SIGMAS,
    aligned_first_state,
    interpolated_values,
    known_first_state,
    lm_params,
    motion_values,
    priors_on_first,
    sequential_initial_values,
)
from fusion.still import StillStart

log = logging.getLogger(__name__)

X, V, B, M = gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.V, gtsam.symbol_shorthand.B, gtsam.symbol_shorthand.M
S = gtsam.symbol_shorthand.S  # the motion factors' speed scales


# GPS fixes are the readers' record, airimu_core.sequence.GpsFixes (t (M,) s on the IMU clock, pos (M, 3)
# world frame m, sigma (M, 3) one-sigma m); ``Gps`` is its former name here, kept for code written against it
Gps = GpsFixes


@dataclass(frozen=True, eq=False)
class Trajectory:
    """A trajectory at the keyframes: ``t`` (K,) s; ``rot`` (K, 3, 3) world <- IMU; ``pos`` (K, 3) m; ``vel``
    (K, 3) m/s; ``pos_cov`` (K, 3, 3) marginal position covariance, m^2, world frame (None if not computed)."""

    t: np.ndarray
    rot: np.ndarray
    pos: np.ndarray
    vel: np.ndarray
    pos_cov: np.ndarray | None = None

    def position_at(self, t) -> np.ndarray:
        """Positions (M, 3), m, at times ``t`` (M,) s within the keyframes' span: cubic Hermite interpolation of the
        keyframe positions and velocities (exact for constant acceleration between keyframes)."""
        t = np.asarray(t, dtype=float)
        if t.size and (t.min() < self.t[0] - 1e-9 or t.max() > self.t[-1] + 1e-9):
            raise InputError(f"position_at: times must lie in [{self.t[0]}, {self.t[-1]}] s")
        if len(self.t) == 1:
            return np.repeat(self.pos, len(t), axis=0)
        k = np.clip(np.searchsorted(self.t, t, side="right") - 1, 0, len(self.t) - 2)
        h = (self.t[k + 1] - self.t[k])[:, None]
        s = (t[:, None] - self.t[k, None]) / h
        return (
            (2 * s**3 - 3 * s**2 + 1) * self.pos[k]
            + (s**3 - 2 * s**2 + s) * h * self.vel[k]
            + (3 * s**2 - 2 * s**3) * self.pos[k + 1]
            + (s**3 - s**2) * h * self.vel[k + 1]
        )

    def write_tum(self, path: str | Path) -> Path:
        """TUM format (``t x y z qx qy qz qw``, quaternion world <- IMU, scalar last) for ``evo_ape tum``."""
        quat = np.roll(matrix_to_quat_wxyz(self.rot), -1, axis=-1)  # x, y, z, w
        rows = np.column_stack([self.t, self.pos, quat])
        with atomic_file(path) as f:
            f.write("# timestamp tx ty tz qx qy qz qw\n")
            np.savetxt(f, rows, fmt="%.9f")
        return Path(path)


@dataclass(frozen=True, eq=False)
class Solution:
    """The solved graph: the trajectory, and the graph and values (for ``gtsam.Marginals``)."""

    trajectory: Trajectory
    graph: gtsam.NonlinearFactorGraph
    values: gtsam.Values
    iterations: int
    final_error: float


MIN_ALIGN_FIXES = 3  # first position, velocity (and the heading) from the GPS track need three fixes at least
MIN_ALIGN_SPREAD_SIGMAS = 5.0  # and a horizontal track longer than this many GPS sigmas, or the heading is noise


def _check_observable(export: Export, gps: GpsFixes, keyframe: np.ndarray) -> None:
    """Without a known first state the GPS track must fix the first heading and velocity: a ``GraphError`` when the
    fused fixes are too few or too close together (the solver would return an arbitrary heading, not an error)."""
    used = keyframe >= 0
    pos, sigma = gps.pos[used], gps.sigma[used]
    spread = float(np.linalg.norm(pos[:, :2] - pos[:1, :2], axis=1).max())
    need = MIN_ALIGN_SPREAD_SIGMAS * float(np.median(sigma[:, :2]))
    if used.sum() < MIN_ALIGN_FIXES or spread < need:
        raise GraphError(
            f"{export.name}: under-constrained: {int(used.sum())} GPS fix(es) on keyframes spanning {spread:.3g} m "
            f"horizontally; without a known first state (ground truth or initial_state) the heading and velocity "
            f"need at least {MIN_ALIGN_FIXES} fixes spread over more than {need:.3g} m "
            f"({MIN_ALIGN_SPREAD_SIGMAS:g} GPS sigmas)"
        )


def build_graph(
    export: Export | str | Path,
    gps: GpsFixes | None,
    settings: FusionSettings | None = None,
    initial_state=None,
    bias: BiasStates | None = None,
    motion: BodyVelocities | None = None,
    guess: gtsam.Values | None = None,
    still: StillStart | None = None,
    mount_sigma_rad=None,
    speed_scale: tuple[float, float, float] | None = None,
) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """The pose graph of an export, GPS fixes and learned body-frame velocities, and its initial values (see the
    module docstring).

    ``initial_state`` (a ``gtsam.NavState``: pose world <- IMU, world velocity m/s) anchors the prior on keyframe 0;
    default: the export's ground truth at the first keyframe if it has one, else an initial alignment to the GPS
    track (position and velocity from the fixes, roll and pitch from gravity, yaw by search; its prior is loose:
    ``ALIGNED_PRIOR_SIGMAS``). ``gps``: None (or no fix) for none: dead reckoning, which needs a known first state.
    ``bias``: estimate a bias per keyframe interval (module docstring); the initial values are then found on the
    graph without bias states, every bias starting at zero. ``motion``: a ``factors.MotionFactor`` at every
    keyframe inside its time span, the velocity and variance interpolated to the keyframe's time. ``guess``: values
    of this export's keyframes from an earlier solve (e.g. the pass before the motion factors changed), one more
    candidate for the initial values (its poses and velocities). ``still``: the log's still start
    (``fusion.still``), for an aligned first state: its gravity gives roll and pitch, and its tilt sigma the prior's
    about the horizontal axes (``fusion.align.aligned_prior``). ``mount_sigma_rad``: with ``motion``, a mounting
    rotation state ``M(0)`` (``Rot3``, the IMU body frame <- the frame the model's velocities are in) on every motion
    factor, with a prior at identity of these sigmas (rad, one or three: roll, pitch, yaw)
    (``fusion.config.MotionSettings.mount_sigma_rad``). ``speed_scale``: with ``motion``, (prior sigma, random walk
    per sqrt(s), interval s): a speed scale ``S(j)`` (a ``Vector`` of one) on the motion factors of the j-th interval
    from the first keyframe, a prior at 1 on ``S(0)`` and a random walk between consecutive scales
    (``fusion.config.MotionSettings.scale_sigma``).
    """
    settings = settings or FusionSettings()
    export = export if isinstance(export, Export) else load_export(export)
    graph = gtsam.NonlinearFactorGraph()
    bias_key = (lambda k: B(0)) if settings.backend == "gtsam" else None
    imu_factors, times = from_export(export, X, V, bias_key, settings.backend)  # the loaded export: no re-read
    for factor in imu_factors:
        graph.add(factor)
    if settings.backend == "gtsam":
        graph.add(gtsam.NonlinearEqualityConstantBias(B(0), gtsam.imuBias.ConstantBias()))

    # GPS factors: the configured noise for the graph; for the initial guesses Huber instead of Cauchy (or the
    # Gaussian itself): a redescending loss lets a drifting guess look better than the truth (its far-off residuals
    # saturate), Huber's linear tails do not
    init_loss = "huber" if settings.gps_robust else None
    gps = gps if gps is not None else GpsFixes.none()
    keyframe = _nearest_keyframes(times, gps.t) if len(gps.t) else np.zeros(0, dtype=int)
    _warn_off_keyframe(export, gps, keyframe)
    gps_factors: dict[int, list] = {}
    init_gps: dict[int, list] = {}
    align_gps: dict[int, list] = {}  # Gaussian: the heading search compares far-off candidates, where a robust
    # loss flattens the cost (a simulated car with Huber fixes aligned 106 degrees off; Gaussian: 0.6 degrees)
    for index, pos, sigma in zip(keyframe, gps.pos, gps.sigma, strict=True):
        if index >= 0:
            factor = GpsFactor(X(index), pos, gps_noise(sigma, settings.gps_robust), settings.lever_arm_m)
            graph.add(factor)
            gps_factors.setdefault(int(index), []).append(factor)
            if init_loss != settings.gps_robust:
                factor = GpsFactor(X(index), pos, gps_noise(sigma, init_loss), settings.lever_arm_m)
            init_gps.setdefault(int(index), []).append(factor)
            if init_loss is not None:
                factor = GpsFactor(X(index), pos, gps_noise(sigma, None), settings.lever_arm_m)
            align_gps.setdefault(int(index), []).append(factor)
    if len(gps.t) and not gps_factors:
        raise InputError(f"{export.path}: no GPS fix lies within half a keyframe interval of a keyframe")
    mount = M(0) if motion is not None and mount_sigma_rad is not None else None
    scales = None
    if motion is not None and speed_scale is not None:  # a walk of zero: one scale for the log
        scales = _scale_index(times, speed_scale[2] if speed_scale[1] > 0 else np.inf)
    moving = keyframe_motion_factors(motion, times, mount, scales) if motion is not None else []
    if not moving:
        mount, scales = None, None
    elif mount is not None:  # the mounting rotation's prior, carried with the motion factors
        sigmas = np.broadcast_to(np.asarray(mount_sigma_rad, dtype=float), (3,))
        moving.append(gtsam.PriorFactorRot3(mount, gtsam.Rot3(), gtsam.noiseModel.Diagonal.Sigmas(sigmas)))
    if scales is not None:  # the speed scales' prior and random walk, carried with the motion factors
        moving.extend(_scale_factors(int(scales.max()) + 1, *speed_scale))
    for factor in moving:
        graph.add(factor)

    first = known_first_state(export, initial_state)
    if first is None and not gps_factors:
        raise GraphError(
            f"{export.name}: without GPS fixes the first state must be known: give an initial state (airimu fuse "
            "--start) or a sequence with ground truth"
        )
    if first is None:  # no ground truth: align the first state to the GPS track (attitude from gravity + a yaw search)
        _check_observable(export, gps, keyframe)
        first = aligned_first_state(export, times, gps, imu_factors, align_gps, settings, still)
        sigmas = ALIGNED_PRIOR_SIGMAS
    else:
        sigmas = (settings.prior_rot_sigma_rad, settings.prior_pos_sigma_m, settings.prior_vel_sigma_m_s)
    pose0, vel0 = first
    if still is not None and sigmas == ALIGNED_PRIOR_SIGMAS:  # the still gravity's tilt sigma, heading loose
        priors = list(aligned_prior(pose0, vel0, still.tilt_sigma_rad))
    else:
        priors = priors_on_first(pose0, vel0, *sigmas)
    for factor in priors:
        graph.add(factor)
    check_anchored(graph)
    # two guesses, the one the (Huber-GPS) graph likes better wins: GPS-interpolated positions (robust to a strongly
    # biased IMU over short spans) or the window-by-window solution (robust to hours of attitude drift)
    candidates = [sequential_initial_values(export, imu_factors, init_gps, priors, (pose0, vel0), settings)]
    if gps_factors:
        candidates.append(interpolated_values(export, times, gps, (pose0, vel0), settings))
    if moving:  # without GPS the IMU alone drifts far: the learned velocities integrated instead
        candidates.append(motion_values(export, times, motion, (pose0, vel0), settings))
    if guess is not None:
        candidates.append(_states_of(guess, len(times), settings))
    for values in candidates:
        if mount is not None and not values.exists(mount):
            values.insert(mount, guess.atRot3(mount) if guess is not None and guess.exists(mount) else gtsam.Rot3())
        for j in range(0 if scales is None else int(scales.max()) + 1):
            if not values.exists(S(j)):
                values.insert(S(j), guess.atVector(S(j)) if guess is not None and guess.exists(S(j)) else np.ones(1))
        check_values(graph, values)
    init_graph = graph
    if init_loss != settings.gps_robust:  # the same graph with the initial guesses' GPS factors
        init_graph = gtsam.NonlinearFactorGraph()
        for i in range(graph.size()):
            if not isinstance(graph.at(i), GpsFactor):
                init_graph.add(graph.at(i))
        for factor in (f for fixes in init_gps.values() for f in fixes):
            init_graph.add(factor)
    values = min(candidates, key=init_graph.error)
    if bias is None:
        return graph, values
    others = [f for fixes in gps_factors.values() for f in fixes] + priors + moving
    return _with_bias_states(values, export, bias, settings.backend, others, still)


def _states_of(values: gtsam.Values, keyframes: int, settings: FusionSettings) -> gtsam.Values:
    """The keyframe poses and velocities of ``values`` (and B(0), zero if it has none, for the gtsam backend)."""
    out = gtsam.Values()
    for k in range(keyframes):
        if not (values.exists(X(k)) and values.exists(V(k))):
            raise GraphError(f"build_graph: the guess has no pose and velocity for keyframe {k} of {keyframes}")
        out.insert(X(k), values.atPose3(X(k)))
        out.insert(V(k), values.atVector(V(k)))
    if settings.backend == "gtsam":
        bias = values.atConstantBias(B(0)) if values.exists(B(0)) else gtsam.imuBias.ConstantBias()
        out.insert(B(0), bias)
    return out


def combined_params(export: Export, bias: BiasStates) -> gtsam.PreintegrationCombinedParams:
    """The ``CombinedImuFactor`` params of ``bias`` (``factor="combined"``): the export's gravity, no integration
    noise, the bias random walk as continuous-time sigma^2 (the per-sample sigmas over the median sample step)."""
    dt = float(np.median(np.diff(export.t)))
    params = gtsam.PreintegrationCombinedParams(export.gravity)
    params.setIntegrationCovariance(np.zeros((3, 3)))
    params.setBiasAccCovariance(np.eye(3) * bias.acc_walk_sigma**2 / dt)
    params.setBiasOmegaCovariance(np.eye(3) * bias.gyro_walk_sigma**2 / dt)
    return params


def _with_bias_states(
    values: gtsam.Values, export: Export, bias: BiasStates, backend: str, others: list, still: StillStart | None = None
):
    """The graph of ``others`` (GPS factors and priors), the export's IMU factors on ``B(k)``, the bias random walk
    and prior (``BiasStates``; after a ``still`` start its gyro part is ``StillStart.gyro_prior_sigma``: the samples
    have its bias taken out); ``values`` with every ``B(k)`` at zero in place of the constant ``B(0)``."""
    graph = gtsam.NonlinearFactorGraph()
    zero = gtsam.imuBias.ConstantBias()
    samples = np.diff(export.keyframe_index)
    if bias.factor == "combined":
        imu_factors = from_export(export, X, V, B, "gtsam", factor="combined", params=combined_params(export, bias))[0]
    else:
        imu_factors = from_export(export, X, V, B, backend)[0]
    for factor in [*imu_factors, *others]:
        graph.add(factor)
    for k, walk in enumerate(bias.walk_sigmas(samples) if bias.factor == "between" else ()):
        graph.add(gtsam.BetweenFactorConstantBias(B(k), B(k + 1), zero, gtsam.noiseModel.Diagonal.Sigmas(walk)))
    gyro = bias.gyro_prior_sigma if still is None else still.gyro_prior_sigma(bias.gyro_prior_sigma)
    prior = np.concatenate([np.full(3, bias.acc_prior_sigma), np.broadcast_to(gyro, (3,))])
    graph.add(gtsam.PriorFactorConstantBias(B(0), zero, gtsam.noiseModel.Diagonal.Sigmas(prior)))
    out = gtsam.Values()
    for k in range(len(samples) + 1):
        out.insert(X(k), values.atPose3(X(k)))
        out.insert(V(k), values.atVector(V(k)))
        out.insert(B(k), zero)
    if values.exists(M(0)):  # the motion factors' mounting rotation
        out.insert(M(0), values.atRot3(M(0)))
    for key in scale_keys(values):  # and their speed scales
        out.insert(key, values.atVector(key))
    check_values(graph, out)
    return graph, out


def solve(
    graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, times: np.ndarray, settings: FusionSettings | None = None
) -> Solution:
    """Levenberg-Marquardt on the graph; the keyframe states as a ``Trajectory``."""
    settings = settings or FusionSettings()
    params = lm_params(settings)
    if settings.backend == "gtsam" and has_motion_factors(graph):
        done = solve_or_explain(lambda: solve_motion_graph(graph, values, params))
        return Solution(trajectory_of(done.values, times), graph, done.values, done.iterations, done.error)
    optimiser = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    result = solve_or_explain(optimiser.optimize)
    return Solution(trajectory_of(result, times), graph, result, optimiser.iterations(), graph.error(result))


def has_motion_factors(graph: gtsam.NonlinearFactorGraph) -> bool:
    return any(isinstance(graph.at(i), MotionFactor) for i in range(graph.size()))


def solve_motion_graph(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, params: gtsam.LevenbergMarquardtParams):
    """GTSAM's LM on a graph with ``MotionFactor``s: Python factors inside GTSAM's own LM get a copy of all values per
    call (``factors.motion``), so it is stepped from Python with the motion factors evaluated together in numpy
    (``MotionTerms``); ``factors.motion.solve_with_python_factors``' result."""
    rest, motion = split_motion_factors(graph)
    return solve_with_python_factors(rest, values, params, extra=(MotionTerms(motion),) if motion else ())


def split_motion_factors(graph: gtsam.NonlinearFactorGraph) -> tuple[gtsam.NonlinearFactorGraph, list[MotionFactor]]:
    """(the graph without its ``MotionFactor``s, those factors)."""
    rest, motion = gtsam.NonlinearFactorGraph(), []
    for i in range(graph.size()):
        factor = graph.at(i)
        if isinstance(factor, MotionFactor):
            motion.append(factor)
        else:
            rest.push_back(factor)
    return rest, motion


def keyframe_motion_factors(
    motion: BodyVelocities, times: np.ndarray, mount_key: int | None = None, scales: np.ndarray | None = None
) -> list:
    """A ``MotionFactor`` on (X(k), V(k)[, ``mount_key``][, S(scales[k])]) for every keyframe time inside
    ``motion``'s span (interpolated)."""
    vel, var, inside = motion.at(times)
    keys = np.flatnonzero(inside)
    if len(keys) == 0:
        log.warning("no keyframe lies inside the motion model's time span: no motion factor")
    scale_keys = None if scales is None else [S(int(j)) for j in scales[keys]]
    return motion_factors(vel[keys], var[keys], X, V, keys=keys, mount_key=mount_key, scale_keys=scale_keys)


def scale_keys(values: gtsam.Values) -> list[int]:
    """The speed-scale keys ``S(0)``, ``S(1)``, ... that ``values`` holds, in time order."""
    keys = []
    while values.exists(S(len(keys))):
        keys.append(S(len(keys)))
    return keys


def _scale_index(times: np.ndarray, interval_s: float) -> np.ndarray:
    """(K,) the speed-scale state of each keyframe: its interval of ``interval_s`` from the first keyframe."""
    return np.floor((times - times[0]) / interval_s).astype(int)


def _scale_factors(count: int, sigma: float, walk: float, interval_s: float) -> list:
    """The prior at 1 on S(0) (``sigma``) and the random walk S(j) -> S(j + 1) (``walk`` per sqrt(s) over
    ``interval_s``)."""
    out = [gtsam.PriorFactorVector(S(0), np.ones(1), gtsam.noiseModel.Isotropic.Sigma(1, sigma))]
    step = gtsam.noiseModel.Isotropic.Sigma(1, walk * np.sqrt(interval_s)) if count > 1 else None
    out.extend(gtsam.BetweenFactorVector(S(j), S(j + 1), np.zeros(1), step) for j in range(count - 1))
    return out


def trajectory_of(values: gtsam.Values, times: np.ndarray, marginals: gtsam.Marginals | None = None) -> Trajectory:
    """Keyframe states X(k), V(k) of ``values`` (and position marginals if ``marginals`` is given)."""
    table = poses_of(values, np.array([X(k) for k in range(len(times))], dtype=np.uint64), "trajectory_of")
    rot, pos = table[:, :9].reshape(-1, 3, 3), table[:, 9:]
    pos_cov = None
    if marginals is not None:  # Pose3 tangent is [rotation, translation]; translation in the body frame
        pos_cov = np.array([r @ marginals.marginalCovariance(X(k))[3:, 3:] @ r.T for k, r in enumerate(rot)])
    return Trajectory(
        t=np.asarray(times, dtype=float),
        rot=rot,
        pos=pos,
        vel=np.array([values.atVector(V(k)) for k in range(len(times))]),
        pos_cov=pos_cov,
    )


def with_marginals(solution: Solution) -> Trajectory:
    """The solution's trajectory with the marginal position covariance of every keyframe; NaN covariances, with a
    warning, where GTSAM finds the graph too poorly conditioned for them (e.g. minutes of keyframes after the last
    GPS fix: the solution stands, its uncertainty cannot be computed)."""
    try:
        marginals = gtsam.Marginals(solution.graph, solution.values)
        return trajectory_of(solution.values, solution.trajectory.t, marginals)
    except RuntimeError as error:
        near = re.search(r"Symbol: (\w+)", str(error))
        log.warning(
            "marginal covariances not computed (NaN in marginals.npz, no ellipsoids): GTSAM finds the graph "
            "nearly indeterminate%s; keyframes far from every GPS fix do that",
            f" near {near.group(1)}" if near else "",
        )
    trajectory = solution.trajectory
    nan = np.full((len(trajectory.t), 3, 3), np.nan)
    return Trajectory(trajectory.t, trajectory.rot, trajectory.pos, trajectory.vel, nan)


def _warn_off_keyframe(export: Export, gps: GpsFixes, keyframe: np.ndarray) -> None:
    """A warning when fixes lie more than 1.5 IMU samples from the keyframe they constrain: the graph applies each
    fix at its keyframe's time, an error of the speed times the offset (``airimu fuse`` puts a keyframe at every fix:
    ``learned_imu.export.merge_keyframes``)."""
    used = keyframe >= 0
    if used.sum() < 1 or len(export.keyframe_t) < 2:
        return
    sample_s = float(np.median(np.diff(export.keyframe_t) / np.diff(export.keyframe_index)))
    offset = np.abs(export.keyframe_t[keyframe[used]] - gps.t[used])
    if offset.max() <= 1.5 * sample_s:
        return
    speed = [0.0]
    if len(gps.t) > 1:
        speed = np.linalg.norm(np.diff(gps.pos, axis=0), axis=1) / np.maximum(np.diff(gps.t), 1e-9)
    log.warning(
        "%s: %d of %d GPS fixes lie between keyframes, up to %.3g s from the keyframe they are applied at (%.3g m at "
        "the track's median speed %.3g m/s): export with a keyframe at every fix (learned_imu.export.merge_keyframes, "
        "as airimu fuse does)",
        export.name,
        int((offset > 1.5 * sample_s).sum()),
        int(used.sum()),
        float(offset.max()),
        float(offset.max() * np.median(speed)),
        float(np.median(speed)),
    )


def _nearest_keyframes(times: np.ndarray, gps_t: np.ndarray) -> np.ndarray:
    """Index of the keyframe nearest to each fix, or -1 if none lies within half a keyframe interval."""
    index = np.clip(np.searchsorted(times, gps_t), 1, len(times) - 1)
    index = np.where(np.abs(times[index - 1] - gps_t) <= np.abs(times[index] - gps_t), index - 1, index)
    half = 0.5 * float(np.median(np.diff(times)))
    return np.where(np.abs(times[index] - gps_t) <= half + 1e-9, index, -1)
