"""The ``airimu`` command line: load, call one library function, print. Heavy imports happen inside commands."""

from __future__ import annotations

import math

import typer

app = typer.Typer(add_completion=False, no_args_is_help=True, help="AirIMU: learned IMU factors for GTSAM.")


@app.callback()
def _root() -> None:
    """AirIMU: learned IMU correction and uncertainty, preintegrated into GTSAM factors."""


@app.command()
def demo(
    out: str = typer.Option("airimu-demo", help="folder for the demo's run, exports, tables and recording"),
    seeds: int = typer.Option(10, help="GPS noise seeds per setting and rate"),
    epochs: int = typer.Option(None, help="override the demo model's training epochs"),
    progress: bool = typer.Option(True, help="show progress bars"),
) -> None:
    """The main job on the embedded simulator (no files needed): train a small AirIMU model, export, run the PGO
    ablation at 1 Hz and 0.1 Hz GPS, print the tables, write demo.rrd and demo.png."""
    import dataclasses
    from pathlib import Path

    from airimu.experiments.pgo_config import load_pgo_config

    folder = Path(out)
    config = load_pgo_config("pgo_demo.yaml")  # the shipped config (package airimu_configs)
    config = dataclasses.replace(
        config, run=str(folder / "run"), options=dataclasses.replace(config.options, seeds=seeds)
    )
    _run_pgo(config, folder, folder / "ablation.json", folder / "ablation.csv", folder / "demo.rrd",
             folder / "demo.png", epochs, progress)  # fmt: skip


@app.command("ablate-pgo")
def ablate_pgo(
    config: str = typer.Option(..., help="PGO ablation config (YAML), e.g. configs/pgo_euroc.yaml"),
    out: str = typer.Option("runs/ablate-pgo", help="folder for the exports"),
    json_out: str = typer.Option(None, "--json", help="write the table to this JSON file"),
    csv_out: str = typer.Option(None, "--csv", help="write the table to this CSV file"),
    rrd: str = typer.Option(None, help="write a Rerun recording of the first sequence"),
    png: str = typer.Option(None, help="write a PNG of the first sequence's trajectories"),
    data_root: str = typer.Option(None, help="folder the experiment's sequence paths are relative to"),
    epochs: int = typer.Option(None, help="override the model's training epochs (if it still trains)"),
    progress: bool = typer.Option(True, help="show progress bars"),
) -> None:
    """The paper's PGO ablation: raw/AirIMU samples x fixed/learned covariance, GPS at each rate, ATE mean +- std."""
    from airimu.experiments.pgo_config import load_pgo_config

    _run_pgo(load_pgo_config(config), out, json_out, csv_out, rrd, png, epochs, progress, data_root)


def _run_pgo(config, out, json_out, csv_out, rrd, png, epochs, progress, data_root=None) -> None:
    from rich.table import Table

    if epochs is not None and epochs < 1:
        raise typer.BadParameter(f"--epochs must be at least 1, got {epochs}")
    _check_outputs(files={"--json": json_out, "--csv": csv_out, "--rrd": rrd, "--png": png}, folders={"--out": out})

    from airimu.experiments.pgo import ablate_pgo as run
    from airimu.experiments.pgo import paper_ate, record, write_table
    from airimu.viz.figures import plot
    from airimu_core.io import folder_lock

    console = _wide_console()
    with folder_lock(out):  # one writer per folder: a second ablate-pgo into it is refused, naming this one
        results = run(config, out, progress=progress, data_root=data_root, epochs=epochs)
    rows = [row for result in results for row in result.rows]
    quoted = any(paper_ate(r) is not None for r in rows)  # the paper's sequences: its ATE beside ours
    for sequence in dict.fromkeys(r.sequence for r in rows):  # one table per sequence: settings x GPS rates
        mine = [r for r in rows if r.sequence == sequence]
        rates = sorted({r.gps_hz for r in mine}, reverse=True)
        table = Table(title=f"{config.name}, {sequence}: ATE (m), mean +- std over {config.options.seeds} GPS seeds")
        table.add_column("Setting")
        for rate in rates:
            table.add_column(f"GPS {rate:g} Hz", justify="right")
            if quoted:
                table.add_column("paper", style="dim", justify="right")
        for setting in dict.fromkeys(r.setting for r in mine):
            cells = {r.gps_hz: r for r in mine if r.setting == setting}
            values = []
            for rate in rates:
                values.append(f"{cells[rate].ate_mean_m:.3f} +- {cells[rate].ate_std_m:.3f}")
                if quoted:
                    ref = paper_ate(cells[rate])
                    values.append("-" if ref is None else f"{ref:.4f}")
            table.add_row(setting, *values)
        console.print(table)
    write_table(rows, json_out, csv_out)
    written = [p for p in (json_out, csv_out) if p]
    if rrd:
        written.append(record(results[0], rrd))
    if png:
        written.append(plot(results[0], png))
    for path in written:
        console.print(f"written: {path}")


