"""The paper's IMU ablation (AirIMU Table I/II): four settings, one runner; the settings are data.

- Baseline: the raw IMU;
- Average Bias: a constant bias fitted on the training sequences (``learned_imu.baselines``);
- AirIMU w/o covariance loss: the network trained with the state loss only;
- AirIMU: the network trained with the state loss and the covariance NLL.

Each learned variant trains in its own run folder (``<out>/<variant.key>``, resumable) and is evaluated from its
best checkpoint. Every variant is scored on the evaluation sequences (``data.evaluate``, else ``data.val``) at the
configured interval. Learned variants also report the calibration of their covariance on those sequences' windows:
the mean normalised squared errors ``e^2 / sigma^2`` of rotation, position and velocity (1 when calibrated).

With several ``seeds`` each learned variant trains once per seed (``<out>/<variant.key>_seed<k>``, ``train.seed``
= k) and ``summarise`` gives mean and standard deviation over seeds: on one short validation sequence the
seed-to-seed spread of a learned variant can exceed the differences between variants (BENCHMARKS.md, EuRoC).
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from learned_imu.baselines import average_bias
from learned_imu.checkpoint import model_from_checkpoint
from learned_imu.config import ExperimentConfig
from learned_imu.evaluate import evaluate
from learned_imu.experiment import build_windows, correct, load_sequences, train_run
from learned_imu.io import write_csv_atomic, write_json_atomic
from learned_imu.model import AirImuNet
from learned_imu.sequence import ImuSequence
from learned_imu.train import noise_residuals

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Variant:
    """One setting: ``correction`` is ``"none"``, ``"average_bias"`` or ``"model"``; ``covariance_weight`` overrides
    ``loss.covariance`` for a model (0 = no covariance loss; None = the config's)."""

    key: str
    name: str
    correction: str
    covariance_weight: float | None = None


VARIANTS = (
    Variant("baseline", "Baseline", "none"),
    Variant("average_bias", "Average Bias", "average_bias"),
    Variant("airimu_no_cov", "AirIMU w/o cov. loss", "model", covariance_weight=0.0),
    Variant("airimu", "AirIMU", "model"),
)


@dataclass(frozen=True)
class AblationRow:
    """Metrics of one variant on one sequence (units in the names). ``nse_*``: NaN without a covariance."""

    variant: str
    sequence: str
    roe_deg: float
    rpe_m: float
    r_rmse_deg: float
    p_rmse_m: float
    ate_m: float
    nse_rot: float = float("nan")
    nse_pos: float = float("nan")
    nse_vel: float = float("nan")
    seed: int | None = None  # train.seed of a learned variant; None for the deterministic baselines


@dataclass(frozen=True)
class AblationSummary:
    """Mean and standard deviation over seeds of one variant on one sequence."""

    variant: str
    sequence: str
    seeds: int
    roe_deg_mean: float
    roe_deg_std: float
    p_rmse_m_mean: float
    p_rmse_m_std: float


def ablate(
    config: ExperimentConfig, out: str | Path, variants=VARIANTS, progress: bool = True, seeds=None
) -> list[AblationRow]:
    """Train what needs training and score every variant on the evaluation sequences; learned variants once per
    seed in ``seeds`` (default: the config's ``train.seed`` alone, in ``<out>/<variant.key>``)."""
    out = Path(out)
    train_seqs = load_sequences(config.data.train, config.data.root)
    eval_seqs = load_sequences(config.data.evaluate or config.data.val, config.data.root)
    rows = []
    for variant in variants:
        if variant.correction != "model" or seeds is None:
            rows += run_variant(variant, config, out, train_seqs, eval_seqs, progress)
            continue
        for seed in seeds:
            seeded = dataclasses.replace(config, train=dataclasses.replace(config.train, seed=int(seed)))
            keyed = dataclasses.replace(variant, key=f"{variant.key}_seed{int(seed)}")
            rows += run_variant(keyed, seeded, out, train_seqs, eval_seqs, progress)
    return rows


def summarise(rows: list[AblationRow]) -> list[AblationSummary]:
    """Mean and standard deviation (population) of ROE and P-RMSE over the rows of each variant and sequence."""
    groups: dict[tuple[str, str], list[AblationRow]] = {}
    for row in rows:
        groups.setdefault((row.variant, row.sequence), []).append(row)
    out = []
    for (variant, sequence), group in groups.items():
        roe, p_rmse = np.array([r.roe_deg for r in group]), np.array([r.p_rmse_m for r in group])
        out.append(AblationSummary(variant, sequence, len(group), roe.mean(), roe.std(), p_rmse.mean(), p_rmse.std()))
    return out


def run_variant(
    variant: Variant,
    config: ExperimentConfig,
    out: Path,
    train_seqs: list[ImuSequence],
    eval_seqs: list[ImuSequence],
    progress: bool = True,
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
    elif variant.correction == "model":
        if variant.covariance_weight is not None:
            config = dataclasses.replace(
                config, loss=dataclasses.replace(config.loss, covariance=variant.covariance_weight)
            )
        train_run(config, out / variant.key, progress=progress)
        model, _ = model_from_checkpoint(out / variant.key / "best.pt")
        outputs = [correct(model, s, config.train.remove_gravity) for s in eval_seqs]
        samples = [(o.gyro.numpy(), o.acc.numpy()) for o in outputs]
    else:
        raise ValueError(f"variant {variant.key}: unknown correction {variant.correction!r}")
    rows = []
    interval = config.evaluation
    for seq, (gyro, acc) in zip(eval_seqs, samples, strict=True):
        result = evaluate(seq, interval.interval, interval.interval_unit, gyro, acc)
        nse = calibration(model, seq, config) if model is not None else np.full(3, np.nan)
        rows.append(
            AblationRow(
                variant.name, seq.name, result.roe_deg, result.rpe_m, result.r_rmse_deg, result.p_rmse_m,
                result.ate_m, *map(float, nse), config.train.seed if model is not None else None,
            )
        )  # fmt: skip
    return rows


def calibration(model: AirImuNet, sequence: ImuSequence, config: ExperimentConfig) -> np.ndarray:
    """(3,) mean e^2 / sigma^2 of rotation, position, velocity over the sequence's windows (see module doc)."""
    return noise_residuals(model, build_windows([sequence], config, None)).nse()


def write_rows(rows: list[AblationRow], json_path: str | Path | None = None, csv_path: str | Path | None = None):
    """Save the table as JSON (a list of row objects) and/or CSV (one header line), atomically."""
    records = [dataclasses.asdict(r) for r in rows]
    if json_path:
        write_json_atomic(json_path, [{k: (None if _nan(v) else v) for k, v in r.items()} for r in records])
    if csv_path:
        write_csv_atomic(csv_path, records)


def _nan(value) -> bool:
    return isinstance(value, float) and np.isnan(value)
