"""Typed records for IMU sequences, the boundary between readers/simulator and everything downstream.

Conventions, for every record in this module:
- time in seconds (float64), strictly increasing;
- ``gyro``: angular rate of the IMU frame w.r.t. inertial space, expressed in the IMU frame, rad/s;
- ``acc``: specific force (reaction to gravity included: about +9.81 m/s^2 up at rest), IMU frame, m/s^2;
- ``rot``: rotation matrices world <- IMU (``v_world = rot @ v_imu``); quaternions, where a file has them,
  are converted at the reader and never cross this boundary;
- world frame is z-up, gravity vector ``gravity`` is expressed in it (e.g. ``[0, 0, -9.81]``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from airimu_core.errors import DataError, InputError, real_array

MAX_GAP_STEPS = 5.0  # a time step longer than this many median steps is a gap


def gap_indices(t: np.ndarray, max_gap_steps: float = MAX_GAP_STEPS) -> np.ndarray:
    """Indices ``i`` where ``t[i+1] - t[i]`` exceeds ``max_gap_steps`` median time steps."""
    if t.shape[0] < 3:
        return np.zeros(0, dtype=np.int64)
    steps = np.diff(t)
    return np.flatnonzero(steps > max_gap_steps * np.median(steps))


def segments(t: np.ndarray, max_gap_steps: float = MAX_GAP_STEPS) -> list[slice]:
    """Contiguous runs of ``t`` between gaps, as slices."""
    cuts = gap_indices(t, max_gap_steps) + 1
    bounds = np.concatenate([[0], cuts, [t.shape[0]]])
    return [slice(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]


def _check_array(source: object, field: str, value: np.ndarray, shape_tail: tuple[int, ...], n: int | None):
    if not isinstance(value, np.ndarray):
        raise DataError(source, field, f"expected a numpy array, got {type(value).__name__}")
    if value.shape[1:] != shape_tail or (n is not None and value.shape[0] != n):
        want = ("N" if n is None else str(n),) + tuple(str(s) for s in shape_tail)
        raise DataError(source, field, f"expected shape ({', '.join(want)}), got {value.shape}")


@dataclass(frozen=True, eq=False)
class GroundTruth:
    """Ground-truth states resampled to the IMU time stamps.

    Attributes:
        rot: (N, 3, 3) world <- IMU rotation matrices.
        pos: (N, 3) position of the IMU origin in the world frame, m.
        vel: (N, 3) velocity of the IMU origin in the world frame, m/s.
        valid: (N,) bool; False where the ground truth had a gap or does not cover the IMU sample.
    """

    rot: np.ndarray
    pos: np.ndarray
    vel: np.ndarray
    valid: np.ndarray


# one-sigma GPS noise per axis (m) of fixes whose source states none (a CSV without sigma columns, a NavSatFix
# without covariance): a consumer receiver's open-sky figure. ``fusion.config.FuseConfig.gps_sigma_m`` defaults to it
GPS_SIGMA_UNKNOWN_M = 1.0


@dataclass(frozen=True, eq=False)
class GpsFixes:
    """GNSS position fixes (a measurement, not ground truth).

    Attributes:
        t: (M,) time of each fix, s, on the IMU clock.
        pos: (M, 3) antenna position in the world frame, m.
        sigma: (M, 3) one-sigma position noise per axis, m (standard deviation, not variance); given as a float
            (every fix, every axis), (3,) (every fix), (M,) (every axis) or (M, 3).
    """

    t: np.ndarray
    pos: np.ndarray
    sigma: np.ndarray

    def __post_init__(self):
        t, pos = real_array(self.t, "GpsFixes.t"), real_array(self.pos, "GpsFixes.pos")
        if t.ndim != 1 or pos.shape != (len(t), 3):
            raise InputError(f"GpsFixes: t must be (M,) and pos (M, 3); got {t.shape} and {pos.shape}")
        sigma = real_array(self.sigma, "GpsFixes.sigma")
        if sigma.shape == (len(t),) and sigma.shape != (3,):
            sigma = sigma[:, None]
        try:
            sigma = np.broadcast_to(sigma, (len(t), 3)).copy()
        except ValueError:
            raise InputError(
                f"GpsFixes: sigma must be a float, (3,), (M,) or (M, 3) with M = {len(t)} fixes; got {sigma.shape}"
            ) from None
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "pos", pos)
        object.__setattr__(self, "sigma", sigma)

    def __getitem__(self, index) -> GpsFixes:
        """The fixes at ``index`` (a slice, boolean mask or index array)."""
        return GpsFixes(self.t[index], self.pos[index], self.sigma[index])

    @classmethod
    def none(cls) -> GpsFixes:
        """No fix at all (a log fused without GPS)."""
        return cls(np.zeros(0), np.zeros((0, 3)), GPS_SIGMA_UNKNOWN_M)

    def with_sigma(self, sigma_m: float) -> GpsFixes:
        """The same fixes with one-sigma ``sigma_m`` (m) on every axis of every fix."""
        return GpsFixes(self.t, self.pos, float(sigma_m))


MAX_IMU_DELAY_S = 0.5  # an IMU delay (s) larger than this is a unit mistake or a clock that needs fixing upstream


def is_imu_delay(value) -> bool:
    """Is ``value`` an IMU delay: a finite number of seconds (not a bool) within +-``MAX_IMU_DELAY_S`` (the readers'
    and ``FuseConfig``'s ``imu_delay_s``)?"""
    number = isinstance(value, int | float) and not isinstance(value, bool)
    return number and math.isfinite(value) and abs(value) <= MAX_IMU_DELAY_S


def read_later(t: np.ndarray, values: np.ndarray, delay_s: float) -> np.ndarray:
    """(N, C) ``values`` (N, C) sampled at ``t`` (N,), read at ``t + delay_s`` instead: linear between samples, held
    past the ends."""
    return np.column_stack([np.interp(t + delay_s, t, values[:, i]) for i in range(values.shape[1])])


@dataclass(frozen=True, eq=False)
class ImuSequence:
    """One IMU recording with optional ground truth and GPS. See the module docstring for conventions.

    Attributes:
        name: short name, e.g. ``"MH_01_easy"``.
        t: (N,) sample times, s, strictly increasing.
        gyro: (N, 3) rad/s, IMU frame.
        acc: (N, 3) specific force, m/s^2, IMU frame.
        gravity: (3,) gravity vector in the world frame, m/s^2.
        gt: ground truth at the N IMU times, or None.
        gps: GPS fixes, or None.
        source: where the sequence came from (a path, or ``"simulator"``), used in error messages.
        imu_delay_s: how much earlier than recorded the samples are stamped, s (``imu_delay_removed``; the readers'
            ``imu_delay_s`` option): 0 for the stamps as recorded.
    """

    name: str
    t: np.ndarray
    gyro: np.ndarray
    acc: np.ndarray
    gravity: np.ndarray
    gt: GroundTruth | None = None
    gps: GpsFixes | None = None
    source: str = ""
    imu_delay_s: float = 0.0

    def __post_init__(self):
        src = self.source or self.name
        _check_array(src, "t", self.t, (), None)
        n = self.t.shape[0]
        _check_array(src, "gyro", self.gyro, (3,), n)
        _check_array(src, "acc", self.acc, (3,), n)
        _check_array(src, "gravity", self.gravity, (), 3)
        for field in ("t", "gyro", "acc"):
            bad = ~np.isfinite(getattr(self, field))
            if bad.any():
                row = int(np.argwhere(bad)[0][0])
                raise DataError(src, field, f"non-finite value at sample {row}")
        steps = np.diff(self.t)
        if (steps <= 0).any():
            row = int(np.argmax(steps <= 0)) + 1
            raise DataError(src, "t", f"timestamps must be strictly increasing; sample {row} is not")
        if self.gt is not None:
            _check_array(src, "gt.rot", self.gt.rot, (3, 3), n)
            _check_array(src, "gt.pos", self.gt.pos, (3,), n)
            _check_array(src, "gt.vel", self.gt.vel, (3,), n)
            _check_array(src, "gt.valid", self.gt.valid, (), n)
        if self.gps is not None:
            m = self.gps.t.shape[0]
            _check_array(src, "gps.t", self.gps.t, (), None)
            _check_array(src, "gps.pos", self.gps.pos, (3,), m)
            _check_array(src, "gps.sigma", self.gps.sigma, (3,), m)

    def __len__(self) -> int:
        return int(self.t.shape[0])

    def part(self, start: float, stop: float) -> ImuSequence:
        """The samples from fraction ``start`` to fraction ``stop`` of the sequence (0 <= start < stop <= 1, by
        sample count), with their ground truth and the GPS fixes inside that time span; named ``NAME[start:stop]``
        (e.g. a held-back tail for validation: ``part(0.85, 1.0)``)."""
        if not 0.0 <= start < stop <= 1.0:
            raise InputError(f"{self.name}: a part needs 0 <= start < stop <= 1, got {start}, {stop}")
        if (start, stop) == (0.0, 1.0):
            return self
        n = len(self)
        first, last = int(round(start * n)), int(round(stop * n))
        if last - first < 2:
            raise InputError(f"{self.name}: part [{start}, {stop}] holds fewer than 2 of its {n} samples")
        return self._samples(slice(first, last), f"{self.name}[{start:g}:{stop:g}]")

    def until(self, t_end: float) -> ImuSequence:
        """The samples up to and including time ``t_end`` (s, IMU clock), with their ground truth and fixes: what a
        causal estimator has seen by then."""
        return self.between(float(self.t[0]), t_end)

    def between(self, t_start: float, t_end: float, name: str | None = None) -> ImuSequence:
        """The samples with ``t_start <= t <= t_end`` (s, IMU clock), with their ground truth and fixes; named
        ``name`` (default: this sequence's name)."""
        first = int(np.searchsorted(self.t, t_start, side="left"))
        last = int(np.searchsorted(self.t, t_end, side="right"))
        if last - first < 2:
            raise InputError(f"{self.name}: fewer than 2 samples lie in [{t_start}, {t_end}] s")
        if (first, last) == (0, len(self)) and name is None:
            return self
        return self._samples(slice(first, last), name or self.name)

    def split_at_gaps(self, max_gap_steps: float = MAX_GAP_STEPS) -> list[ImuSequence]:
        """One sequence per gap-free run (a step longer than ``max_gap_steps`` median steps is a gap; runs of fewer
        than 2 samples are dropped), named ``NAME_part<k>``: the readers' ``on_gap="keep"`` output, split."""
        runs = [run for run in segments(self.t, max_gap_steps) if run.stop - run.start >= 2]
        return [self._samples(run, f"{self.name}_part{k}") for k, run in enumerate(runs)]

    def bridge_gaps(self, max_gap_steps: float = MAX_GAP_STEPS) -> ImuSequence:
        """The sequence with every gap (a step longer than ``max_gap_steps`` median steps) filled with samples at the
        median step, gyro and acc linear between the samples either side of it: integrating them is the trapezoidal
        rule over the gap where holding the last sample (the readers' ``on_gap="keep"`` output integrated as is) is
        the rectangle rule, which on a car turning through a 1.6-s gap of KITTI's OXTS stream lost up to 15 degrees
        of heading. Ground truth on a filled sample: position and velocity linear, the rotation of the sample before,
        not valid. Unchanged (the same object) without gaps."""
        gaps = gap_indices(self.t, max_gap_steps)
        if gaps.size == 0:
            return self
        step = float(np.median(np.diff(self.t)))
        filled = []
        for g in gaps.tolist():
            count = int(round((self.t[g + 1] - self.t[g]) / step)) - 1
            filled.append(self.t[g] + (self.t[g + 1] - self.t[g]) * np.arange(1, count + 1) / (count + 1))
        t = np.concatenate([self.t, *filled])
        order = np.argsort(t, kind="stable")
        t, original = t[order], (np.arange(len(t)) < len(self.t))[order]

        def linear(values: np.ndarray) -> np.ndarray:
            return np.column_stack([np.interp(t, self.t, values[:, i]) for i in range(values.shape[1])])

        gt = None
        if self.gt is not None:
            before = np.searchsorted(self.t, t, side="right") - 1
            valid = np.zeros(len(t), dtype=bool)
            valid[original] = self.gt.valid
            gt = GroundTruth(self.gt.rot[before], linear(self.gt.pos), linear(self.gt.vel), valid)
        gyro, acc = linear(self.gyro), linear(self.acc)
        return ImuSequence(self.name, t, gyro, acc, self.gravity, gt, self.gps, self.source, self.imu_delay_s)

    def imu_delay_removed(self, delay_s: float) -> ImuSequence:
        """The sequence with its IMU ``delay_s`` seconds late against its clock (the ground truth's and the GPS's),
        put on that clock by its stamps: each sample keeps its gyro and acc and is stamped ``delay_s`` earlier, when
        it was measured. The ground truth is read at the new stamps (position and velocity linear, the rotation at a
        constant rate between the two samples around each; valid where both are and no gap lies between them), the
        samples whose new stamp leaves the recording's span are dropped, and the fixes outside it too. No IMU value is
        interpolated: read later instead (``read_later``, what ``FuseConfig.imu_delay_s`` does to the preintegration's
        samples), a KITTI drive's IMU interpolated across its 70-250 ms gaps integrated to 42.8 % t_rel where these
        stamps give 19.1 % (2011_09_26_drive_0061, 74 gaps). The readers' ``imu_delay_s``; the same object for 0."""
        if delay_s == 0:
            return self
        t = self.t - delay_s
        keep = (t >= self.t[0]) & (t <= self.t[-1])
        t = t[keep]
        if len(t) < 2:
            raise InputError(f"{self.name}: an IMU delay of {delay_s} s leaves fewer than 2 samples")
        gt = None
        if self.gt is not None:
            from airimu_core.rotations import slerp

            k = np.clip(np.searchsorted(self.t, t, side="right") - 1, 0, len(self.t) - 2)
            span = self.t[k + 1] - self.t[k]
            frac = np.clip((t - self.t[k]) / span, 0.0, 1.0)
            f = frac[:, None]
            steady = span <= MAX_GAP_STEPS * float(np.median(np.diff(self.t)))
            valid = self.gt.valid[k] & self.gt.valid[k + 1] & steady
            pos = (1 - f) * self.gt.pos[k] + f * self.gt.pos[k + 1]
            vel = (1 - f) * self.gt.vel[k] + f * self.gt.vel[k + 1]
            gt = GroundTruth(slerp(self.gt.rot[k], self.gt.rot[k + 1], frac), pos, vel, valid)
        gps = None if self.gps is None else self.gps[(self.gps.t >= t[0]) & (self.gps.t <= t[-1])]
        delayed = self.imu_delay_s + delay_s
        return ImuSequence(self.name, t, self.gyro[keep], self.acc[keep], self.gravity, gt, gps, self.source, delayed)

    def _samples(self, cut: slice, name: str) -> ImuSequence:
        """The samples ``cut`` with their ground truth and the GPS fixes inside their time span."""
        gt = None
        if self.gt is not None:
            gt = GroundTruth(self.gt.rot[cut], self.gt.pos[cut], self.gt.vel[cut], self.gt.valid[cut])
        t = self.t[cut]
        gps = None if self.gps is None else self.gps[(self.gps.t >= t[0]) & (self.gps.t <= t[-1])]
        gyro, acc = self.gyro[cut], self.acc[cut]
        return ImuSequence(name, t, gyro, acc, self.gravity, gt, gps, self.source, self.imu_delay_s)

    @property
    def dt(self) -> np.ndarray:
        """(N,) time step of each sample, s: ``t[k+1] - t[k]``, the last one repeating its predecessor."""
        if len(self) < 2:
            return np.zeros_like(self.t)
        d = np.diff(self.t)
        return np.concatenate([d, d[-1:]])
