"""``airimu train``, ``ablate-imu``, ``evaluate``, ``export``, ``scale-noise`` and ``export-model``: the training and
model side of the command line (``learned_imu``)."""

from __future__ import annotations

import math

import typer

from airimu.cli.app import (
    READER_OPTION_HELP,
    _check_noise_flags,
    _check_outputs,
    _read_with_options,
    _wide_console,
    app,
)

# (column, field): window-end statistics first (the paper's columns; learned_imu.evaluation.metrics), then
# every-state RMSEs
METRIC_COLUMNS = (
    ("ROE (deg)", "roe_deg"),
    ("ROE RMSE (deg)", "roe_rmse_deg"),
    ("RPE (m)", "rpe_m"),
    ("RPE RMSE (m)", "rpe_rmse_m"),
)
FIELD_LABELS = {
    "roe_deg": "ROE (deg)",
    "rpe_m": "RPE (m)",
    "roe_rmse_deg": "RMSE (deg)",
    "rpe_rmse_m": "P-RMSE (m)",
    "roe_rmse_10f_deg": "R-RMSE (deg)",
    "rpe_rmse_10f_m": "P-RMSE (m)",
    "nse_rot": "NSE rot",
    "nse_pos": "NSE pos",
    "nse_vel": "NSE vel",
}


def _load_config(config: str, data_root: str | None):
    from learned_imu.config import load_config

    return load_config(config, data_root=data_root)


def _overrides(config, epochs: int | None, device: str | None):
    """``--epochs`` and ``--device`` applied to a loaded experiment config (checked like the YAML keys)."""
    from learned_imu.config import DEVICES
    from learned_imu.training.experiment import with_device, with_epochs

    if epochs is not None:
        if epochs < 1:
            raise typer.BadParameter(f"--epochs must be at least 1, got {epochs}")
        config = with_epochs(config, epochs)
    if device is not None:
        if device not in DEVICES:
            raise typer.BadParameter(f"--device must be one of {', '.join(DEVICES)}, got {device!r}")
        config = with_device(config, device)
    return config


@app.command()
def evaluate(
    dataset: str = typer.Option(..., help="reader name: euroc, tumvi, kitti, kitti_raw, broad, rosbag, csv"),
    path: str = typer.Option(..., help="the sequence (EuRoC, TUM-VI: the folder holding mav0/)"),
    interval: float = typer.Option(1.0, help="evaluation interval, in --interval-unit"),
    interval_unit: str = typer.Option("s", help="'s' (seconds) or 'frames' (IMU samples)"),
    imu_file: str = typer.Option(None, help="EuRoC/TUM-VI: IMU csv relative to the sequence folder"),
    reader_option: list[str] = typer.Option(None, help=READER_OPTION_HELP),  # noqa: B008 (typer reads repeats as a list)
    checkpoint: str = typer.Option(None, help="a trained model (best.pt): evaluate its corrected IMU"),
    json_out: str = typer.Option(None, "--json", help="write the metrics to this JSON file"),
) -> None:
    """Integrate a sequence's IMU (raw, or corrected by --checkpoint) over windows restarted from ground truth and
    print the paper's metrics."""
    from rich.table import Table

    from airimu_core.io import write_json_atomic
    from learned_imu.config import INTERVAL_UNITS
    from learned_imu.evaluation.evaluate import evaluate as run_evaluation

    if not (math.isfinite(interval) and interval > 0):
        raise typer.BadParameter(f"--interval must be a positive number, got {interval}")
    if interval_unit not in INTERVAL_UNITS:
        raise typer.BadParameter(f"--interval-unit must be one of {', '.join(INTERVAL_UNITS)}, got {interval_unit!r}")
    _check_outputs(files={"--json": json_out})
    sequence = _read_with_options(dataset, path, reader_option or [], imu_file)
    gyro = acc = None
    label = "raw IMU"
    if checkpoint:
        from learned_imu.network.inference import correct_from_checkpoint

        out = correct_from_checkpoint(checkpoint, sequence)
        gyro, acc, label = out.gyro.numpy(), out.acc.numpy(), f"corrected by {checkpoint}"
    result = run_evaluation(sequence, interval, interval_unit, gyro, acc)
    table = Table(title=f"{result.sequence}: {label}, interval {result.interval_s:.3f} s ({result.n_windows} windows)")
    extra = (
        ("rot RMSE all states (deg)", "rot_rmse_states_deg"),
        ("pos RMSE all states (m)", "pos_rmse_states_m"),
        ("vel RMSE all states (m/s)", "vel_rmse_states_m_s"),
        ("ATE (m)", "ate_m"),
        ("ATE aligned (m)", "ate_aligned_m"),
    )
    names = (*METRIC_COLUMNS, *extra)
    for column, _ in names:
        table.add_column(column)
    table.add_row(*(f"{getattr(result, key):.4g}" for _, key in names))
    _wide_console().print(table)
    if json_out:
        _wide_console().print(f"metrics written to {write_json_atomic(json_out, result.to_json_dict())}")