READER_OPTION_HELP = (
    "a reader option as key=value (repeatable): e.g. on_backward=drop, on_duplicate=drop, on_gap=keep; lists as "
    "gt_pos=px,py,pz or gt_pos=[px,py,pz]"
)
GPS_HELP = "GPS CSV (t,x,y,z or t,lat,lon,alt; optional sigma columns); default: the log's own fixes"


@app.command()
def fuse(
    dataset: str = typer.Option(..., help="reader name: euroc, kitti, kitti_raw, broad, rosbag, csv"),
    path: str = typer.Option(..., help="the IMU log (file or folder, as the reader takes it)"),
    out: str = typer.Option(..., help="folder for fused.tum, marginals.npz, fused.rrd, fused.png, summary.json"),
    gps: str = typer.Option(None, help=GPS_HELP),
    gps_sigma: float = typer.Option(None, help="GPS one-sigma per axis (m) where the file gives none"),
    gps_every: int = typer.Option(1, help="fuse every n-th fix (all of them score the result)"),
    checkpoint: str = typer.Option(None, help="a trained model; without it the raw IMU with fixed noise"),
    bias: bool = typer.Option(False, help="estimate a bias state per keyframe"),
    keyframes: str = typer.Option("fixes", help="'fixes' (a keyframe at every fused fix) or an interval like '1s'"),
    gyro_noise_density: float = typer.Option(
        None, help="gyro sigma, rad/s/sqrt(Hz), without --checkpoint only (refused with it); default 0.004"
    ),
    acc_noise_density: float = typer.Option(
        None, help="acc sigma, m/s^2/sqrt(Hz), without --checkpoint only (refused with it); default 0.08"
    ),
    reader_option: list[str] = typer.Option(None, help=READER_OPTION_HELP),  # noqa: B008 (typer reads repeats as a list)
    gps_time_offset: float = typer.Option(
        0.0, help="seconds the GPS clock runs ahead of the IMU's, subtracted from every fix time (a GPS track that "
        "fits the IMU far better shifted is warned about with its estimated offset)",
    ),
) -> None:
    """Fuse a user's own IMU + GPS log: robust GPS factors, learned (or fixed) IMU factors, optional bias states.

    Writes to --out: fused.tum (the estimated keyframe states, TUM: t x y z qx qy qz qw, world <- IMU),
    fused_imu_rate.tum (every IMU sample: each keyframe's state carried forward by the IMU to the next one; compare
    this one with evo against a ground truth), marginals.npz (keyframe positions and their 3x3 covariances),
    fused.rrd (Rerun), fused.png and summary.json (RMSE against the fixes; with ground truth, the ATE after an SE(3)
    alignment and without one). Given noise densities 3x under or 10x over the samples' own white noise are warned
    about, naming both; GPS files that fit the IMU far better in another unit (lat/lon in radians, x/y/z in km or
    mm) or with two columns swapped are refused; a GPS clock offset is warned about with its estimate."""
    from pathlib import Path

    from airimu.fuse import BiasStates, check_gps_clock, check_gps_units, fuse, read_gps_csv, write_outputs

    if gps_every < 1:
        raise typer.BadParameter(f"--gps-every must be >= 1, got {gps_every}")
    if not (math.isfinite(gps_time_offset) and abs(gps_time_offset) <= 3600.0):
        raise typer.BadParameter(f"--gps-time-offset: expected seconds within +-3600, got {gps_time_offset}")
    _check_outputs(folders={"--out": out})
    given = (gyro_noise_density, acc_noise_density)
    if checkpoint and any(v is not None for v in given):
        raise typer.BadParameter(
            "--gyro-noise-density / --acc-noise-density apply without --checkpoint only: the model predicts the "
            "IMU's noise"
        )
    if (gyro_noise_density is None) != (acc_noise_density is None):
        raise typer.BadParameter("give both --gyro-noise-density and --acc-noise-density, or neither")
    noise = None if gyro_noise_density is None else (gyro_noise_density, acc_noise_density)
    if noise is not None:
        _check_noise_flags(*noise)
    keyframe_s = None
    if keyframes != "fixes":
        try:
            keyframe_s = float(keyframes.removesuffix("s"))
        except ValueError:
            raise typer.BadParameter(
                f"--keyframes: expected 'fixes' or an interval like '1s', got {keyframes!r}"
            ) from None
        if not (math.isfinite(keyframe_s) and keyframe_s > 0):
            raise typer.BadParameter(f"--keyframes: the interval must be positive, got {keyframes!r}")
    sequence = _read_with_options(dataset, path, reader_option or [])
    fixes = read_gps_csv(gps, gps_sigma) if gps else sequence.gps
    if gps:
        check_gps_units(sequence, gps, fixes, gps_sigma)
    if fixes is None:
        raise typer.BadParameter(f"{path}: the log has no GPS fixes; pass --gps FILE")
    if gps_time_offset:
        import dataclasses

        fixes = dataclasses.replace(fixes, t=fixes.t - gps_time_offset)
    check_gps_clock(sequence, gps or path, fixes)
    used = fixes[::gps_every]
    model = None
    if checkpoint:
        from learned_imu.network.checkpoint import model_from_checkpoint

        model = model_from_checkpoint(checkpoint)[0]
    states = BiasStates(1.67e-4, 2.91e-6, 0.1, 0.01, factor="combined") if bias else None  # CombinedImuFactor
    from airimu_core.io import folder_lock

    with folder_lock(out):  # one writer per folder from here on: a second fuse into it is refused, naming this one
        result = fuse(sequence, used, model, keyframe_s=keyframe_s, bias=states, noise_density=noise)
        summary, written = write_outputs(result, Path(out), reference=fixes)
    console = _wide_console()
    console.print(
        f"fused {len(result.gps.t)} fixes over {len(result.solution.trajectory.t)} keyframes of {sequence.name}: "
        f"RMSE against all {summary.reference_fixes} fixes {summary.rmse_to_gps_m:.3f} m"
        + (
            f", ATE against the ground truth {summary.ate_aligned_m:.3f} m SE(3)-aligned, "
            f"{summary.ate_unaligned_m:.3f} m unaligned"
            if summary.ate_aligned_m is not None
            else ""
        )
    )
    fits = ", ".join(f"{kind} {r['chi2_per_dof']:.3g}" for kind, r in (summary.normalised_residuals or {}).items())
    console.print(f"normalised residuals (chi-square per degree of freedom, about 1 when the inputs fit): {fits}")
    for item in written:
        console.print(f"written: {item}")


