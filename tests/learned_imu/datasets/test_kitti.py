"""KITTI (GTSAM example files) reader on the real data in shared/data/kitti_gtsam."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from airimu_core.errors import DataError
from learned_imu.datasets import ReadChecks, read_sequence
from learned_imu.datasets.kitti import GPS_SIGMA, read_kitti

IMU_ROWS = 46968  # data rows of KittiEquivBiasedImu.txt; the first is dropped (1.92 s before the second)
GPS_ROWS = 470


@pytest.fixture(scope="module")
def kitti(shared_data):
    return read_kitti(shared_data / "kitti_gtsam")


def test_imu_counts_rate_and_units(kitti):
    seq = kitti
    assert len(seq) == IMU_ROWS - 1
    assert seq.t[0] == pytest.approx(46536.397971133) and seq.t[-1] == pytest.approx(47006.014548089)
    assert np.median(np.diff(seq.t)) == pytest.approx(0.009998, abs=1e-5)
    assert np.diff(seq.t).max() < 0.021  # logger jitter only, no gap once the first row is dropped
    # accel columns come before gyro in this file: the mean specific force is ~9.79 m/s^2 up (z)
    np.testing.assert_allclose(seq.acc.mean(axis=0), [-0.053, 0.272, 9.794], atol=2e-3)
    assert np.abs(seq.gyro.mean(axis=0)).max() < 0.02  # rad/s, mean turning rate 0.013 about z
    np.testing.assert_array_equal(seq.gravity, [0.0, 0.0, -9.8])
    assert seq.gt is None


def test_gps_fixes(kitti):
    seq = kitti
    gps = seq.gps
    assert gps.t.shape == (GPS_ROWS - 1,)  # the first fix precedes the IMU and is dropped
    assert gps.t[0] == pytest.approx(46537.387955333)
    assert gps.t[0] >= seq.t[0] and gps.t[-1] <= seq.t[-1]
    np.testing.assert_allclose(gps.pos[0], [3.8971155017667178, 7.5450738511330808, 0.0247879028299991])
    np.testing.assert_allclose(gps.sigma, np.sqrt(0.07))
    assert GPS_SIGMA == pytest.approx(0.26458, abs=1e-5)
    speed = np.linalg.norm(np.diff(gps.pos[:, :2], axis=0), axis=1) / np.diff(gps.t)
    assert speed.max() < 20.0  # m/s: a car in a city, so X/Y are metres
    path_2d = np.linalg.norm(np.diff(gps.pos[:, :2], axis=0), axis=1).sum()
    assert path_2d == pytest.approx(3708, rel=0.01)  # the README's 2-D path length


def test_default_path_is_gtsams_copy_and_matches_shared_data(kitti):
    seq = read_kitti()
    np.testing.assert_array_equal(seq.t, kitti.t)
    np.testing.assert_array_equal(seq.acc, kitti.acc)


def test_keeping_the_first_row_reports_the_gap(shared_data):
    with pytest.raises(DataError, match="gap of 1.92 s") as err:
        read_kitti(shared_data / "kitti_gtsam", skip_first=False)
    assert err.value.line == 3  # header, first row, then the row after the gap
    kept = read_kitti(shared_data / "kitti_gtsam", skip_first=False, gps_file=None, checks=ReadChecks(on_gap="keep"))
    parts = kept.split_at_gaps()
    assert len(parts) == 1 and len(parts[0]) == IMU_ROWS - 1  # a 1-sample part is not a sequence


def test_malformed_imu_row(shared_data, tmp_path):
    lines = (shared_data / "kitti_gtsam" / "KittiEquivBiasedImu.txt").read_text().splitlines()[:300]
    lines[120] = lines[120].replace(" ", "  ", 1) + " 7"
    (tmp_path / "KittiEquivBiasedImu.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match="expected 8 columns, got 9") as err:
        read_kitti(tmp_path, gps_file=None)
    assert err.value.line == 121


@pytest.mark.parametrize("skip_first", [True, False])
def test_a_repeated_time_stamp_names_its_own_line(shared_data, tmp_path, skip_first):
    lines = (shared_data / "kitti_gtsam" / "KittiEquivBiasedImu.txt").read_text().splitlines()[:300]
    lines = lines if skip_first else [lines[0], *lines[2:]]  # without the first row's 1.92 s gap when it is kept
    lines[150] = lines[149]  # file line 151 repeats line 150
    (tmp_path / "KittiEquivBiasedImu.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match="Time") as err:
        read_kitti(tmp_path, gps_file=None, skip_first=skip_first)
    assert err.value.line == 151


@pytest.mark.slow
def test_module_does_not_import_gtsam():
    code = "import sys, learned_imu.datasets; print('gtsam' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout
    assert out.strip() == "False"


def test_gps_fixes_all_outside_the_imu_span_name_the_file_and_both_spans(shared_data, tmp_path):
    source = shared_data / "kitti_gtsam"
    for name in ("KittiEquivBiasedImu.txt", "KittiEquivBiasedImu_metadata.txt"):
        (tmp_path / name).symlink_to(source / name)
    lines = (source / "KittiGps_converted.txt").read_text().splitlines()
    shifted = [lines[0]] + [",".join([repr(float(x.split(",")[0]) + 1e5), *x.split(",")[1:]]) for x in lines[1:]]
    (tmp_path / "KittiGps_converted.txt").write_text("\n".join(shifted) + "\n")  # a clock 1e5 s off
    with pytest.raises(
        DataError,
        match=r"KittiGps_converted.txt: field 'gps': none of the 470 GPS fixes, "
        r"\[146534.4\d+, 147005.3\d+\] s, lies within the IMU's time span "
        r"\[46536.3\d+, 47006.0\d+\] s",
    ):
        read_sequence("kitti", tmp_path)
