"""A start without a known first state, from the stream itself (``OnlineFusion(initial_state=None)``).

The first state at the first IMU sample is found from what has come in so far, never from ground truth
(``Aligner.update``, called as fixes arrive):

- roll and pitch from gravity: the mean specific force of a still start (``fusion.still``, confirmed by the GPS
  fixes; its tilt sigma from the scatter), else of the first ``LEVEL_S`` (sigma ``ALIGNED_PRIOR_SIGMAS[0]``);
- the raw gyro's bias from the still start's mean rate (``OnlineFusion`` takes it out of the raw samples, as
  ``airimu fuse`` does);
- heading, position and velocity by search: for every ``YAW_STEP_DEG`` of heading, a window of everything received up
  to the last fix (the raw samples preintegrated by GTSAM between keyframes at each fix and every ``KEYFRAME_S``; the
  fixes; one constant IMU bias with the loose prior ``BIAS_PRIOR_SIGMAS``, its gyro part the still start's sigma after
  one (a free gyro bias turns the heading at the first sample by bias x the time before the motion); a prior on the
  tilt alone, heading and velocity free) is solved by Levenberg-Marquardt from positions interpolated between the
  fixes and rotations carried by the gyro; later updates extend each surviving candidate warm-started (rotations
  predicted with its bias estimate), and candidates ``PRUNE_ERROR`` worse than the best or converged onto its attitude
  are dropped.

Heading is observable only once the platform has accelerated (the IMU's acceleration, rotated by the right heading,
explains the change of the GPS velocity), and until the attitude changes an accelerometer bias looks like a tilt. So
the search starts once the track has moved ``MOVE_M`` beyond three sigmas with ``MIN_FIXES`` fixes, and its answer
is taken when the window pins it: one candidate left, the heading's marginal sigma under ``YAW_SIGMA_MAX_RAD`` and
the tilt's under ``TILT_SIGMA_MAX_RAD``; else the stream waits, up to ``MAX_WAIT_S`` of IMU, after which the best
candidate is taken (``forced``, ``OnlineFusion`` warns). The prior on the aligned state: the window's sigmas times
``PRIOR_INFLATION`` (the same data are replayed into the graph), at least ``ALIGNED_PRIOR_SIGMAS`` for heading and
the still start's sigma for tilt; ``ALIGNED_PRIOR_SIGMAS`` for position and velocity. Conventions: world z up
(gravity (0, 0, -g)); sigmas are standard deviations; rotations world <- IMU.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from airimu_core.errors import InputError
from airimu_core.sequence import GpsFixes
from factors import GpsFactor, gps_noise, learned_pim
from fusion.initial import ALIGNED_PRIOR_SIGMAS, YAW_STEP_DEG, _rotation_between
from fusion.still import StillStart, still_start

X, V, B = gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.V, gtsam.symbol_shorthand.B
MIN_FIXES = 3
MOVE_M = 1.0  # m the GPS track must have moved from its first fix (beyond three sigmas) before a heading search
YAW_SIGMA_MAX_RAD = np.radians(5.0)  # found: the heading's marginal sigma in the search's window under this
TILT_SIGMA_MAX_RAD = np.radians(2.0)  # and the tilt's under this (an acc bias looks like a tilt until the IMU turns)
PRIOR_INFLATION = 2.0  # the replayed data gave the window's sigmas: the prior on the aligned state is this much looser
FREE_YAW_SIGMA_RAD = 1e3  # the search's prior leaves heading free
FREE_VEL_SIGMA_M_S = 1e3  # and the first velocity (the fixes give it)
PRUNE_ERROR = 50.0  # a heading candidate whose window error exceeds the best one's by this is dropped
MAX_WAIT_S = 120.0  # s of IMU after which the best heading is taken however flat the search was
KEYFRAME_S = 1.0  # keyframe grid of the alignment window (every fix has its own keyframe too)
LEVEL_S = 0.5  # s of specific force that give roll and pitch without a still start
# one constant bias over the window, estimated (acc m/s^2 then gyro rad/s, sigmas): a raw gyro's bias of 0.01-0.1
# rad/s (EuRoC's) turns a minute's dead reckoning by degrees to radians
BIAS_PRIOR_SIGMAS = np.array([0.3, 0.3, 0.3, 0.1, 0.1, 0.1])
STILL_GYRO_FLOOR_RAD_S = 1e-4  # the gyro part after a still start: its sigma (the heading at the start hangs on it)


@dataclass(frozen=True)
class Alignment:
    """The first state found from the stream (module docstring).

    ``state``: at the first IMU sample (pose world <- IMU, world velocity m/s); ``prior``: the prior factors on it
    (``X(0)``, ``V(0)``); ``waited_s``: IMU time from the first sample to the sample that allowed it; ``still``: the
    still start used (None without one); ``yaw_sigma_rad``, ``tilt_sigma_rad``: the heading's and the tilt's
    marginal sigma in the search's window (rad, standard deviations); ``forced``: taken at ``MAX_WAIT_S`` or at the
    end of the stream with a sigma above ``YAW_SIGMA_MAX_RAD`` / ``TILT_SIGMA_MAX_RAD`` or two headings left."""

    state: gtsam.NavState
    prior: tuple
    waited_s: float
    still: StillStart | None
    yaw_sigma_rad: float
    tilt_sigma_rad: float
    forced: bool


class Aligner:
    """The alignment carried over a stream (module docstring): each ``update`` extends every heading candidate's
    window with the keyframes since the last one (new rotations predicted through the IMU with the candidate's bias
    estimate, positions and velocities from the fixes), solves it warm-started, and drops candidates whose error
    exceeds the best one's by ``PRUNE_ERROR`` or that converged onto a better one's heading."""

    def __init__(self, gravity: np.ndarray, noise_density: tuple[float, float]):
        self._gravity = np.asarray(gravity, float)
        if np.linalg.norm(self._gravity[:2]) > 1e-6 * np.linalg.norm(self._gravity) or self._gravity[2] >= 0:
            raise InputError(f"the alignment needs a z-up world, gravity (0, 0, -g) m/s^2; got {self._gravity}")
        self._density = noise_density
        self._candidates: list[gtsam.Values] | None = None
        self._keyframes = np.zeros(0, dtype=int)

    def update(self, t: np.ndarray, gyro: np.ndarray, acc: np.ndarray, fixes: GpsFixes, force: bool = False):
        """The ``Alignment`` of the raw samples ``t`` (N,) s, ``gyro`` rad/s and ``acc`` m/s^2 (N, 3, IMU frame)
        received so far and the GPS ``fixes`` among them (world frame, m; sigmas one-sigma); None while the data
        cannot give it yet. ``force`` takes the best heading as soon as two fixes are in."""
        inside = (fixes.t >= t[0]) & (fixes.t <= t[-1])
        fix_t, fix_pos, fix_sigma = fixes.t[inside], fixes.pos[inside], fixes.sigma[inside]
        if len(fix_t) < (2 if force else MIN_FIXES):
            return None
        spread = np.linalg.norm(fix_pos - fix_pos[0], axis=1) - 3.0 * np.linalg.norm(fix_sigma + fix_sigma[0], axis=1)
        waited = float(t[-1] - t[0])
        force = force or waited >= MAX_WAIT_S
        if not force and spread.max() < MOVE_M:
            return None
        still = still_start(t, gyro, acc, GpsFixes(fix_t, fix_pos, fix_sigma))
        bias = still.gyro_bias if still is not None else np.zeros(3)
        bias_sigmas = BIAS_PRIOR_SIGMAS.copy()
        if still is not None:
            bias_sigmas[3:] = np.maximum(still.gyro_bias_sigma, STILL_GYRO_FLOOR_RAD_S)
        bias_prior = gtsam.noiseModel.Diagonal.Sigmas(bias_sigmas)
        up_world = -self._gravity / np.linalg.norm(self._gravity)
        if still is not None:
            up_body, tilt_sigma = still.up, still.tilt_sigma_rad
        else:
            force_mean = acc[t <= t[0] + LEVEL_S].mean(axis=0)
            up_body, tilt_sigma = force_mean / np.linalg.norm(force_mean), ALIGNED_PRIOR_SIGMAS[0]
        keyframes = _keyframes(t, fix_t)
        factors = _imu_factors(t, gyro - bias, acc, keyframes, self._gravity, self._density)
        gps = [
            GpsFactor(X(_nearest(keyframes, t, ti)), p, gps_noise(s, None))
            for ti, p, s in zip(fix_t, fix_pos, fix_sigma, strict=True)
        ]
        times = t[keyframes]
        same_start = len(self._keyframes) and np.array_equal(keyframes[: len(self._keyframes)], self._keyframes)
        if self._candidates is None or not same_start:  # first try (or the keyframes changed): every heading
            level = gtsam.Rot3(_rotation_between(up_body, up_world))  # world <- body, heading arbitrary
            pos0 = fix_pos[0] - (fix_pos[1] - fix_pos[0]) / max(fix_t[1] - fix_t[0], 1e-9) * (fix_t[0] - t[0])
            self._candidates = [
                _guess(
                    factors,
                    gtsam.Pose3(gtsam.Rot3.AxisAngle(up_world, yaw).compose(level), pos0),
                    times,
                    fix_t,
                    fix_pos,
                )
                for yaw in np.deg2rad(np.arange(0.0, 360.0, YAW_STEP_DEG))
            ]
        else:
            self._candidates = [
                _extended(v, factors, len(self._keyframes), times, fix_t, fix_pos) for v in self._candidates
            ]
        self._keyframes = keyframes
        solved = []
        for guess in self._candidates:
            graph = gtsam.NonlinearFactorGraph()
            pose = guess.atPose3(X(0))
            for factor in (*factors, *gps, *_tilt_prior(pose, up_body, tilt_sigma)):
                graph.add(factor)
            graph.add(gtsam.PriorFactorConstantBias(B(0), gtsam.imuBias.ConstantBias(), bias_prior))
            values = gtsam.LevenbergMarquardtOptimizer(graph, guess).optimize()
            solved.append((graph.error(values), values.atPose3(X(0)).rotation(), graph, values))
        solved.sort(key=lambda c: c[0])
        kept = []
        for c in solved:  # a candidate that converged onto a better one's attitude is the same answer
            close = any(
                np.linalg.norm(gtsam.Rot3.Logmap(c[1].between(k[1]))) < np.radians(YAW_STEP_DEG / 3) for k in kept
            )
            if c[0] <= solved[0][0] + PRUNE_ERROR and not close:
                kept.append(c)
        self._candidates = [c[3] for c in kept]
        _, _, graph, values = kept[0]
        pose = values.atPose3(X(0))
        try:
            cov = gtsam.Marginals(graph, values).marginalCovariance(X(0))[:3, :3]  # body-frame rotation tangent
            rot = pose.rotation().matrix()
            world = rot @ cov @ rot.T
            yaw_sigma = float(np.sqrt(max(world[2, 2], 0.0)))
            tilt_sigma_found = float(np.sqrt(max(np.linalg.eigvalsh(world[:2, :2]).max(), 0.0)))
        except RuntimeError:  # indeterminate: heading unobservable so far
            yaw_sigma = tilt_sigma_found = np.inf
        ambiguous = len(kept) > 1  # another heading explains the data almost as well
        unsure = yaw_sigma > YAW_SIGMA_MAX_RAD or tilt_sigma_found > TILT_SIGMA_MAX_RAD or ambiguous
        if unsure and not force:
            return None
        state = gtsam.NavState(pose, values.atVector(V(0)))
        heading_prior = float(np.clip(PRIOR_INFLATION * yaw_sigma, ALIGNED_PRIOR_SIGMAS[0], np.pi))
        tilt_prior = max(tilt_sigma, min(PRIOR_INFLATION * tilt_sigma_found, ALIGNED_PRIOR_SIGMAS[0]))
        prior = aligned_prior(pose, state.velocity(), tilt_prior, heading_prior)
        return Alignment(state, prior, waited, still, yaw_sigma, tilt_sigma_found, unsure)


def _tilt_prior(pose: gtsam.Pose3, up_body: np.ndarray, tilt_sigma: float) -> tuple:
    """The search's priors: the attitude nearest the candidate's whose up axis is the measured ``up_body`` (tilt
    from gravity, ``tilt_sigma``), heading, position and velocity free."""
    rot = pose.rotation()
    now_up = rot.matrix()[2]  # the world's up axis in the body frame, R^T e_z
    target = gtsam.Pose3(rot.compose(gtsam.Rot3(_rotation_between(up_body, now_up))), pose.translation())
    return aligned_prior(target, np.zeros(3), tilt_sigma, FREE_YAW_SIGMA_RAD, vel_sigma=FREE_VEL_SIGMA_M_S)


def aligned_prior(
    pose: gtsam.Pose3, vel, tilt_sigma: float, heading: float = ALIGNED_PRIOR_SIGMAS[0], vel_sigma: float | None = None
) -> tuple:
    """Priors on ``X(0)`` and ``V(0)``: ``tilt_sigma`` rad about the horizontal world axes, ``heading`` rad about the
    world's vertical, ``ALIGNED_PRIOR_SIGMAS`` for position (m) and velocity (m/s); the rotation's covariance
    expressed in the body frame, GTSAM's ``Pose3`` tangent."""
    _, pos_sigma, default_vel_sigma = ALIGNED_PRIOR_SIGMAS
    vel_sigma = default_vel_sigma if vel_sigma is None else vel_sigma
    rot = pose.rotation().matrix()
    world = np.diag([tilt_sigma**2, tilt_sigma**2, heading**2])  # z up: the gravity axis of an aligned state
    cov = np.zeros((6, 6))
    cov[:3, :3] = rot.T @ world @ rot
    cov[3:, 3:] = np.eye(3) * pos_sigma**2
    return (
        gtsam.PriorFactorPose3(X(0), pose, gtsam.noiseModel.Gaussian.Covariance(cov)),
        gtsam.PriorFactorVector(V(0), np.asarray(vel, float), gtsam.noiseModel.Isotropic.Sigma(3, vel_sigma)),
    )


