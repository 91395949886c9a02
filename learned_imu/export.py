"""The hand-off from torch to GTSAM: ``preintegration_export`` preintegrates a sequence's (corrected) samples between
keyframes into an ``airimu_core.export.Export`` in memory (every field's shape, unit and frame: that module's
docstring); ``export_preintegration`` writes the same as a ``.npz`` (no pickle) for another process, to a temporary
name then renamed, so a crash never leaves a half-written export (``airimu_core.export.load_export`` reads it back,
validated).
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import numpy as np
import torch

from airimu_core.errors import DataError, InputError
from airimu_core.export import FORMAT_VERSION, Export, export_from_arrays, save_export
from airimu_core.sequence import ImuSequence
from learned_imu.geometry.preintegration import preintegrate
from learned_imu.network.model import Correction

log = logging.getLogger(__name__)

SAMPLES_PER_CALL = 100_000  # samples preintegrated per batched call (about 0.5 GB of float64 intermediates)


def keyframes_every(sequence: ImuSequence, interval_s: float) -> np.ndarray:
    """Keyframe sample indices every ``interval_s`` seconds (the last one at or before the last sample); an interval
    longer than the sequence gives its first sample alone (callers that need two say so, naming their option)."""
    if not interval_s > 0:  # NaN too
        raise InputError(f"keyframes_every: the interval must be a positive number of seconds, got {interval_s}")
    samples = interval_s / float(np.median(sequence.dt))
    step = max(1, int(round(min(samples, float(len(sequence))))))  # capped: 1e308 s would overflow an int
    return np.arange(0, len(sequence), step)


def merge_keyframes(required: np.ndarray, extra: np.ndarray) -> np.ndarray:
    """Keyframe sample indices: every one of ``required`` (e.g. the samples of the GPS fixes, so that each fix
    constrains the state at its own time) and those of ``extra`` (e.g. a regular grid) that lie at least two samples
    from every required one (an interval needs two samples). Required indices closer than two samples to the
    previous kept one are left out too: the fix there attaches to a keyframe one sample away. Of two ``extra``
    indices closer than two samples (two grids, e.g. 1 s and 0.09 s at 100 Hz: samples 99 and 100), the later is left
    out."""
    kept: list[int] = []
    for i in np.unique(np.asarray(required, dtype=np.int64)):
        if not kept or i - kept[-1] >= 2:
            kept.append(int(i))
    fixed = np.asarray(kept, dtype=np.int64)
    extra = np.unique(np.asarray(extra, dtype=np.int64))
    if len(fixed) and len(extra):
        at = np.searchsorted(fixed, extra)  # fixed[at - 1] < extra <= fixed[at]
        after = np.abs(fixed[np.minimum(at, len(fixed) - 1)] - extra)
        before = np.abs(extra - fixed[np.maximum(at - 1, 0)])
        extra = extra[np.minimum(before, after) >= 2]
    merged: list[int] = []
    for i in np.union1d(fixed, extra).tolist():  # a required one is two or more from every extra left
        if not merged or i - merged[-1] >= 2:
            merged.append(i)
    return np.asarray(merged, dtype=np.int64)


def export_preintegration(
    path: str | Path,
    sequence: ImuSequence,
    keyframe_index: np.ndarray,
    gyro_cov=None,
    acc_cov=None,
    gyro: np.ndarray | None = None,
    acc: np.ndarray | None = None,
    *,
    correction: Correction | None = None,
) -> Path:
    """``preintegration_export`` written to ``path`` (atomically): the route to another process."""
    export = preintegration_export(sequence, keyframe_index, gyro_cov, acc_cov, gyro, acc, correction=correction)
    return save_export(export, path)


def preintegration_export(
    sequence: ImuSequence,
    keyframe_index: np.ndarray,
    gyro_cov=None,
    acc_cov=None,
    gyro: np.ndarray | None = None,
    acc: np.ndarray | None = None,
    *,
    correction: Correction | None = None,
) -> Export:
    """Preintegrate ``sequence`` between keyframes into an ``Export`` (see the module docstring), validated.

    ``correction``: a model's output for the sequence (``learned_imu.network.inference.correct``): its corrected
    samples and per-sample densities are exported. Without it: ``gyro``/``acc`` (N, 3) replace the raw samples and
    ``gyro_cov``/``acc_cov`` are densities (sigma^2), (3,) or per sample (N, 3). Intervals of equal length are
    integrated in one batched call.
    """
    if correction is not None:
        if any(x is not None for x in (gyro_cov, acc_cov, gyro, acc)):
            raise InputError("export: give a correction or samples and densities, not both")
        gyro, acc = correction.gyro.double().cpu().numpy(), correction.acc.double().cpu().numpy()
        gyro_cov, acc_cov = correction.gyro_cov.double().cpu().numpy(), correction.acc_cov.double().cpu().numpy()
    if gyro_cov is None or acc_cov is None:
        raise InputError("export: give the noise densities (gyro_cov, acc_cov) or a correction")
    n = len(sequence)
    keyframe_index = np.asarray(keyframe_index, dtype=np.int64)
    if keyframe_index.ndim != 1 or len(keyframe_index) < 2 or np.any(np.diff(keyframe_index) <= 0):
        raise InputError("export: keyframe_index must hold at least two strictly increasing sample indices")
    if keyframe_index[0] < 0 or keyframe_index[-1] > n - 1:
        raise InputError(f"export: keyframe indices must lie in [0, {n - 1}]")
    if np.any(np.diff(keyframe_index) < 2):
        k = int(np.flatnonzero(np.diff(keyframe_index) < 2)[0])
        raise InputError(
            f"export: keyframes {k} and {k + 1} are one sample apart (indices {keyframe_index[k]}, "
            f"{keyframe_index[k + 1]}): one sample's position and velocity noise are one source, so the interval's "
            "covariance is singular; keyframes need at least two samples between them"
        )
    gyro = sequence.gyro if gyro is None else np.asarray(gyro, dtype=float)
    acc = sequence.acc if acc is None else np.asarray(acc, dtype=float)
    gyro_cov = np.broadcast_to(np.asarray(gyro_cov, dtype=float), (n, 3))
    acc_cov = np.broadcast_to(np.asarray(acc_cov, dtype=float), (n, 3))
    dt = sequence.dt

    k = len(keyframe_index) - 1
    out = {
        "delta_rot": np.zeros((k, 3, 3)),
        "delta_pos": np.zeros((k, 3)),
        "delta_vel": np.zeros((k, 3)),
        "delta_dt": np.zeros(k),
        "delta_cov": np.zeros((k, 9, 9)),
        "bias_jacobian": np.zeros((k, 9, 6)),
    }
    lengths = np.diff(keyframe_index)
    for length in np.unique(lengths):
        same = np.flatnonzero(lengths == length)
        per_call = max(1, SAMPLES_PER_CALL // int(length))  # bounds the memory of one batched call
        for first in range(0, len(same), per_call):
            _integrate_intervals(
                out, same[first : first + per_call], int(length), keyframe_index, (gyro, acc, dt, gyro_cov, acc_cov)
            )

    arrays = {
        "format_version": np.array(FORMAT_VERSION),
        "name": np.array(sequence.name),
        "gravity": sequence.gravity,
        "t": sequence.t,
        "gyro": gyro,
        "acc": acc,
        "gyro_cov": np.ascontiguousarray(gyro_cov),
        "acc_cov": np.ascontiguousarray(acc_cov),
        "keyframe_t": sequence.t[keyframe_index],
        "keyframe_index": keyframe_index,
        **out,
    }
    if sequence.gt is not None:
        gt = sequence.gt
        arrays.update(gt_rot=gt.rot, gt_pos=gt.pos, gt_vel=gt.vel, gt_valid=gt.valid)
    return export_from_arrays(arrays)


def _integrate_intervals(out: dict, which: np.ndarray, length: int, keyframe_index: np.ndarray, samples) -> None:
    """Preintegrate the intervals ``which`` (all ``length`` samples long) in one batched call into ``out``."""
    take = keyframe_index[which][:, None] + np.arange(length)[None, :]  # samples from keyframe k to k + 1
    pre = preintegrate(*(torch.as_tensor(x[take]) for x in samples), at=-1, bias_jacobian=True)
    out["delta_rot"][which] = pre.rot[:, -1].numpy()
    out["delta_pos"][which] = pre.pos[:, -1].numpy()
    out["delta_vel"][which] = pre.vel[:, -1].numpy()
    out["delta_dt"][which] = pre.dt[:, -1].numpy()
    out["delta_cov"][which] = pre.cov[:, -1].numpy()
    out["bias_jacobian"][which] = pre.bias_jacobian[:, -1].numpy()


def check_keyframe_interval(sequence: ImuSequence, interval_s: float, spec: str) -> None:
    """An ``InputError`` naming ``--keyframes`` (as ``spec``), the recording's length and a likely unit when an
    interval of ``interval_s`` seconds cannot give two keyframes."""
    span = float(sequence.t[-1] - sequence.t[0])
    if interval_s > span:
        hint = " (milliseconds given as seconds?)" if interval_s / 1000.0 <= span else ""
        raise InputError(
            f"--keyframes {spec}: the interval is longer than the recording, {span:.4g} s "
            f"({len(sequence)} samples): at least two keyframes are needed{hint}"
        )


def keyframes_from_spec(sequence: ImuSequence, spec: str) -> np.ndarray:
    """Keyframe sample indices from ``"0.1s"`` (every 0.1 s) or a text file of times (s, one per line, IMU clock;
    each maps to the nearest sample, which must lie within half a sample period)."""
    if spec.endswith("s") and not Path(spec).exists():
        try:
            interval = float(spec[:-1])
        except ValueError:
            raise InputError(f"keyframes: expected an interval like '0.1s' or a file of times, got {spec!r}") from None
        if not (np.isfinite(interval) and interval > 0):
            raise InputError(f"keyframes: interval must be positive, got {spec!r}")
        check_keyframe_interval(sequence, interval, spec)
        return keyframes_every(sequence, interval)
    path = Path(spec)
    if not path.is_file():
        raise InputError(f"keyframes: {spec!r} is neither an interval like '0.1s' nor a file")
    try:
        times = np.loadtxt(path, ndmin=1, comments="#")
    except ValueError as error:
        raise DataError(path, "time", f"expected one time in seconds per line ({error})") from error
    if times.ndim != 1 or not np.all(np.isfinite(times)) or np.any(np.diff(times) <= 0):
        raise DataError(path, "time", "expected finite, strictly increasing times in seconds, one per line")
    index, on_sample = nearest_samples(sequence, times)
    if not on_sample.all():
        t0, t1 = float(sequence.t[0]), float(sequence.t[-1])
        raise DataError(
            path,
            "time",
            f"time {times[~on_sample][0]!r} s lies outside the IMU samples of "
            f"{sequence.name} ([{t0!r}, {t1!r}] s, or in a gap; times in ns or on another clock?)",
        )
    if len(index) < 2:
        raise DataError(path, "time", f"{len(index)} keyframe time(s): at least two are needed")
    return index


def nearest_samples(sequence: ImuSequence, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The index of the sample nearest to each of ``times`` (s, IMU clock), and whether it lies within half a
    (median) sample period of it (False for a time in a gap or outside the samples)."""
    times = np.asarray(times, dtype=float)
    index = np.clip(np.searchsorted(sequence.t, times), 1, len(sequence) - 1)
    index = np.where(np.abs(sequence.t[index - 1] - times) <= np.abs(sequence.t[index] - times), index - 1, index)
    return index, np.abs(sequence.t[index] - times) <= 0.5 * float(np.median(sequence.dt))


def fixes_on_samples(sequence: ImuSequence) -> ImuSequence:
    """``sequence`` with only the recorded fixes that fall on an IMU sample (within half a sample period); the
    others (inside a gap of the IMU) are dropped with a warning."""
    if sequence.gps is None:
        raise InputError(f"{sequence.name}: no recorded GPS fixes")
    _, on_sample = nearest_samples(sequence, sequence.gps.t)
    if not on_sample.all():
        t = sequence.gps.t[~on_sample]
        before, after = int((t < sequence.t[0]).sum()), int((t > sequence.t[-1]).sum())
        where = [
            f"{n} {text}"
            for n, text in (
                (before, "before the first IMU sample"),
                (after, "after the last IMU sample"),
                (len(t) - before - after, "in gaps of the IMU"),
            )
            if n
        ]
        log.warning(
            "%s: %d of %d GPS fixes are not used: %s%s",
            sequence.name,
            len(t),
            on_sample.size,
            ", ".join(where),
            " (a GPS file of a longer stretch, or in another time base?)" if before or after else "",
        )
    fixes = sequence.gps
    return dataclasses.replace(sequence, gps=fixes[on_sample])
