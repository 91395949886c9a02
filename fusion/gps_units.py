"""Is a GPS track in the unit its file claims? Its accelerations against the IMU's, before anything is fused.

For three fixes i, j, k (times t_i < t_j < t_k at IMU samples, T1 = t_j - t_i, T2 = t_k - t_j), Forster's
preintegrated deltas of the IMU between them give, with p the positions, g the world gravity and R_i the
(unknown) attitude at i:

    (p_k - p_j) / T2 - (p_j - p_i) / T1 - g (T1 + T2) / 2 = R_i m,   m = dv_ij - dp_ij / T1 + dR_ij dp_jk / T2

(the velocity at i eliminated). Over a stretch of a few triples the attitudes are one unknown rotation R times the
IMU's own relative rotations, so ``track_misfit`` fits that rotation per stretch (Wahba's problem, an SVD) and
returns the RMS of what is left, m/s. A track in the wrong unit (lat/lon in radians read as degrees: 1/57.3 of the
motion; x/y/z in km or mm) leaves the IMU's motion, or a thousand times more than it, unexplained.

The altitude alone in another unit hides in that misfit (it looks like a noisier or a smoother vertical); for a
ground vehicle its unit shows in the climb instead (``vertical_scale``).
"""

from __future__ import annotations

import dataclasses
import weakref
from dataclasses import dataclass

import numpy as np

from airimu_core.sequence import GpsFixes, ImuSequence

SPACING_S = 2.0  # fixes at least this far apart (GPS noise over shorter spans swamps the motion)
STRETCH_TRIPLES = 6  # triples sharing one attitude unknown (gyro drift over ~2 x 6 x SPACING_S is small)


CLOCK_SEARCH_S = 60.0  # GPS clock offsets searched, +- s: every 0.5 s, then every CLOCK_STEP_S around the best
CLOCK_COARSE_STEP_S = 0.5
CLOCK_STEP_S = 0.05
CLOCK_RATIO = 1.25  # the best offset explains the track this many times better than as read: a clock offset
# (on-time fixes, 5 KITTI drives x 10 noise draws: at most 1.11 where the best offset is >= CLOCK_MIN_S;
# 1 s late: 1.05-3.0)
CLOCK_MIN_S = 0.3  # smaller best offsets are not reported (the fixes' association to IMU samples moves the misfit)


def track_misfit(sequence: ImuSequence, fixes: GpsFixes) -> float | None:
    """RMS, m/s, of the GPS track's velocity changes that the IMU cannot explain (module docstring); None when
    the fixes inside the IMU's span make fewer than one stretch of triples."""
    fit = _stretch_fit(sequence, fixes)
    if fit is None:
        return None
    return float(np.sqrt(np.mean(np.sum(fit.residual**2, axis=1))))


def _spaced(t: np.ndarray) -> list[int]:
    """Indices of the fix times ``t`` kept so that each is at least ``SPACING_S`` after the one kept before."""
    keep = [0] if len(t) else []
    for i in range(1, len(t)):
        if t[i] - t[keep[-1]] >= SPACING_S:
            keep.append(i)
    return keep


@dataclass(frozen=True)
class _StretchFit:
    """The fixes kept (``pos`` (K, 3), ``t`` (K,), at least ``SPACING_S`` apart), per triple (i, j, k) of consecutive
    kept fixes inside a whole stretch (T of them: j = 1 .. T): ``rot`` (T, 3, 3) world <- IMU at j (the stretch's
    fitted rotation times the IMU's own), ``residual`` (T, 3) m/s (module docstring)."""

    t: np.ndarray
    pos: np.ndarray
    rot: np.ndarray
    residual: np.ndarray