@app.command()
def train(
    config: str = typer.Option(..., help="experiment config (YAML), e.g. configs/euroc.yaml"),
    out: str = typer.Option(..., help="run folder; an existing run there is resumed"),
    data_root: str = typer.Option(None, help="folder the config's sequence paths are relative to"),
    epochs: int = typer.Option(None, help="override train.epochs"),
    device: str = typer.Option(None, help="override train.device: cpu, cuda or auto"),
    model: str = typer.Option(
        None,
        help="override train.model: correction (AirIMU), motion (body-frame velocity) or both (into "
        "OUT/correction and OUT/motion)",
    ),
    progress: bool = typer.Option(True, help="show progress bars"),
) -> None:
    """Train AirIMU (corrections + uncertainty) or the motion model (body-frame velocity + variance) into a run
    folder: config.yaml, metrics.jsonl, best.pt, last.pt. Launched by torchrun (README: several processes or
    machines), the processes share each batch."""
    import dataclasses
    from pathlib import Path

    from airimu.viz.recording import write_training_recording
    from learned_imu.config import TRAINED_MODELS
    from learned_imu.training.distributed import process_group
    from learned_imu.training.experiment import train_run

    if model is not None and model not in (*TRAINED_MODELS, "both"):
        raise typer.BadParameter(f"--model must be one of {', '.join(TRAINED_MODELS)}, both; got {model!r}")
    cfg = _overrides(_load_config(config, data_root), epochs, device)
    _check_outputs(folders={"--out": out})
    kinds = TRAINED_MODELS if model == "both" else (model or cfg.train.model,)
    for kind in kinds:
        run = dataclasses.replace(cfg, train=dataclasses.replace(cfg.train, model=kind))
        folder = Path(out) / kind if model == "both" else Path(out)
        with process_group() as world:  # training.rrd: the losses and validation metrics in Rerun, every epoch
            summary = train_run(run, folder, progress=progress, world=world, on_epoch=write_training_recording)
        if world is not None and not world.writer:
            continue
        _wide_console().print(
            f"{kind} model: {summary.epochs} epochs; best validation loss {summary.best_val_loss:.5f} at epoch "
            f"{summary.best_epoch} ({summary.seconds_to_best:.0f} s of training); run folder: {summary.folder}"
        )