def _keyframes(t: np.ndarray, fix_t: np.ndarray) -> np.ndarray:
    """Sample indices: the first, every ``KEYFRAME_S`` and each fix's nearest up to the last fix (so that a later
    update keeps these and appends); two samples apart at least."""
    at_fix = np.clip(np.searchsorted(t, fix_t), 0, len(t) - 1)
    grid = np.searchsorted(t, np.arange(t[0], t[at_fix[-1]], KEYFRAME_S))
    index = np.unique(np.concatenate([[0], grid, at_fix]))
    keep = [int(index[0])]
    for i in index[1:]:
        if i - keep[-1] >= 2:
            keep.append(int(i))
    return np.array(keep)


def _nearest(keyframes: np.ndarray, t: np.ndarray, ti: float) -> int:
    return int(np.argmin(np.abs(t[keyframes] - ti)))


def _imu_factors(t, gyro, acc, keyframes, gravity, noise_density) -> list:
    dt = np.diff(t)
    density = [np.full(3, noise_density[0] ** 2), np.full(3, noise_density[1] ** 2)]
    factors = []
    for k, (a, b) in enumerate(zip(keyframes[:-1], keyframes[1:], strict=True)):
        pim = learned_pim(gyro[a:b], acc[a:b], dt[a:b], *density, gravity)
        factors.append(gtsam.ImuFactor(X(k), V(k), X(k + 1), V(k + 1), B(0), pim))
    return factors


