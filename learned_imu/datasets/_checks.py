"""Checks every reader runs: time stamps, gaps, units, and the frame self-check of ground truth against the IMU.

The frame self-check uses two facts that hold for any correctly read sequence:

- averaged over a sequence, the world acceleration is small (|v_end - v_start| / duration), so the mean of
  ``R_gt @ (acc - b)`` (specific force in the world frame) is close to ``-gravity``, i.e. +|g| along world z, with
  ``b`` the accelerometer's constant bias, fitted (least squares) and held to ``ACC_BIAS_MAX``: a real sensor's
  bias (EuRoC's 0.55 m/s^2, raw TUM-VI's 1.4 m/s^2) is not a convention error, a permutation of the axes
  (a "bias" of ~|g|) is;
- the gyro integrated over a short interval equals the rotation between the ground-truth orientations at its
  ends, ``Log(R_i^T R_j) ~= integral of gyro`` (body frame), up to a constant gyro bias (fitted and removed).

``check_motion`` then holds the ground truth's translation to the same standard: over 1-s intervals the velocity
change equals the IMU's specific force rotated to the world plus gravity, integrated, and the displacement equals
the velocity integrated. A least-squares scale between the two far from 1 names the field (positions in mm or
km, a negated or mis-scaled velocity). The velocity change's scale is fitted together with a constant
accelerometer bias (IMU frame), so that on a gentle flight a normal bias, which over 1 s can outweigh the true
velocity change, is not taken for a unit error; the predicted motion the bias does not explain must reach
``MOTION_MIN_RMS``, else there is too little to judge, unless the ground truth moves more than
``MOTION_IMPLAUSIBLE_RMS`` over the intervals while the IMU stays still (positions in mm on a gentle recording).

When the data as read fail, the usual mistakes are tried (quaternion order, inverted rotation, acc in g, gyro
in deg/s, each also the other way round) and the DataError names the one that makes both facts hold.
"""

from __future__ import annotations

import dataclasses
import logging
import typing
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np

from airimu_core.errors import DataError
from airimu_core.rotations import matrix_to_quat_wxyz, quat_to_matrix, relative_rotvec
from airimu_core.sequence import MAX_GAP_STEPS, gap_indices, segments  # noqa: F401 (re-exported: readers, tests)

logger = logging.getLogger(__name__)

STANDARD_GRAVITY = 9.80665  # m/s^2, the "g" of accelerometers that report in g
DEG = np.pi / 180.0
OnDuplicate = Literal["error", "drop"]
OnGap = Literal["error", "keep"]  # the readers'; a config's on_gap: split reads with keep, then splits
ON_DUPLICATE = typing.get_args(OnDuplicate)
ON_BACKWARD = ("error", "drop")  # a time stamp before the previous one: refuse, or drop the row
ON_GAP = typing.get_args(OnGap)

# units check without ground truth (median |acc| is robust to the large accelerations of hand-held trials)
ACC_IN_G = (0.5, 2.0)  # median |acc| in this range: the file is in g
ACC_PLAUSIBLE_MS2 = (4.0, 25.0)  # median |acc| outside this range: not specific force on Earth in m/s^2
GYRO_MEDIAN_MAX = 10.0  # rad/s; a median rate above this is not a hand-held, vehicle or drone motion
GYRO_MAX = 40.0  # rad/s; above the 2000 deg/s (34.9 rad/s) full scale of common MEMS gyros