@app.command("ablate-imu")
def ablate_imu(
    config: str = typer.Option(..., help="experiment config (YAML)"),
    out: str = typer.Option("runs/ablate-imu", help="folder for the trained variants"),
    data_root: str = typer.Option(None, help="folder the config's sequence paths are relative to"),
    epochs: int = typer.Option(None, help="override train.epochs"),
    json_out: str = typer.Option(None, "--json", help="write the table to this JSON file"),
    csv_out: str = typer.Option(None, "--csv", help="write the table to this CSV file"),
    seeds: str = typer.Option(None, help="train the learned variants once per seed, e.g. '0,1,2' (mean +- std)"),
    device: str = typer.Option(None, help="override train.device: cpu, cuda or auto"),
    progress: bool = typer.Option(True, help="show progress bars"),
) -> None:
    """The paper's IMU ablation: Baseline, Average Bias, linear calibration, AirIMU w/o and with covariance loss;
    prints the rows and the paper's tables with its published values beside ours (learned_imu.evaluation.ablation)."""
    from rich.table import Table

    from airimu.viz.recording import write_training_recording
    from learned_imu.evaluation.ablation import ablate, paper_tables, write_rows

    cfg = _overrides(_load_config(config, data_root), epochs, device)
    _check_outputs(files={"--json": json_out, "--csv": csv_out}, folders={"--out": out})
    try:
        seed_list = None if seeds is None else [int(s) for s in seeds.split(",") if s.strip()]
    except ValueError:
        raise typer.BadParameter(f"--seeds must be integers separated by commas, got {seeds!r}") from None
    rows = ablate(cfg, out, progress=progress, seeds=seed_list, on_epoch=write_training_recording)
    console = _wide_console()
    table = Table(title=f"{cfg.name}: IMU ablation, interval {cfg.evaluation.interval} {cfg.evaluation.interval_unit}")
    for column in ("Sequence", "Setting", "Seed", *(c for c, _ in METRIC_COLUMNS), "NSE rot/pos/vel"):
        table.add_column(column)
    for row in rows:
        nse = "-" if row.nse_rot != row.nse_rot else f"{row.nse_rot:.2f}/{row.nse_pos:.2f}/{row.nse_vel:.2f}"
        seed = "-" if row.seed is None else str(row.seed)
        table.add_row(row.sequence, row.variant, seed, *(f"{getattr(row, k):.4g}" for _, k in METRIC_COLUMNS), nse)
    console.print(table)
    if seed_list and len(seed_list) > 1:
        console.print(f"mean +- std over seeds {seeds} in the tables below")
    for paper_table in paper_tables(rows):
        console.print(_paper_table(paper_table))
    write_rows(rows, json_out, csv_out)
    for path in (json_out, csv_out):
        if path:
            console.print(f"table written to {path}")


def _paper_table(paper_table):
    """A rich table: one row per sequence and setting; per field our mean +- std, then the paper's value."""
    from rich.table import Table

    cells = {(c.sequence, c.setting, c.field): c for c in paper_table.cells}
    table = Table(title=paper_table.title)
    table.add_column("Sequence")
    table.add_column("Setting")
    quoted = any(c.paper is not None for c in paper_table.cells)  # the NSE has no paper column
    for field in paper_table.fields:
        table.add_column(FIELD_LABELS.get(field, field), justify="right")
        if quoted:
            table.add_column("paper", style="dim", justify="right")
    for sequence, setting in dict.fromkeys((c.sequence, c.setting) for c in paper_table.cells):
        values = []
        for field in paper_table.fields:
            cell = cells.get((sequence, setting, field))
            values.append("-" if cell is None else _ours(cell))
            if quoted:
                values.append("-" if cell is None or cell.paper is None else f"{cell.paper:.4g}")
        table.add_row(sequence, setting, *values)
    return table


def _ours(cell) -> str:
    if cell.mean is None or cell.mean != cell.mean:
        return "-"
    return f"{cell.mean:.4g}" if cell.seeds <= 1 else f"{cell.mean:.4g} +- {cell.std:.2g}"


