"""Training runs: config -> sequences -> windows -> model -> epochs, in a run folder that explains itself.

A run folder holds:

- ``config.yaml``: the resolved config (every key, defaults filled in, absolute data root);
- ``metrics.jsonl``: one JSON line per epoch: ``epoch``, ``train_loss``, ``val_loss`` (the state loss alone, the
  selection criterion: ``Trainer.validation_loss``), ``lr``, ``seconds``
  (wall time since the run began, summed over resumptions) and the validation metrics ``val_roe_deg``,
  ``val_rpe_rmse_m`` (means over the validation sequences at the configured interval;
  ``learned_imu.evaluation.metrics``);
- ``last.pt`` after every epoch and ``best.pt`` at the best validation loss (``learned_imu.network.checkpoint``); when
  training ends, the noise decoders of ``best.pt`` are calibrated (``train.calibrate_uncertainty``,
  ``train.calibration_steps``), with ``train.scale_noise_on_val`` its noise is then scaled to the validation
  windows (``train.fit_noise_scales``, the scales kept as ``noise_scales``), and it is marked ``calibrated``.

Running again on the same folder resumes from ``last.pt`` (same config required, except ``RESUMABLE_CHANGES``)
and continues the metrics log;
a finished run returns at once. Every file is replaced atomically, so an interruption loses at most the epoch in
progress. Under ``torchrun`` (``world``, ``learned_imu.training.distributed``) every rank trains and reads
``last.pt`` to
resume (the folder must be on a file system all nodes share), but only rank 0 validates, calibrates and writes.
"""

from __future__ import annotations

import json
import logging
import math
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch

from airimu_core.config import to_dict
from airimu_core.errors import ConfigError, DataError, InputError
from airimu_core.io import atomic_file, folder_lock, remove_temporaries
from airimu_core.sequence import ImuSequence
from learned_imu.config import ExperimentConfig, SequenceConfig, resolve_device, save_config
from learned_imu.datasets import SIMULATOR, SPLIT
from learned_imu.evaluation.evaluate import Evaluation, evaluate
from learned_imu.network.checkpoint import (
    CALIBRATION_FIELDS,
    BestEpoch,
    Checkpoint,
    TrainedOn,
    build_model,
    build_motion_model,
    load_checkpoint,
    motion_from_checkpoint,
    save_checkpoint,
)
from learned_imu.network.inference import correct
from learned_imu.network.model import AirImuNet
from learned_imu.training.chunks import concat_chunks, make_chunks
from learned_imu.training.distributed import World, agree, barrier, check_batch_size, is_writer
from learned_imu.training.losses import LossWeights
from learned_imu.training.motion import (
    MotionChunks,
    collapse_warning,
    concat_motion_chunks,
    make_motion_chunks,
    output_spread,
)
from learned_imu.training.train import (
    EpochLog,
    Trainer,
    TrainingData,
    calibrate_uncertainty,
    fit_noise_scales,
    scale_noise,
    stopped_early,
)
from learned_imu.training.windows import concat_windows, make_windows

log = logging.getLogger(__name__)
# keys that may differ when resuming: the data may move, and the epoch budget may grow
RESUMABLE_CHANGES = (
    "data.root",
    "train.epochs",
    "train.early_stop_patience",
    "train.calibration_steps",
    "train.scale_noise_on_val",
    "train.device",  # a run started on a GPU may finish on the CPU and vice versa
    "data.evaluate",  # what is scored after training, not what trains
    "evaluation.frames",
    "evaluation.windows",
)
RUN_FILES = ("config.yaml", "metrics.jsonl", "best.pt", "last.pt")


@dataclass(frozen=True)
class RunSummary:
    """Where a run's files are and how it ended."""

    folder: Path
    epochs: int
    best_epoch: int
    best_val_loss: float
    seconds_to_best: float


def load_sequence(spec: SequenceConfig, root: str | Path) -> list[ImuSequence]:
    """Read one configured sequence (a dataset reader, or the simulator); a list, since ``on_gap: split`` reads
    with ``"keep"`` and splits the sequence at its gaps (``ImuSequence.split_at_gaps``)."""
    if spec.dataset == SIMULATOR:
        from learned_imu.datasets.simulator import simulate

        return [simulate(**spec.options).part(*spec.span)]
    from learned_imu.datasets import read_sequence

    path = Path(spec.path)
    split = spec.options.get("on_gap") == SPLIT
    options = {**spec.options, "on_gap": "keep"} if split else spec.options
    sequence = read_sequence(spec.dataset, path if path.is_absolute() else Path(root) / path, **options)
    return [s.part(*spec.span) for s in (sequence.split_at_gaps() if split else [sequence])]


