"""Error types of the toolkit. Every message names the file or argument, the field, and what was expected."""

from __future__ import annotations


class AirImuError(Exception):
    """Base class of the toolkit's own errors."""


class InputError(AirImuError, ValueError):
    """An argument passed to a function is malformed (shape, dtype, sign, NaN)."""


class DataError(AirImuError, ValueError):
    """A user's data file is malformed: the message names the file, the line or field, and what was expected."""

    def __init__(self, path: object, field: str, problem: str, line: int | None = None):
        where = f"{path}" + (f", line {line}" if line is not None else "")
        super().__init__(f"{where}: field '{field}': {problem}")
        self.path = path
        self.field = field
        self.problem = problem
        self.line = line


class ConfigError(AirImuError, ValueError):
    """A configuration file or mapping has an unknown, missing or ill-typed key."""


class DependencyError(AirImuError, ImportError):
    """An optional dependency that a requested feature needs is not installed; the message names the extra."""


class ExportError(AirImuError, ValueError):
    """An export is missing, of another format version, or malformed; the message names file (or export) and field."""


class GraphError(AirImuError, ValueError):
    """A factor graph that cannot be solved as built (a key without a value, an unanchored part, a singular
    system); the message names the keys."""


class PimLayoutError(AirImuError, RuntimeError):
    """This gtsam's serialisation of a preintegrated measurement is not the layout ``factors.pim_from_deltas``
    rebuilds; the message names the gtsam version."""


class FolderBusyError(AirImuError, RuntimeError):
    """Another process is writing the same run folder; the message names the folder and that process."""


def real_array(value, name: str):
    """``value`` as a float64 numpy array, or an ``InputError`` naming ``name`` when it is not an array of real
    numbers: ragged nested lists (numpy's "setting an array element with a sequence"), text, or complex numbers
    (which ``np.asarray(..., dtype=float)`` would cast to their real part with only a warning)."""
    import numpy as np

    try:
        array = np.asarray(value)  # numpy's own dtype: complex stays complex, text stays text
    except ValueError:
        raise InputError(
            f"{name}: expected an array of real numbers, got a ragged nesting (rows of different lengths)"
        ) from None
    if np.iscomplexobj(array):
        raise InputError(f"{name}: expected real numbers, got complex values")
    if not (np.issubdtype(array.dtype, np.number) or array.dtype == bool):
        raise InputError(f"{name}: expected an array of real numbers, got {repr(value)[:60]}")
    return array.astype(np.float64)
