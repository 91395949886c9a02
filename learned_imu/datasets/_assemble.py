"""From arrays as read to a checked ``ImuSequence``: velocity from positions, ground truth resampled to the IMU
time stamps, crop to the IMU/GT overlap, gap policy, units check and frame self-check. Shared by every reader, as
are the options of those checks, one ``ReadChecks`` record (a config or ``read_sequence`` gives its fields flat).

Conventions decided here (each reader's docstring repeats the ones that matter to it):

- **crop**: by default the IMU is cropped to the time span of the valid ground truth (``crop_to_gt=True``), so
  every returned sample lies inside it; ``crop_to_gt=False`` keeps all IMU samples and marks the ones outside
  ``valid=False``.
- **resampling**: position and velocity linearly, rotation by slerp, between the two ground-truth samples that
  bracket each IMU time. Rows with NaN are dropped first; an IMU sample gets ``valid=False`` when the GT row
  nearest to it was NaN or its bracketing interval is longer than ``MAX_GAP_STEPS`` median GT steps. Values
  where ``valid`` is False are placeholders (interpolated across the gap, or held at the nearest GT sample):
  finite, but not ground truth.
- **velocity from positions** (files without velocity): at each GT sample, the derivative of a least-squares
  cubic fitted to the positions within a centred window of ``VEL_WINDOW_S`` (a Savitzky-Golay filter evaluated on
  the actual time stamps, windows shifted inward at the ends and never across a gap). On EuRoC V1_02 it matches
  the velocity of the official ground truth to 3.2 mm/s rms (tests/learned_imu/datasets/test_euroc.py).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from airimu_core.errors import DataError, InputError
from airimu_core.rotations import UNIT_NORM_TOL, quat_to_matrix, slerp
from airimu_core.sequence import GpsFixes, GroundTruth, ImuSequence
from learned_imu.datasets import _checks
from learned_imu.datasets._tilt import check_gyro_unit

VEL_WINDOW_S = 0.05  # s; 11 samples at 200 Hz, chosen on EuRoC V1_02 (3.2 mm/s rms vs the file velocity)
VEL_POLYORDER = 3
# IMU stamps this fraction of a median GT step outside the GT span still count as inside (TUM files print
# stamps to 10 us, so the first/last GT stamp may miss its IMU stamp by a few us)
EDGE_TOL_STEPS = 0.01


@dataclass(frozen=True)
class ReadChecks:
    """How a reader checks what it reads: the options every reader shares (flat keys in a config's ``options``,
    ``read_sequence``'s keywords and the CLI's ``--reader-option``, gathered into this record there).

    Attributes:
        on_duplicate: repeated time stamps (IMU and ground truth): ``"error"`` names the first one's line;
            ``"drop"`` keeps the first sample of each (``_checks.check_timestamps``).
        on_gap: an IMU time step longer than ``MAX_GAP_STEPS`` median steps: ``"error"`` names it; ``"keep"``
            accepts the gaps (``ImuSequence.split_at_gaps()`` then splits; a config's ``on_gap: split`` does both).
        crop_to_gt: crop the IMU to the time span of the valid ground truth; False keeps every IMU sample and
            marks those outside it ``valid=False``.
        check_frame: run the frame and motion self-checks of the ground truth against the IMU
            (``_checks.check_frame``).
        check_units: refuse acc that does not look like m/s^2 or gyro that does not look like rad/s
            (``_checks.check_units``; ``read_csv`` also refuses time stamps at no IMU's rate).
        vel_window_s: s, the centred window of the local cubic that differentiates ground-truth positions into a
            velocity where the file holds none (module docstring).

    A reader that cannot honour a field refuses any value but its default (``refuse``; ``check_options`` refuses
    it as no option of that reader): ``read_kitti`` crop_to_gt, check_frame and vel_window_s (the files
    hold no ground truth); ``read_kitti_raw`` crop_to_gt and vel_window_s (its ground truth lies on the IMU's own
    stamps, with the velocity read from the file); ``read_broad`` on_duplicate (its stamps are the sample index
    over the rate, never repeated).
    """

    on_duplicate: _checks.OnDuplicate = "error"
    on_gap: _checks.OnGap = "error"
    crop_to_gt: bool = True
    check_frame: bool = True
    check_units: bool = True
    vel_window_s: float = VEL_WINDOW_S

    def __post_init__(self):
        if self.on_gap == "split":
            raise _error("on_gap", "'split' is a step of its own: read with on_gap='keep', then .split_at_gaps()")
        for name, allowed in (("on_duplicate", _checks.ON_DUPLICATE), ("on_gap", _checks.ON_GAP)):
            if getattr(self, name) not in allowed:
                raise _error(name, f"expected one of {', '.join(allowed)}, got {getattr(self, name)!r}")
        for name in ("crop_to_gt", "check_frame", "check_units"):
            if not isinstance(getattr(self, name), bool):
                raise _error(name, f"expected True or False, got {getattr(self, name)!r}")
        window = self.vel_window_s
        real = isinstance(window, int | float) and not isinstance(window, bool)
        if not (real and math.isfinite(window) and window > 0):
            raise _error("vel_window_s", f"expected a positive number of seconds, got {window!r}")

    def refuse(self, names: tuple[str, ...], reader: str, why: str) -> None:
        """An ``InputError`` naming the first of ``names`` that is not at its default: ``reader`` cannot honour
        it, because ``why``."""
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name in names and value != f.default:
                raise _error(f.name, f"{reader} cannot honour {value!r} ({why}); leave it at {f.default!r}")


def _error(name: str, problem: str) -> InputError:
    return InputError(f"ReadChecks.{name}: {problem}")


@dataclass(frozen=True, eq=False)
class GtSamples:
    """Ground truth at its own time stamps, as read from a file (before resampling).

    Attributes:
        t: (M,) s, on the IMU clock, non-decreasing.
        rot: (M, 3, 3) world <- IMU (identity placeholders where ``valid`` is False).
        pos: (M, 3) m, world frame.
        vel: (M, 3) m/s world frame, or None to differentiate ``pos``.
        valid: (M,) False for rows with NaN/Inf.
        source: the file, for error messages.
    """

    t: np.ndarray
    rot: np.ndarray
    pos: np.ndarray
    vel: np.ndarray | None
    valid: np.ndarray
    source: object

    @classmethod
    def from_quaternions(cls, t, quat, order: str, pos, vel, source, field: str = "gt.quaternion") -> GtSamples:
        """Build from (M, 4) quaternions in ``order``; rows with a NaN (a missing sample) are marked invalid, an
        infinite value is refused (no recorder writes inf for "missing": a unit or overflow error upstream)."""
        infinite = np.isinf(quat).any(axis=1) | np.isinf(pos).any(axis=1)
        if vel is not None:
            infinite |= np.isinf(vel).any(axis=1)
        if infinite.any():
            row = int(np.argmax(infinite))
            raise DataError(
                source,
                "gt",
                f"ground-truth sample {row} (t = {float(t[row])!r}) holds an infinite value; "
                f"NaN marks a missing sample, inf does not ({int(infinite.sum())} such sample(s))",
            )
        valid = np.isfinite(quat).all(axis=1) & np.isfinite(pos).all(axis=1)
        if vel is not None:
            valid &= np.isfinite(vel).all(axis=1)
        rows = np.flatnonzero(valid)
        norm = np.linalg.norm(quat[rows], axis=1)
        bad = np.abs(norm - 1.0) > UNIT_NORM_TOL
        if bad.any():
            row = int(rows[np.argmax(bad)])
            raise DataError(
                source,
                field,
                f"quaternion of ground-truth sample {row} has norm {norm[np.argmax(bad)]:.4g}, "
                "expected 1 (wrong columns?)",
            )
        rot = np.broadcast_to(np.eye(3), (t.shape[0], 3, 3)).copy()
        rot[valid] = quat_to_matrix(quat[valid], order, source, field)
        return cls(t, rot, pos, vel, valid, source)


def differentiate_positions(
    t: np.ndarray, pos: np.ndarray, window_s: float = VEL_WINDOW_S, polyorder: int = VEL_POLYORDER
) -> np.ndarray:
    """(N, 3) velocity, m/s, of positions (N, 3) m at times (N,) s (see the module docstring); split at gaps."""
    vel = np.zeros_like(pos, dtype=np.float64)
    for seg in _checks.segments(t):
        vel[seg] = _local_poly_derivative(t[seg], pos[seg], window_s, polyorder)
    return vel


def _local_poly_derivative(t: np.ndarray, pos: np.ndarray, window_s: float, polyorder: int) -> np.ndarray:
    n = t.shape[0]
    if n < 2:
        return np.zeros_like(pos)
    width = int(round(window_s / np.median(np.diff(t))))
    width = min(max(width | 1, polyorder + 2), n)
    order = min(polyorder, width - 1)
    if width < 3:
        return np.gradient(pos, t, axis=0)
    start = np.clip(np.arange(n) - width // 2, 0, n - width)
    idx = start[:, None] + np.arange(width)
    tau = (t[idx] - t[:, None]) / window_s  # scaled for a well-conditioned normal matrix
    vander = tau[..., None] ** np.arange(order + 1)  # (n, width, order + 1)
    normal = np.einsum("nwi,nwj->nij", vander, vander)
    rhs = np.einsum("nwi,nwk->nik", vander, pos[idx])
    coef = np.linalg.solve(normal, rhs)
    return coef[:, 1, :] / window_s


def resample_ground_truth(
    t: np.ndarray,
    gt: GtSamples,
    max_gap_steps: float = _checks.MAX_GAP_STEPS,
    vel_window_s: float = VEL_WINDOW_S,
    max_gt_distance_s: float | None = None,
) -> GroundTruth:
    """Ground truth at the times ``t`` (see the module docstring for interpolation and validity). With
    ``max_gt_distance_s`` a sample is also invalid when either ground-truth stamp that brackets it is farther than
    that (s): no value interpolated across a hole in a motion-capture stream (the TUM-VI reader's rule)."""
    steps = np.diff(gt.t)
    max_step = max_gap_steps * float(np.median(steps)) if steps.size else 0.0
    keep = gt.valid
    tg, rot, pos = gt.t[keep], gt.rot[keep], gt.pos[keep]
    if tg.shape[0] < 2:
        raise DataError(gt.source, "gt", f"fewer than 2 valid ground-truth samples ({tg.shape[0]})")
    vel = gt.vel[keep] if gt.vel is not None else differentiate_positions(tg, pos, vel_window_s)
    k = np.clip(np.searchsorted(tg, t, side="right") - 1, 0, tg.shape[0] - 2)
    span = tg[k + 1] - tg[k]
    frac = np.clip((t - tg[k]) / np.where(span > 0, span, 1.0), 0.0, 1.0)
    edge = EDGE_TOL_STEPS * float(np.median(steps)) if steps.size else 0.0
    inside = (t >= tg[0] - edge) & (t <= tg[-1] + edge)
    coincide = np.abs(t - tg[_nearest(tg, t)]) <= edge  # on a GT stamp: valid even at the edge of a gap
    valid = inside & ((span <= max_step) | coincide) & gt.valid[_nearest(gt.t, t)]
    if max_gt_distance_s is not None:
        near = (t - tg[k] <= max_gt_distance_s) & (tg[k + 1] - t <= max_gt_distance_s)
        valid &= near | coincide
    f = frac[:, None]
    return GroundTruth(
        rot=slerp(rot[k], rot[k + 1], frac),
        pos=(1 - f) * pos[k] + f * pos[k + 1],
        vel=(1 - f) * vel[k] + f * vel[k + 1],
        valid=valid,
    )


def _nearest(grid: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Index of the ``grid`` element nearest to each ``t``."""
    hi = np.clip(np.searchsorted(grid, t), 1, max(grid.shape[0] - 1, 1))
    lo = hi - 1
    return np.where(np.abs(t - grid[lo]) <= np.abs(grid[hi] - t), lo, hi) if grid.shape[0] > 1 else lo * 0


def build_sequence(
    name: str,
    source: object,
    t: np.ndarray,
    gyro: np.ndarray,
    acc: np.ndarray,
    gravity: np.ndarray,
    *,
    gt: GtSamples | None = None,
    gps: GpsFixes | None = None,
    checks: ReadChecks = ReadChecks(),
    line_of: Callable[[int], int | None] | None = None,
    frame_interval_s: float = _checks.GYRO_INTERVAL_S,
    max_gt_distance_s: float | None = None,
    gps_source: object = None,
) -> ImuSequence:
    """Checked sequence from IMU arrays (time stamps already strictly increasing) and optional raw GT.

    Args:
        checks: the gap policy, crop, self-checks and velocity window (``ReadChecks``; its ``on_duplicate`` was
            the reader's to apply, through ``_checks.check_timestamps``).
        line_of: maps an index of the given arrays to its file line, for error messages.
        frame_interval_s: the frame self-check's gyro interval (``_checks.frame_score``).
        max_gt_distance_s: see ``resample_ground_truth``.
        gps_source: the GPS file, for error messages (default ``source``).
    Returns:
        The checked ``ImuSequence``.
    """
    line_of = line_of or (lambda row: None)
    gravity = np.asarray(gravity, dtype=np.float64)
    if len(t) < 2:  # one sample has no time step: nothing downstream (windows, preintegration, fusion) can use it
        raise DataError(source, "time", f"{len(t)} IMU sample(s) after reading; a sequence needs at least 2")
    if checks.check_units:
        _checks.check_units(acc, gyro, source)
    rows = np.arange(t.shape[0])
    if gt is not None:
        rows = _overlap_rows(t, gt, checks.crop_to_gt)
        t, gyro, acc = t[rows], gyro[rows], acc[rows]
    gaps = _checks.gap_indices(t)
    if gaps.size and checks.on_gap == "error":
        i = int(gaps[0])
        raise DataError(
            source,
            "t",
            f"gap of {t[i + 1] - t[i]:.4g} s after t = {float(t[i])!r} ({gaps.size} gap(s) "
            f"longer than {_checks.MAX_GAP_STEPS:g} median steps); pass on_gap='keep' (then split_at_gaps(), or "
            "on_gap: split in a config)",
            line=line_of(int(rows[i + 1])),
        )
    truth = (
        resample_ground_truth(t, gt, vel_window_s=checks.vel_window_s, max_gt_distance_s=max_gt_distance_s)
        if gt is not None
        else None
    )
    if truth is None and checks.check_units:  # the gyro unit from gravity, turns (with truth: the frame check)
        check_gyro_unit(t, gyro, acc, source)
    if truth is not None and checks.check_frame:
        _checks.check_frame(
            t,
            gyro,
            acc,
            truth.rot,
            truth.valid,
            gravity,
            source,
            gt.source,
            truth.vel,
            frame_interval_s,
            pos=truth.pos,
            vel_given=gt.vel is not None,
        )
    return _make(name, source, t, gyro, acc, gravity, truth, gps, slice(None), gps_source)


def _overlap_rows(t: np.ndarray, gt: GtSamples, crop: bool) -> np.ndarray:
    """Indices of the IMU samples to keep: those inside the valid GT span when cropping, else all."""
    tg = gt.t[gt.valid]
    if tg.size == 0:
        raise DataError(gt.source, "gt", "no valid ground-truth sample (all rows NaN/Inf)")
    if tg[-1] < t[0] or tg[0] > t[-1]:
        raise DataError(
            gt.source,
            "t",
            f"ground truth [{float(tg[0])!r}, {float(tg[-1])!r}] s does not overlap "
            f"the IMU [{float(t[0])!r}, {float(t[-1])!r}] s (different clocks or units?)",
        )
    if not crop:
        return np.arange(t.shape[0])
    edge = EDGE_TOL_STEPS * float(np.median(np.diff(gt.t))) if gt.t.size > 1 else 0.0
    rows = np.flatnonzero((t >= tg[0] - edge) & (t <= tg[-1] + edge))
    if rows.size < 2:
        raise DataError(gt.source, "t", f"ground truth overlaps fewer than 2 IMU samples ({rows.size})")
    return rows


def _make(name, source, t, gyro, acc, gravity, truth, gps, part: slice, gps_source=None) -> ImuSequence:
    t = t[part]
    if truth is not None:
        truth = GroundTruth(truth.rot[part], truth.pos[part], truth.vel[part], truth.valid[part])
    if gps is not None:
        inside = (gps.t >= t[0]) & (gps.t <= t[-1])
        if len(gps.t) and not inside.any():
            raise DataError(
                gps_source or source,
                "gps",
                f"none of the {len(gps.t)} GPS fixes, [{float(gps.t[0])!r}, {float(gps.t[-1])!r}] s, lies within the "
                f"IMU's time span [{float(t[0])!r}, {float(t[-1])!r}] s (another clock or time unit?)",
            )
        gps = gps[inside]
    return ImuSequence(
        name=name, t=t, gyro=gyro[part], acc=acc[part], gravity=gravity.copy(), gt=truth, gps=gps, source=str(source)
    )


def resolve(base: Path, name: str | Path) -> Path:
    """``name`` if absolute, else relative to ``base``."""
    name = Path(name)
    return name if name.is_absolute() else base / name
