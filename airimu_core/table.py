"""Numeric text tables (CSV, space separated) parsed fast, with file line numbers recovered on failure.

The fast path is one ``np.loadtxt`` call. Only when it fails, or when a caller needs the line of a bad row,
is the file scanned line by line, so a malformed line is reported as ``<file>, line <n>`` (1-based, counting
every line of the file, header and comments included).
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from airimu_core.errors import DataError

ColumnKey = str | int
# Far beyond any IMU log (EuRoC flights are 2-3 MB of CSV, a KITTI drive of 100-Hz OXTS a few MB, hours of 1-kHz IMU
# a few hundred MB): a larger input is refused before it is read line by line into memory.
# AIRIMU_MAX_INPUT_BYTES overrides it.
MAX_INPUT_BYTES = 4 * 2**30
MAX_INPUT_ENV = "AIRIMU_MAX_INPUT_BYTES"


def check_input_size(path: Path, field: str = "file") -> None:
    """A ``DataError`` when the file ``path`` is larger than ``MAX_INPUT_BYTES`` (or ``$AIRIMU_MAX_INPUT_BYTES``)."""
    from airimu_core.errors import ConfigError

    text = os.environ.get(MAX_INPUT_ENV)
    try:
        limit = MAX_INPUT_BYTES if text is None else int(text)
    except ValueError:
        raise ConfigError(f"{MAX_INPUT_ENV}: expected a whole number of bytes, got {text!r}") from None
    size = path.stat().st_size
    if size > limit:
        raise DataError(
            path,
            field,
            f"{size / 2**30:.3g} GiB is beyond the {limit / 2**30:.3g} GiB any IMU log fits in (not a "
            f"log, or a corrupt one?); set {MAX_INPUT_ENV} to a larger number of bytes to read it anyway",
        )


def _tokens(line: str, delimiter: str | None) -> list[str]:
    if delimiter is None:
        return line.split()
    return [tok.strip() for tok in line.split(delimiter)]


def _content(line: str, comments: str | None) -> str:
    """The line without its comment part and surrounding white space."""
    if comments is not None and comments in line:
        line = line[: line.index(comments)]
    return line.strip()


def _is_number(token: str) -> bool:
    """Whether numpy's text parser reads ``token`` as a number (Python's ``float`` also takes ``'1_0'`` and
    non-ASCII digits, which ``np.loadtxt`` refuses: those must be reported as malformed, with their line)."""
    if not token.isascii() or "_" in token:
        return False
    try:
        float(token)
    except ValueError:
        return False
    return True


def _unit_free(name: str) -> str:
    """``'w_RS_S_x [rad s^-1]'`` -> ``'w_RS_S_x'``: header names may be given without their unit suffix."""
    return name.split("[")[0].strip()


@dataclass(frozen=True, eq=False)
class Table:
    """A parsed numeric table.

    Attributes:
        path: the file.
        data: (rows, columns) float64 values; NaN/Inf are kept as parsed (callers decide what they mean).
        header: column names from the header line (a ``#``-comment header counts), or ``()`` if none.
        skip_lines: number of file lines before the first line that may hold data.
        delimiter: column separator, None for any white space.
        comments: comment marker, or None.
    """

    path: Path
    data: np.ndarray
    header: tuple[str, ...]
    skip_lines: int
    delimiter: str | None
    comments: str | None

    @cached_property
    def _data_lines(self) -> np.ndarray:
        """1-based file line number of every data row (computed on first use only: a full file scan)."""
        lines = []
        with open(self.path, encoding="utf-8-sig", errors="replace") as f:
            for number, line in enumerate(f, start=1):
                if number > self.skip_lines and _content(line, self.comments):
                    lines.append(number)
        return np.asarray(lines, dtype=np.int64)

    def line_of(self, row: int) -> int:
        """File line number (1-based) of data row ``row`` (0-based)."""
        return int(self._data_lines[row])

    def column_index(self, key: ColumnKey, field: str) -> int:
        """Index of a column given by header name (with or without its ``[unit]`` suffix) or 0-based index."""
        ncols = self.data.shape[1]
        if isinstance(key, int | np.integer):
            if not -ncols <= key < ncols:
                raise DataError(self.path, field, f"column index {key} out of range: the file has {ncols} columns")
            return int(key) % ncols
        for names in (self.header, tuple(_unit_free(h) for h in self.header)):
            if key in names:
                return names.index(key)
        known = ", ".join(repr(h) for h in self.header) or "none (the file has no header line)"
        raise DataError(self.path, field, f"no column named {key!r}; header columns: {known}")

    def columns(self, keys: Sequence[ColumnKey], field: str) -> np.ndarray:
        """(rows, len(keys)) float64 copy of the named columns."""
        return self.data[:, [self.column_index(k, field) for k in keys]].astype(np.float64, copy=True)

    def require_finite(self, values: np.ndarray, field: str) -> None:
        """Raise a DataError naming the first row (as a file line) with NaN or Inf in ``values``."""
        bad = ~np.isfinite(values.reshape(values.shape[0], -1)).all(axis=1)
        if bad.any():
            row = int(np.argmax(bad))
            raise DataError(self.path, field, f"non-finite value (NaN or Inf): {values[row]}", line=self.line_of(row))


def _find_header(path: Path, delimiter: str | None, comments: str | None, header: bool | None):
    """(header names, number of lines to skip) from the first non-blank line.

    ``header=None`` detects it: a first line without any number is the header (a leading comment marker is
    stripped first, as in EuRoC's ``#timestamp [ns],...``); a line mixing numbers and text is a malformed data
    row, reported as such rather than silently skipped as a header.
    """
    with open(path, encoding="utf-8-sig", errors="replace") as f:
        for number, line in enumerate(f, start=1):
            text = line.strip()
            if not text:
                continue
            commented = comments is not None and text.startswith(comments)
            body = text[len(comments) :].strip() if commented else _content(text, comments)
            names = tuple(_tokens(body, delimiter))
            is_header = header if header is not None else not any(_is_number(t) for t in names if t)
            if not is_header:
                return (), number - 1
            return names, number
    return (), 0


def _first_bad_line(path: Path, skip: int, delimiter: str | None, comments: str | None):
    """(line number, problem) of the first line that is not a row of numbers of the usual width, or None.

    The usual width is the most common column count, so a truncated first row is still the one reported.
    """
    rows = []
    with open(path, encoding="utf-8-sig", errors="replace") as f:
        for number, line in enumerate(f, start=1):
            text = _content(line, comments) if number > skip else ""
            if text:
                rows.append((number, _tokens(text, delimiter)))
    if not rows:
        return None
    widths, counts = np.unique([len(tokens) for _, tokens in rows], return_counts=True)
    ncols = int(widths[np.argmax(counts)])
    for number, tokens in rows:
        if len(tokens) != ncols:
            return number, f"expected {ncols} columns, got {len(tokens)} (truncated or malformed line)"
        for col, token in enumerate(tokens):
            if not _is_number(token):
                what = "empty value" if not token else f"{token!r} is not a number{_separator_hint(token, delimiter)}"
                return number, f"column {col}: {what}"
    return None


SEPARATORS = {";": "';'", "\t": "'\\t'", " ": "None (any white space)", ",": "','"}


def _separator_hint(token: str, delimiter: str | None) -> str:
    """'; the line looks ;-separated: pass delimiter=...' when ``token`` is numbers joined by another separator."""
    for separator, option in SEPARATORS.items():
        parts = token.split(separator) if separator != " " else token.split()
        if separator != delimiter and len(parts) > 1 and all(_is_number(part.strip()) for part in parts):
            return f" (the line looks {separator!r}-separated: pass delimiter={option})"
    return ""


def read_table(
    path: str | Path,
    *,
    delimiter: str | None = ",",
    comments: str | None = "#",
    header: bool | None = None,
    min_columns: int = 1,
    field: str = "file",
) -> Table:
    """Parse a numeric table; a malformed line raises a DataError with its file line number.

    Args:
        path: the file.
        delimiter: column separator (None: any white space).
        comments: comment marker; text after it on a line is ignored.
        header: True if the first non-blank line is a header, False if not, None to detect it.
        min_columns: fewer columns than this is an error.
        field: field name used in error messages about the file as a whole.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError(path, field, "file not found")
    check_input_size(path, field)
    if delimiter == "":
        raise DataError(path, "delimiter", "an empty delimiter; give the column separator, or None for any white space")
    with open(path, "rb") as f:
        start = f.read(4096)
    if start[:2] in (b"\xff\xfe", b"\xfe\xff") or start.count(b"\x00") > len(start) // 4:
        raise DataError(path, field, "the file is UTF-16 (or binary), not text in UTF-8: save it as UTF-8 (CSV)")
    names, skip = _find_header(path, delimiter, comments, header)
    try:
        with warnings.catch_warnings():  # an empty file: "no data rows" below says it
            warnings.filterwarnings("ignore", "loadtxt: input contained no data", UserWarning)
            data = np.loadtxt(
                path,
                delimiter=delimiter,
                comments=comments,
                skiprows=skip,
                ndmin=2,
                dtype=np.float64,
                encoding="utf-8-sig",
            )
    except ValueError as err:
        bad = _first_bad_line(path, skip, delimiter, comments)
        if bad is not None:
            raise DataError(path, field, bad[1], line=bad[0]) from err
        data = _parse_content_lines(path, skip, delimiter, comments, field)
    if data.shape[0] == 0:
        raise DataError(path, field, "no data rows")
    if names and data.shape[1] != len(names):
        # the header names a different number of columns than the rows carry: trust the rows, keep names only
        # when they line up (EuRoC headers do); otherwise name lookups would silently pick the wrong column
        names = ()
    if data.shape[1] < min_columns:
        line = _first_line_number(path, skip, comments)
        raise DataError(path, field, f"expected at least {min_columns} columns, got {data.shape[1]}", line=line)
    return Table(path, data, names, skip, delimiter, comments)


def _parse_content_lines(path: Path, skip: int, delimiter: str | None, comments: str | None, field: str):
    """Parse only the lines with content. ``np.loadtxt`` refuses a line of white space or an indented comment as a
    row of one empty column, while the line scan (``_content``) skips them as blank: parse what the scan sees."""
    with open(path, encoding="utf-8-sig", errors="replace") as f:
        lines = [line for number, line in enumerate(f, start=1) if number > skip and _content(line, comments)]
    if not lines:
        raise DataError(path, field, "no data rows")
    try:
        return np.loadtxt(lines, delimiter=delimiter, comments=comments, ndmin=2, dtype=np.float64)
    except ValueError as err:
        raise DataError(path, field, f"could not parse: {err}") from err


def _first_line_number(path: Path, skip: int, comments: str | None) -> int | None:
    with open(path, encoding="utf-8-sig", errors="replace") as f:
        for number, line in enumerate(f, start=1):
            if number > skip and _content(line, comments):
                return number
    return None
