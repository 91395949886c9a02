"""Generic CSV reader: columns by name or index, units, ground-truth columns and the mistakes the checks catch.
Files are written to tmp_path from the real EuRoC V1_02 excerpt; MH_01's IMU file is read directly."""

from __future__ import annotations

import numpy as np
import pytest

from airimu_core.errors import ConfigError, DataError
from airimu_core.rotations import matrix_to_quat_wxyz
from learned_imu.datasets import ReadChecks
from learned_imu.datasets.csv import read_csv
from learned_imu.datasets.euroc import read_euroc

HEADER = "stamp_ms,ax_g,ay_g,az_g,wx_dps,wy_dps,wz_dps,px,py,pz,qx,qy,qz,qw"
NAMED = {
    "time": "stamp_ms",
    "acc": ("ax_g", "ay_g", "az_g"),
    "gyro": ("wx_dps", "wy_dps", "wz_dps"),
    "time_unit": "ms",
    "acc_unit": "g",
    "gyro_unit": "deg/s",
    "gt_pos": ("px", "py", "pz"),
    "gt_quat": ("qx", "qy", "qz", "qw"),
    "quat_order": "xyzw",
}


@pytest.fixture(scope="module")
def v102(shared_data):
    return read_euroc(shared_data / "euroc" / "V1_02_medium", imu_file="mav0/imu0/data_partial_first40s.csv")


def _write(path, seq, rows=slice(0, 3000)):
    """``seq`` as a CSV in ms, g and deg/s, with GT position and a scalar-last quaternion; returns its lines."""
    q = matrix_to_quat_wxyz(seq.gt.rot[rows])[:, [1, 2, 3, 0]]
    table = np.concatenate(
        [seq.t[rows, None] * 1e3, seq.acc[rows] / 9.80665, np.rad2deg(seq.gyro[rows]), seq.gt.pos[rows], q], axis=1
    )
    lines = [HEADER] + [",".join(f"{v:.17g}" for v in row) for row in table]
    path.write_text("\n".join(lines) + "\n")
    return lines


def test_named_columns_and_units_round_trip(v102, tmp_path):
    path = tmp_path / "imu.csv"
    _write(path, v102)
    seq = read_csv(path, **NAMED)
    assert seq.name == "imu" and len(seq) == 3000 and seq.gt.valid.all()
    np.testing.assert_allclose(seq.t, v102.t[:3000], rtol=0, atol=1e-5)
    np.testing.assert_allclose(seq.acc, v102.acc[:3000], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(seq.gyro, v102.gyro[:3000], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(seq.gt.rot, v102.gt.rot[:3000], atol=1e-9)
    vel_err = np.linalg.norm(seq.gt.vel - v102.gt.vel[:3000], axis=1)
    assert np.sqrt((vel_err**2).mean()) < 0.005  # differentiated vs the file velocity


@pytest.mark.parametrize(
    ("override", "field", "message"),
    [
        ({"quat_order": "wxyz"}, "gt.rot", "file is scalar-last"),
        ({"acc_unit": "m/s^2"}, "acc", "acc looks like it is in g"),
        ({"gyro_unit": "rad/s"}, "gyro", "gyro looks like it is in deg/s"),
    ],
)
def test_wrong_options_are_named(v102, tmp_path, override, field, message):
    path = tmp_path / "imu.csv"
    _write(path, v102)
    with pytest.raises(DataError, match=message) as err:
        read_csv(path, **{**NAMED, **override})
    assert err.value.field == field and err.value.path == path


def test_gyro_declared_deg_per_s_while_in_rad_per_s_is_named(v102, tmp_path):
    path = tmp_path / "imu.csv"
    lines = _write(path, v102)
    rows = [line.split(",") for line in lines[1:]]
    for row in rows:
        row[4:7] = [f"{np.deg2rad(float(v)):.17g}" for v in row[4:7]]  # the file really holds rad/s
    path.write_text("\n".join([HEADER] + [",".join(r) for r in rows]) + "\n")
    with pytest.raises(DataError, match="gyro is already in rad/s but was converted from deg/s") as err:
        read_csv(path, **NAMED)
    assert err.value.field == "gyro"


def test_nan_ground_truth_rows_are_invalid_but_nan_imu_is_an_error(v102, tmp_path):
    path = tmp_path / "imu.csv"
    lines = _write(path, v102)
    cells = lines[1001].split(",")
    lines[1001] = ",".join(cells[:7] + ["nan"] * 7)
    path.write_text("\n".join(lines) + "\n")
    seq = read_csv(path, **NAMED)
    np.testing.assert_array_equal(np.flatnonzero(~seq.gt.valid), [1000])
    lines[2001] = ",".join(["nan" if i == 2 else c for i, c in enumerate(lines[2001].split(","))])
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match="non-finite") as err:
        read_csv(path, **NAMED)
    assert err.value.line == 2002 and err.value.field == "gyro/acc"


def test_malformed_line_and_unknown_column(v102, tmp_path):
    path = tmp_path / "imu.csv"
    lines = _write(path, v102)
    lines[1500] = lines[1500] + ",3.0"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match="expected 14 columns, got 15") as err:
        read_csv(path, **NAMED)
    assert err.value.line == 1501
    _write(path, v102)
    with pytest.raises(DataError, match="no column named 'ax'"):
        read_csv(path, **{**NAMED, "acc": ("ax", "ay_g", "az_g")})