def _guess(factors: list, pose: gtsam.Pose3, times: np.ndarray, fix_t: np.ndarray, fix_pos: np.ndarray) -> gtsam.Values:
    """Initial values: positions interpolated between the fixes, velocities their differences, rotations
    dead-reckoned from ``pose`` (as ``fusion.initial.interpolated_values``: predicting the positions through a
    biased IMU puts them kilometres off within a minute)."""
    pos = np.column_stack([np.interp(times, fix_t, fix_pos[:, i]) for i in range(3)])
    vel = np.gradient(pos, times, axis=0) if len(times) > 1 else np.zeros((1, 3))
    values, rot = gtsam.Values(), pose.rotation()
    values.insert(B(0), gtsam.imuBias.ConstantBias())
    for k in range(len(times)):
        values.insert(X(k), gtsam.Pose3(rot, pos[k]))
        values.insert(V(k), vel[k])
        if k < len(factors):
            rot = rot.compose(factors[k].preintegratedMeasurements().deltaRij())
    return values


def _extended(values: gtsam.Values, factors: list, known: int, times, fix_t, fix_pos) -> gtsam.Values:
    """``values`` (a solution over ``known`` keyframes) with the keyframes after them: rotations predicted through
    the IMU with the solution's bias, positions and velocities from the fixes."""
    out = gtsam.Values(values)
    pos = np.column_stack([np.interp(times, fix_t, fix_pos[:, i]) for i in range(3)])
    vel = np.gradient(pos, times, axis=0)
    bias = values.atConstantBias(B(0))
    state = gtsam.NavState(values.atPose3(X(known - 1)), values.atVector(V(known - 1)))
    for k in range(known, len(times)):
        state = factors[k - 1].preintegratedMeasurements().predict(state, bias)
        out.insert(X(k), gtsam.Pose3(state.pose().rotation(), pos[k]))
        out.insert(V(k), vel[k])
        state = gtsam.NavState(out.atPose3(X(k)), vel[k])
    return out
