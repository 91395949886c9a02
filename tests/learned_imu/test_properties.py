"""Property-based tests (hypothesis): the readers on random valid and malformed IMU files, the time stamp checks on
random stamps, and the preintegrator against the float64 sample-by-sample reference on random rates, lengths and
time steps. Settings are derandomized (the same examples on every run) and modest, so the file runs in seconds."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from airimu_core.errors import DataError
from learned_imu import preintegrate
from learned_imu.datasets._checks import check_timestamps, segments
from learned_imu.datasets.csv import read_csv
from learned_imu.datasets.euroc import read_euroc
from learned_imu.geometry.preintegration_reference import preintegrate_loop

PROPERTY = settings(
    max_examples=40,
    deadline=None,
    derandomize=True,  # deterministic in CI: the examples are a function of the test alone
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
READERS = settings(PROPERTY, max_examples=150)  # a file read takes milliseconds: more examples, same budget
DELTAS = ("rot", "vel", "pos", "dt", "cov")

# ---------------------------------------------------------------------------------------------------------------
# Readers: random IMU tables, written as text, read back (generic CSV in s, EuRoC's data.csv in ns)
# ---------------------------------------------------------------------------------------------------------------

EUROC_HEADER = "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
EUROC_HEADER += "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]"
CSV_HEADER = "t,wx,wy,wz,ax,ay,az"
FORMATS = (repr, "{:.17g}".format, "{:.17e}".format, "{:+.17g}".format)  # all round-trip a float64 exactly
NOT_DATA = ("", "# a comment", "   ", "\t", "  # indented comment")  # lines a reader skips
NOT_FINITE = ("nan", "NaN", "-nan", "inf", "-inf", "Infinity", "1e400", "-1e999")
CORRUPTIONS = ("drop_field", "extra_field", "text", "empty", "not_finite", "truncated", "duplicate", "backwards", "gap")
# Python's float() reads the first three, numpy does not; none is a number in a numeric table
NOT_NUMBERS = ("1_0", "\u0661\u0662", "\uff11\uff12", "0x10", "1d3", "nan(1)", "--1", "1.0j", "e5", "1;5")
# printable text without the delimiter, the comment marker or line breaks
TOKEN_CHARS = st.characters(blacklist_categories=("Cs", "Cc", "Zl", "Zp"), blacklist_characters=",#")


@dataclass
class ImuTable:
    """A table as written: the numbers, the text of their fields, and the lines around them."""

    t: np.ndarray  # (n,) as written in the file's unit (s, or integer ns for EuRoC)
    imu: np.ndarray  # (n, 6) gyro rad/s, acc m/s^2
    cells: list[list[str]]  # per data row, the text of its fields
    ns: bool
    header: str | None
    extra_lines: dict[int, str]  # comment / blank lines inserted before data row k
    spaced: bool
    newline: str

    def render(self) -> tuple[str, list[int]]:
        """The file text and the 1-based file line of each data row."""
        lines, data_lines = [], []
        if self.header is not None:
            lines.append(self.header)
        for k, row in enumerate(self.cells):
            if k in self.extra_lines:
                lines.append(self.extra_lines[k])
            lines.append((" , " if self.spaced else ",").join(row))
            data_lines.append(len(lines))
        return self.newline.join(lines) + self.newline, data_lines


@st.composite
def imu_tables(draw, ns: bool, min_rows: int = 3, max_rows: int = 40) -> ImuTable:
    """Strictly increasing stamps without gaps (steps within +-40 % of the nominal one), gyro in [-3, 3] rad/s,
    acc within 3 m/s^2 of +g per axis, in one of several number formats, header, comment and blank lines."""
    n = draw(st.integers(min_rows, max_rows))
    step = draw(st.sampled_from([0.0025, 0.005, 0.01]))
    jitter = draw(arrays(np.float64, n, elements=st.floats(-0.2, 0.2)))
    gyro = draw(arrays(np.float64, (n, 3), elements=st.floats(-3.0, 3.0)))
    acc = draw(arrays(np.float64, (n, 3), elements=st.floats(-3.0, 3.0))) + [0.0, 0.0, 9.81]
    if ns:
        t0 = draw(st.integers(0, 2 * 10**18))
        t = np.array([t0 + int(round((k + jitter[k]) * step * 1e9)) for k in range(n)], dtype=object)
    else:
        t = draw(st.floats(0.0, 1e6)) + step * (np.arange(n) + jitter)
    fmt = draw(st.sampled_from(FORMATS))
    cells = [[str(t[k]) if ns else fmt(float(t[k]))] + [fmt(float(v)) for v in (*gyro[k], *acc[k])] for k in range(n)]
    header = draw(st.sampled_from([None, EUROC_HEADER if ns else CSV_HEADER]))
    extra = draw(st.dictionaries(st.integers(1, n - 1), st.sampled_from(NOT_DATA), max_size=3))
    spaced, newline = draw(st.booleans()), draw(st.sampled_from(["\n", "\r\n"]))
    return ImuTable(t, np.concatenate([gyro, acc], 1), cells, ns, header, extra, spaced, newline)


def write_table(table: ImuTable, folder: Path) -> tuple[Path, list[int]]:
    """Write the table as EuRoC's ``mav0/imu0/data.csv`` (ns) or a plain CSV (s); returns the file and its lines."""
    path = folder / "mav0" / "imu0" / "data.csv" if table.ns else folder / "imu.csv"
    path.parent.mkdir(parents=True, exist_ok=True)
    text, lines = table.render()
    path.write_bytes(text.encode("utf-8"))
    return path, lines