def load_sequences(specs: tuple[SequenceConfig, ...], root: str | Path) -> list[ImuSequence]:
    """All configured sequences, in order."""
    return [seq for spec in specs for seq in load_sequence(spec, root)]


def build_windows(
    sequences: list[ImuSequence], config: ExperimentConfig, stride: int | None, key: str = "data.train"
) -> TrainingData:
    """Windows of every sequence, concatenated (with ``train.chunk``, chunks holding those windows:
    ``learned_imu.training.chunks``); a sequence without a usable window (time gaps in every one, as in some KITTI
    drives, or shorter than a chunk) is skipped with a warning, none at all is an error naming them, ``key`` (the
    config key that listed them) and ``train.window``."""
    train = config.train
    if not sequences:
        raise ConfigError(f"{key}: no sequence listed (training needs at least one)")
    parts = []
    for s in sequences:
        if train.context + train.window >= len(s):  # shorter than one window: skipped like one without any
            part = None
        elif train.chunk:
            part = make_chunks(
                s,
                train.chunk,
                train.window,
                train.every,
                stride or train.window,
                remove_gravity=train.remove_gravity,
                allow_empty=True,
                context=train.context,
                gt_rotation=train.gt_rotation,
            )
        else:
            part = make_windows(
                s,
                train.window,
                train.every,
                stride,
                remove_gravity=train.remove_gravity,
                allow_empty=True,
                context=train.context,
            )
        if part is None:
            log.warning("%s: no usable window of %d samples (gaps, invalid truth); skipped", s.name, train.window)
        else:
            parts.append(part)
    if not parts:
        found = ", ".join(
            f"{s.name} ({len(s)} samples, {int(s.gt.valid.sum()) if s.gt is not None else 0} with ground truth)"
            for s in sequences
        )
        what = f" (and train.chunk = {train.chunk})" if train.chunk else ""
        raise InputError(
            f"train.window = {train.window} samples{what}: no window without a gap or invalid ground truth in "
            f"{key}: {found}; a shorter train.window, on_gap: split, or sequences with more ground truth"
        )
    return concat_chunks(parts) if train.chunk else concat_windows(parts)


def build_motion_chunks(
    sequences: list[ImuSequence], config: ExperimentConfig, stride: int, key: str = "data.train"
) -> MotionChunks:
    """The motion model's chunks of every sequence (``learned_imu.training.motion``), concatenated; a sequence
    without a usable chunk is skipped with a warning, none at all is an error naming ``key`` and ``motion.chunk``."""
    m = config.motion
    if not sequences:
        raise ConfigError(f"{key}: no sequence listed (training needs at least one)")
    parts = []
    for s in sequences:
        part = make_motion_chunks(
            s,
            m.chunk,
            stride,
            m.context,
            m.block,
            math.radians(m.tilt_noise_deg),
            True,
            math.radians(m.frame_rotation_deg),
            m.mirror_axis,
            m.spin_axis,
            m.time_reversal,
            m.drift,
            m.axis_weights,
        )
        if part is None:
            log.warning("%s: no usable chunk of %d samples (gaps, invalid truth); skipped", s.name, m.context + m.chunk)
        else:
            parts.append(part)
    if not parts:
        raise InputError(
            f"motion.chunk = {m.chunk} (+ motion.context = {m.context}) samples: no chunk without a gap or invalid "
            f"ground truth in {key}; a shorter motion.chunk or sequences with more ground truth"
        )
    return concat_motion_chunks(parts)


def training_speed(sequences: list[ImuSequence]) -> float | None:
    """The highest ground-truth speed among ``sequences`` (m/s): the largest of each one's 99.9th percentile of
    ``|v|`` over its valid samples (a single glitch does not set it); None when none has ground truth."""
    speeds = [
        float(np.percentile(np.linalg.norm(s.gt.vel[s.gt.valid], axis=1), 99.9))
        for s in sequences
        if s.gt is not None and s.gt.valid.any()
    ]
    return max(speeds) if speeds else None


def loss_weights(config: ExperimentConfig) -> LossWeights:
    return LossWeights(**asdict(config.loss))