# frame self-check thresholds
FRAME_MIN_SAMPLES = 200  # fewer valid ground-truth samples: the check is skipped
ACC_TOL = 0.06  # |mean(R (acc - b)) + g| / |g|; 0.06 * 9.81 = 0.59 m/s^2 of mean acceleration + bias beyond b
ACC_BIAS_MAX = 2.0  # m/s^2 (0.2 g), the largest accelerometer bias the frame check fits away
GYRO_TOL = 0.35  # rms(Log(R_i^T R_j)/dt - mean gyro - bias) / rms(Log(R_i^T R_j)/dt)
GYRO_INTERVAL_S = 0.05  # length of the intervals the gyro is integrated over, s
GYRO_MIN_RATE = 0.05  # rad/s rms; below this the ground truth barely rotates and the gyro test is skipped
# motion self-check (positions and velocities in the IMU's metres and seconds, same sign)
MOTION_INTERVAL_S = 1.0  # intervals over which velocity change and displacement are compared, s
MOTION_MIN_RMS = 0.2  # m/s (velocity change) or m (displacement) rms over the intervals; less: too still to judge
# ... unless the ground truth's own rms over the intervals exceeds this (m/s or m): positions in mm on a still or
# gentle recording (a GNSS/INS position wanders by ~0.4 m over 1 s when parked, KITTI 2011_09_28_drive_0039)
MOTION_IMPLAUSIBLE_RMS = 5.0
MOTION_SCALE = (0.5, 2.0)  # fitted ground truth / prediction scale accepted (mm read as m gives 1000, negated -1)


def forward_rows(t: np.ndarray, source, field: str, on_backward: str, line_of, cause: str = "") -> np.ndarray:
    """Rows to keep: all (``on_backward="error"``, which raises a ``DataError`` naming the first backward step's
    line) or those whose stamp is not before the last kept one (``"drop"``; equal stamps are left to
    ``on_duplicate``). ``cause``: the likely reason, for the message (e.g. replayed packets)."""
    if on_backward not in ON_BACKWARD:
        raise ValueError(f"on_backward must be one of {ON_BACKWARD}, got {on_backward!r}")
    back = np.flatnonzero(np.diff(t) < 0)
    if back.size == 0:
        return np.arange(len(t))
    if on_backward == "error":
        row = int(back[0]) + 1
        raise DataError(
            source,
            field,
            f"time goes backwards: {float(t[row])!r} after {float(t[row - 1])!r} ({back.size} backward step(s)"
            + (f", {cause}" if cause else "")
            + "); pass on_backward='drop' to drop the rows not after the last kept one",
            line=line_of(row),
        )
    latest = np.maximum.accumulate(t)
    return np.flatnonzero(t >= np.concatenate([[-np.inf], latest[:-1]]))


def check_timestamps(
    t: np.ndarray,
    source: object,
    field: str = "t",
    *,
    on_duplicate: OnDuplicate = "error",
    line_of: Callable[[int], int] | None = None,
) -> np.ndarray:
    """Indices of the samples to keep; raises on time going backwards and, by default, on duplicates.

    Args:
        t: (N,) time stamps, s, finite.
        source, field: named in errors.
        on_duplicate: ``"error"`` (default) or ``"drop"`` (keep the first sample of each repeated stamp).
        line_of: maps a row to its file line number, for the error message.
    """
    if on_duplicate not in ON_DUPLICATE:
        raise ValueError(f"on_duplicate must be one of {ON_DUPLICATE}, got {on_duplicate!r}")
    line = line_of or (lambda row: None)

    def sample(row: int) -> str:  # where the file line is named, the sample index is not
        return "" if line(row) is not None else f" (sample {row})"

    steps = np.diff(t)
    if (steps < 0).any():
        row = int(np.argmax(steps < 0)) + 1
        raise DataError(
            source,
            field,
            f"time goes backwards: {float(t[row])!r} after {float(t[row - 1])!r}{sample(row)}",
            line=line(row),
        )
    dup = steps == 0
    if dup.any():
        row = int(np.argmax(dup)) + 1
        if on_duplicate == "error":
            raise DataError(
                source,
                field,
                f"duplicated time stamp {float(t[row])!r}{sample(row)}: {int(dup.sum())} repeat(s) in "
                "the file; pass on_duplicate='drop' to keep the first of each",
                line=line(row),
            )
        logger.warning("%s: dropping %d samples with duplicated time stamps", source, int(dup.sum()))
    return np.flatnonzero(np.concatenate([[True], ~dup]))