def _check_noise_flags(gyro: float, acc: float) -> None:
    from airimu_core.config import check_noise_density
    from airimu_core.errors import ConfigError

    try:
        check_noise_density("gyro", gyro, "--gyro-noise-density")
        check_noise_density("acc", acc, "--acc-noise-density")
    except ConfigError as error:
        raise typer.BadParameter(str(error)) from None


def _read_with_options(dataset: str, path: str, options: list[str], imu_file: str | None = None):
    """One sequence read with ``key=value`` reader options, each checked against the reader's signature
    (``learned_imu.datasets.check_options``). Values are YAML (``gravity=9.81``, ``header=true``); a list option
    takes ``gt_pos=px,py,pz`` or ``gt_pos=[px,py,pz]`` alike (column names or 0-based indices)."""
    import inspect

    import yaml

    from learned_imu.datasets import READERS, read_sequence

    if dataset not in READERS:
        raise typer.BadParameter(f"--dataset: unknown reader {dataset!r}; known: {', '.join(sorted(READERS))}")
    parsed = {"imu_file": imu_file} if imu_file else {}
    signature = inspect.signature(READERS[dataset]).parameters.items()
    lists = {name for name, p in signature if "Sequence[" in str(p.annotation)}
    for item in options:
        key, sep, text = item.partition("=")
        if not sep or not key:
            raise typer.BadParameter(f"--reader-option: expected key=value, got {item!r}")
        if key in lists and "," in text and not text.lstrip().startswith("["):
            text = f"[{text}]"  # gt_pos=px,py,pz reads as gt_pos=[px,py,pz]
        try:
            parsed[key] = yaml.safe_load(text)
        except yaml.YAMLError:
            parsed[key] = text
    return read_sequence(dataset, path, **parsed)


