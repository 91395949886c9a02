"""KITTI odometry relative errors t_rel and r_rel, as the KITTI odometry devkit defines them and AI-IMU reports them.

Source: the KITTI odometry devkit (``devkit_odometry.zip``, ``cpp/evaluate_odometry.cpp``: ``trajectoryDistances``,
``lastFrameFromSegmentLength``, ``calcSequenceErrors``, ``saveStats``). AI-IMU (Brossard et al. 2020) scores its
100 Hz KITTI raw estimates this way after subsampling estimate and ground truth to 10 Hz (the author's answer in
mbrossar/ai-imu-dr issue #15); its paper's words: "averaged relative translation increment error for all possible
subsequences of length 100 m, ..., 800 m, in percent of the traveled distance".

Definition (frames k = 0..N-1 of a 10 Hz trajectory; poses T_k = [R_k, p_k] in SE(3)):
- ``dist[k]``: ground-truth path length from frame 0 to k (sum of |p_gt[i] - p_gt[i-1]|, m).
- Segments: for every first frame f = 0, step, 2 step, ... (``step`` = 10 frames, one second at 10 Hz) and every
  length L in ``lengths`` (100, 200, ..., 800 m), the last frame l is the first frame with
  ``dist[l] > dist[f] + L`` (strictly greater); the segment is skipped when no such frame exists. A segment thus
  spans a little more than L metres of ground truth, and its errors are still divided by L.
- Errors: ``dT_gt = inv(T_gt[f]) T_gt[l]``, ``dT_est = inv(T_est[f]) T_est[l]``, ``E = inv(dT_est) dT_gt``;
  ``t_err = |translation(E)| / L`` (m/m) and ``r_err = angle(E) / L`` (rad/m), where angle(E) =
  ``acos(clip((tr R_E - 1) / 2, -1, 1))``. Here the same angle comes from ``metrics.rotation_angle_deg`` (an atan2
  form, exact near zero where acos loses digits).
- t_rel, r_rel: the plain mean of ``t_err`` and ``r_err`` over all segments of all lengths (every segment weighs
  the same, as in the devkit's ``saveStats``; ``pool`` does the same across sequences).

Units: t_rel in percent (100 x m/m); r_rel in deg/m, the unit of the KITTI leaderboard and of the devkit's plots
(its ``stats.txt`` holds rad/m). ``KittiErrors.r_rel_deg_per_100m`` gives deg/(100 m), the unit of ORB-SLAM2's
per-sequence KITTI table. Frames: rotations are world<-body (``R @ v_body`` is ``v`` in world), positions are
the body origin in world, metres; estimate and ground truth describe the same body (the devkit scores the left
camera's poses; here it is whatever body both trajectories share). Relative poses are taken in the body frame at f,
so no alignment is needed: a rigid change of the estimate's world frame leaves every error unchanged.
The devkit computes in float32, here float64: a frame exactly at ``dist[f] + L`` can fall on the other side.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from airimu_core.errors import InputError, real_array
from learned_imu.evaluation.metrics import rotation_angle_deg

DEVKIT_LENGTHS_M = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)  # segment lengths of the benchmark
DEVKIT_STEP_FRAMES = 10  # a segment starts every 10th frame: once a second at KITTI's 10 Hz
DEVKIT_RATE_HZ = 10.0  # KITTI odometry's frame rate, to which 100 Hz trajectories are subsampled
ROTATION_TOLERANCE = 1e-3  # max |R^T R - I| entry accepted as a rotation matrix


@dataclass(frozen=True, eq=False)
class KittiErrors:
    """t_rel, r_rel of one trajectory (or of several pooled), with every segment behind them.

    Scalars: ``t_rel_percent`` (%), ``r_rel_deg_per_m`` (deg/m), ``segments`` (count).
    Per length, shape (L,): ``lengths_m``, ``segments_per_length``, ``t_rel_percent_per_length``,
    ``r_rel_deg_per_m_per_length`` (NaN for a length without segments).
    Per segment, shape (S,): ``first_frame``, ``last_frame`` (10 Hz frame indices), ``length_m`` (the nominal L the
    errors are divided by), ``t_err_percent``, ``r_err_deg_per_m``.
    """

    t_rel_percent: float
    r_rel_deg_per_m: float
    segments: int
    lengths_m: np.ndarray
    segments_per_length: np.ndarray
    t_rel_percent_per_length: np.ndarray
    r_rel_deg_per_m_per_length: np.ndarray
    first_frame: np.ndarray
    last_frame: np.ndarray
    length_m: np.ndarray
    t_err_percent: np.ndarray
    r_err_deg_per_m: np.ndarray

    @property
    def r_rel_deg_per_100m(self) -> float:
        """r_rel in deg per 100 m (ORB-SLAM2's KITTI table)."""
        return 100.0 * self.r_rel_deg_per_m


def subsample_indices(t_s, rate_hz: float = DEVKIT_RATE_HZ) -> np.ndarray:
    """Indices of the samples nearest to the ticks ``t_s[0] + k / rate_hz``, k = 0, 1, ... up to ``t_s[-1]`` (plus
    half the median sample step, for jitter).

    On a uniform 100 Hz stream this is every 10th sample; on a jittered one it is the sample closest to each 10 Hz
    tick. Apply the indices to ground truth and estimate alike. Raises ``InputError`` when ``t_s`` (s) is not
    strictly increasing, is slower than ``rate_hz``, or has no sample within half a tick period of some tick (a gap).
    """
    t = real_array(t_s, "t_s")
    if t.ndim != 1 or len(t) < 2 or not np.all(np.isfinite(t)):
        raise InputError(f"t_s: expected a finite 1-D array of at least 2 times (s), got shape {t.shape}")
    if not np.all(np.diff(t) > 0):
        raise InputError(f"t_s: times must increase strictly; sample {int(np.argmin(np.diff(t) > 0)) + 1} does not")
    if not (np.isfinite(rate_hz) and rate_hz > 0):
        raise InputError(f"rate_hz: expected a positive rate (Hz), got {rate_hz}")
    period = 1.0 / rate_hz
    step = np.median(np.diff(t))
    if step > period:
        raise InputError(f"t_s: median step {step:.4g} s is slower than rate_hz = {rate_hz} Hz")
    # ticks t[0] + k period up to half a sample step past the last sample (jitter may end a stream just short of one)
    ticks = t[0] + period * np.arange(int(np.floor((t[-1] + 0.5 * step - t[0]) / period)) + 1)
    right = np.clip(np.searchsorted(t, ticks), 1, len(t) - 1)
    nearest = np.where(ticks - t[right - 1] <= t[right] - ticks, right - 1, right)
    offset = np.abs(t[nearest] - ticks)
    if np.any(offset >= 0.5 * period):
        k = int(np.argmax(offset >= 0.5 * period))
        raise InputError(f"t_s: no sample within {0.5 * period:.4g} s of the tick at {ticks[k]:.4f} s (a gap)")
    return nearest


def relative_errors(
    gt_rot, gt_pos, est_rot, est_pos, lengths=DEVKIT_LENGTHS_M, step: int = DEVKIT_STEP_FRAMES
) -> KittiErrors:
    """The devkit's t_rel (%) and r_rel (deg/m) of an estimate against ground truth at the same 10 Hz frames.

    ``gt_rot``, ``est_rot``: (N, 3, 3) world<-body rotations; ``gt_pos``, ``est_pos``: (N, 3) world positions (m);
    ``lengths``: segment lengths (m); ``step``: frames between segment starts. See the module docstring for the
    definition. Subsample 100 Hz trajectories first (``subsample_indices``). Raises ``InputError`` naming the
    argument for a wrong shape, a NaN or infinity, a matrix that is not a rotation, or a ground-truth path no longer
    than the shortest length.
    """
    gt_rot, gt_pos, est_rot, est_pos = (
        _checked(gt_rot, "gt_rot", (3, 3)),
        _checked(gt_pos, "gt_pos", (3,)),
        _checked(est_rot, "est_rot", (3, 3)),
        _checked(est_pos, "est_pos", (3,)),
    )
    n = len(gt_rot)
    for name, array in (("gt_pos", gt_pos), ("est_rot", est_rot), ("est_pos", est_pos)):
        if len(array) != n:
            raise InputError(f"{name}: {len(array)} frames, but gt_rot has {n}")
    lengths_m = real_array(lengths, "lengths")
    if lengths_m.ndim != 1 or len(lengths_m) == 0 or not np.all(np.isfinite(lengths_m) & (lengths_m > 0)):
        raise InputError(f"lengths: expected a non-empty 1-D sequence of positive lengths (m), got {lengths!r}")
    if len(np.unique(lengths_m)) != len(lengths_m):
        raise InputError(f"lengths: each length may appear once, got {lengths!r}")
    if isinstance(step, bool) or not isinstance(step, int | np.integer) or step < 1:
        raise InputError(f"step: expected a positive whole number of frames, got {step!r}")

    # path length along the ground truth, from frame 0
    dist = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(gt_pos, axis=0), axis=1))])
    if dist[-1] <= lengths_m.min():
        raise InputError(
            f"gt_pos: the ground-truth path is {dist[-1]:.1f} m long, not longer than the shortest segment length "
            f"{lengths_m.min():g} m, so it holds no segment"
        )
    # segments: every step-th first frame x every length; last frame = first with dist > dist[first] + length
    first, length = (a.ravel() for a in np.meshgrid(np.arange(0, n, step), lengths_m, indexing="ij"))
    last = np.searchsorted(dist, dist[first] + length, side="right")
    keep = last < n
    first, last, length = first[keep], last[keep], length[keep]
    # relative motions in the body frame at the first frame, and the error pose inv(dT_est) dT_gt
    d_rot_gt, d_pos_gt = _relative(gt_rot, gt_pos, first, last)
    d_rot_est, d_pos_est = _relative(est_rot, est_pos, first, last)
    t_err = np.linalg.norm(d_pos_gt - d_pos_est, axis=-1)  # |dR_est^T (dp_gt - dp_est)|: rotations keep norms
    r_err_deg = rotation_angle_deg(d_rot_est, d_rot_gt)
    return _summarise(lengths_m, first, last, length, 100.0 * t_err / length, r_err_deg / length)