def evaluate_model(model: AirImuNet, sequence: ImuSequence, config: ExperimentConfig) -> Evaluation:
    """The paper's metrics of the corrected IMU on ``sequence`` at the configured interval."""
    out = correct(model, sequence, config.train.remove_gravity)
    interval = config.evaluation
    return evaluate(
        sequence, interval.interval, interval.interval_unit, out.gyro.numpy(), out.acc.numpy(), interval.windows
    )


def train_run(
    config: ExperimentConfig,
    folder: str | Path,
    progress: bool = True,
    world: World | None = None,
    on_epoch: Callable[[Path, list[EpochLog]], None] | None = None,
) -> RunSummary:
    """Train (or resume) the run in ``folder``; see the module docstring. ``loss.covariance = 0`` trains
    without the covariance loss (and skips the covariance propagation). ``world``: this process's rank in a
    ``torchrun`` job (``learned_imu.training.distributed.process_group``); every rank calls this and returns the
    summary.
    ``on_epoch(folder, history)``: called on the writing rank after each epoch's files are written, with the metrics
    of every epoch so far (``airimu.viz.recording.write_training_recording`` draws them in Rerun). ``progress``: a bar
    per epoch on a terminal, one line per epoch elsewhere (a log file, CI)."""
    folder = Path(folder)
    check_batch_size(config.train.batch_size, world)  # before anything is written
    if not is_writer(world):
        return _train_run(config, folder, progress, world, on_epoch)
    with folder_lock(folder):  # one writer per run folder: a second airimu train there is refused, naming this one
        return _train_run(config, folder, progress, world, on_epoch)


def _train_run(config: ExperimentConfig, folder: Path, progress: bool, world: World | None, on_epoch) -> RunSummary:
    writer = is_writer(world)
    if writer:
        folder.mkdir(parents=True, exist_ok=True)
        for stale in remove_temporaries(folder, ["*"]):  # a killed run's unfinished writes (the folder is locked)
            log.warning("removed %s, left by an interrupted write", stale)
    train_seqs = load_sequences(config.data.train, config.data.root)
    val_seqs = load_sequences(config.data.val, config.data.root)
    t = config.train
    torch.manual_seed(t.seed)
    motion = t.model == "motion"
    if motion:  # the motion model: body-frame velocity from chunks (learned_imu.training.motion)
        model = build_motion_model(config.motion)
        use_cov = config.motion.covariance > 0
        weights = LossWeights(covariance=config.motion.covariance)
        train_data = build_motion_chunks(train_seqs, config, config.motion.chunk_stride)
        val_data = build_motion_chunks(val_seqs, config, config.motion.val_chunk_stride, "data.val")
    else:
        model = build_model(config.model)
        use_cov = config.loss.covariance > 0
        weights = loss_weights(config)
        train_data = build_windows(train_seqs, config, t.stride or None)
        val_data = build_windows(val_seqs, config, t.val_stride or None, "data.val")
    trainer = Trainer(
        model,
        train_data,
        val_data,
        batch_size=t.batch_size,
        lr=t.lr,
        weight_decay=t.weight_decay,
        weights=weights,
        use_covariance=use_cov,
        plateau_factor=t.plateau_factor,
        plateau_patience=t.plateau_patience,
        seed=t.seed,
        world=world,
        device=resolve_device(t.device),
        min_lr=t.min_lr,
        ema_decay=t.ema_decay,
        val_covariance=t.val_covariance,
    )
    trained_on = TrainedOn(
        rate_hz=float(np.median([1.0 / float(np.median(np.diff(s.t))) for s in train_seqs])),
        datasets=tuple(sorted({spec.dataset for spec in config.data.train})),
        speed_m_s=training_speed(train_seqs),
    )
    history, best = _resume(folder, config, trainer)
    if not agree(trainer.epochs_done, world):
        raise ConfigError(f"{folder}: the ranks read different last.pt files; put the run folder on a shared disk")
    if writer:
        save_config(folder / "config.yaml", config)
    clock = time.perf_counter() - ((history[-1].seconds or 0.0) if history else 0.0)
    while trainer.epochs_done < t.epochs and not _stalled(history, best, t.early_stop_patience):
        entry = trainer.epoch(on_batch=_progress_bar(progress and writer, trainer, history))
        if writer and not motion:  # the other ranks go on to the next epoch and wait for rank 0 in its first step
            with trainer.averaged():
                metrics = [evaluate_model(model, s, config) for s in val_seqs]
            entry = replace(
                entry,
                val_roe_deg=float(np.mean([m.roe_deg for m in metrics])),
                val_rpe_rmse_m=float(np.mean([m.rpe_rmse_m for m in metrics])),
            )
        entry = replace(entry, seconds=time.perf_counter() - clock)
        history.append(entry)
        improved = best is None or entry.val_loss < best.val_loss  # val_loss: rank 0's, on every rank
        best = BestEpoch.from_dict(entry.to_dict()) if improved else best
        if writer:
            _write_epoch(folder, Checkpoint(config, trainer.state_dict(), best, trained_on), history, improved)
            if on_epoch is not None:
                on_epoch(folder, history)
            if progress:
                _epoch_line(config.name, entry, t.epochs)
        log.info("%s epoch %d: %s", config.name, entry.epoch, json.dumps(entry.to_dict()))
    if writer and use_cov and not motion:  # the motion model's variance is trained with it (its NLL term)
        _finish_calibration(folder, config, best, trained_on, trainer)
    if writer and motion:  # a model that gives one velocity whatever it reads trains and validates quietly
        net, _ = motion_from_checkpoint(folder / "best.pt")
        message = collapse_warning(output_spread(net, val_data, t.batch_size), str(folder / "best.pt"))
        if message is not None:
            log.warning("%s", message)
    barrier(world)  # every rank returns once the folder is complete
    return RunSummary(folder, trainer.epochs_done, best.epoch, best.val_loss, best.seconds)


