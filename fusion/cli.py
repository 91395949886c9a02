"""The ``airimu`` command line: load, call one library function, print. Heavy imports happen inside commands."""

from __future__ import annotations

import typer

app = typer.Typer(add_completion=False, no_args_is_help=True, help="AirIMU: learned IMU factors for GTSAM.")


@app.callback()
def _root() -> None:
    """AirIMU: learned IMU correction and uncertainty, preintegrated into GTSAM factors."""


@app.command()
def demo(
    duration: float = typer.Option(60.0, help="length of the simulated sequence, s"),
    seed: int = typer.Option(0, help="simulator seed"),
) -> None:
    """Run the main job on the embedded simulator (no files needed)."""
    from fusion.demo import run_demo

    run_demo(duration_s=duration, seed=seed)


@app.command()
def evaluate(
    dataset: str = typer.Option(..., help="reader name: euroc, kitti, broad, rosbag, csv"),
    path: str = typer.Option(..., help="the sequence (EuRoC/TUM-VI: the folder holding mav0/)"),
    interval: float = typer.Option(1.0, help="evaluation interval, in --interval-unit"),
    interval_unit: str = typer.Option("s", help="'s' (seconds) or 'frames' (IMU samples)"),
    imu_file: str = typer.Option(None, help="EuRoC/TUM-VI: IMU csv relative to the sequence folder"),
    json_out: str = typer.Option(None, "--json", help="write the metrics to this JSON file"),
) -> None:
    """Integrate a sequence's raw IMU over windows restarted from ground truth and print the paper's metrics."""
    from rich.console import Console
    from rich.table import Table

    from learned_imu.datasets import read_sequence
    from learned_imu.evaluate import evaluate as run_evaluation
    from learned_imu.io import write_json_atomic

    options = {"imu_file": imu_file} if imu_file else {}
    result = run_evaluation(read_sequence(dataset, path, **options), interval, interval_unit)
    table = Table(title=f"{result.sequence}: raw IMU, interval {result.interval_s:.3f} s ({result.n_windows} windows)")
    for column in ("ROE (deg)", "RPE (m)", "R-RMSE (deg)", "P-RMSE (m)", "V-RMSE (m/s)", "ATE (m)", "ATE aligned (m)"):
        table.add_column(column)
    table.add_row(
        *(
            f"{v:.4g}"
            for v in (
                result.roe_deg,
                result.rpe_m,
                result.r_rmse_deg,
                result.p_rmse_m,
                result.v_rmse_m_s,
                result.ate_m,
                result.ate_aligned_m,
            )
        )
    )
    Console().print(table)
    if json_out:
        Console().print(f"metrics written to {write_json_atomic(json_out, result.to_json_dict())}")


def main() -> None:
    app()
