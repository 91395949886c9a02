"""The product's main job, stage by stage: model -> corrected IMU -> exports -> graphs -> ATE table -> recording.

``ablate_pgo(config, out)`` trains the configured model (or finishes its interrupted run), corrects every
evaluation sequence, runs the PGO ablation (``fusion.pgo``) and optionally writes a Rerun recording (``record``)
and a PNG (``fusion.figures.plot``) of the first sequence.
"""

from __future__ import annotations

import logging
import weakref
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from fusion.config import PgoConfig
from fusion.graph import with_marginals
from fusion.pgo import PgoRow, run_sequence
from learned_imu.config import load_config
from learned_imu.datasets.sequence import ImuSequence
from learned_imu.geometry.preintegration import NavState, predict, preintegrate
from learned_imu.network.checkpoint import model_from_checkpoint
from learned_imu.network.inference import correct
from learned_imu.network.model import Correction
from learned_imu.training.experiment import load_sequences, train_run, with_epochs

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class SequenceResult:
    """What one sequence produced: its rows, the model output, and one solution per setting (first rate, seed 0)."""

    sequence: ImuSequence
    correction: Correction
    rows: list[PgoRow]
    examples: dict


def ablate_pgo(
    config: PgoConfig,
    out: str | Path,
    progress: bool = True,
    data_root: str | Path | None = None,
    epochs: int | None = None,
) -> list[SequenceResult]:
    """Run the PGO ablation of ``config`` (see the module docstring); exports go to ``out/exports``."""
    out = Path(out)
    experiment = load_config(config.experiment, data_root=data_root)
    if epochs:
        experiment = with_epochs(experiment, epochs)
    run = Path(config.run)
    from fusion.recording import write_training_recording

    # resumes an interrupted run, drawing its epochs into run/training.rrd; returns at once if finished
    train_run(experiment, run, progress=progress, on_epoch=write_training_recording)
    model, _ = model_from_checkpoint(run / "best.pt")
    specs = config.sequences or experiment.data.evaluate or experiment.data.val
    results = []
    for sequence in load_sequences(specs, experiment.data.root):
        correction = correct(model, sequence, experiment.train.remove_gravity)
        rows, examples = run_sequence(sequence, correction, out / "exports", config.options, config.fusion)
        results.append(SequenceResult(sequence, correction, rows, examples))
    return results


def dead_reckoning(sequence: ImuSequence, gyro: np.ndarray, acc: np.ndarray, times: np.ndarray) -> np.ndarray:
    """(K, 3) positions at ``times`` of the IMU integrated from the ground-truth state at the first sample."""
    as_t = torch.as_tensor
    pre = preintegrate(as_t(gyro), as_t(acc), as_t(sequence.dt))
    gt = sequence.gt
    start = NavState(as_t(gt.rot[0]), as_t(gt.vel[0]), as_t(gt.pos[0]))
    pos = np.concatenate([gt.pos[:1], predict(start, pre, as_t(sequence.gravity)).pos.numpy()[:-1]])
    index = np.clip(np.searchsorted(sequence.t, times), 0, len(sequence) - 1)
    return pos[index]


def record(result: SequenceResult, path: str | Path) -> Path:
    """A Rerun recording of one sequence (``fusion.recording``): ground truth, GPS, fused tracks with covariance
    ellipsoids, errors against 3-sigma bounds, raw and AirIMU dead reckoning, IMU series, corrections, sigmas."""
    from fusion.recording import ImuSeries, Track, write_recording

    seq, c = result.sequence, result.correction
    fused = [Track(name, *marginal_track(solution)) for name, (solution, _) in result.examples.items()]
    times = fused[0].t
    truth, drift = None, []
    if seq.gt is not None:
        truth = Track("ground truth", seq.t, seq.gt.pos)
        drift = [
            Track("raw IMU", times, dead_reckoning(seq, seq.gyro, seq.acc, times)),
            Track("AirIMU", times, dead_reckoning(seq, c.gyro.numpy(), c.acc.numpy(), times)),
        ]
    gps = next(iter(result.examples.values()))[1]
    imu = ImuSeries(seq.t, seq.gyro, seq.acc, c.d_gyro.numpy(), c.d_acc.numpy(), c.gyro_cov.numpy(), c.acc_cov.numpy())
    return write_recording(path, fused, truth, drift, (gps.t, gps.pos), imu)


def marginal_track(solution) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, pos, pos_cov) of a solution's keyframes, the marginals computed once per solution."""
    if solution not in _MARGINALS:
        trajectory = with_marginals(solution)
        _MARGINALS[solution] = (trajectory.t, trajectory.pos, trajectory.pos_cov)
    return _MARGINALS[solution]


_MARGINALS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # record() and plot() share them


def paper_ate(row: PgoRow) -> float | None:
    """The paper's ATE (m) for a row's sequence, GPS rate and setting, or None where it has none."""
    from learned_imu.evaluation.paper import EUROC_PGO

    return EUROC_PGO.get(row.sequence, {}).get(row.gps_hz, {}).get(row.setting)


def write_table(rows: list[PgoRow], json_path: str | Path | None = None, csv_path: str | Path | None = None) -> None:
    """The ablation rows as JSON (keys setting, gps_hz, sequence, ate_mean_m, ate_std_m, paper_ate_m) and/or CSV,
    atomically; ``paper_ate_m`` is the AirIMU paper's published ATE for that cell (``learned_imu.evaluation.paper``),
    or null."""
    from dataclasses import asdict

    from learned_imu.io import write_csv_atomic, write_json_atomic

    records = [{**asdict(r), "paper_ate_m": paper_ate(r)} for r in rows]
    if json_path:
        write_json_atomic(json_path, records)
    if csv_path:
        write_csv_atomic(csv_path, records)