@app.command()
def export(
    checkpoint: str = typer.Option(None, help="trained model (best.pt); without it the raw IMU is exported"),
    dataset: str = typer.Option(..., help="reader name: euroc, tumvi, kitti, kitti_raw, broad, rosbag, csv"),
    path: str = typer.Option(..., help="the sequence"),
    keyframes: str = typer.Option("0.1s", help="keyframe interval like '0.1s', or a file of times (s) per line"),
    out: str = typer.Option(..., help="output .npz (format in learned_imu.export)"),
    imu_file: str = typer.Option(None, help="EuRoC/TUM-VI: IMU csv relative to the sequence folder"),
    reader_option: list[str] = typer.Option(None, help=READER_OPTION_HELP),  # noqa: B008 (typer reads repeats as a list)
    gyro_noise_density: float = typer.Option(
        None, help="without --checkpoint: gyro noise density, sigma, rad/s/sqrt(Hz) (Kalibr)"
    ),
    acc_noise_density: float = typer.Option(
        None, help="without --checkpoint: acc noise density, sigma, m/s^2/sqrt(Hz) (Kalibr)"
    ),
) -> None:
    """Export corrected samples, their learned noise and preintegrated keyframe deltas + covariances for GTSAM."""
    from learned_imu.export import export_preintegration, keyframes_from_spec

    if checkpoint and (gyro_noise_density is not None or acc_noise_density is not None):
        raise typer.BadParameter(
            "--gyro-noise-density / --acc-noise-density apply without --checkpoint only (the model predicts the "
            "IMU's noise); drop them, or --checkpoint to export the raw IMU with them"
        )
    _check_outputs(files={"--out": out})
    sequence = _read_with_options(dataset, path, reader_option or [], imu_file)
    index = keyframes_from_spec(sequence, keyframes)
    if checkpoint:
        from learned_imu.network.inference import correct_from_checkpoint

        written = export_preintegration(out, sequence, index, correction=correct_from_checkpoint(checkpoint, sequence))
    else:
        if gyro_noise_density is None or acc_noise_density is None:
            raise typer.BadParameter("without --checkpoint, give --gyro-noise-density and --acc-noise-density")
        _check_noise_flags(gyro_noise_density, acc_noise_density)
        written = export_preintegration(out, sequence, index, gyro_noise_density**2, acc_noise_density**2)
    _wide_console().print(f"{len(index) - 1} keyframe intervals of {sequence.name} written to {written}")


@app.command("scale-noise")
def scale_noise_command(
    checkpoint: str = typer.Option(..., help="trained model (best.pt)"),
    dataset: str = typer.Option(..., help="reader name of a held-out sequence with ground truth"),
    path: str = typer.Option(..., help="the held-out sequence (not trained on, not evaluated on)"),
    out: str = typer.Option(..., help="the scaled checkpoint to write (may be CHECKPOINT itself)"),
    imu_file: str = typer.Option(None, help="EuRoC/TUM-VI: IMU csv relative to the sequence folder"),
    reader_option: list[str] = typer.Option(None, help=READER_OPTION_HELP),  # noqa: B008 (typer reads repeats as a list)
) -> None:
    """Scale a trained model's noise densities (one factor per sensor) to a held-out sequence's windows by maximum
    likelihood, so that its covariance is calibrated on data it has not seen
    (learned_imu.training.train.noise_residuals)."""
    from learned_imu.training.noise_scaling import scale_checkpoint_noise

    _check_outputs(files={"--out": out})
    sequence = _read_with_options(dataset, path, reader_option or [], imu_file)
    done = scale_checkpoint_noise(checkpoint, sequence, out)
    (gyro, acc), before, after = done.scales, done.nse_before, done.nse_after
    _wide_console().print(
        f"noise scaled by {gyro:.3g} (gyro) and {acc:.3g} (acc) on {sequence.name}; NSE rot/pos/vel "
        f"{before[0]:.2f}/{before[1]:.2f}/{before[2]:.2f} -> {after[0]:.2f}/{after[1]:.2f}/{after[2]:.2f}; "
        f"written to {done.path}"
    )


@app.command("export-model")
def export_model(
    checkpoint: str = typer.Option(..., help="trained model (best.pt)"),
    format: str = typer.Option(..., "--format", help="'torchscript' or 'onnx' (needs the deploy extra)"),
    out: str = typer.Option(..., help="output file, e.g. airimu.onnx or airimu.pt"),
) -> None:
    """Write the model's streaming step as a file that runs without this package (TorchScript or ONNX, explicit
    GRU/convolution state in and out; conventions in learned_imu.network.deploy)."""
    from learned_imu.network.deploy import export_checkpoint

    _check_outputs(files={"--out": out})
    written = export_checkpoint(checkpoint, out, format)
    _wide_console().print(f"{format} model of {checkpoint} written to {written}")