def check_units(acc: np.ndarray, gyro: np.ndarray, source: object) -> None:
    """Raise a DataError when acc does not look like m/s^2 or gyro does not look like rad/s (no GT needed)."""
    acc_norm = float(np.median(np.linalg.norm(acc, axis=1)))
    gyro_norm = float(np.median(np.linalg.norm(gyro, axis=1)))
    low, high = ACC_PLAUSIBLE_MS2
    if not low < acc_norm < high and low < gyro_norm < high:  # a sustained 4-25 rad/s is no IMU's median rate
        raise DataError(
            source,
            "gyro/acc",
            f"the gyro columns hold the specific force (median |gyro| = {gyro_norm:.3g}, |acc| = {acc_norm:.3g}; "
            "gravity is about 9.81 m/s^2): gyro and acc columns swapped?",
        )
    if ACC_IN_G[0] < acc_norm < ACC_IN_G[1]:
        raise DataError(
            source,
            "acc",
            f"acc looks like it is in g, not m/s^2: median |acc| = {acc_norm:.3f} "
            "(expected about 9.81 m/s^2); convert it (e.g. acc_unit='g')",
        )
    if not ACC_PLAUSIBLE_MS2[0] < acc_norm < ACC_PLAUSIBLE_MS2[1]:
        raise DataError(
            source,
            "acc",
            f"median |acc| = {acc_norm:.3g}, expected about 9.81 m/s^2 "
            "(specific force at rest); wrong columns or unit?",
        )
    rate = np.linalg.norm(gyro, axis=1)
    median, peak = float(np.median(rate)), float(rate.max())
    if median > GYRO_MEDIAN_MAX or peak > GYRO_MAX:
        raise DataError(
            source,
            "gyro",
            f"gyro looks like it is in deg/s, not rad/s: median |gyro| = "
            f"{median:.3g}, max {peak:.3g} (implausible in rad/s); convert it (e.g. gyro_unit='deg/s')",
        )


@dataclass(frozen=True)
class _Convention:
    """One way the data may have been misread: a field, what is wrong, and how to undo it."""

    field: str
    hint: str
    fix_rot: Callable[[np.ndarray], np.ndarray] = lambda rot: rot
    acc_scale: float = 1.0
    gyro_scale: float = 1.0


def _requat(rot: np.ndarray, shift: int) -> np.ndarray:
    q = np.roll(matrix_to_quat_wxyz(rot), shift, axis=1)
    return quat_to_matrix(q / np.linalg.norm(q, axis=1, keepdims=True), "wxyz")


ALTERNATIVES = (
    _Convention(
        "gt.rot",
        "quaternion order: the file is scalar-last (x, y, z, w) but was read as (w, x, y, z)",
        fix_rot=lambda rot: _requat(rot, 1),
    ),
    _Convention(
        "gt.rot",
        "quaternion order: the file is scalar-first (w, x, y, z) but was read as (x, y, z, w)",
        fix_rot=lambda rot: _requat(rot, -1),
    ),
    _Convention(
        "gt.rot",
        "rotation inverted: the file gives IMU <- world, not world <- IMU (transpose it)",
        fix_rot=lambda rot: np.swapaxes(rot, -1, -2),
    ),
    _Convention("acc", "acc is in g, not m/s^2 (multiply by 9.80665)", acc_scale=STANDARD_GRAVITY),
    _Convention("acc", "acc is already in m/s^2 but was converted from g", acc_scale=1.0 / STANDARD_GRAVITY),
    _Convention("gyro", "gyro is in deg/s, not rad/s (multiply by pi/180)", gyro_scale=DEG),
    _Convention("gyro", "gyro is already in rad/s but was converted from deg/s", gyro_scale=1.0 / DEG),
)


@dataclass(frozen=True)
class FrameScore:
    """Residuals of the two self-check facts; the data pass when both are below their tolerance.

    Attributes:
        acc: |mean(R @ (acc - acc_bias)) + gravity| / |gravity|.
        gyro: relative rms mismatch of gyro and ground-truth rotation rate (0 when GT barely rotates).
        mean_world_acc: (3,) mean of R @ acc, m/s^2 (as read, no bias removed).
        acc_bias: (3,) m/s^2 IMU frame, the fitted accelerometer bias (at most ``ACC_BIAS_MAX`` long).
    """

    acc: float
    gyro: float
    mean_world_acc: np.ndarray
    acc_bias: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))

    @property
    def ok(self) -> bool:
        return self.acc < ACC_TOL and self.gyro < GYRO_TOL


