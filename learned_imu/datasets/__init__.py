"""Dataset readers: one module per format, each returning a checked ``ImuSequence`` (see
``airimu_core.sequence``).

``read_sequence("euroc", path, **options)`` dispatches by name through ``READERS``; each reader's module
docstring states its frames, quaternion order and units. The options every reader shares (duplicates, gaps, crop,
self-checks, velocity window) are one ``ReadChecks`` record, given flat here and in configs. Shared parsing and
checks live in the ``_`` modules: ``_table`` (text parsing with line numbers), ``_checks`` (time stamps, gaps,
units, frame self-check), ``_assemble`` (``ReadChecks``, ground-truth resampling, velocity from positions, crop
and gap policy).
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable
from dataclasses import fields
from pathlib import Path

from airimu_core.sequence import MAX_IMU_DELAY_S, ImuSequence, is_imu_delay
from airimu_core.table import check_input_size
from learned_imu.datasets import broad, kitti, kitti_raw
from learned_imu.datasets._assemble import ReadChecks
from learned_imu.datasets.broad import read_broad
from learned_imu.datasets.csv import read_csv
from learned_imu.datasets.euroc import read_euroc
from learned_imu.datasets.kitti import read_kitti
from learned_imu.datasets.kitti_raw import read_kitti_raw
from learned_imu.datasets.rosbag import read_rosbag
from learned_imu.datasets.tumvi import read_tumvi

READERS: dict[str, Callable[..., ImuSequence]] = {
    "euroc": read_euroc,
    "kitti": read_kitti,
    "kitti_raw": read_kitti_raw,
    "broad": read_broad,
    "rosbag": read_rosbag,
    "csv": read_csv,
    "tumvi": read_tumvi,
}
# the ReadChecks fields a reader cannot honour (each module's UNUSED_CHECKS): no option of that reader
UNUSED_CHECKS = {"kitti": kitti.UNUSED_CHECKS, "kitti_raw": kitti_raw.UNUSED_CHECKS, "broad": broad.UNUSED_CHECKS}


# every reader's option: how late (s) the IMU's samples are against the clock of its ground truth (and GPS); each
# sample is stamped that much earlier (``ImuSequence.imu_delay_removed``), for training and fusion alike
IMU_DELAY_OPTION = "imu_delay_s"
SPLIT = "split"  # a config's on_gap: read with "keep", then ImuSequence.split_at_gaps()
SIMULATOR = "simulator"  # a config's sequence made by learned_imu.datasets.simulator.simulate instead of a reader
# Reader and simulator options are a handful of scalars and short lists: anything far larger is a mistake or an
# attack (YAML aliases nest to ~10^9 elements in a few hundred bytes), refused before it is expanded.
MAX_OPTION_ITEMS = 1000
MAX_OPTION_DEPTH = 3


def read_sequence(dataset: str, path: str | Path | None = None, **options) -> ImuSequence:
    """Read a sequence with the reader registered as ``dataset`` (a key of ``READERS``).

    ``options`` are the reader's keyword arguments (checked by ``check_options``), the fields of its ``checks``
    record given flat (``on_gap="keep"``) and gathered into a ``ReadChecks`` here; ``path`` may be None only for
    ``"kitti"`` (gtsam's copy). Splitting at gaps is a step of its own: ``on_gap="keep"``, then
    ``ImuSequence.split_at_gaps()`` (a config's ``on_gap: split`` does both). Every reader also takes
    ``imu_delay_s`` (``IMU_DELAY_OPTION``): each IMU sample stamped that much earlier, on the ground truth's clock,
    and the truth read at the new stamps (``ImuSequence.imu_delay_removed``). A file the reader cannot parse at all
    (zero bytes, random bytes, another format, no permission) is a ``DataError`` naming it; the parser's own
    exception is its ``__cause__``.
    """
    from airimu_core.errors import AirImuError, DataError, InputError

    if dataset not in READERS:
        raise InputError(f"unknown dataset {dataset!r}; known datasets: {', '.join(sorted(READERS))}")
    if path is None and dataset != "kitti":
        raise InputError(f"dataset {dataset!r} needs a path")
    options = check_options(dataset, options, "reader option")
    delay_s = options.pop(IMU_DELAY_OPTION, 0.0)
    checks = ReadChecks(**{f.name: options.pop(f.name) for f in fields(ReadChecks) if f.name in options})
    if path is not None and not Path(path).exists():
        raise DataError(path, "path", "no such file or folder")
    if path is not None and Path(path).is_file():
        check_input_size(Path(path))
    try:
        sequence = READERS[dataset](path, checks=checks, **options)
    except (AirImuError, MemoryError, KeyboardInterrupt):
        raise
    except Exception as error:  # the parsers' own errors (scipy, h5py, rosbags, UnicodeDecodeError, OSError...)
        text = getattr(error, "strerror", None) or str(error)
        problem = text.splitlines()[0] if text else "no detail"
        raise DataError(path, "file", f"cannot be read as {dataset}: {type(error).__name__}: {problem}") from error
    return sequence.imu_delay_removed(delay_s)


def check_options(dataset: str, options: dict, where: str = "options") -> dict:
    """``options`` checked against the signature of ``dataset``'s reader (or ``simulate`` for ``"simulator"``):
    every key a keyword of it or a field of its ``checks`` record (``ReadChecks``, less the reader's
    ``UNUSED_CHECKS``), every value of the annotated type (numbers, strings, booleans, lists of them) or one of the
    option's choices, at most ``MAX_OPTION_ITEMS`` values nested ``MAX_OPTION_DEPTH`` deep. A ``ConfigError`` names
    ``where``.key."""
    from airimu_core.errors import ConfigError

    if dataset == SIMULATOR:
        from learned_imu.datasets.simulator import simulate as function
    elif dataset in READERS:
        function = READERS[dataset]
    else:
        known = ", ".join(sorted([*READERS, SIMULATOR]))
        raise ConfigError(f"dataset: unknown dataset {dataset!r}; known: {known}")
    if not isinstance(options, dict):
        raise ConfigError(f"{where}: expected a mapping of option names to values, got {type(options).__name__}")
    _check_size(options, where)
    parameters = {n: p.annotation for n, p in inspect.signature(function).parameters.items() if n != "path"}
    if parameters.pop("checks", None) is not None:  # a reader: its ReadChecks fields are options of their own
        unused = UNUSED_CHECKS.get(dataset, ())
        parameters |= {f.name: f.type for f in fields(ReadChecks) if f.name not in unused}
        parameters[IMU_DELAY_OPTION] = "float"
    for key, value in options.items():
        if key not in parameters:
            raise ConfigError(
                f"{where} '{key}': {dataset} has no such option; its options: {', '.join(sorted(parameters))}"
            )
        allowed = _choices().get(key)
        if allowed is not None and value not in allowed:
            raise ConfigError(f"{where} '{key}': expected one of {', '.join(map(str, allowed))}, got {value!r}")
        annotation = parameters[key]
        if allowed is None and isinstance(annotation, str) and not _matches(annotation, value):
            raise ConfigError(f"{where} '{key}': expected {annotation}, got {value!r} ({type(value).__name__})")
        if key in POSITIVE_OPTIONS and value is not None and not (math.isfinite(value) and value > 0):
            raise ConfigError(f"{where} '{key}': expected a positive number ({POSITIVE_OPTIONS[key]}), got {value!r}")
        if key == IMU_DELAY_OPTION and not is_imu_delay(value):
            raise ConfigError(
                f"{where} '{key}': expected a delay (s) within +-{MAX_IMU_DELAY_S:g}, got {value!r} (a value in ms?)"
            )
    return dict(options)


# numeric reader and simulator options that must be positive and finite (their unit)
POSITIVE_OPTIONS = {
    "duration_s": "s",
    "rate_hz": "Hz",
    "gps_rate_hz": "Hz",
    "gps_sigma_m": "m",
    "gps_sigma": "m",
    "gravity": "m/s^2, the magnitude",
    "vel_window_s": "s",
    "max_gt_distance_s": "s",
}


def _choices() -> dict[str, tuple]:
    """Options with a fixed set of values, by name (the same name means the same choice in every reader)."""
    from airimu_core import rotations as _rotations
    from learned_imu.datasets import _checks, csv, kitti_raw, rosbag, tumvi
    from learned_imu.datasets.simulator import GRADES, PROFILES

    return {
        "on_gap": (*_checks.ON_GAP, SPLIT),
        "on_duplicate": _checks.ON_DUPLICATE,
        "on_backward": _checks.ON_BACKWARD,
        "gps_frame": kitti_raw.GPS_FRAMES,
        "stamp": rosbag.STAMPS,
        "quat_order": _rotations.QUAT_ORDERS,
        "time_unit": tuple(csv.TIME_UNITS),
        "gyro_unit": tuple(csv.GYRO_UNITS),
        "acc_unit": tuple(csv.ACC_UNITS),
        "profile": PROFILES,
        "grade": tuple(GRADES),
        "imu": tuple(tumvi.IMU_FILES),
    }


def _check_size(value, where: str) -> None:
    from airimu_core.errors import ConfigError

    count = 0
    stack = [(value, 0)]
    while stack:
        item, depth = stack.pop()
        count += 1
        if count > MAX_OPTION_ITEMS or depth > MAX_OPTION_DEPTH:
            raise ConfigError(
                f"{where}: more than {MAX_OPTION_ITEMS} values or nested deeper than {MAX_OPTION_DEPTH} levels "
                "(YAML aliases?); reader and simulator options are a few scalars and short lists"
            )
        if isinstance(item, dict):
            stack.extend((v, depth + 1) for v in item.values())
        elif isinstance(item, list | tuple):
            stack.extend((v, depth + 1) for v in item)


_SCALARS = {
    "None": lambda v: v is None,
    "bool": lambda v: isinstance(v, bool),
    "int": lambda v: isinstance(v, int) and not isinstance(v, bool),
    "float": lambda v: isinstance(v, int | float) and not isinstance(v, bool),
    "str": lambda v: isinstance(v, str),
    "Path": lambda v: isinstance(v, str | Path),
    "ColumnKey": lambda v: isinstance(v, str | int) and not isinstance(v, bool),
}


def _matches(annotation: str, value) -> bool:
    """Does ``value`` fit a reader's string annotation (``'float | None'``, ``'Sequence[ColumnKey] | None'``)?"""
    for alternative in (a.strip() for a in annotation.split("|")):
        if alternative.startswith("Sequence[") and isinstance(value, list | tuple):
            inner = alternative[len("Sequence[") : -1]
            if all(_matches(inner, v) for v in value):
                return True
        elif alternative in _SCALARS and _SCALARS[alternative](value):
            return True
    return False


__all__ = [
    "READERS",
    "SIMULATOR",
    "ReadChecks",
    "check_options",
    "read_broad",
    "read_csv",
    "read_euroc",
    "read_kitti",
    "read_kitti_raw",
    "read_rosbag",
    "read_sequence",
]
