"""What fusing one sequence produced, and its views: ``SequenceResult`` (the sequence, the model's correction, the
ablation rows if any, one solution per setting), ``record`` (a Rerun recording) and ``marginal_track`` (keyframe
positions with their marginal covariances, computed once per solution and shared by ``record`` and
``airimu.viz.figures.plot``). Used by the PGO ablation (``airimu.experiments.pgo``) and by ``airimu fuse``
(``airimu.fuse``) alike.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from airimu_core.sequence import ImuSequence
from fusion.graph import with_marginals
from learned_imu.evaluation.evaluate import dead_reckoning
from learned_imu.network.model import Correction


@dataclass(frozen=True, eq=False)
class SequenceResult:
    """What one sequence produced: its rows, the model output, and one solution per setting (first rate, seed 0)."""

    sequence: ImuSequence
    correction: Correction
    rows: list  # airimu.experiments.pgo.PgoRow, empty for a single fused run
    examples: dict
    outages: tuple = ()  # (first, last) time, s on the IMU clock, of each GPS outage: shaded in the views


def record(result: SequenceResult, path: str | Path) -> Path:
    """A Rerun recording of one sequence (``airimu.viz.recording``): ground truth, GPS, fused tracks with covariance
    ellipsoids, errors against 3-sigma bounds, raw and AirIMU dead reckoning, IMU series, corrections, sigmas."""
    from airimu.viz.recording import ImuSeries, Track, write_recording

    seq, c = result.sequence, result.correction
    fused = [Track(name, *marginal_track(solution)) for name, (solution, _) in result.examples.items()]
    times = fused[0].t
    truth, drift = None, []
    if seq.gt is not None:
        truth = Track("ground truth", seq.t, seq.gt.pos)
        drift = [
            Track("raw IMU", times, _at_times(seq, dead_reckoning(seq, seq.gyro, seq.acc), times)),
            Track("AirIMU", times, _at_times(seq, dead_reckoning(seq, c.gyro.numpy(), c.acc.numpy()), times)),
        ]
    gps = next(iter(result.examples.values()))[1]
    imu = ImuSeries(seq.t, seq.gyro, seq.acc, c.d_gyro.numpy(), c.d_acc.numpy(), c.gyro_cov.numpy(), c.acc_cov.numpy())
    return write_recording(path, fused, truth, drift, (gps.t, gps.pos), imu, outages=result.outages)


def _at_times(sequence: ImuSequence, pos: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Per-sample positions (N, 3) at ``times`` (the sample at or after each time)."""
    return pos[np.clip(np.searchsorted(sequence.t, times), 0, len(sequence) - 1)]


def marginal_track(solution) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, pos, pos_cov) of a solution's keyframes, the marginals computed once per solution (pos_cov None where
    they could not be: ``with_marginals``)."""
    if solution not in _MARGINALS:
        trajectory = with_marginals(solution)
        cov = trajectory.pos_cov if np.all(np.isfinite(trajectory.pos_cov)) else None
        _MARGINALS[solution] = (trajectory.t, trajectory.pos, cov)
    return _MARGINALS[solution]


_MARGINALS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # record() and plot() share them