def _bounded_bias(mean_rot: np.ndarray, residual: np.ndarray) -> np.ndarray:
    """The bias b (3,) of length at most ``ACC_BIAS_MAX`` that minimises |residual - mean_rot @ b| (a trust-region
    least squares: ridge-regularised, the weight found by bisection when the plain solution is longer)."""

    def solve(weight: float) -> np.ndarray:
        return np.linalg.solve(mean_rot.T @ mean_rot + weight * np.eye(3), mean_rot.T @ residual)

    bias = np.linalg.lstsq(mean_rot, residual, rcond=None)[0]
    if np.linalg.norm(bias) <= ACC_BIAS_MAX:
        return bias
    low, high = 0.0, 1.0
    while np.linalg.norm(solve(high)) > ACC_BIAS_MAX:
        high *= 10.0
    for _ in range(60):
        mid = 0.5 * (low + high)
        low, high = (mid, high) if np.linalg.norm(solve(mid)) > ACC_BIAS_MAX else (low, mid)
    return solve(high)


def frame_score(t, gyro, acc, rot, valid, gravity, vel=None, interval_s: float = GYRO_INTERVAL_S) -> FrameScore:
    """Score one reading of the data (see the module docstring). With the ground truth's world velocity ``vel``
    (N, 3), the mean world specific force is compared with ``(v_last - v_first) / T - gravity`` (a drive that ends
    faster than it began has a mean acceleration), else with ``-gravity``. ``interval_s``: the gyro is compared with
    the ground truth's rotation over intervals of this length."""
    world_acc = np.einsum("nij,nj->ni", rot[valid], acc[valid]).mean(axis=0)
    expected = -gravity
    rows = np.flatnonzero(valid)
    if vel is not None and rows.size >= 2 and t[rows[-1]] > t[rows[0]]:
        expected = expected + (vel[rows[-1]] - vel[rows[0]]) / (t[rows[-1]] - t[rows[0]])
    mean_rot = rot[valid].mean(axis=0)
    bias = _bounded_bias(mean_rot, world_acc - expected)
    acc_res = float(np.linalg.norm(world_acc - mean_rot @ bias - expected) / np.linalg.norm(gravity))
    dt = np.diff(t, append=t[-1])
    step = max(1, int(round(interval_s / np.median(np.diff(t)))))
    i = np.arange(0, t.shape[0] - step, step)
    j = i + step
    span = t[j] - t[i]
    keep = valid[i] & valid[j] & (span < 1.5 * step * np.median(np.diff(t)))
    i, j, span = i[keep], j[keep], span[keep]
    gyro_res = 0.0
    if i.shape[0] >= 10:
        integral = np.concatenate([np.zeros((1, 3)), np.cumsum(gyro * dt[:, None], axis=0)])
        rate_imu = (integral[j] - integral[i]) / span[:, None]
        rate_gt = relative_rotvec(rot[i], rot[j]) / span[:, None]
        scale = float(np.sqrt((rate_gt**2).sum(axis=1).mean()))
        if scale > GYRO_MIN_RATE:
            diff = rate_gt - rate_imu
            diff -= diff.mean(axis=0)  # a constant gyro bias is not a convention error
            gyro_res = float(np.sqrt((diff**2).sum(axis=1).mean())) / scale
    return FrameScore(acc_res, gyro_res, world_acc, bias)


