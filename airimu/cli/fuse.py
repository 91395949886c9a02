"""``airimu demo``, ``ablate-pgo``, ``fuse`` and ``view``: the fusion side of the command line."""

from __future__ import annotations

import dataclasses
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
    _run_pgo(
        config,
        folder,
        folder / "ablation.json",
        folder / "ablation.csv",
        folder / "demo.rrd",
        folder / "demo.png",
        epochs,
        progress,
    )


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


GPS_HELP = "GPS CSV (t,x,y,z or t,lat,lon,alt; optional sigma columns); default: the log's own fixes"


@app.command()
def fuse(
    dataset: str = typer.Option(..., help="reader name: euroc, kitti, kitti_raw, broad, rosbag, csv"),
    path: str = typer.Option(
        ...,
        help="the IMU log (file or folder, as the reader takes it); with --dataset kitti, 'gtsam': the drive "
        "installed with gtsam (nothing to download)",
    ),
    out: str = typer.Option(..., help="folder for fused.tum, marginals.npz, fused.rrd, fused.png, summary.json"),
    config: str = typer.Option(
        "fuse.yaml", help="fusion config (YAML; default the shipped configs/fuse.yaml); the flags below override it"
    ),
    gps: str = typer.Option(None, help=GPS_HELP),
    gps_sigma: float = typer.Option(
        None,
        help="GPS one-sigma per axis (m): for a --gps file without sigma columns, or replacing the sigmas of "
        "the log's own fixes; default: config gps_sigma_m (files) or the reader's (the log's fixes)",
    ),
    gps_every: int = typer.Option(1, help="fuse every n-th fix (all of them score the result)"),
    checkpoint: str = typer.Option(None, help="a trained model; without it the raw IMU with fixed noise"),
    bias: bool = typer.Option(
        None, "--bias/--no-bias", help="estimate a bias state per keyframe (config: estimate_bias)"
    ),
    keyframes: str = typer.Option(
        None,
        help="a keyframe at every fused fix always; an interval like '1s' adds keyframes between them "
        "('fixes': none); default: config keyframe_s",
    ),
    gyro_noise_density: float = typer.Option(
        None, help="gyro sigma, rad/s/sqrt(Hz), without --checkpoint only; default: config gyro_noise_density"
    ),
    acc_noise_density: float = typer.Option(
        None, help="acc sigma, m/s^2/sqrt(Hz), without --checkpoint only; default: config acc_noise_density"
    ),
    reader_option: list[str] = typer.Option(None, help=READER_OPTION_HELP),  # noqa: B008 (typer reads repeats as a list)
    gps_time_offset: float = typer.Option(
        0.0,
        help="seconds the GPS clock runs ahead of the IMU's, subtracted from every fix time (a GPS track that "
        "fits the IMU far better shifted is warned about with its estimated offset)",
    ),
    motion: str = typer.Option(
        None, help="a trained motion model (airimu train --model motion): learned body-frame velocity factors"
    ),
    start: str = typer.Option(
        None,
        help="the state at the log's first IMU sample: 'ground-truth' (the log's own) or 10 numbers "
        "'x,y,z,qw,qx,qy,qz,vx,vy,vz' (position m, quaternion w first, world <- IMU, velocity m/s, world frame); "
        "default: aligned to the GPS track. Needed with --no-gps",
    ),
    no_gps: bool = typer.Option(False, "--no-gps", help="fuse no GPS fix: dead reckoning from --start"),
    trust_model: bool = typer.Option(
        False,
        "--trust-model",
        help="fuse with --checkpoint even where its corrected samples fit the GPS track 3x worse than the raw ones",
    ),
    gps_outage: list[str] = typer.Option(  # noqa: B008 (typer reads repeats as a list)
        None,
        help="START:DURATION, s from the log's first sample: the fixes inside are not fused (they still score the "
        "result); repeatable. Shaded in fused.rrd and fused.png; summary.json gives the error at each one's end",
    ),
) -> None:
    """Fuse a user's own IMU + GPS log: GPS factors (robust with the config's graph.gps_robust), learned (or fixed)
    IMU factors, optional bias states.

    Settings come from --config (configs/fuse.yaml by default: noise, GPS, keyframes, bias states, priors, solver);
    the flags override it. Writes to --out: fused.tum (the estimated keyframe states, TUM: t x y z qx qy qz qw,
    world <- IMU), fused_imu_rate.tum (every IMU sample: each keyframe's state carried forward by the IMU to the next
    one; compare this one with evo against a ground truth), marginals.npz (keyframe positions and their 3x3
    covariances), fused.rrd (Rerun), fused.png and summary.json (RMSE against the fixes; with ground truth, the ATE
    after an SE(3) alignment and without one). Given noise densities 100x under or 10x over the samples' own white
    noise are warned about, naming both; GPS files that fit the IMU far better in another unit (lat/lon in radians,
    x/y/z in km or mm) or with two columns swapped are refused; a GPS clock offset is warned about with its
    estimate."""
    from pathlib import Path

    from airimu.fuse import FuseRequest, run_fuse

    if gps_every < 1:
        raise typer.BadParameter(f"--gps-every must be >= 1, got {gps_every}")
    if not (math.isfinite(gps_time_offset) and abs(gps_time_offset) <= 3600.0):
        raise typer.BadParameter(f"--gps-time-offset: expected seconds within +-3600, got {gps_time_offset}")
    if gps_sigma is not None and not (math.isfinite(gps_sigma) and gps_sigma > 0):
        raise typer.BadParameter(f"--gps-sigma: expected a positive one-sigma in m, got {gps_sigma}")
    _check_outputs(folders={"--out": out})
    given = (gyro_noise_density, acc_noise_density)
    if checkpoint and any(v is not None for v in given):
        raise typer.BadParameter(
            "--gyro-noise-density / --acc-noise-density apply without --checkpoint only: the model predicts the "
            "IMU's noise"
        )
    if (gyro_noise_density is None) != (acc_noise_density is None):
        raise typer.BadParameter("give both --gyro-noise-density and --acc-noise-density, or neither")
    if gyro_noise_density is not None:
        _check_noise_flags(gyro_noise_density, acc_noise_density)
    outages = tuple(_outage(text) for text in gps_outage or [])
    start_state = _start(start)
    if no_gps and (gps or outages):
        raise typer.BadParameter("--no-gps fuses no fix: leave out --gps and --gps-outage")
    if no_gps and start_state is None:
        raise typer.BadParameter("--no-gps needs --start (ground-truth, or the first state's 10 numbers)")
    sequence = _read_with_options(dataset, path, reader_option or [])
    if not gps and sequence.gps is None and not no_gps:
        raise typer.BadParameter(f"{path}: the log has no GPS fixes; pass --gps FILE, or --no-gps with --start")
    request = FuseRequest(
        sequence=sequence,
        source=path,
        out=Path(out),
        config=_fuse_config(config, gps_sigma, bias, keyframes, gyro_noise_density, acc_noise_density),
        gps_file=gps,
        gps_sigma_m=gps_sigma,
        gps_every=gps_every,
        gps_time_offset_s=gps_time_offset,
        checkpoint=checkpoint,
        motion_checkpoint=motion,
        start=start_state,
        no_gps=no_gps,
        outages=outages,
        trust_model=trust_model,
    )
    done = run_fuse(request)
    summary = done.summary
    console = _wide_console()
    against = (
        f"RMSE against all {summary.reference_fixes} fixes {summary.rmse_to_gps_m:.3f} m"
        if summary.rmse_to_gps_m is not None
        else "no fix to score against"
    )
    console.print(
        f"fused {done.fused_fixes} fixes and {summary.motion_factors} motion factors over {summary.keyframes} "
        f"keyframes of {summary.sequence}: {against}"
        + (
            f", ATE against the ground truth {summary.ate_aligned_m:.3f} m SE(3)-aligned, "
            f"{summary.ate_unaligned_m:.3f} m unaligned"
            if summary.ate_aligned_m is not None
            else ""
        )
    )
    fits = ", ".join(f"{kind} {r['chi2_per_dof']:.3g}" for kind, r in (summary.normalised_residuals or {}).items())
    console.print(f"normalised residuals (chi-square per degree of freedom, about 1 when the inputs fit): {fits}")
    for outage in summary.outages or []:
        errors = [
            f"{value:.3f} m against the {name}"
            for name, value in (("ground truth", outage["error_to_truth_m"]), ("GPS", outage["error_to_gps_m"]))
            if value is not None
        ]
        console.print(
            f"GPS outage {outage['start_s']:g}+{outage['duration_s']:g} s: at its end "
            + (", ".join(errors) if errors else "nothing to score against")
        )
    for item in done.written:
        console.print(f"written: {item}")