@app.command()
def view(recording: str = typer.Argument(..., help="an .rrd written by demo/ablate-pgo --rrd")) -> None:
    """Open a recording in the Rerun viewer."""
    import subprocess
    import sys
    from pathlib import Path

    if not Path(recording).is_file():
        raise typer.BadParameter(f"{recording}: no such recording")
    with open(recording, "rb") as f:
        magic = f.read(3)
    if magic != b"RRF":  # every .rrd starts so (RRF2 today); the viewer's own error for another file is opaque
        raise typer.BadParameter(f"{recording}: not a Rerun recording (an .rrd starts with 'RRF', this with {magic!r})")
    raise typer.Exit(subprocess.call([sys.executable, "-m", "rerun", recording]))


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
    progress: bool = typer.Option(True, help="show progress bars"),
) -> None:
    """Train AirIMU (corrections + uncertainty) into a run folder: config.yaml, metrics.jsonl, best.pt, last.pt.
    Launched by torchrun (README: several processes or machines), the processes share each batch."""
    from airimu.viz.recording import write_training_recording
    from learned_imu.training.distributed import process_group
    from learned_imu.training.experiment import train_run

    cfg = _overrides(_load_config(config, data_root), epochs, device)
    _check_outputs(folders={"--out": out})
    with process_group() as world:  # out/training.rrd: the losses and validation metrics in Rerun, every epoch
        summary = train_run(cfg, out, progress=progress, world=world, on_epoch=write_training_recording)
    if world is not None and not world.writer:
        return
    _wide_console().print(
        f"{summary.epochs} epochs; best validation loss {summary.best_val_loss:.5f} at epoch {summary.best_epoch} "
        f"({summary.seconds_to_best:.0f} s of training); run folder: {summary.folder}"
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


def _check_outputs(files: dict | None = None, folders: dict | None = None) -> None:
    """Output flags of the wrong kind refused before any work: a file flag naming a folder, a folder flag a file."""
    from pathlib import Path

    for flag, value in (files or {}).items():
        if value and Path(value).is_dir():
            raise typer.BadParameter(f"{flag}: {value} is a folder; give the path of a file to write")
    for flag, value in (folders or {}).items():
        if value and Path(value).exists() and not Path(value).is_dir():
            raise typer.BadParameter(f"{flag}: {value} is a file; give a folder")


def _wide_console():
    """A rich console; 150 columns when not a terminal (logs, pipes), so the tables do not wrap; lines of text
    (paths) are never wrapped either (soft wrap)."""
    import sys

    from rich.console import Console

    return Console(width=None if sys.stdout.isatty() else 150, soft_wrap=True)


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


def main() -> None:
    """Console entry point: the toolkit's own errors (bad files, configs, checkpoints, exports, graphs) print as
    one line (``AIRIMU_DEBUG=1``: the traceback)."""
    import os
    import sys

    try:
        code = app(standalone_mode=False)  # typer's own usage errors come back here, to print as one line too
    except typer.TyperException as error:  # a bad flag or value: typer itself would draw a multi-line box
        context = getattr(error, "ctx", None)
        command = context.command_path if context is not None and context.command_path else "airimu"
        print(f"airimu: error: {' '.join(error.format_message().split())} (see {command} --help)", file=sys.stderr)
        sys.exit(2)
    except typer.Abort:
        print("airimu: aborted", file=sys.stderr)
        sys.exit(1)
    except Exception as error:
        if os.environ.get("AIRIMU_DEBUG") or not isinstance(error, _own_errors()):
            raise
        print(f"airimu: error: {error}", file=sys.stderr)
        sys.exit(2)
    sys.exit(code if isinstance(code, int) else 0)


def _own_errors() -> tuple[type, ...]:
    """The toolkit's error types among the loaded modules (a command loads those it can raise): one line each."""
    import sys

    names = {
        "airimu_core.errors": ("AirImuError",),
        "factors.export_file": ("ExportError",),
        "factors.checks": ("GraphError",),
        "factors.pim_from_deltas": ("PimLayoutError",),
    }
    return tuple(getattr(sys.modules[m], n) for m, ns in names.items() if m in sys.modules for n in ns)