def test_bad_options_are_config_errors_naming_the_option(tmp_path):
    path = tmp_path / "imu.csv"
    path.write_text("0,0,0,0,0,0,9.81\n")
    with pytest.raises(ConfigError, match="reader option 'time_unit': expected one of s, ms, us, ns"):
        read_csv(path, time_unit="min")
    with pytest.raises(ConfigError, match="reader option 'gt_quat': ground truth needs both gt_pos and gt_quat"):
        read_csv(path, gt_pos=(7, 8, 9))
    with pytest.raises(ConfigError, match=r"reader option 'gyro': expected 3 columns .* got \(1, 2\)"):
        read_csv(path, gyro=(1, 2))
    with pytest.raises(DataError, match="field 'delimiter': an empty delimiter"):
        read_csv(path, delimiter="")


ROWS = ["t,gx,gy,gz,ax,ay,az"] + [f"{0.005 * i:.3f},0.1,0.0,0.0,0.0,0.0,9.81" for i in range(400)]


@pytest.mark.parametrize(
    "name, content, field, message",
    [
        ("semicolons", "\n".join(r.replace(",", ";") for r in ROWS), "file", "looks ';'-separated: pass delimiter=';'"),
        ("tabs", "\n".join(r.replace(",", "\t") for r in ROWS), "file", r"looks '\\t'-separated"),
        ("one sample", "\n".join(ROWS[:2]), "time", "1 IMU sample"),
        ("UTF-16", None, "file", "UTF-16 .* save it as UTF-8"),
    ],
)
def test_a_table_read_wrongly_says_what_to_change(tmp_path, name, content, field, message):
    """Mistakes in the file itself: the refusal names the file, the field and what to change."""
    path = tmp_path / "imu.csv"
    if content is None:
        path.write_bytes("\n".join(ROWS).encode("utf-16"))
    else:
        path.write_text(content + "\n")
    with pytest.raises(DataError, match=message) as err:
        read_csv(path)
    assert err.value.field == field and str(path) in str(err.value)


def test_whitespace_table_without_header_by_index(shared_data):
    """KITTI's IMU file through the generic reader: accel before gyro, whitespace separated."""
    seq = read_csv(
        shared_data / "kitti_gtsam" / "KittiEquivBiasedImu.txt",
        delimiter=None,
        header=True,
        time=0,
        acc=(2, 3, 4),
        gyro=(5, 6, 7),
        checks=ReadChecks(on_gap="keep"),
    ).split_at_gaps()
    assert [len(part) for part in seq] == [46967]  # the lone first row (1.92 s before the rest) is dropped
    assert seq[0].acc.mean(axis=0)[2] == pytest.approx(9.794, abs=1e-3)


def test_three_minute_euroc_imu_by_header_names(shared_data):
    path = shared_data / "euroc" / "MH_01_easy" / "mav0" / "imu0" / "data.csv"
    seq = read_csv(
        path,
        time="timestamp",
        gyro=("w_RS_S_x", "w_RS_S_y", "w_RS_S_z"),
        acc=("a_RS_S_x", "a_RS_S_y", "a_RS_S_z"),
        time_unit="ns",
    )
    assert len(seq) == 36820 and seq.t[-1] - seq.t[0] == pytest.approx(184.095, abs=1e-3)


def test_wrong_quaternion_columns_are_caught_by_the_norm(v102, tmp_path):
    path = tmp_path / "imu.csv"
    _write(path, v102)
    with pytest.raises(DataError, match="quaternion of ground-truth sample 0 has norm") as err:
        read_csv(path, **{**NAMED, "gt_quat": ("px", "qy", "qz", "qw")})
    assert err.value.field == "gt_quat"


def test_time_in_the_wrong_unit_is_named_with_the_unit_that_fits(v102, tmp_path):
    path = tmp_path / "imu.csv"
    _write(path, v102)  # time in ms
    with pytest.raises(DataError, match=r"'time'.*read as 's' the samples come at 0.2 Hz.*'ms' it would be 200 Hz"):
        read_csv(path, **{**NAMED, "time_unit": "s"})
    with pytest.raises(DataError, match=r"read as 'ns' the samples come at 2e\+08 Hz.*time_unit='ms'"):
        read_csv(path, **{**NAMED, "time_unit": "ns"})