def check_frame(
    t,
    gyro,
    acc,
    rot,
    valid,
    gravity,
    source: object,
    gt_source: object = None,
    vel=None,
    interval_s: float = GYRO_INTERVAL_S,
    pos=None,
    vel_given: bool = False,
) -> FrameScore | None:
    """Frame self-check of ground truth against the IMU; raises a DataError naming the misread convention. With
    ``pos`` (N, 3) and ``vel`` the motion self-check (``check_motion``) runs too: after a pass, and before a failure
    that no rotation or IMU-unit mistake explains (positions in mm also fail the mean-acceleration fact).

    Args:
        t (N,) s, gyro (N, 3) rad/s, acc (N, 3) m/s^2, rot (N, 3, 3) world <- IMU, valid (N,) bool,
        gravity (3,) m/s^2 world frame; source: the IMU file, gt_source: the ground-truth file (if different);
        vel (N, 3) the ground truth's world velocity, if any; interval_s: see ``frame_score``.
    Returns:
        The score of the data as read, or None when there is too little valid ground truth to judge.
    """
    gt_source = source if gt_source is None else gt_source
    if int(valid.sum()) < FRAME_MIN_SAMPLES:
        logger.info("%s: frame self-check skipped (%d valid ground-truth samples)", source, int(valid.sum()))
        return None
    score = frame_score(t, gyro, acc, rot, valid, gravity, vel, interval_s)
    motion = (t, acc, rot, pos, vel, valid, gravity, gt_source, vel_given)
    if score.ok:
        if pos is not None and vel is not None:
            check_motion(*motion)
        return score
    found = (
        f"mean of R_gt @ acc = {np.round(score.mean_world_acc, 3).tolist()} m/s^2, expected about "
        f"{np.round(-gravity, 3).tolist()} (= -gravity; relative residual {score.acc:.3f} after removing an acc "
        f"bias of {np.round(score.acc_bias, 3).tolist()} m/s^2, at most {ACC_BIAS_MAX:g} long; tolerance "
        f"{ACC_TOL}); gyro vs ground-truth rotation rate residual {score.gyro:.3f} (tolerance {GYRO_TOL})"
    )
    fits = []
    for alt in ALTERNATIVES:
        alt_score = frame_score(
            t, alt.gyro_scale * gyro, alt.acc_scale * acc, alt.fix_rot(rot), valid, gravity, vel, interval_s
        )
        if alt_score.ok:
            fits.append((alt_score.acc / ACC_TOL + alt_score.gyro / GYRO_TOL, alt, alt_score))
    if not fits:
        if pos is not None and vel is not None:
            failure = _motion_failure(*motion)
            if failure is not None and failure[1]:  # a translation in other units or sign explains it better
                raise failure[0]
        # else the frame error below: a motion scale that names no unit says little once the frame is wrong
        raise DataError(
            gt_source,
            "gt.rot",
            f"frame self-check failed: {found}; none of the usual mistakes "
            "(quaternion order, inverted rotation, acc in g, gyro in deg/s) explains it",
        )
    _, alt, alt_score = min(fits, key=lambda fit: fit[0])
    where = gt_source if alt.field == "gt.rot" else source
    raise DataError(
        where,
        alt.field,
        f"frame self-check failed: {found}. It passes if {alt.hint} "
        f"(residuals then {alt_score.acc:.3f} and {alt_score.gyro:.3f})",
    )


def check_motion(t, acc, rot, pos, vel, valid, gravity, gt_source: object, vel_given: bool) -> None:
    """Motion self-check (module docstring): a ``DataError`` naming ``gt.vel`` or ``gt.pos`` when the ground truth's
    velocity change is not the integrated specific force plus gravity, or its displacement not the integrated
    velocity, within ``MOTION_SCALE``. Skipped when the motion is too small to judge. Arrays as ``check_frame``'s,
    ``pos``/``vel`` (N, 3) world frame; ``vel_given``: the velocity was read from the file (not differentiated)."""
    failure = _motion_failure(t, acc, rot, pos, vel, valid, gravity, gt_source, vel_given)
    if failure is not None:
        raise failure[0]


