"""The paper's IMU ablation (AirIMU Tables I/II and its EuRoC tables), plus two baselines it lacks; settings are data.

- Baseline: the raw IMU;
- Average Bias: a constant bias fitted on the training sequences (``learned_imu.evaluation.baselines``);
- Linear calibration: per-axis scale, misalignment and bias of gyro and accelerometer, least squares over the
  training sequences (what Kalibr-style intrinsics give; ``learned_imu.evaluation.baselines.linear_calibration``);
- AirIMU w/o covariance loss: the network trained with the state loss only;
- AirIMU: the network trained with the state loss and the covariance NLL.

Each learned variant trains in its own run folder (``<out>/<variant.key>``, resumable) and is evaluated from its
best checkpoint. Every variant is scored on the evaluation sequences (``data.evaluate``, else ``data.val``) at the
configured interval and at ``evaluation.frames`` IMU samples (the paper's 10-frame table); the metric fields are
defined in ``learned_imu.evaluation.metrics``. Learned variants also report the calibration of their covariance on those
sequences' windows: the mean normalised squared errors ``e^2 / sigma^2`` of rotation, position and velocity
(1 when calibrated).

With several ``seeds`` each learned variant trains once per seed (``<out>/<variant.key>_seed<k>``, ``train.seed``
= k) and ``summarise`` gives mean and standard deviation over seeds. ``paper_tables`` lays the summary out as the
paper's tables, with the paper's published values (``learned_imu.evaluation.paper``) as reference columns.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from airimu_core.io import write_csv_atomic, write_json_atomic
from airimu_core.sequence import ImuSequence
from learned_imu.config import ExperimentConfig
from learned_imu.evaluation import paper
from learned_imu.evaluation.baselines import average_bias, linear_calibration
from learned_imu.evaluation.evaluate import evaluate
from learned_imu.network.checkpoint import model_from_checkpoint
from learned_imu.network.inference import correct
from learned_imu.network.model import AirImuNet
from learned_imu.training.experiment import load_sequences, train_run
from learned_imu.training.train import noise_residuals
from learned_imu.training.windows import make_windows

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Variant:
    """One setting: ``correction`` is ``"none"``, ``"average_bias"``, ``"linear_calibration"`` or ``"model"``;
    ``covariance_weight`` overrides ``loss.covariance`` for a model (0 = no covariance loss; None = the config's);
    ``reader_options`` ((key, value) pairs) are set on every sequence of the config read by a reader that has them
    (TUM-VI's ``imu``: the same rooms' raw or calibrated IMU)."""

    key: str
    name: str
    correction: str
    covariance_weight: float | None = None
    reader_options: tuple[tuple[str, object], ...] = ()

    def configure(self, config: ExperimentConfig) -> ExperimentConfig:
        """``config`` with this variant's reader options set on its sequences."""
        if not self.reader_options:
            return config
        options = dict(self.reader_options)

        def apply(specs):
            return tuple(
                dataclasses.replace(spec, options={**spec.options, **options}) if spec.dataset == "tumvi" else spec
                for spec in specs
            )

        data = config.data
        data = dataclasses.replace(data, train=apply(data.train), val=apply(data.val), evaluate=apply(data.evaluate))
        return dataclasses.replace(config, data=data)


VARIANTS = (
    Variant("baseline", "Baseline", "none"),
    Variant("average_bias", "Average Bias", "average_bias"),
    Variant("linear_calibration", "Linear calibration", "linear_calibration"),
    Variant("airimu_no_cov", "AirIMU w/o cov. loss", "model", covariance_weight=0.0),
    Variant("airimu", "AirIMU", "model"),
)


# TUM-VI (the paper's third table): the rooms' raw IMU and TUM-VI's calibrated one (its "Kalibr" column), a
# model trained on each; configs/tumvi.yaml reads the calibrated IMU, as the official AirIMU loader does
RAW, CALIBRATED = (("imu", "raw"),), (("imu", "calibrated"),)
TUMVI_VARIANTS = (
    Variant("baseline", "Baseline", "none", reader_options=RAW),
    Variant("kalibr_baseline", "Kalibr + Baseline", "none", reader_options=CALIBRATED),
    Variant("average_bias", "Average Bias", "average_bias", reader_options=CALIBRATED),
    Variant("linear_calibration", "Linear calibration", "linear_calibration", reader_options=RAW),
    Variant("airimu_raw", "AirIMU (raw IMU)", "model", reader_options=RAW),
    Variant("airimu", "AirIMU", "model", reader_options=CALIBRATED),
)


def variants_for(config: ExperimentConfig) -> tuple[Variant, ...]:
    """The settings of ``config``'s table: ``TUMVI_VARIANTS`` when it trains on TUM-VI alone, else ``VARIANTS``."""
    if config.data.train and all(spec.dataset == "tumvi" for spec in config.data.train):
        return TUMVI_VARIANTS
    return VARIANTS


METRICS = ("roe_deg", "roe_rmse_deg", "rpe_m", "rpe_rmse_m", "roe_rmse_10f_deg", "rpe_rmse_10f_m", "ate_m")


@dataclass(frozen=True)
class AblationRow:
    """Metrics of one variant on one sequence (units in the names; ``learned_imu.evaluation.metrics``). The ``*_10f_*``
    fields are at ``evaluation.frames`` IMU samples (NaN when it is 0); ``nse_*``: NaN without a covariance."""

    variant: str
    sequence: str
    roe_deg: float
    roe_rmse_deg: float
    rpe_m: float
    rpe_rmse_m: float
    roe_rmse_10f_deg: float
    rpe_rmse_10f_m: float
    ate_m: float
    nse_rot: float = float("nan")
    nse_pos: float = float("nan")
    nse_vel: float = float("nan")
    seed: int | None = None  # train.seed of a learned variant; None for the deterministic baselines


@dataclass(frozen=True)
class AblationSummary:
    """Mean and standard deviation (population) over seeds of one variant on one sequence, per metric field."""

    variant: str
    sequence: str
    seeds: int
    mean: dict[str, float]
    std: dict[str, float]


@dataclass(frozen=True)
class TableCell:
    """One cell of a paper table: ours (mean, std over ``seeds``; None for a paper-only setting) and the paper's."""

    setting: str
    sequence: str
    field: str
    mean: float | None
    std: float | None
    seeds: int
    paper: float | None


@dataclass(frozen=True)
class PaperTable:
    """One of the paper's tables: a title, its metric fields and every cell (settings x sequences x fields)."""

    title: str
    fields: tuple[str, ...]
    cells: tuple[TableCell, ...]


# the paper's tables: title and fields (learned_imu.evaluation.metrics); reference values in
# learned_imu.evaluation.paper
PAPER_TABLES = (
    ("Gyroscope integration over the interval: ROE (deg) and RMSE (deg)", ("roe_deg", "roe_rmse_deg")),
    ("Integration over evaluation.frames samples: R-RMSE (deg) and P-RMSE (m)", ("roe_rmse_10f_deg", "rpe_rmse_10f_m")),
    ("P-RMSE over the interval (m), the learned-inertial-odometry table", ("rpe_rmse_m",)),
    (
        "Covariance calibration on the evaluated windows: NSE rotation, position, velocity (1 = calibrated)",
        ("nse_rot", "nse_pos", "nse_vel"),
    ),
)
KITTI_TABLES = (
    (
        "KITTI: ROE (deg) and RPE (m) over the interval (the paper's: 10 Hz sync stream; ours: 100 Hz OXTS)",
        ("roe_deg", "rpe_m"),
    ),
    PAPER_TABLES[-1],
)
TUMVI_TABLES = (("TUM-VI: ROE (deg) and RPE (m) over the interval", ("roe_deg", "rpe_m")), PAPER_TABLES[-1])


def ablate(
    config: ExperimentConfig, out: str | Path, variants=None, progress: bool = True, seeds=None, on_epoch=None
) -> list[AblationRow]:
    """Train what needs training and score every variant (default ``variants_for(config)``) on the evaluation
    sequences; learned variants once per seed in ``seeds`` (default: the config's ``train.seed`` alone, in
    ``<out>/<variant.key>``); ``on_epoch``: as ``train_run`` takes it."""
    out = Path(out)
    rows = []
    read: dict[tuple, tuple[list[ImuSequence], list[ImuSequence]]] = {}  # sequences by reader options
    for variant in variants_for(config) if variants is None else variants:
        configured = variant.configure(config)
        if variant.reader_options not in read:
            read[variant.reader_options] = (
                load_sequences(configured.data.train, configured.data.root),
                load_sequences(configured.data.evaluate or configured.data.val, configured.data.root),
            )
        train_seqs, eval_seqs = read[variant.reader_options]
        if variant.correction != "model" or seeds is None:
            rows += run_variant(variant, configured, out, train_seqs, eval_seqs, progress, on_epoch)
            continue
        for seed in seeds:
            seeded = dataclasses.replace(configured, train=dataclasses.replace(configured.train, seed=int(seed)))
            keyed = dataclasses.replace(variant, key=f"{variant.key}_seed{int(seed)}")
            rows += run_variant(keyed, seeded, out, train_seqs, eval_seqs, progress, on_epoch)
    return rows


def summarise(rows: list[AblationRow]) -> list[AblationSummary]:
    """Mean and standard deviation (population) of every metric over the rows of each variant and sequence."""
    groups: dict[tuple[str, str], list[AblationRow]] = {}
    for row in rows:
        groups.setdefault((row.variant, row.sequence), []).append(row)
    out = []
    for (variant, sequence), group in groups.items():
        values = {k: np.array([getattr(r, k) for r in group]) for k in (*METRICS, "nse_rot", "nse_pos", "nse_vel")}
        mean = {k: float(v.mean()) for k, v in values.items()}
        std = {k: float(v.std()) for k, v in values.items()}
        out.append(AblationSummary(variant, sequence, len(group), mean, std))
    return out


def paper_tables(rows: list[AblationRow]) -> list[PaperTable]:
    """The paper's tables from the rows: our mean +- std over seeds beside the paper's values. The paper's KITTI
    table (``KITTI_TABLES``, values ``learned_imu.evaluation.paper.KITTI_IMU``) when the rows are of its KITTI
    drives, else its
    EuRoC tables (``PAPER_TABLES``, ``learned_imu.evaluation.paper.EUROC_IMU``). Settings the paper has and we do not
    run
    ("Brossard et al.") appear with the paper's values alone, where it reports the field."""
    if any(r.sequence in paper.KITTI_IMU for r in rows):
        specs, reference = KITTI_TABLES, paper.KITTI_IMU
    elif any(r.sequence in paper.TUMVI_IMU for r in rows):
        specs, reference = TUMVI_TABLES, paper.TUMVI_IMU
    else:
        specs, reference = PAPER_TABLES, paper.EUROC_IMU
    summaries = summarise(rows)
    sequences = list(dict.fromkeys(r.sequence for r in rows))
    ours = list(dict.fromkeys(r.variant for r in rows))
    quoted = [s for seq in sequences for s in reference.get(seq, {}) if s not in ours]
    settings = ours + list(dict.fromkeys(quoted))
    by = {(s.variant, s.sequence): s for s in summaries}
    tables = []
    for title, fields in specs:
        cells = []
        for setting in settings:
            for sequence in sequences:
                summary = by.get((setting, sequence))
                for field in fields:
                    value = paper.reference(reference, sequence, setting, field)
                    if summary is None and value is None:
                        continue
                    mean = None if summary is None else summary.mean[field]
                    std = None if summary is None else summary.std[field]
                    seeds = 0 if summary is None else summary.seeds
                    cells.append(TableCell(setting, sequence, field, mean, std, seeds, value))
        cells = [c for c in cells if not (c.mean is not None and np.isnan(c.mean) and c.paper is None)]
        tables.append(PaperTable(title, fields, tuple(cells)))
    return tables


def run_variant(
    variant: Variant,
    config: ExperimentConfig,
    out: Path,
    train_seqs: list[ImuSequence],
    eval_seqs: list[ImuSequence],
    progress: bool = True,
    on_epoch=None,
) -> list[AblationRow]:
    """Score one variant on every evaluation sequence (training it first if it is learned)."""
    if variant.correction == "none":
        samples = [(s.gyro, s.acc) for s in eval_seqs]
        model = None
    elif variant.correction == "average_bias":
        bias = average_bias(train_seqs)
        log.info("average bias: gyro %s rad/s, acc %s m/s^2", bias.gyro_rad_s, bias.acc_m_s2)
        samples = [bias.correct(s) for s in eval_seqs]
        model = None
    elif variant.correction == "linear_calibration":
        fitted = linear_calibration(train_seqs)
        log.info("linear calibration: %s", fitted)
        samples = [fitted.correct(s) for s in eval_seqs]
        model = None
    elif variant.correction == "model":
        if variant.covariance_weight is not None:
            config = dataclasses.replace(
                config, loss=dataclasses.replace(config.loss, covariance=variant.covariance_weight)
            )
        train_run(config, out / variant.key, progress=progress, on_epoch=on_epoch)
        model, _ = model_from_checkpoint(out / variant.key / "best.pt")
        outputs = [correct(model, s, config.train.remove_gravity) for s in eval_seqs]
        samples = [(o.gyro.numpy(), o.acc.numpy()) for o in outputs]
    else:
        raise ValueError(f"variant {variant.key}: unknown correction {variant.correction!r}")
    rows = []
    for seq, (gyro, acc) in zip(eval_seqs, samples, strict=True):
        rows.append(score(variant.name, seq, gyro, acc, config, model))
    return rows


def score(name: str, sequence: ImuSequence, gyro, acc, config: ExperimentConfig, model=None) -> AblationRow:
    """One row: the samples ``gyro``, ``acc`` (N, 3) of ``sequence`` at the configured interval and frames, and
    the covariance's NSE when a ``model`` gave them."""
    interval = config.evaluation
    result = evaluate(sequence, interval.interval, interval.interval_unit, gyro, acc, interval.windows)
    short_rot = short_pos = float("nan")
    if interval.frames > 0:
        short = evaluate(sequence, interval.frames, "frames", gyro, acc, interval.windows)
        short_rot, short_pos = short.roe_rmse_deg, short.rpe_rmse_m
    nse = calibration(model, sequence, config) if model is not None else np.full(3, np.nan)
    return AblationRow(
        name,
        sequence.name,
        result.roe_deg,
        result.roe_rmse_deg,
        result.rpe_m,
        result.rpe_rmse_m,
        short_rot,
        short_pos,
        result.ate_m,
        *map(float, nse),
        config.train.seed if model is not None else None,
    )


def calibration(model: AirImuNet, sequence: ImuSequence, config: ExperimentConfig) -> np.ndarray:
    """(3,) mean e^2 / sigma^2 of rotation, position, velocity over the sequence's windows (see module doc); NaN
    where the sequence has no usable window of ``train.window`` samples (gaps in every one)."""
    t = config.train
    windows = make_windows(
        sequence, t.window, t.every, None, remove_gravity=t.remove_gravity, allow_empty=True, context=t.context
    )
    if windows is None:
        log.warning("%s: no window of %d samples for the NSE", sequence.name, t.window)
        return np.full(3, np.nan)
    return noise_residuals(model, windows).nse()


def write_rows(rows: list[AblationRow], json_path: str | Path | None = None, csv_path: str | Path | None = None):
    """Save the ablation atomically. JSON: an object with ``rows`` (one per variant, sequence and seed),
    ``summary`` (mean and std over seeds) and ``paper_tables`` (``paper_tables``: our values beside the paper's).
    CSV: the rows (one header line) at ``csv_path``, and the paper tables' cells in long form (table, setting,
    sequence, field, mean, std, seeds, paper) beside it as ``<stem>_tables.csv``. NaN is written as null / empty."""
    tables = paper_tables(rows)
    cells = [{"table": t.title, **dataclasses.asdict(c)} for t in tables for c in t.cells]
    if json_path:
        write_json_atomic(
            json_path,
            _nulls(
                {
                    "rows": [dataclasses.asdict(r) for r in rows],
                    "summary": [dataclasses.asdict(s) for s in summarise(rows)],
                    "paper_tables": [
                        {"title": t.title, "fields": list(t.fields), "cells": [dataclasses.asdict(c) for c in t.cells]}
                        for t in tables
                    ],
                }
            ),
        )
    if csv_path:
        csv_path = Path(csv_path)
        write_csv_atomic(csv_path, _nulls([dataclasses.asdict(r) for r in rows]))
        write_csv_atomic(csv_path.with_name(f"{csv_path.stem}_tables.csv"), _nulls(cells))


def _nulls(value):
    """NaN -> None, recursively (JSON has no NaN)."""
    if isinstance(value, dict):
        return {k: _nulls(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_nulls(v) for v in value]
    return None if _nan(value) else value


def _nan(value) -> bool:
    return isinstance(value, float) and np.isnan(value)