def _stretch_fit(sequence: ImuSequence, fixes: GpsFixes) -> _StretchFit | None:
    rot0, vel, prefix, elapsed = _prefix(sequence)
    inside = (fixes.t >= sequence.t[0]) & (fixes.t < sequence.t[-1])
    t, pos = fixes.t[inside], fixes.pos[inside]
    keep = _spaced(t)
    if len(keep) < STRETCH_TRIPLES + 2:
        return None
    sample = np.clip(np.searchsorted(sequence.t, t[keep]), 0, len(sequence.t) - 1)
    a, b, c = sample[:-2], sample[1:-1], sample[2:]
    t1, t2 = (elapsed[b] - elapsed[a])[:, None], (elapsed[c] - elapsed[b])[:, None]
    # in the frame of sample 0: R_i m = R_0i dv_ij - R_0i dp_ij / T1 + R_0j dp_jk / T2
    dv = vel[b] - vel[a]
    dp_ij = prefix[b] - prefix[a] - vel[a] * t1
    dp_jk = prefix[c] - prefix[b] - vel[b] * t2
    u = dv - dp_ij / t1 + dp_jk / t2
    p = pos[keep]
    y = (p[2:] - p[1:-1]) / t2 - (p[1:-1] - p[:-2]) / t1 - 0.5 * np.asarray(sequence.gravity) * (t1 + t2)
    residual, rot = [], []
    for start in range(0, len(u) - STRETCH_TRIPLES + 1, STRETCH_TRIPLES):
        part = slice(start, start + STRETCH_TRIPLES)
        w, _, vt = np.linalg.svd(y[part].T @ u[part])
        r = w @ np.diag([1.0, 1.0, np.linalg.det(w @ vt)]) @ vt  # world <- frame of sample 0 for this stretch
        residual.append(y[part] - u[part] @ r.T)
        rot.append(r @ rot0[b[part]])
    return _StretchFit(t[keep], p, np.concatenate(rot), np.concatenate(residual))


MIN_SPEED_M_S = 3.0  # fixes slower than this say little about the direction of travel
SCALE_MIN_ROWS = 10
SCALE_MIN_SIGNIFICANCE = 5.0  # a scale at least this many standard errors from 0
VERTICAL_MIN_ROWS = 30
VERTICAL_MIN_R2 = 0.75  # the track's climb must follow the IMU's tilt this closely (a ground vehicle, a hilly road)
HEADING_MIN_R2 = 0.5  # the track's turns must follow the gyro's this closely (a vehicle that turns where it heads)
MAX_CHORD_SPANS = 2.0  # heading_scale's chords: at most this many times their median duration (none over a gap)


@dataclass(frozen=True)
class TrackScale:
    """A slope of the GPS track against the IMU (``vertical_scale``, ``heading_scale``): ``scale``, its standard
    error ``sigma``, the regression's ``r2``, the number of ``rows`` in it and the R^2 it needs (``min_r2``)."""

    scale: float
    sigma: float
    r2: float
    rows: int
    min_r2: float

    @property
    def decided(self) -> bool:
        """The track says something about the scale: R^2 at least ``min_r2`` and the scale at least
        ``SCALE_MIN_SIGNIFICANCE`` standard errors from 0."""
        return self.r2 >= self.min_r2 and abs(self.scale) >= SCALE_MIN_SIGNIFICANCE * self.sigma