def _motion_failure(t, acc, rot, pos, vel, valid, gravity, gt_source, vel_given) -> tuple[DataError, bool] | None:
    """``check_motion``'s error and whether its scale names a unit or sign mistake, or None when it passes."""
    median_dt = float(np.median(np.diff(t)))
    step = max(1, int(round(MOTION_INTERVAL_S / median_dt)))
    i = np.arange(0, t.shape[0] - step, step)
    j = i + step
    ok = valid[i] & valid[j] & (t[j] - t[i] < 1.5 * step * median_dt)
    bad_rows = np.flatnonzero(~valid)  # no invalid row inside an interval
    if bad_rows.size:
        ok &= np.searchsorted(bad_rows, i) == np.searchsorted(bad_rows, j)
    i, j = i[ok], j[ok]
    if i.shape[0] < 5:
        return None
    dt = np.diff(t, append=t[-1])[:, None]
    world = np.where(valid[:, None], np.einsum("nij,nj->ni", rot, acc) + gravity, 0.0)
    integral = np.concatenate([np.zeros((1, 3)), np.cumsum(world * dt, axis=0)])
    # what a constant body-frame acc bias b adds to the velocity change over [i, j]: A b with A the integral of R dt
    rot_integral = np.concatenate(
        [np.zeros((1, 3, 3)), np.cumsum(np.where(valid[:, None, None], rot, 0.0) * dt[:, :, None], axis=0)]
    )
    bias_effect = rot_integral[j] - rot_integral[i]  # (intervals, 3 axes, 3 unknowns)
    checks = [
        (
            "gt.vel" if vel_given else "gt.pos",
            "velocity change",
            vel[j] - vel[i],
            integral[j] - integral[i],
            bias_effect,
        )
    ]
    if vel_given:
        v_integral = np.concatenate([np.zeros((1, 3)), np.cumsum(np.where(valid[:, None], vel, 0.0) * dt, axis=0)])
        checks.append(("gt.pos", "displacement", pos[j] - pos[i], v_integral[j] - v_integral[i], None))
    for field, what, observed, predicted, basis in checks:
        if basis is not None:
            observed, predicted = _without(basis, observed), _without(basis, predicted)
        rms = float(np.sqrt((predicted**2).sum(axis=1).mean()))
        seen = float(np.sqrt((observed**2).sum(axis=1).mean()))
        if rms < MOTION_MIN_RMS and seen < MOTION_IMPLAUSIBLE_RMS:
            continue  # too still to judge, and the ground truth is still too
        source = "the integrated IMU (R_gt @ acc + gravity)" if what == "velocity change" else "the integrated velocity"
        if rms < MOTION_MIN_RMS:  # a still IMU under a ground truth that moves metres a second: its unit
            unit = "m/s" if what == "velocity change" else "m"
            problem = (
                f"motion self-check failed: over {MOTION_INTERVAL_S:g}-s intervals the ground truth's {what} is "
                f"{seen:.4g} {unit} rms while that of {source} is {rms:.3g} {unit}: positions in mm or cm, not m?"
            )
            return DataError(gt_source, field, problem), True
        scale = float((observed * predicted).sum() / (predicted**2).sum())
        if MOTION_SCALE[0] <= scale <= MOTION_SCALE[1]:
            continue
        hint = _scale_hint(scale)
        error = DataError(
            gt_source,
            field,
            f"motion self-check failed: over {MOTION_INTERVAL_S:g}-s intervals the ground truth's {what} is "
            f"{scale:.4g} times that of {source} (expected about 1){hint}",
        )
        return error, bool(hint)
    return None


def _without(basis: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``x`` (M, 3) less its least-squares fit by ``basis`` (M, 3, P) @ c with one c (P,) for all rows: the part
    of the motion that constant offsets do not explain."""
    design = basis.reshape(-1, basis.shape[2])
    coef, *_ = np.linalg.lstsq(design, x.reshape(-1), rcond=None)
    return x - (design @ coef).reshape(x.shape)


def _scale_hint(scale: float) -> str:
    for factor, hint in (
        (-1.0, "negated (sign flipped, or another world frame)"),
        (1000.0, "in mm, not m"),
        (100.0, "in cm, not m"),
        (0.001, "in km, not m"),
    ):
        if 0.7 < scale / factor < 1.4:
            return f": {hint}?"
    return ""
