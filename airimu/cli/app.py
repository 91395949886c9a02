"""The ``airimu`` command's application object and what its commands share: output-flag checks, the console, a
sequence read with ``--reader-option``s. The commands live beside it by topic: ``airimu.cli.fuse`` (demo,
ablate-pgo, fuse, view) and ``airimu.cli.train`` (train, ablate-imu, evaluate, export, scale-noise, export-model).
Each is thin: flags -> one request (a config) -> one library call -> print. Heavy imports happen inside commands."""

from __future__ import annotations

import typer

app = typer.Typer(add_completion=False, no_args_is_help=True, help="AirIMU: learned IMU factors for GTSAM.")


@app.callback()
def _root() -> None:
    """AirIMU: learned IMU correction and uncertainty, preintegrated into GTSAM factors."""


READER_OPTION_HELP = (
    "a reader option as key=value (repeatable): e.g. on_backward=drop, on_duplicate=drop, on_gap=keep; lists as "
    "gt_pos=px,py,pz or gt_pos=[px,py,pz]"
)


def _check_noise_flags(gyro: float, acc: float) -> None:
    from airimu_core.config import check_noise_density
    from airimu_core.errors import ConfigError

    try:
        check_noise_density("gyro", gyro, "--gyro-noise-density")
        check_noise_density("acc", acc, "--acc-noise-density")
    except ConfigError as error:
        raise typer.BadParameter(str(error)) from None


GTSAM_EXAMPLE = "gtsam"  # --dataset kitti --path gtsam: the KITTI IMU and GPS files installed with gtsam's wheel


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
    if dataset == "kitti" and path == GTSAM_EXAMPLE:  # the drive GTSAM ships: read from the installed gtsam
        return read_sequence(dataset, None, **parsed)
    return read_sequence(dataset, path, **parsed)


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