def vertical_scale(sequence: ImuSequence, fixes: GpsFixes) -> TrackScale | None:
    """How many metres the GPS track's vertical unit is, from a ground vehicle's IMU: a car travels along a fixed
    axis f of its body (it does not slide sideways or up), so the sine of the track's climb angle, v_z / |v|, equals
    f . (R^T e_z), the IMU's tilt as ``track_misfit``'s stretches fit it (gravity fixes it to a fraction of a
    degree). The sines regressed on the up axis in the body frame (both with their mean taken out, the up axis in
    the two coordinates it varies in; coefficients w = scale * f): |w| is the altitude's unit over a metre, whatever
    f is. Velocities over two fix spacings, at ``MIN_SPEED_M_S`` or faster; the gyro's median taken out first (as
    ``check_imu_units``). None with fewer than ``VERTICAL_MIN_ROWS`` such fixes. Only decided results say anything
    (R^2 >= ``VERTICAL_MIN_R2``): a flat road, or a drone, whose direction of travel does not follow its tilt,
    leave R^2 low. KITTI raw drives with 0.5 m GPS noise: 2011_09_30 0033 / 0034 and 2011_10_03 0034 decide, at
    0.84-0.95 in m and 2.65-2.95 in feet; the shorter and flatter drives do not (BENCHMARKS.md, Hostile inputs)."""
    steady = dataclasses.replace(sequence, gyro=sequence.gyro - np.median(sequence.gyro, axis=0))
    fit = _stretch_fit(steady, fixes)
    if fit is None:
        return None
    j = np.arange(1, len(fit.rot) + 1)
    vel = (fit.pos[j + 1] - fit.pos[j - 1]) / (fit.t[j + 1] - fit.t[j - 1])[:, None]
    moving = np.linalg.norm(vel[:, :2], axis=1) >= MIN_SPEED_M_S
    if moving.sum() < VERTICAL_MIN_ROWS:
        return None
    climb = vel[moving, 2] / np.linalg.norm(vel[moving], axis=1)
    up = fit.rot[moving, 2, :]  # R^T e_z: the third row of world <- IMU
    # a unit vector varies in the plane normal to its mean (pitch and roll): two coordinates there
    tangent = np.linalg.svd(up.mean(axis=0)[None, :])[2][1:].T  # (3, 2): an orthonormal basis of that plane
    x, y = (up - up.mean(axis=0)) @ tangent, climb - climb.mean()
    w, *_ = np.linalg.lstsq(x, y, rcond=None)
    left = y - x @ w
    scale = float(np.linalg.norm(w))
    if scale == 0.0 or not float(y @ y) > 0.0:
        return None
    cov = float(left @ left) / (len(y) - 3) * np.linalg.inv(x.T @ x)
    sigma = float(np.sqrt(max(w @ cov @ w, 0.0))) / scale
    return TrackScale(scale, sigma, 1.0 - float(left @ left) / float(y @ y), len(y), VERTICAL_MIN_R2)


def heading_scale(sequence: ImuSequence, fixes: GpsFixes) -> TrackScale | None:
    """How many times the GPS track turns as far as the gyro says, for a vehicle that heads where it goes (a car, a
    fixed-wing): the change of the track's course from one chord (consecutive fixes ``SPACING_S`` or more apart, but not
    across a gap: at most ``MAX_CHORD_SPANS`` times the median chord; both at ``MIN_SPEED_M_S`` or faster) to the next,
    regressed through 0 on the change of the gyro's heading averaged over the same chords (the rate about the up axis,
    up from the accelerometer averaged over +-1 s; the gyro's median taken out first). 1 for a gyro in rad/s; pi/180 for
    one in deg/s read as rad/s, 1e-3 for mrad/s, 180/pi for rad/s converted as if deg/s; -1 for a gyro whose sign is
    flipped. None with fewer than ``SCALE_MIN_ROWS`` pairs of chords; decided with R^2 >= ``HEADING_MIN_R2`` (a drone
    that flies sideways is not). KITTI raw drives with 0.5 m GPS noise (BENCHMARKS.md, Hostile inputs)."""
    inside = (fixes.t >= sequence.t[0]) & (fixes.t <= sequence.t[-1])
    t, pos = fixes.t[inside], fixes.pos[inside]
    keep = _spaced(t)
    if len(keep) < SCALE_MIN_ROWS + 2:
        return None
    t, pos = t[keep], pos[keep]
    dt = np.diff(sequence.t)
    half = max(1, int(round(1.0 / float(np.median(dt)))))
    total = np.concatenate([np.zeros((1, 3)), np.cumsum(sequence.acc, axis=0)])
    n = np.arange(len(sequence.t))
    lo, hi = np.clip(n - half, 0, None), np.clip(n + half + 1, None, len(sequence.t))
    up = (total[hi] - total[lo]) / (hi - lo)[:, None]
    up /= np.linalg.norm(up, axis=1, keepdims=True)
    rate = np.sum((sequence.gyro - np.median(sequence.gyro, axis=0)) * up, axis=1)
    heading = np.concatenate([[0.0], np.cumsum(rate[:-1] * dt)])  # rad, at each sample
    area = np.concatenate([[0.0], np.cumsum(0.5 * (heading[1:] + heading[:-1]) * dt)])  # its integral over time
    at = np.interp(t, sequence.t, area)
    mean_heading = np.diff(at) / np.diff(t)  # over each chord
    chord = np.diff(pos[:, :2], axis=0)
    span = np.diff(t)
    # a chord over a gap of the fixes (an outage) may hold a whole turn, which the course's wrap to (-pi, pi] can
    # flip: KITTI seq 06 (2011_09_30_drive_0020) with fixes missing for 60 s from 27.6 s read as a gyro of the
    # wrong sign (slope -1.04, R^2 0.98, from that one pair of chords)
    fast = (np.linalg.norm(chord, axis=1) / span >= MIN_SPEED_M_S) & (span <= MAX_CHORD_SPANS * np.median(span))
    course = np.arctan2(chord[:, 1], chord[:, 0])
    pair = fast[1:] & fast[:-1]
    turn = np.angle(np.exp(1j * np.diff(course)))[pair]
    gyro_turn = np.diff(mean_heading)[pair]
    if len(turn) < SCALE_MIN_ROWS or not float(gyro_turn @ gyro_turn) > 0.0 or not float(turn @ turn) > 0.0:
        return None
    scale = float(gyro_turn @ turn) / float(gyro_turn @ gyro_turn)
    left = turn - scale * gyro_turn
    sigma = float(np.sqrt(float(left @ left) / (len(turn) - 1) / float(gyro_turn @ gyro_turn)))
    return TrackScale(scale, sigma, 1.0 - float(left @ left) / float(turn @ turn), len(turn), HEADING_MIN_R2)