def _write_epoch(folder: Path, checkpoint: Checkpoint, history: list[EpochLog], improved: bool) -> None:
    """An epoch's files: ``best.pt`` if it improved, the metrics log, ``last.pt``."""
    if improved:
        save_checkpoint(folder / "best.pt", checkpoint)
    # the log before last.pt: a resume cuts the log back to last.pt's epochs, so a kill between the two
    # writes repeats this epoch; the other order would lose its line from the log
    _write_metrics(folder / "metrics.jsonl", history)
    save_checkpoint(folder / "last.pt", checkpoint)


def _finish_calibration(
    folder: Path, config: ExperimentConfig, best: BestEpoch, trained_on: TrainedOn, trainer: Trainer
) -> None:
    """Calibrate the best checkpoint if it is not yet (a finished run asked for the scaling later gets it then; the
    second stage is never repeated). ``best.pt`` is written before ``last.pt``: after a kill between the two, the
    record in ``best.pt`` says what was done, and only ``last.pt`` is brought up to date."""
    t = config.train
    stored = load_checkpoint(folder / "best.pt")
    if stored.best is not None and stored.best.epoch == best.epoch:
        best = replace(best, **{name: getattr(stored.best, name) for name in CALIBRATION_FIELDS})
    stage = t.calibration_steps > 0 and not best.calibrated
    scale = t.scale_noise_on_val and best.noise_scales is None
    if stage or scale:
        trainer.model.load_state_dict(stored.trainer["model"])
        best = _calibrate(trainer, replace(best, calibrated=True), t, stage, scale)
        calibrated = Checkpoint(config, stored.trainer, best, trained_on).with_weights(trainer.model.state_dict())
        save_checkpoint(folder / "best.pt", calibrated)
        log.info("calibrated the noise of %s", folder / "best.pt")
    last = load_checkpoint(folder / "last.pt")
    if last.best != best:
        save_checkpoint(folder / "last.pt", Checkpoint(config, last.trainer, best, trained_on))


def _calibrate(trainer: Trainer, best: BestEpoch, t, stage: bool, scale: bool) -> BestEpoch:
    """Second stage on ``trainer.model`` (``train.calibrate_uncertainty``), then the noise scaling on the validation
    windows (``train.fit_noise_scales``), as asked; returns ``best`` with what they did."""
    if stage:
        nll = calibrate_uncertainty(trainer.model, trainer.train, t.calibration_steps, t.batch_size, seed=t.seed)
        best = replace(best, calibration_nll=nll)
    if scale:
        best = replace(best, noise_scales=tuple(float(s) for s in fit_noise_scales(trainer.model, trainer.val)))
        scale_noise(trainer.model, *best.noise_scales)
        log.info("noise scaled by %.3g (gyro) and %.3g (acc) on the validation windows", *best.noise_scales)
    return best