def pool(results: Sequence[KittiErrors]) -> KittiErrors:
    """The segments of several trajectories scored together, each segment weighing the same (the devkit's total
    over a set of sequences). All must use the same lengths; frame indices stay those of each one's trajectory."""
    if len(results) == 0:
        raise InputError("results: expected at least one KittiErrors to pool, got none")
    lengths_m = results[0].lengths_m
    if any(not np.array_equal(r.lengths_m, lengths_m) for r in results):
        raise InputError("results: every KittiErrors must use the same segment lengths to be pooled")
    fields = ("first_frame", "last_frame", "length_m", "t_err_percent", "r_err_deg_per_m")
    return _summarise(lengths_m, *(np.concatenate([getattr(r, f) for r in results]) for f in fields))


def _checked(value, name: str, tail: tuple[int, ...]) -> np.ndarray:
    """``value`` as float64 of shape (N, *tail), finite, and (for 3 x 3) a rotation matrix, or ``InputError``."""
    array = real_array(value, name)
    if array.ndim != 1 + len(tail) or array.shape[1:] != tail or len(array) < 2:
        raise InputError(f"{name}: expected shape (N, {', '.join(map(str, tail))}) with N >= 2, got {array.shape}")
    bad = ~np.isfinite(array).reshape(len(array), -1).all(axis=1)
    if bad.any():
        raise InputError(f"{name}: frame {int(np.argmax(bad))} is not finite (NaN or infinity)")
    if tail == (3, 3):
        gram = np.einsum("nji,njk->nik", array, array) - np.eye(3)
        off = np.abs(gram).reshape(len(array), -1).max(axis=1) > ROTATION_TOLERANCE
        if off.any():
            raise InputError(f"{name}: frame {int(np.argmax(off))} is not a rotation matrix (R^T R != I)")
    return array