def clock_offset(
    sequence: ImuSequence, fixes: GpsFixes, search_s: float = CLOCK_SEARCH_S
) -> tuple[float, float, float]:
    """(offset, misfit there, misfit as read): the shift of the GPS times, s, within +-``search_s`` (every
    ``CLOCK_COARSE_STEP_S``, then every ``CLOCK_STEP_S`` within one coarse step of the best) that lets the IMU
    explain the track best (``track_misfit``, m/s); subtract it from the GPS times. KITTI 0027 with fixes 7 s late
    or 30 s early: found to 0.05 s (the +-5 s search of before missed them). A clock offset of the fixes shows as
    a misfit whose minimum is away from 0 (KITTI 0027 with fixes 0.5 /
    1 / 2 s late: 1.52 / 2.18 / 2.40 m/s as read, 0.64 at the offset; tests/fusion/test_fuse_mistakes.py).
    (nan, nan, nan) when too few fixes lie in the IMU's span."""
    as_read = track_misfit(sequence, fixes)
    if as_read is None:
        return (np.nan, np.nan, np.nan)
    best, best_misfit = 0.0, as_read
    coarse = np.arange(-search_s, search_s + CLOCK_COARSE_STEP_S / 2, CLOCK_COARSE_STEP_S)
    for grid in (coarse, None):
        if grid is None:  # refine around the coarse best
            grid = best + np.arange(-CLOCK_COARSE_STEP_S, CLOCK_COARSE_STEP_S + CLOCK_STEP_S / 2, CLOCK_STEP_S)
        for offset in grid:
            misfit = track_misfit(sequence, GpsFixes(fixes.t - offset, fixes.pos, fixes.sigma))
            if misfit is not None and misfit < best_misfit:
                best, best_misfit = float(offset), misfit
    return best, best_misfit, as_read


def _prefix(sequence: ImuSequence) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The IMU's preintegrated rotation (frame of sample 0 <- IMU), velocity and position from sample 0 and the time
    elapsed, per sample (index n: at sample n, in the frame of sample 0); one preintegration of the whole log per
    sequence, however many readings, shifts and checks ask (the unit check's alternatives and the clock search ask up
    to ~100 times)."""
    if sequence not in _PREFIXES:
        import torch

        from learned_imu.geometry.preintegration import preintegrate

        gyro, acc, dt = (torch.as_tensor(x) for x in (sequence.gyro, sequence.acc, sequence.dt))
        deltas = preintegrate(gyro, acc, dt)
        rot = np.concatenate([np.eye(3)[None], deltas.rot.numpy()])
        vel = np.concatenate([np.zeros((1, 3)), deltas.vel.numpy()])
        prefix = np.concatenate([np.zeros((1, 3)), deltas.pos.numpy()])
        elapsed = np.concatenate([[0.0], deltas.dt.numpy()])
        _PREFIXES[sequence] = (rot, vel, prefix, elapsed)
    return _PREFIXES[sequence]


_PREFIXES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # ImuSequence (hashed by identity) -> _prefix
