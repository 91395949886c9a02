"""Evaluate IMU integration on a sequence with ground truth: the paper's metrics over an interval.

See ``learned_imu.evaluation.metrics`` for the definitions and for which of the paper's table columns each field is.
The raw
IMU is evaluated unless corrected samples are given (a trained model's output).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import torch

from airimu_core.errors import InputError
from airimu_core.sequence import ImuSequence
from learned_imu.config import WINDOW_RULES
from learned_imu.evaluation import metrics
from learned_imu.geometry.preintegration import NavState, predict, preintegrate
from learned_imu.training.windows import usable_windows

INTERVAL_UNITS = ("s", "frames")


@dataclass(frozen=True)
class Evaluation:
    """Metrics of one sequence at one interval (units in the names; see ``learned_imu.evaluation.metrics``)."""

    sequence: str
    interval_s: float
    interval_frames: int
    n_windows: int
    roe_deg: float
    roe_rmse_deg: float
    rpe_m: float
    rpe_rmse_m: float
    rot_rmse_states_deg: float
    pos_rmse_states_m: float
    vel_rmse_states_m_s: float
    ate_m: float
    ate_aligned_m: float

    def to_json_dict(self) -> dict:
        """Plain dict for JSON: every field, named as above."""
        return asdict(self)


def evaluate(
    sequence: ImuSequence,
    interval: float,
    interval_unit: str = "s",
    gyro: np.ndarray | None = None,
    acc: np.ndarray | None = None,
    windows: str = "valid",
) -> Evaluation:
    """Integrate ``sequence``'s IMU (or the given corrected ``gyro``/``acc``, (N, 3)) and score it.

    ``interval`` is in seconds (``interval_unit="s"``) or IMU samples (``"frames"``). ``windows``: ``"valid"``
    scores the windows whose every sample has ground truth; ``"end_valid"`` those whose end sample has (the official
    AirIMU evaluation's ``--mask``, used by its TUM-VI table: the start state may be a value interpolated across a
    hole in the ground truth).
    """
    if windows not in WINDOW_RULES:
        raise InputError(f"evaluate: windows must be one of {', '.join(WINDOW_RULES)}, got {windows!r}")
    if sequence.gt is None:
        raise InputError(
            f"{sequence.source or sequence.name}: evaluation needs ground truth, and the sequence was read without "
            "any (its reader found no ground-truth file or topic; the reader options gt_file or gt_topic name one)"
        )
    gyro = sequence.gyro if gyro is None else _samples("gyro", gyro, len(sequence))
    acc = sequence.acc if acc is None else _samples("acc", acc, len(sequence))
    length = _window_length(sequence, interval, interval_unit)
    gt, dt = sequence.gt, sequence.dt
    starts = np.arange(0, len(sequence) - length, length)  # window [s, s + L) ends at state s + L <= N - 1
    if windows == "valid":
        ok = usable_windows(sequence, starts, length)
    else:  # no time gap inside the window either way
        ok = gt.valid[starts + length] & usable_windows(sequence, starts, length, need_valid=False)
    starts = starts[ok]
    if len(starts) == 0:
        raise InputError(
            f"{sequence.name}: no window of {length} samples with valid ground truth "
            f"(sequence has {len(sequence)} samples)"
        )
    take = starts[:, None] + np.arange(length)[None, :]  # samples of each window
    after = take + 1  # ground-truth state after each sample

    as_t = torch.as_tensor
    pre = preintegrate(as_t(gyro[take]), as_t(acc[take]), as_t(dt[take]))
    start = NavState(rot=as_t(gt.rot[starts]), vel=as_t(gt.vel[starts]), pos=as_t(gt.pos[starts]))
    pred = predict(start, pre, gravity=as_t(sequence.gravity))
    err = metrics.window_errors(
        pred.rot.numpy(), pred.pos.numpy(), pred.vel.numpy(), gt.rot[after], gt.pos[after], gt.vel[after]
    )

    # Dead reckoning over the whole valid span from the first state, for ATE.
    first, last = _valid_span(gt.valid)
    est = dead_reckoning(sequence, gyro, acc, first, last)
    truth, valid = gt.pos[first:last], gt.valid[first:last]

    return Evaluation(
        sequence=sequence.name,
        interval_s=float(length * np.median(dt)),
        interval_frames=length,
        n_windows=len(starts),
        roe_deg=float(err.end_rot_deg.mean()),
        roe_rmse_deg=metrics.rmse(err.end_rot_deg),
        rpe_m=float(err.end_pos_m.mean()),
        rpe_rmse_m=metrics.rmse(err.end_pos_m),
        rot_rmse_states_deg=metrics.rmse(err.rot_deg),
        pos_rmse_states_m=metrics.rmse(err.pos_m),
        vel_rmse_states_m_s=metrics.rmse(err.vel_m_s),
        ate_m=metrics.ate_m(est[valid], truth[valid], align=False),
        ate_aligned_m=metrics.ate_m(est[valid], truth[valid], align=True),
    )


def dead_reckoning(sequence: ImuSequence, gyro, acc, first: int = 0, last: int | None = None) -> np.ndarray:
    """(last - first, 3) world positions, m, of samples ``first`` .. ``last - 1`` of the IMU ``gyro``/``acc`` (N, 3)
    integrated from the ground-truth state at sample ``first`` (default: the whole sequence)."""
    last = len(sequence) if last is None else last
    gt, as_t = sequence.gt, torch.as_tensor
    take = slice(first, last)
    pre = preintegrate(as_t(np.asarray(gyro)[take]), as_t(np.asarray(acc)[take]), as_t(sequence.dt[take]))
    origin = NavState(rot=as_t(gt.rot[first]), vel=as_t(gt.vel[first]), pos=as_t(gt.pos[first]))
    track = predict(origin, pre, gravity=as_t(sequence.gravity)).pos.numpy()
    return np.concatenate([gt.pos[first : first + 1], track[:-1]])  # the state at each sample, before it


def _window_length(sequence: ImuSequence, interval: float, unit: str) -> int:
    if unit not in INTERVAL_UNITS:
        raise InputError(f"interval unit must be one of {INTERVAL_UNITS}, got {unit!r}")
    if not interval > 0:
        raise InputError(f"interval must be positive, got {interval!r}")
    length = int(round(interval / float(np.median(sequence.dt)))) if unit == "s" else int(interval)
    if length < 1 or length >= len(sequence):
        raise InputError(
            f"{sequence.name}: an interval of {interval} {unit} ({length} samples) does not fit in the sequence "
            f"({len(sequence)} samples)"
        )
    return length


def _valid_span(valid: np.ndarray) -> tuple[int, int]:
    """First valid index and one past the last valid index."""
    idx = np.flatnonzero(valid)
    return int(idx[0]), int(idx[-1]) + 1


def _samples(name: str, value, n: int) -> np.ndarray:
    out = np.asarray(value, dtype=float)
    if out.shape != (n, 3) or not np.all(np.isfinite(out)):
        raise InputError(f"evaluate: {name} must be finite and shaped ({n}, 3), got {out.shape}")
    return out
