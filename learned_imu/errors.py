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


class FolderBusyError(AirImuError, RuntimeError):
    """Another process is writing the same run folder; the message names the folder and that process."""
