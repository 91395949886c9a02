"""A still start: the gyro's bias from its mean rate and roll / pitch from gravity, before the platform moves.

From the first sample on, consecutive ``WINDOW_S`` windows count as still while each window's rate stays within
``GYRO_RIPPLE_RAD_S`` of its own mean, its mean within ``GYRO_DRIFT_RAD_S`` of the first window's and under
``GYRO_BIAS_MAX_RAD_S``, its mean specific force within ``ACC_DRIFT_M_S2`` of the first window's and the spread of
``|acc|`` under ``ACC_RIPPLE_M_S2`` (a still IMU measures one constant rate, its bias, and one constant force,
gravity). The IMU alone cannot tell still from cruising at a constant velocity, so a still start also needs the
motion to say so: the GPS fixes inside the span within ``GPS_STILL_M`` (plus three sigmas) of the first, or a given
start velocity under ``START_STILL_M_S``; without either there is none (never read from ground truth unless the start
was asked for from it).

Conventions: gyro rad/s and acc m/s^2 in the IMU frame; ``up`` the world's up axis seen from the body (``R^T e_z``,
from the mean specific force); sigmas are standard deviations (sigma, not sigma^2) of the means, from the scatter of
the window means (white noise and vibration alike; the tilt's at least what an accelerometer bias of
``ACC_BIAS_FLOOR_M_S2`` tilts). The Earth's rate (7.3e-5 rad/s) stays in the bias.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from airimu_core.sequence import GpsFixes

WINDOW_S = 0.5
MIN_S = 2.0  # shorter still spans are not used
GYRO_RIPPLE_RAD_S = 0.05
GYRO_DRIFT_RAD_S = 0.01
GYRO_BIAS_MAX_RAD_S = 0.1  # a still gyro reads its bias: above 5.7 deg/s it is turning (EuRoC's raw: 0.08 at most)
ACC_RIPPLE_M_S2 = 0.15
ACC_DRIFT_M_S2 = 0.1
GPS_STILL_M = 0.5
START_STILL_M_S = 0.1
ACC_BIAS_FLOOR_M_S2 = 0.05  # the tilt's sigma covers at least this accelerometer bias (BROAD: 0.05-0.38 deg off)
GYRO_BIAS_FLOOR_RAD_S = 1e-4  # a prior on what is left of the gyro's bias covers at least this (its instability)


@dataclass(frozen=True)
class StillStart:
    """A still span at the start of a log (module docstring)."""

    samples: int  # the span is samples [0, samples)
    duration_s: float
    gyro_bias: np.ndarray  # (3,) rad/s, the mean rate
    gyro_bias_sigma: np.ndarray  # (3,) rad/s
    up: np.ndarray  # (3,) unit, the world's up axis in the body frame
    tilt_sigma_rad: float

    def gyro_prior_sigma(self, configured: float) -> np.ndarray:
        """(3,) rad/s: the sigma of a prior on the gyro bias left after this one is taken out: its own sigma, at
        least ``GYRO_BIAS_FLOOR_RAD_S``, at most the ``configured`` prior's."""
        return np.minimum(np.maximum(self.gyro_bias_sigma, GYRO_BIAS_FLOOR_RAD_S), configured)

    def to_json_dict(self) -> dict:
        return {
            "duration_s": round(self.duration_s, 3),
            "gyro_bias_rad_s": [float(v) for v in self.gyro_bias],
            "gyro_bias_sigma_rad_s": [float(v) for v in self.gyro_bias_sigma],
            "tilt_sigma_deg": float(np.degrees(self.tilt_sigma_rad)),
        }


def still_start(
    t: np.ndarray,
    gyro: np.ndarray,
    acc: np.ndarray,
    fixes: GpsFixes | None = None,
    start_velocity: np.ndarray | None = None,
) -> StillStart | None:
    """The still span at the start of the samples ``t`` (N,) s, ``gyro`` and ``acc`` (N, 3), confirmed by the
    ``fixes`` or a given ``start_velocity`` (m/s, world frame); None when there is none of ``MIN_S`` (module
    docstring)."""
    rate = 1.0 / float(np.median(np.diff(t)))
    width = max(2, int(round(WINDOW_S * rate)))
    windows = len(t) // width
    if windows * width < MIN_S * rate:
        return None
    g = gyro[: windows * width].reshape(windows, width, 3)
    a = acc[: windows * width].reshape(windows, width, 3)
    g_mean, a_mean = g.mean(axis=1), a.mean(axis=1)
    quiet = (
        (np.abs(g - g_mean[:, None]).max(axis=(1, 2)) < GYRO_RIPPLE_RAD_S)
        & (np.linalg.norm(a, axis=2).std(axis=1) < ACC_RIPPLE_M_S2)
        & (np.abs(g_mean - g_mean[0]).max(axis=1) < GYRO_DRIFT_RAD_S)
        & (np.linalg.norm(g_mean, axis=1) < GYRO_BIAS_MAX_RAD_S)
        & (np.abs(a_mean - a_mean[0]).max(axis=1) < ACC_DRIFT_M_S2)
    )
    count = int(np.argmin(quiet)) if not quiet.all() else windows
    if count * width < MIN_S * rate:  # the IMU was not quiet for long enough: nothing for the motion to confirm
        return None
    samples = _confirmed_samples(t, count * width, fixes, start_velocity)
    if samples < MIN_S * rate:
        return None
    count = samples // width
    end = float(t[samples - 1])
    bias = gyro[:samples].mean(axis=0)
    force = acc[:samples].mean(axis=0)
    scatter = g_mean[:count].std(axis=0, ddof=1) if count > 1 else np.full(3, GYRO_DRIFT_RAD_S)
    acc_scatter = float(a_mean[:count].std(axis=0, ddof=1).max()) if count > 1 else ACC_DRIFT_M_S2
    return StillStart(
        samples=samples,
        duration_s=end - float(t[0]),
        gyro_bias=bias,
        gyro_bias_sigma=scatter / np.sqrt(count),
        up=force / np.linalg.norm(force),
        tilt_sigma_rad=max(acc_scatter / np.sqrt(count), ACC_BIAS_FLOOR_M_S2) / float(np.linalg.norm(force)),
    )


def _confirmed_samples(t: np.ndarray, samples: int, fixes: GpsFixes | None, start_velocity) -> int:
    """How many of the first ``samples`` the motion confirms as still: up to the first fix that moved more than
    ``GPS_STILL_M`` and three of its sigmas from the first fix (at least two fixes still), else all of them with a
    given start velocity under ``START_STILL_M_S``; 0 without either."""
    if start_velocity is not None and float(np.linalg.norm(start_velocity)) >= START_STILL_M_S:
        return 0
    if fixes is not None and len(fixes.t):
        inside = (fixes.t >= t[0]) & (fixes.t <= t[samples - 1])
        if inside.sum() >= 2:
            times, pos, sigma = fixes.t[inside], fixes.pos[inside], fixes.sigma[inside]
            moved = np.any(np.abs(pos - pos[0]) > GPS_STILL_M + 3.0 * (sigma + sigma[0]), axis=1)
            if moved[1]:
                return 0
            if moved.any():  # still until the last fix before the first that moved
                return int(np.searchsorted(t, times[int(np.argmax(moved)) - 1], side="right"))
            return samples
    return samples if start_velocity is not None else 0
