"""Generic IMU CSV / text tables with configurable columns, delimiter and units.

Conventions:

- Columns are given by header name (with or without a ``[unit]`` suffix, e.g. ``"w_RS_S_x"``) or by 0-based index.
  The defaults read the EuRoC order ``t, gyro(3), acc(3)``.
- Units are converted at the reader: ``time_unit`` in ``s | ms | us | ns``, ``gyro_unit`` in ``rad/s | deg/s``,
  ``acc_unit`` in ``m/s^2 | g`` (g = 9.80665 m/s^2). Gyro and acc are in the IMU frame; acc is specific force.
- Optional ground truth in the same rows: ``gt_pos`` (3 columns, m, world frame), ``gt_quat`` (4 columns holding
  the quaternion in ``quat_order``: ``"wxyz"`` scalar-first or ``"xyzw"`` scalar-last, rotating IMU vectors into
  the world frame, i.e. world <- IMU) and optionally ``gt_vel`` (3 columns, m/s, world frame; else differentiated
  from positions, see ``_assemble``). Rows whose GT values are NaN/Inf (an empty cell is an error, write ``nan``)
  get ``valid=False``. World frame z-up, gravity ``[0, 0, -gravity]``.
- With ground truth the IMU is cropped to the valid GT span (``crop_to_gt``) and the frame self-check runs.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from airimu_core.errors import ConfigError, DataError
from airimu_core.rotations import QUAT_ORDERS
from airimu_core.sequence import ImuSequence
from airimu_core.table import ColumnKey, read_table
from learned_imu.datasets._assemble import GtSamples, ReadChecks, build_sequence
from learned_imu.datasets._checks import DEG, STANDARD_GRAVITY, check_timestamps, forward_rows

TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}  # seconds per unit
GYRO_UNITS = {"rad/s": 1.0, "deg/s": DEG}  # rad/s per unit
ACC_UNITS = {"m/s^2": 1.0, "g": STANDARD_GRAVITY}  # m/s^2 per unit
GRAVITY = 9.81


def _unit(table: dict[str, float], value: str, option: str) -> float:
    if value not in table:
        raise ConfigError(f"reader option {option!r}: expected one of {', '.join(table)}, got {value!r}")
    return table[value]


def _keys(keys: Sequence[ColumnKey] | None, count: int, option: str) -> list[ColumnKey] | None:
    if keys is None:
        return None
    if isinstance(keys, str | int) or len(keys) != count:
        raise ConfigError(
            f"reader option {option!r}: expected {count} columns (header names or 0-based indices, "
            f"e.g. {option}=a,b,c on the command line), got {keys!r}"
        )
    return list(keys)


IMU_RATE_HZ = (1.0, 10_000.0)  # any IMU's sample rate; outside it the time column's unit is wrong


def _check_time_unit(t: np.ndarray, path: Path, time_unit: str) -> None:
    """A ``DataError`` when the median step makes no IMU rate: e.g. nanoseconds read as seconds (``time_unit``)."""
    if len(t) < 2:
        return
    rate = 1.0 / float(np.median(np.diff(t)))
    if IMU_RATE_HZ[0] <= rate <= IMU_RATE_HZ[1]:
        return
    fits = [
        unit
        for unit, scale in TIME_UNITS.items()
        if IMU_RATE_HZ[0] <= rate * TIME_UNITS[time_unit] / scale <= IMU_RATE_HZ[1]
    ]
    hint = ""
    if fits:
        hint = f"; with time_unit={fits[0]!r} it would be {rate * TIME_UNITS[time_unit] / TIME_UNITS[fits[0]]:.4g} Hz"
    raise DataError(
        path, "time", f"read as {time_unit!r} the samples come at {rate:.4g} Hz, no IMU's rate{hint} (time_unit)"
    )


def read_csv(
    path: str | Path,
    *,
    time: ColumnKey = 0,
    gyro: Sequence[ColumnKey] = (1, 2, 3),
    acc: Sequence[ColumnKey] = (4, 5, 6),
    delimiter: str | None = ",",
    comments: str | None = "#",
    header: bool | None = None,
    time_unit: str = "s",
    gyro_unit: str = "rad/s",
    acc_unit: str = "m/s^2",
    gt_pos: Sequence[ColumnKey] | None = None,
    gt_quat: Sequence[ColumnKey] | None = None,
    quat_order: str = "wxyz",
    gt_vel: Sequence[ColumnKey] | None = None,
    gravity: float = GRAVITY,
    name: str | None = None,
    on_backward: str = "error",
    checks: ReadChecks = ReadChecks(),
) -> ImuSequence:
    """Read an IMU table (see the module docstring for the conventions).

    Args:
        path: the file.
        time, gyro, acc: time column and the 3 gyro / 3 acc columns (header names or 0-based indices).
        delimiter: column separator (None: any white space); comments: comment marker or None.
        header: True / False if the first non-blank line is / is not a header; None detects it.
        time_unit, gyro_unit, acc_unit: units of the file's columns, converted to s, rad/s, m/s^2.
        gt_pos, gt_quat, quat_order, gt_vel: optional ground-truth columns (``gt_pos`` and ``gt_quat`` together).
        gravity: magnitude of gravity, m/s^2 (world z-up).
        name: sequence name (default: the file stem).
        on_backward: ``"error"`` (a time stamp before the previous one is an error naming the line) or ``"drop"``
            (drop the rows not after the last kept one; equal stamps are ``checks.on_duplicate``'s).
        checks: duplicates, gaps, crop, self-checks, velocity window (``_assemble.ReadChecks``); ``check_units``
            also refuses time stamps at no IMU's rate (``time_unit``).
    """
    t_scale = _unit(TIME_UNITS, time_unit, "time_unit")
    w_scale = _unit(GYRO_UNITS, gyro_unit, "gyro_unit")
    a_scale = _unit(ACC_UNITS, acc_unit, "acc_unit")
    gyro_keys, acc_keys = _keys(gyro, 3, "gyro"), _keys(acc, 3, "acc")
    pos_keys, quat_keys, vel_keys = _keys(gt_pos, 3, "gt_pos"), _keys(gt_quat, 4, "gt_quat"), _keys(gt_vel, 3, "gt_vel")
    if (pos_keys is None) != (quat_keys is None):
        given, missing = ("gt_pos", "gt_quat") if quat_keys is None else ("gt_quat", "gt_pos")
        raise ConfigError(f"reader option {missing!r}: ground truth needs both gt_pos and gt_quat; only {given} given")
    if quat_order not in QUAT_ORDERS:
        raise ConfigError(f"reader option 'quat_order': expected one of {', '.join(QUAT_ORDERS)}, got {quat_order!r}")

    path = Path(path)
    table = read_table(path, delimiter=delimiter, comments=comments, header=header)
    t = table.columns([time], "time")[:, 0]
    table.require_finite(t[:, None], "time")
    imu = np.concatenate([table.columns(gyro_keys, "gyro") * w_scale, table.columns(acc_keys, "acc") * a_scale], 1)
    table.require_finite(imu, "gyro/acc")
    forward = forward_rows(t, path, "time", on_backward, table.line_of)
    kept = check_timestamps(
        t[forward] * t_scale,
        path,
        "time",
        on_duplicate=checks.on_duplicate,
        line_of=lambda row: table.line_of(int(forward[row])),
    )
    keep = forward[kept]
    t = t[keep] * t_scale
    if checks.check_units:
        _check_time_unit(t, path, time_unit)
    gt = None
    if pos_keys is not None:
        vel = table.columns(vel_keys, "gt_vel")[keep] if vel_keys is not None else None
        gt = GtSamples.from_quaternions(
            t,
            table.columns(quat_keys, "gt_quat")[keep],
            quat_order,
            table.columns(pos_keys, "gt_pos")[keep],
            vel,
            path,
            "gt_quat",
        )
    return build_sequence(
        name or path.stem,
        path,
        t,
        imu[keep, :3],
        imu[keep, 3:],
        np.array([0.0, 0.0, -gravity]),
        gt=gt,
        checks=checks,
        line_of=lambda row: table.line_of(int(keep[row])),
    )