def read(table: ImuTable, folder: Path):
    return read_euroc(folder) if table.ns else read_csv(folder / "imu.csv")


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("tables")


@READERS
@given(data=st.data(), ns=st.booleans())
def test_valid_files_read_back_the_written_numbers(folder, data, ns):
    table = data.draw(imu_tables(ns))
    write_table(table, folder)
    seq = read(table, folder)
    written_t = np.array([float(c[0]) for c in table.cells]) * (1e-9 if ns else 1.0)  # as the reader scales
    np.testing.assert_array_equal(seq.t, written_t)
    np.testing.assert_array_equal(seq.gyro, table.imu[:, :3])
    np.testing.assert_array_equal(seq.acc, table.imu[:, 3:])
    assert np.isfinite(seq.gyro).all() and np.isfinite(seq.acc).all() and np.all(np.diff(seq.t) > 0)


@st.composite
def corrupted_tables(draw, ns: bool):
    """A valid table with one malformed data row: (table, row, kind); the reader must point at that row's line."""
    kind = draw(st.sampled_from(CORRUPTIONS))
    table = draw(imu_tables(ns, min_rows=8 if kind == "gap" else 3))
    n = len(table.cells)
    row = draw(st.integers(1 if kind in ("duplicate", "backwards", "gap") else 0, n - 1))
    cells = table.cells[row]
    col = draw(st.integers(0, 6))
    if kind == "drop_field":
        del cells[col]
    elif kind == "extra_field":
        cells.insert(col, "1.0")
    elif kind == "text":
        cells[col] = draw(
            st.one_of(
                st.sampled_from(NOT_NUMBERS),
                st.text(TOKEN_CHARS, min_size=1, max_size=8).filter(lambda s: s.strip() and not _numpy_parses(s)),
            )
        )
    elif kind == "empty":
        cells[col] = draw(st.sampled_from(["", " "]))
    elif kind == "not_finite":
        cells[col] = draw(st.sampled_from(NOT_FINITE))
    elif kind == "truncated":  # cut after the time stamp, before the last delimiter: fewer columns
        # (a first line without any number is a header by the reader's definition, so the stamp is kept)
        text = ",".join(cells)
        table.cells[row] = text[: draw(st.integers(len(cells[0]) + 1, text.rindex(",")))].split(",")
    else:  # time stamps: a copy of the previous one, one before it, or all later ones shifted by a gap
        t = list(table.t)
        if kind == "duplicate":
            t[row] = t[row - 1]
        elif kind == "backwards":
            back = draw(st.floats(0.01, 5.0))
            t[row] = t[row - 1] - (int(back * 5e6) + 1 if ns else back * 0.005)
        else:
            for k in range(row, n):
                t[k] = t[k] + (int(20 * 0.01e9) if ns else 20 * 0.01)
        for k in range(n):
            table.cells[k][0] = str(t[k]) if ns else repr(float(t[k]))
    return table, row, kind


def _numpy_parses(token: str) -> bool:
    """Whether ``np.loadtxt`` reads ``token`` as a number (then it is no 'text' corruption)."""
    try:
        np.loadtxt([token], delimiter=",", comments="#")
    except ValueError:
        return False
    return True


@READERS
@given(data=st.data(), ns=st.booleans())
def test_malformed_line_raises_a_data_error_naming_the_file_and_line(folder, data, ns):
    table, row, kind = data.draw(corrupted_tables(ns))
    path, lines = write_table(table, folder)
    with pytest.raises(DataError) as err:
        read(table, folder)
    assert Path(err.value.path) == path and str(path) in str(err.value), kind
    assert err.value.line == lines[row], (kind, str(err.value))


