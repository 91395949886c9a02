"""Is the gyro in rad/s? Its rotations against the gravity the accelerometer sees, with no ground truth and no GPS.

Over a stretch of ``TILT_STRETCH_S`` the gyro, integrated from the stretch's first sample, carries every specific
force sample into that first sample's frame; averaged over a window of ``TILT_WINDOW_S`` the result is gravity's
reaction plus the window's velocity change over its length, so on a correctly read log the windows' means agree to
about the platform's own accelerations (the median over stretches of their RMS spread about the stretch's mean,
m/s^2). A gyro read 57x or 1000x too large (deg/s or mrad/s taken for rad/s) turns every wobble of a car's
suspension or a drone's attitude into tens of degrees and the means wander by several m/s^2. The gyro's constant
bias is fitted first (Gauss-Newton on the spread, the preintegration's bias Jacobian), since a raw MEMS gyro's bias
(EuRoC: 0.02-0.08 rad/s) alone tilts a 20-s stretch by up to a radian; its median is not its bias on an aggressive
flight (EuRoC V1_03: 0.03 rad/s off).

``check_gyro_tilt`` refuses a gyro whose spread as read is at least ``TILT_MIN_SPREAD`` and ``TILT_RATIO`` times
that of another reading (``GYRO_READINGS``). Both rules are needed: a drone's accelerometer sees its thrust, always
near the body's z axis, so "no rotation at all" (any reading that shrinks the gyro) explains a drone's or a hand-held
log's specific force about as well as the right gyro or better (EuRoC V1_03 as read 0.29, shrunk 57x 0.16 m/s^2),
and only an as-read spread no real platform makes says anything. For the same reason a gyro read too small (a rad/s
file converted as if deg/s) shows only on a platform that tilts (BROAD's rotation trials), not on a car or a drone.
A log with fewer than ``TILT_MIN_STRETCHES`` stretches without a gap is checked over ``TILT_SHORT`` instead; a
shorter one is not checked. Measured on every shared recording (2026-12-07, ``benchmarks/gyro_tilt.py``):
BENCHMARKS.md "Hostile inputs".

A gyro read too small on a car is what the turns show instead (``turn_speeds``, ``check_gyro_turns``): a platform
that travels along one axis of its body (a car, a wheeled robot) feels the centripetal force ``omega x v`` in a turn,
so over a window of ``TURN_WINDOW_S`` its horizontal specific force follows its yaw rate (the gyro about the up the
accelerometer sees) along one direction, and the slope, force over rate, is its speed. Where that fit holds
(R^2 >= ``TURN_MIN_R2``, the fitted force varying by at least ``TURN_MIN_FORCE``) on ``TURN_MIN_WINDOWS`` windows or
more, a median speed over ``TURN_MAX_SPEED`` is refused: no ground vehicle turns that fast, and a rad/s gyro
converted as if deg/s puts a car's 5-15 m/s at 290-830 m/s (KITTI). The statistic needs no unit of the gyro (R^2 and the
force do not change with its scale), and a drone or a hand-held log, whose force does not follow its yaw, has few
such windows, at walking or flying speeds (measured: BENCHMARKS.md "Hostile inputs").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from airimu_core.errors import DataError
from airimu_core.sequence import gap_indices

TILT_STRETCH_S = 20.0  # the gyro integrated over this long (its bias fitted: drift over it stays small)
TILT_WINDOW_S = 4.0  # the specific force averaged over this long (a platform's accelerations average out)
TILT_MIN_STRETCHES = 3  # fewer stretches without a gap: the bias is not determined, the check does not run
TILT_SHORT = (10.0, 2.0)  # stretch and window (s) of a log too short for three stretches of TILT_STRETCH_S
TILT_MAX_STRETCHES = 24  # at most this many, evenly spread (the cost of a long log)
TILT_BIAS_ITERATIONS = 3
TILT_MIN_SPREAD = 1.0  # m/s^2: below this the gyro as read is not refused (right logs: at most 0.98 as read)
TILT_RATIO = 3.0  # ... and another reading must spread this many times less
TURN_WINDOW_S = 5.0  # a turn's centripetal force against its yaw rate over this long (half-overlapping windows)
TURN_MIN_R2 = 0.8  # the force must follow the yaw rate this closely along one direction ...
TURN_MIN_FORCE = 0.5  # m/s^2: ... and vary by this much (std of the fit): a turn, not vibration
TURN_MIN_WINDOWS = 5  # fewer such windows: nothing decided (one odd window on a city drive reaches 190 m/s)
TURN_MAX_SPEED = 120.0  # m/s: faster than any train or race car through a turn (right logs: median 5-15 as read)

GYRO_READINGS = {  # what a gyro read as rad/s may really be -> (factor to rad/s, the fix)
    "deg/s": (np.pi / 180.0, "read it with gyro_unit='deg/s' (airimu: --reader-option gyro_unit=deg/s)"),
    "mrad/s": (1e-3, "divide the gyro columns by 1000 (rad/s expected)"),
    "rad/s converted as if deg/s": (180.0 / np.pi, "read it without gyro_unit=deg/s (it is already rad/s)"),
}


def reading_fixes(units: list[str]) -> str:
    """The fixes of the ``GYRO_READINGS`` named ``units``, joined as one sentence for a message."""
    text = "; or ".join(GYRO_READINGS[unit][1] for unit in units)
    return text[0].upper() + text[1:]


@dataclass(frozen=True)
class TiltFit:
    """``gravity_spread``'s answer: the median over stretches of the windows' RMS spread (m/s^2), the fitted gyro
    bias (rad/s, IMU frame) and how many stretches were used."""

    spread: float
    bias: np.ndarray
    stretches: int


def _stretch_starts(t: np.ndarray, length: int) -> np.ndarray:
    """First samples of non-overlapping stretches of ``length`` samples without a gap, at most
    ``TILT_MAX_STRETCHES`` of them, evenly spread over the log."""
    gaps = gap_indices(t)
    starts, k = [], 0
    while k + length <= len(t):
        inside = gaps[(gaps >= k) & (gaps < k + length - 1)]
        if inside.size:
            k = int(inside[-1]) + 1
            continue
        starts.append(k)
        k += length
    starts = np.asarray(starts, dtype=int)
    if len(starts) > TILT_MAX_STRETCHES:
        starts = starts[np.linspace(0, len(starts) - 1, TILT_MAX_STRETCHES).round().astype(int)]
    return starts


def gravity_spread(
    t: np.ndarray, gyro: np.ndarray, acc: np.ndarray, stretch_s: float = TILT_STRETCH_S, window_s: float = TILT_WINDOW_S
) -> TiltFit | None:
    """The module docstring's statistic for ``gyro`` (N, 3) rad/s and ``acc`` (N, 3) m/s^2 at times ``t`` (s), over
    stretches of ``stretch_s`` and windows of ``window_s``; None with fewer than ``TILT_MIN_STRETCHES`` stretches."""
    import torch

    from learned_imu.geometry.preintegration import preintegrate

    dt = float(np.median(np.diff(t)))
    per_window = max(int(round(window_s / dt)), 1)
    length = per_window * int(round(stretch_s / window_s))
    starts = _stretch_starts(t, length)
    if len(starts) < TILT_MIN_STRETCHES:
        return None
    rows = starts[:, None] + np.arange(length)[None, :]
    samples_gyro, samples_acc, times = torch.as_tensor(gyro[rows]), torch.as_tensor(acc[rows]), t[rows]
    steps = torch.as_tensor(np.diff(times, axis=1, append=times[:, -1:] + dt))
    at = list(range(per_window - 1, length, per_window))
    bias = np.zeros(3)
    for iteration in range(TILT_BIAS_ITERATIONS + 1):
        pre = preintegrate(samples_gyro - torch.as_tensor(bias), samples_acc, steps, at=at, bias_jacobian=True)
        vel = np.concatenate([np.zeros((len(starts), 1, 3)), pre.vel.numpy()], axis=1)
        jac = pre.bias_jacobian.numpy()[..., 6:9, 3:6]  # d velocity / d gyro bias (bias subtracted)
        jac = np.concatenate([np.zeros((len(starts), 1, 3, 3)), jac], axis=1)
        means, mean_jac = np.diff(vel, axis=1) / window_s, np.diff(jac, axis=1) / window_s
        deviation = means - means.mean(axis=1, keepdims=True)
        if iteration == TILT_BIAS_ITERATIONS:
            break
        jac_dev = (mean_jac - mean_jac.mean(axis=1, keepdims=True)).reshape(-1, 3)
        bias = bias + np.linalg.lstsq(jac_dev, -deviation.reshape(-1), rcond=1e-6)[0]
    per_stretch = np.sqrt((deviation**2).sum(axis=-1).mean(axis=1))
    return TiltFit(float(np.median(per_stretch)), bias, len(starts))


def check_gyro_tilt(t: np.ndarray, gyro: np.ndarray, acc: np.ndarray, source: object) -> None:
    """Refuse a gyro that is not in rad/s by the module docstring's rule, naming ``source``, the gyro, every reading
    that fits ``TILT_RATIO`` times better than as read, best first, and its fix. Silent where the log is too short
    or nothing is decided."""
    lengths = (TILT_STRETCH_S, TILT_WINDOW_S)
    as_read = gravity_spread(t, gyro, acc, *lengths)
    if as_read is None:  # a short log: half the lengths
        lengths = TILT_SHORT
        as_read = gravity_spread(t, gyro, acc, *lengths)
    if as_read is None or as_read.spread < TILT_MIN_SPREAD:
        return
    spreads = {u: gravity_spread(t, gyro * factor, acc, *lengths).spread for u, (factor, _) in GYRO_READINGS.items()}
    best = min(spreads.values())
    if best * TILT_RATIO > as_read.spread:
        return
    # every reading that fits TILT_RATIO times better is named: deg/s and mrad/s both leave a drone nearly unturned,
    # and "no rotation" explains its thrust-borne specific force best (a deg/s file on EuRoC fits mrad/s better)
    ranked = sorted(spreads.items(), key=lambda item: item[1])
    alike = [unit for unit, spread in ranked if spread * TILT_RATIO <= as_read.spread]
    raise DataError(
        source,
        "gyro",
        f"the gyro as read does not follow the gravity the accelerometer sees: integrated over {lengths[0]:g}-s "
        f"stretches it scatters the specific force's {lengths[1]:g}-s means by {as_read.spread:.3g} m/s^2, "
        f"as {alike[0]} by {best:.3g} (a platform's own accelerations: about 1 or less): gyro in "
        f"{' or '.join(alike)}? {reading_fixes(alike)}",
    )


def turn_speeds(t: np.ndarray, gyro: np.ndarray, acc: np.ndarray) -> np.ndarray:
    """The speeds (m/s) the module docstring's turn fit implies, one per window of ``TURN_WINDOW_S`` (half
    overlapping, none across a gap) where it holds; ``gyro`` (N, 3) as read (rad/s expected), ``acc`` (N, 3) m/s^2."""
    dt = float(np.median(np.diff(t)))
    length = max(int(round(TURN_WINDOW_S / dt)), 8)
    starts = np.arange(0, len(t) - length + 1, length // 2)
    gaps = gap_indices(t)
    if gaps.size:
        first_gap = np.searchsorted(gaps, starts)  # the first gap at or after each start
        after = np.append(gaps, len(t))[first_gap]
        starts = starts[after >= starts + length - 1]
    if not starts.size:
        return np.zeros(0)
    rows = starts[:, None] + np.arange(length)[None, :]
    force, rate = acc[rows], gyro[rows]  # (W, L, 3)
    up = force.mean(axis=1)
    up /= np.linalg.norm(up, axis=-1, keepdims=True)
    yaw = np.einsum("wlk,wk->wl", rate, up)
    yaw -= yaw.mean(axis=1, keepdims=True)
    horizontal = force - np.einsum("wl,wk->wlk", np.einsum("wlk,wk->wl", force, up), up)
    horizontal -= horizontal.mean(axis=1, keepdims=True)
    power = np.maximum((yaw**2).sum(axis=1), 1e-300)
    slope = np.einsum("wl,wlk->wk", yaw, horizontal) / power[:, None]  # force per unit yaw rate, a vector
    speed = np.linalg.norm(slope, axis=-1)
    along = np.einsum("wlk,wk->wl", horizontal, slope / np.maximum(speed, 1e-300)[:, None])
    fitted = yaw * speed[:, None]
    r2 = 1.0 - ((along - fitted) ** 2).sum(axis=1) / np.maximum((along**2).sum(axis=1), 1e-300)
    held = (r2 >= TURN_MIN_R2) & (fitted.std(axis=1) >= TURN_MIN_FORCE)
    return speed[held]


def check_gyro_turns(t: np.ndarray, gyro: np.ndarray, acc: np.ndarray, source: object) -> None:
    """Refuse a gyro that turns too little for the centripetal force the accelerometer feels in a car's turns
    (module docstring), naming ``source``, the gyro, the speed it implies and every reading that brings it under
    ``TURN_MAX_SPEED``. Silent where fewer than ``TURN_MIN_WINDOWS`` windows are turns of that kind."""
    speeds = turn_speeds(t, gyro, acc)
    if len(speeds) < TURN_MIN_WINDOWS:
        return
    speed = float(np.median(speeds))
    if speed <= TURN_MAX_SPEED:
        return
    fits = [unit for unit, (factor, _) in GYRO_READINGS.items() if 1.0 <= speed / factor <= TURN_MAX_SPEED]
    named = (
        f"gyro in {' or '.join(fits)}? {reading_fixes(fits)}"
        if fits
        else "the gyro reads too small by a factor none of the usual units explains"
    )
    raise DataError(
        source,
        "gyro",
        f"the gyro as read turns too little for the centripetal force the accelerometer feels: in {len(speeds)} "
        f"{TURN_WINDOW_S:g}-s windows where the horizontal specific force follows the yaw rate, force over rate "
        f"puts the speed at {speed:.3g} m/s (median; a ground vehicle turns at under {TURN_MAX_SPEED:g}); {named}",
    )


def check_gyro_unit(t: np.ndarray, gyro: np.ndarray, acc: np.ndarray, source: object) -> None:
    """Both checks of a gyro's unit without ground truth or GPS: ``check_gyro_tilt`` (a gyro too large, any
    platform; too small on one that tilts) and ``check_gyro_turns`` (too small on a car)."""
    check_gyro_tilt(t, gyro, acc, source)
    check_gyro_turns(t, gyro, acc, source)