@app.command("noise")
def noise_command(
    dataset: str = typer.Option(..., help="reader name: euroc, tumvi, kitti, kitti_raw, broad, rosbag, csv"),
    path: str = typer.Option(..., help="a recording with a still stretch"),
    out: str = typer.Option(..., help="folder for imu_kalibr.yaml, gtsam_preintegration.yaml, allan.json, allan.png"),
    start: float = typer.Option(0.0, help="the still stretch's start, s from the first sample"),
    end: float = typer.Option(None, help="its end, s from the first sample (default: the recording's end)"),
    reader_option: list[str] = typer.Option(None, help=READER_OPTION_HELP),  # noqa: B008 (typer reads repeats as a list)
    datasheet: list[str] = typer.Option(  # noqa: B008
        None,
        help="a datasheet value to show beside, KEY=VALUE UNIT (repeatable): KEY a Kalibr name "
        "(gyroscope_noise_density, ...), UNIT one of deg/sqrt(h), deg/h, deg/s/sqrt(Hz), rad/s/sqrt(Hz), "
        "ug/sqrt(Hz), mg/sqrt(Hz), m/s/sqrt(h), m/s^2/sqrt(Hz), mg, ug",
    ),
) -> None:
    """Noise densities from a still recording: the Allan deviation of each axis (allantools), white noise, bias
    instability and random walk fitted, written in Kalibr's names and as GTSAM's continuous-time covariances, and
    plotted (learned_imu.evaluation.allan, airimu.noise)."""
    from pathlib import Path

    from airimu.noise import still_noise, write_noise
    from learned_imu.evaluation.allan import from_datasheet

    if not (math.isfinite(start) and start >= 0) or (end is not None and not (math.isfinite(end) and end > start)):
        raise typer.BadParameter(f"--start / --end: need 0 <= start < end (s), got {start}, {end}")
    _check_outputs(folders={"--out": out})
    sheet = {}
    for item in datasheet or []:
        key, _, rest = item.partition("=")
        value, _, unit = rest.strip().partition(" ")
        try:
            sheet[key] = from_datasheet(float(value), unit.strip())
        except ValueError:
            raise typer.BadParameter(f"--datasheet: expected KEY=VALUE UNIT, got {item!r}") from None
    sequence = _read_with_options(dataset, path, reader_option or [])
    result = still_noise(sequence, start, end)
    written = write_noise(result, Path(out), sheet)
    kalibr = result.kalibr()
    console = _wide_console()
    for key, value in kalibr.items():
        beside = f"   (datasheet {sheet[key]:.3g})" if key in sheet else ""
        console.print(f"{key}: {'-' if value is None else f'{value:.3g}'}{beside}")
    for path_written in written:
        console.print(f"written: {path_written}")


@app.command("models")
def models_command() -> None:
    """The models installed with the package (use the name as --checkpoint / --motion), each with its card: what
    it was trained on, the IMU and rate, the metrics it reaches and where, the data's licence."""
    from learned_imu.network.shipped import SHIPPED_DIR, shipped_models

    console = _wide_console()
    cards = shipped_models()
    if not cards:
        console.print(f"no models installed in {SHIPPED_DIR}")
        return
    for name, card in cards.items():
        size = (SHIPPED_DIR / f"{name}.pt").stat().st_size / 1e6
        console.print(f"[bold]{name}[/bold] ({card['kind']}, {size:.2f} MB): {card['summary']}")
        console.print(f"  trained on: {card['trained_on']}")
        console.print(f"  IMU: {card['imu']}, {card['rate_hz']:g} Hz (other rates are refused)")
        for metric in card["metrics"]:
            console.print(f"  measured: {metric}")
        console.print(f"  licence of the training data: {card['licence']}")
        console.print(f"  trained with: {card['command']}")