@READERS
@given(
    t=arrays(np.float64, st.integers(1, 40), elements=st.floats(-1e6, 1e6)),
    drop=st.booleans(),
    offset=st.integers(0, 100),
)
def test_time_stamp_check_raises_exactly_on_backwards_or_duplicated_stamps(t, drop, offset):
    steps = np.diff(t)
    on_duplicate = "drop" if drop else "error"
    bad = (steps < 0).any() or (not drop and (steps == 0).any())
    if bad:
        with pytest.raises(DataError) as err:
            check_timestamps(t, "stamps.csv", "t", on_duplicate=on_duplicate, line_of=lambda row: row + offset)
        first = int(np.argmax((steps < 0) if (steps < 0).any() else (steps == 0))) + 1
        assert err.value.line == first + offset and err.value.path == "stamps.csv"
        return
    keep = check_timestamps(t, "stamps.csv", "t", on_duplicate=on_duplicate)
    assert keep[0] == 0 and np.all(np.diff(t[keep]) > 0)
    np.testing.assert_array_equal(np.unique(t), t[keep])  # every distinct stamp once, first of each kept
    covered = np.concatenate([np.arange(s.start, s.stop) for s in segments(t[keep])])
    np.testing.assert_array_equal(covered, np.arange(len(keep)))  # gap segments partition the samples


# ---------------------------------------------------------------------------------------------------------------
# Preintegrator: the parallel scan against the sample loop (the same model one sample at a time), float64
# ---------------------------------------------------------------------------------------------------------------


def rel_err(ours: torch.Tensor, ref: torch.Tensor) -> float:
    """max |ours - ref| / max |ref| (ref never all zero here: acc holds gravity and densities are positive)."""
    return float((ours - ref).abs().max() / ref.abs().max())


@st.composite
def imu_inputs(draw, batch: tuple[int, ...] = (), min_n: int = 1, max_n: int = 300):
    """Random samples: N in [min_n, max_n], rates up to ``max_rate`` <= 3 rad/s per axis, specific force within
    4 m/s^2 of +g, dt in [1e-4, 0.05] s (one value or per sample), densities as a float, (3,) or per sample."""
    n = draw(st.integers(min_n, max_n))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    max_rate = draw(st.floats(0.0, 3.0))
    gyro = torch.tensor(rng.uniform(-max_rate, max_rate, (*batch, n, 3)))
    acc = torch.tensor(rng.uniform(-4.0, 4.0, (*batch, n, 3)) + [0.0, 0.0, 9.81])
    dt = draw(st.floats(1e-4, 0.05))
    if draw(st.booleans()):
        dt = torch.tensor(dt * rng.uniform(0.2, 1.8, (*batch, n)))
    shape = draw(st.sampled_from([(), (3,), (*batch, n, 3)]))
    gyro_cov = torch.tensor(10.0 ** rng.uniform(-8, -2, shape))
    acc_cov = torch.tensor(10.0 ** rng.uniform(-6, -1, shape))
    return gyro, acc, dt, gyro_cov, acc_cov


@pytest.mark.slow
@PROPERTY
@given(args=imu_inputs())
def test_preintegrate_equals_the_sample_loop(args):
    scan, loop = preintegrate(*args), preintegrate_loop(*args)
    for field in DELTAS:
        assert rel_err(getattr(scan, field), getattr(loop, field)) < 1e-9, field
    assert rel_err(scan.cov, scan.cov.mT) < 1e-12  # symmetric


@pytest.mark.slow
@PROPERTY
@given(args=imu_inputs(max_n=120), data=st.data())
def test_reported_samples_equal_the_sample_loop_at_those_samples(args, data):
    """``at`` (a single sample takes its own covariance route: the export's ``at=-1``) against the loop."""
    n = args[0].shape[-2]
    at = data.draw(
        st.one_of(
            st.integers(-n, n - 1),
            st.builds(slice, st.integers(0, n - 1), st.none(), st.integers(1, max(1, n))),
        )
    )
    some, loop = preintegrate(*args, at=at), preintegrate_loop(*args)
    index = torch.arange(n)[at].reshape(-1)
    for field in DELTAS:
        assert rel_err(getattr(some, field), getattr(loop, field)[index]) < 1e-9, (field, at)


@PROPERTY
@given(args=imu_inputs(batch=(3,), max_n=150))
def test_batch_equals_items_alone(args):
    gyro, acc, dt, gyro_cov, acc_cov = args
    full = preintegrate(*args)

    def item(x, b):  # per-sample dt (3, N) and densities (3, N, 3) are per item; a float or (3,) is shared
        return x[b] if isinstance(x, torch.Tensor) and x.ndim >= 2 else x

    for b in range(3):
        one = preintegrate(gyro[b], acc[b], item(dt, b), item(gyro_cov, b), item(acc_cov, b))
        for field in DELTAS:
            assert rel_err(getattr(full, field)[b], getattr(one, field)) < 1e-13, (field, b)
