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


def main() -> None:
    app()