def _outage(text: str) -> tuple[float, float]:
    """``--gps-outage START:DURATION`` -> (start, duration), s."""
    parts = text.split(":")
    try:
        begin, duration = (float(p) for p in parts) if len(parts) == 2 else (math.nan, math.nan)
    except ValueError:
        begin = duration = math.nan
    if not (math.isfinite(begin) and math.isfinite(duration) and begin >= 0 and duration > 0):
        raise typer.BadParameter(f"--gps-outage: expected START:DURATION in s (START >= 0, DURATION > 0), got {text!r}")
    return begin, duration


def _start(text: str | None):
    """``--start``: None, 'ground-truth', or a ``gtsam.NavState`` from 10 numbers (help text)."""
    if text is None or text == "ground-truth":
        return text
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 10 or not all(math.isfinite(v) for v in values):
        raise typer.BadParameter(
            f"--start: expected 'ground-truth' or 10 numbers x,y,z,qw,qx,qy,qz,vx,vy,vz, got {text!r}"
        )
    quat = values[3:7]
    norm = math.sqrt(sum(q * q for q in quat))
    if abs(norm - 1.0) > 1e-3:
        raise typer.BadParameter(f"--start: the quaternion (qw, qx, qy, qz) must have unit norm, got {norm:.6g}")
    import gtsam

    rot = gtsam.Rot3.Quaternion(*(q / norm for q in quat))
    return gtsam.NavState(rot, values[:3], values[7:])


def _fuse_config(path: str, gps_sigma, bias, keyframes, gyro_noise_density, acc_noise_density):
    """The config file with the flags that were given laid over it (each checked as the file's keys are)."""
    from fusion.config import load_fuse_config, with_overrides

    config = load_fuse_config(path)
    keyframe_s = None
    if keyframes is not None and keyframes != "fixes":
        try:
            keyframe_s = float(keyframes.removesuffix("s"))
        except ValueError:
            raise typer.BadParameter(
                f"--keyframes: expected 'fixes' or an interval like '1s', got {keyframes!r}"
            ) from None
        if not (math.isfinite(keyframe_s) and keyframe_s > 0):
            raise typer.BadParameter(f"--keyframes: the interval must be positive, got {keyframes!r}")
    config = with_overrides(
        config,
        gps_sigma_m=gps_sigma,
        estimate_bias=bias,
        keyframe_s=keyframe_s,
        gyro_noise_density=gyro_noise_density,
        acc_noise_density=acc_noise_density,
    )
    if keyframes == "fixes":
        config = dataclasses.replace(config, keyframe_s=None)
    return config


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