def _relative(rot: np.ndarray, pos: np.ndarray, first: np.ndarray, last: np.ndarray):
    """inv(T[first]) T[last] as rotations (S, 3, 3) and translations (S, 3)."""
    rot_t = np.swapaxes(rot[first], -1, -2)
    return rot_t @ rot[last], np.einsum("sij,sj->si", rot_t, pos[last] - pos[first])


def _summarise(lengths_m, first, last, length, t_err_percent, r_err_deg_per_m) -> KittiErrors:
    match = length[None, :] == lengths_m[:, None]  # (L, S)
    count = match.sum(axis=1)
    with np.errstate(invalid="ignore"):  # a length without segments gives NaN, not a warning
        t_per_length = (match * t_err_percent).sum(axis=1) / count
        r_per_length = (match * r_err_deg_per_m).sum(axis=1) / count
    return KittiErrors(
        t_rel_percent=float(np.mean(t_err_percent)),
        r_rel_deg_per_m=float(np.mean(r_err_deg_per_m)),
        segments=len(first),
        lengths_m=lengths_m,
        segments_per_length=count,
        t_rel_percent_per_length=t_per_length,
        r_rel_deg_per_m_per_length=r_per_length,
        first_frame=first,
        last_frame=last,
        length_m=length,
        t_err_percent=t_err_percent,
        r_err_deg_per_m=r_err_deg_per_m,
    )