def _resume(folder: Path, config: ExperimentConfig, trainer: Trainer) -> tuple[list[EpochLog], BestEpoch | None]:
    """Restore ``trainer`` from ``folder/last.pt`` if there is one; the metrics log is cut to its epochs."""
    last = folder / "last.pt"
    if not last.exists():
        return [], None
    stored = load_checkpoint(last)
    differs = _differences(to_dict(stored.config), to_dict(config))
    if differs:
        raise ConfigError(
            f"{folder}: the run was started with another config (differs at: {', '.join(differs)}); "
            "use a new output folder or the original config"
        )
    trainer.load_state_dict(stored.trainer)
    history = read_metrics(folder / "metrics.jsonl")[: trainer.epochs_done]
    log.info("resuming %s after epoch %d", folder, trainer.epochs_done)
    return history, stored.best


def read_metrics(path: str | Path) -> list[EpochLog]:
    """A run folder's ``metrics.jsonl`` (none yet: empty); a line that is not an epoch record is a ``DataError``
    naming the file and line."""
    path = Path(path)
    if not path.exists():
        return []
    history = []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        try:
            history.append(EpochLog.from_dict(json.loads(line)))
        except (ValueError, KeyError, TypeError) as error:
            raise DataError(path, "epoch", f"not an epoch record ({error})", line=number) from None
    return history


def _differences(old: dict, new: dict, where: str = "") -> list[str]:
    keys = sorted(set(old) | set(new))
    out = []
    for key in keys:
        path = f"{where}.{key}" if where else key
        if path in RESUMABLE_CHANGES:
            continue
        a, b = old.get(key), new.get(key)
        if isinstance(a, dict) and isinstance(b, dict):
            out += _differences(a, b, path)
        elif a != b:
            out.append(path)
    return out


def _stalled(history: list[EpochLog], best: BestEpoch | None, patience: int) -> bool:
    return bool(history) and stopped_early(history[-1].epoch, best.epoch, patience)


def _write_metrics(path: Path, history: list[EpochLog]) -> None:
    with atomic_file(path) as f:
        f.writelines(json.dumps(entry.to_dict()) + "\n" for entry in history)


def _progress_bar(enabled: bool, trainer: Trainer, history: list[EpochLog]):
    """A per-epoch tqdm bar over batches showing the running loss and the last validation metrics, on a terminal
    only: redrawn bars would flood a log file (there, ``_epoch_line`` writes one line per epoch)."""
    if not enabled or not sys.stderr.isatty():
        return None
    from tqdm.auto import tqdm

    batches = -(-len(trainer.train) // trainer.batch_size)
    bar = tqdm(total=batches, desc=f"epoch {trainer.epochs_done}", leave=False, unit="batch")
    last = history[-1] if history else None
    seen = []

    def on_batch(loss: float) -> None:
        seen.append(loss)
        shown = {"loss": f"{np.mean(seen):.4f}"}
        if last is not None:
            shown["val"] = f"{last.val_loss:.4f}"
            if last.val_roe_deg is not None:
                shown["val_roe"] = f"{last.val_roe_deg:.3f}deg"
        bar.set_postfix(shown, refresh=False)
        bar.update()
        if len(seen) == batches:
            bar.close()

    return on_batch


def _epoch_line(name: str, entry: EpochLog, epochs: int) -> None:
    """One line per finished epoch on stderr (above the bar on a terminal): losses, validation metrics, time."""
    from tqdm.auto import tqdm

    line = f"{name} epoch {entry.epoch + 1}/{epochs}: train_loss {entry.train_loss:.4f}, val_loss {entry.val_loss:.4f}"
    if entry.val_roe_deg is not None:
        line += f", val_roe {entry.val_roe_deg:.3f} deg, val_rpe_rmse {entry.val_rpe_rmse_m:.4f} m"
    tqdm.write(f"{line}, lr {entry.lr:.2g}, {entry.seconds:.1f} s", file=sys.stderr)


def with_epochs(config: ExperimentConfig, epochs: int) -> ExperimentConfig:
    """``config`` with another epoch budget (for quick runs)."""
    return replace(config, train=replace(config.train, epochs=epochs))


def with_device(config: ExperimentConfig, device: str) -> ExperimentConfig:
    """``config`` training on another device (``train.device``: cpu, cuda or auto)."""
    return replace(config, train=replace(config.train, device=device))
