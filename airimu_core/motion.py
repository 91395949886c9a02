"""Body-frame velocities with their variances: what a motion model (``learned_imu.network.motion``) hands the
estimator (``fusion``), one record at the boundary.

Conventions: ``t`` (M,) s on the IMU clock, strictly increasing; ``vel`` (M, 3) the IMU's velocity in its own frame,
``R^T v`` (R world <- IMU, v world-frame), m/s; ``var`` (M, 3) its per-axis variance, (m/s)^2 (sigma^2, not sigma).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from airimu_core.errors import InputError, real_array


@dataclass(frozen=True, eq=False)
class BodyVelocities:
    """A motion model's output (module docstring). ``at(t)`` interpolates it linearly."""

    t: np.ndarray
    vel: np.ndarray
    var: np.ndarray

    def __post_init__(self):
        t = real_array(self.t, "BodyVelocities.t")
        vel, var = real_array(self.vel, "BodyVelocities.vel"), real_array(self.var, "BodyVelocities.var")
        if t.ndim != 1 or len(t) == 0 or vel.shape != (len(t), 3) or var.shape != (len(t), 3):
            raise InputError(
                f"BodyVelocities: t must be (M,) with M >= 1, vel and var (M, 3); got {t.shape}, {vel.shape}, "
                f"{var.shape}"
            )
        for name, value in (("t", t), ("vel", vel), ("var", var)):
            if not np.all(np.isfinite(value)):
                raise InputError(f"BodyVelocities.{name} contains NaN or Inf")
        if np.any(np.diff(t) <= 0):
            raise InputError("BodyVelocities.t must be strictly increasing")
        if np.any(var <= 0):
            raise InputError("BodyVelocities.var: variances must be positive, (m/s)^2")
        for name, value in (("t", t), ("vel", vel), ("var", var)):
            object.__setattr__(self, name, value)

    def at(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """At times ``t`` (K,) s: (vel (K, 3), var (K, 3), inside (K,) bool). Linear between outputs; a time
        outside [t[0], t[-1]] is not inside (its rows hold the nearest output's values)."""
        t = np.asarray(t, dtype=float)
        inside = (t >= self.t[0] - 1e-9) & (t <= self.t[-1] + 1e-9)
        vel = np.column_stack([np.interp(t, self.t, self.vel[:, i]) for i in range(3)])
        var = np.column_stack([np.interp(t, self.t, self.var[:, i]) for i in range(3)])
        return vel, var, inside

    def scaled(self, factor) -> BodyVelocities:
        """The same velocities with every variance times ``factor`` (> 0): one number, or three (per body axis)."""
        factor = np.asarray(factor, dtype=float)
        if factor.shape not in ((), (3,)) or not np.all(np.isfinite(factor) & (factor > 0)):
            raise InputError(f"BodyVelocities.scaled: factor must be one or three positive numbers, got {factor!r}")
        return BodyVelocities(self.t, self.vel, self.var * factor)

    def along_track_free(self, estimate: np.ndarray, where: np.ndarray | None = None) -> BodyVelocities:
        """The same velocities with the along-track axis left to the IMU (its variance times ``ALONG_TRACK_FREE``)
        at the outputs ``where`` (M,) bool (default: all). The along-track axis of an output is the body axis the
        estimator's velocity ``estimate`` (M, 3) m/s is mostly along; the other two (a car's zero lateral and
        vertical speed) are kept."""
        estimate = np.asarray(estimate, dtype=float)
        if estimate.shape != self.vel.shape:
            raise InputError(
                f"BodyVelocities.along_track_free: estimate must be {self.vel.shape}, got {estimate.shape}"
            )
        rows = np.arange(len(self.t)) if where is None else np.flatnonzero(where)
        var = self.var.copy()
        var[rows, np.abs(estimate[rows]).argmax(axis=1)] *= ALONG_TRACK_FREE
        return BodyVelocities(self.t, self.vel, var)

    def outside_envelope(self, estimate: np.ndarray, limit_m_s: float) -> tuple[BodyVelocities, np.ndarray]:
        """The speed envelope: where the estimator's speed ``|estimate|`` ((M, 3) body frame, m/s) exceeds
        ``limit_m_s`` (the model's training speeds, ``fusion.config.MotionSettings.speed_envelope``), the model
        extrapolates its speed along the track (KITTI's highway, BENCHMARKS.md), so that axis is left to the IMU
        (``along_track_free``). Returns the velocities and (M,) which outputs were beyond the envelope."""
        if not (np.isfinite(limit_m_s) and limit_m_s > 0):
            raise InputError(f"BodyVelocities.outside_envelope: limit_m_s must be > 0 m/s, got {limit_m_s!r}")
        beyond = np.linalg.norm(np.asarray(estimate, dtype=float), axis=-1) > limit_m_s
        return self.along_track_free(estimate, beyond), beyond


# a variance factor that leaves an axis of the motion factor to the IMU (sigma x 1000)
ALONG_TRACK_FREE = 1.0e6
