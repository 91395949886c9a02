"""Shared reader machinery: table parsing with line numbers, time stamps, resampling, velocity, units and frame
self-check (on real EuRoC V1_02 data), the readers' ReadChecks record, and the reader registry."""

from __future__ import annotations

import functools

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from airimu_core.errors import ConfigError, DataError, InputError
from airimu_core.rotations import matrix_to_quat_wxyz, quat_to_matrix
from airimu_core.table import read_table
from learned_imu.config import SequenceConfig
from learned_imu.datasets import READERS, ReadChecks, read_sequence
from learned_imu.datasets._assemble import VEL_WINDOW_S, GtSamples, differentiate_positions, resample_ground_truth
from learned_imu.datasets._checks import (
    ACC_TOL,
    GYRO_TOL,
    check_frame,
    check_timestamps,
    check_units,
    frame_score,
    gap_indices,
    segments,
)
from learned_imu.datasets.broad import read_broad
from learned_imu.datasets.csv import read_csv
from learned_imu.datasets.euroc import read_euroc
from learned_imu.datasets.kitti import read_kitti
from learned_imu.datasets.kitti_raw import read_kitti_raw


@pytest.fixture(scope="module")
def v102(shared_data):
    """Real V1_02 IMU excerpt with the official ground truth, read without the frame check."""
    return read_euroc(
        shared_data / "euroc" / "V1_02_medium",
        imu_file="mav0/imu0/data_partial_first40s.csv",
        checks=ReadChecks(check_frame=False),
    )


# --- tables -------------------------------------------------------------------------------------------------


def test_table_reports_the_line_of_a_truncated_row(tmp_path):
    path = tmp_path / "imu.csv"
    path.write_text("#t,gx,gy,gz\n\n0.0,1,2,3\n# a comment\n0.1,1,2,3\n0.2,1,2\n0.3,1,2,3\n")
    with pytest.raises(DataError) as err:
        read_table(path)
    assert err.value.line == 6 and err.value.path == path
    assert "expected 4 columns, got 3" in str(err.value)


def test_table_reports_a_non_number_and_an_empty_cell(tmp_path):
    path = tmp_path / "imu.csv"
    path.write_text("t,a\n0,1\n1,x1\n")
    with pytest.raises(DataError, match="'x1' is not a number") as err:
        read_table(path)
    assert err.value.line == 3
    path.write_text("0,1\n1,\n2,3\n")
    with pytest.raises(DataError, match="empty value") as err:
        read_table(path)
    assert err.value.line == 2


def test_table_header_names_and_line_of_rows(tmp_path):
    path = tmp_path / "imu.csv"
    path.write_text("#timestamp [ns],w_x [rad s^-1]\n# note\n10,0.5\n\n20,nan\n")
    table = read_table(path)
    assert table.header == ("timestamp [ns]", "w_x [rad s^-1]")
    assert table.column_index("w_x", "f") == 1 and table.column_index("w_x [rad s^-1]", "f") == 1
    assert table.line_of(1) == 5
    with pytest.raises(DataError, match="non-finite") as err:
        table.require_finite(table.data, "w")
    assert err.value.line == 5
    with pytest.raises(DataError, match="no column named 'w_y'"):
        table.column_index("w_y", "f")


# --- time stamps and gaps -----------------------------------------------------------------------------------


def test_duplicate_time_stamps_raise_or_are_dropped():
    t = np.array([0.0, 0.1, 0.1, 0.2, 0.3, 0.3])
    with pytest.raises(DataError, match="duplicated time stamp") as err:
        check_timestamps(t, "f.csv", line_of=lambda row: row + 2)
    assert err.value.line == 4  # row 2 -> line 4 with the mapping above
    keep = check_timestamps(t, "f.csv", on_duplicate="drop")
    np.testing.assert_array_equal(keep, [0, 1, 3, 4])


def test_time_going_backwards_raises_even_when_dropping_duplicates():
    with pytest.raises(DataError, match="time goes backwards") as err:
        check_timestamps(np.array([0.0, 0.2, 0.1]), "f.csv", on_duplicate="drop", line_of=lambda row: 10 + row)
    assert err.value.line == 12


def test_gaps_and_segments():
    t = np.concatenate([np.arange(10) * 0.01, 0.5 + np.arange(5) * 0.01])
    np.testing.assert_array_equal(gap_indices(t), [9])
    assert [(s.start, s.stop) for s in segments(t)] == [(0, 10), (10, 15)]
    jitter = np.cumsum(np.full(50, 0.01) + 0.004 * np.sin(np.arange(50)))
    assert gap_indices(jitter).size == 0  # jitter of 40 % is not a gap


# --- resampling and velocity --------------------------------------------------------------------------------


def test_velocity_is_exact_for_a_cubic_on_uneven_stamps():
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.004, 0.006, 400))
    pos = np.stack([t**3 - 2 * t, 0.5 * t**2, np.full_like(t, 3.0)], axis=1)
    vel = differentiate_positions(t, pos)
    expected = np.stack([3 * t**2 - 2, t, np.zeros_like(t)], axis=1)
    np.testing.assert_allclose(vel, expected, atol=1e-8)


def test_velocity_never_crosses_a_gap():
    t = np.concatenate([np.arange(100) * 0.005, 10 + np.arange(100) * 0.005])
    pos = np.where(t[:, None] < 5, 1.0, 2.0) * t[:, None] * np.ones(3)  # slope 1 then 2, jump across the gap
    vel = differentiate_positions(t, pos)
    np.testing.assert_allclose(vel[:100], 1.0, atol=1e-9)
    np.testing.assert_allclose(vel[100:], 2.0, atol=1e-9)


def test_resampling_slerps_rotation_and_masks_gaps_and_nan_rows():
    t_gt = np.array([0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 20.0, 21.0])
    angle = 0.03 * t_gt
    rot = Rotation.from_rotvec(angle[:, None] * np.array([0.0, 0.0, 1.0])).as_matrix()
    pos = np.stack([t_gt, 2 * t_gt, 0 * t_gt], axis=1)
    valid = np.ones(t_gt.size, bool)
    valid[3] = False  # an isolated NaN row
    gt = GtSamples(t_gt, rot, pos, np.ones_like(pos), valid, "gt.txt")
    t = np.array([0.5, 2.9, 3.1, 3.6, 10.0, 20.5])
    out = resample_ground_truth(t, gt)
    yaw = Rotation.from_matrix(out.rot).as_rotvec()[:, 2]
    np.testing.assert_allclose(yaw[[0, 5]], 0.03 * t[[0, 5]], atol=1e-12)
    np.testing.assert_allclose(out.pos[:, 0], t, atol=1e-12)
    # 2.9 and 3.1 are nearest to the NaN row; 3.6 is nearest to a valid row, its 2 s interval is no gap
    # (median step 1 s, gaps start at 5); 10.0 lies in the 14 s gap
    np.testing.assert_array_equal(out.valid, [True, False, False, True, False, True])


# --- units and frame self-check on real data ----------------------------------------------------------------


def test_units_check_passes_on_real_data_and_names_g_and_deg_per_s(v102):
    check_units(v102.acc, v102.gyro, "v102")
    with pytest.raises(DataError, match="acc looks like it is in g") as err:
        check_units(v102.acc / 9.81, v102.gyro, "v102")
    assert err.value.field == "acc"
    with pytest.raises(DataError, match="gyro looks like it is in deg/s") as err:
        check_units(v102.acc, np.rad2deg(v102.gyro), "v102")
    assert err.value.field == "gyro"
    with pytest.raises(DataError, match="expected about 9.81"):
        check_units(v102.acc * 1000, v102.gyro, "v102")  # mm/s^2
    with pytest.raises(DataError, match="gyro and acc columns swapped") as err:  # was "acc looks like it is in g"
        check_units(v102.gyro, v102.acc, "v102")
    assert err.value.field == "gyro/acc"


def test_frame_self_check_passes_on_real_data(v102):
    score = check_frame(v102.t, v102.gyro, v102.acc, v102.gt.rot, v102.gt.valid, v102.gravity, "v102")
    assert score.acc < 0.02 < ACC_TOL  # measured 0.006: mean world acceleration + bias ~ 0.06 m/s^2
    assert score.gyro < 0.05 < GYRO_TOL  # measured 0.012 after removing the constant gyro bias
    np.testing.assert_allclose(score.mean_world_acc, [0, 0, 9.81], atol=0.1)


def _misread_quaternion(rot: np.ndarray, true_order: str) -> np.ndarray:
    """Rotations a reader gets when the file is in ``true_order`` and read in the other order."""
    q_wxyz = matrix_to_quat_wxyz(rot)
    in_file = q_wxyz if true_order == "wxyz" else q_wxyz[:, [1, 2, 3, 0]]
    return quat_to_matrix(in_file, "xyzw" if true_order == "wxyz" else "wxyz")


@pytest.mark.parametrize(
    ("misread", "field", "hint"),
    [
        (lambda s: (s.gyro, s.acc, _misread_quaternion(s.gt.rot, "xyzw")), "gt.rot", "file is scalar-last"),
        (lambda s: (s.gyro, s.acc, _misread_quaternion(s.gt.rot, "wxyz")), "gt.rot", "file is scalar-first"),
        (lambda s: (s.gyro, s.acc, np.swapaxes(s.gt.rot, 1, 2)), "gt.rot", "rotation inverted"),
        (lambda s: (s.gyro, s.acc / 9.80665, s.gt.rot), "acc", "acc is in g"),
        (lambda s: (s.gyro, s.acc * 9.80665, s.gt.rot), "acc", "already in m/s^2"),
        (lambda s: (np.rad2deg(s.gyro), s.acc, s.gt.rot), "gyro", "gyro is in deg/s"),
        (lambda s: (np.deg2rad(s.gyro), s.acc, s.gt.rot), "gyro", "already in rad/s"),
    ],
)
def test_frame_self_check_names_the_misread_convention(v102, misread, field, hint):
    gyro, acc, rot = misread(v102)
    assert not frame_score(v102.t, gyro, acc, rot, v102.gt.valid, v102.gravity).ok
    with pytest.raises(DataError, match="frame self-check failed") as err:
        check_frame(v102.t, gyro, acc, rot, v102.gt.valid, v102.gravity, "imu.csv", "gt.csv")
    assert err.value.field == field and hint in str(err.value)
    assert err.value.path == ("gt.csv" if field == "gt.rot" else "imu.csv")


def test_frame_self_check_without_a_fitting_convention(v102):
    rng = np.random.default_rng(1)
    rot = Rotation.random(len(v102), random_state=rng).as_matrix()
    with pytest.raises(DataError, match="none of the usual mistakes"):
        check_frame(v102.t, v102.gyro, v102.acc, rot, v102.gt.valid, v102.gravity, "imu.csv")


# --- the readers' checks: one record, flat in configs and at the dispatcher ----------------------------------


def test_read_checks_defaults_are_the_strict_ones():
    checks = ReadChecks()
    assert (checks.on_duplicate, checks.on_gap) == ("error", "error")
    assert checks.crop_to_gt and checks.check_frame and checks.check_units
    assert checks.vel_window_s == VEL_WINDOW_S == 0.05


@pytest.mark.parametrize(
    "field, value, problem",
    [
        ("on_duplicate", "keep", "expected one of error, drop, got 'keep'"),
        ("on_gap", "skip", "expected one of error, keep, got 'skip'"),
        ("on_gap", "split", "'split' is a step of its own: read with on_gap='keep', then .split_at_gaps()"),
        ("crop_to_gt", "no", "expected True or False, got 'no'"),
        ("check_frame", 0, "expected True or False, got 0"),
        ("check_units", None, "expected True or False, got None"),
        ("vel_window_s", 0.0, "expected a positive number of seconds, got 0.0"),
        ("vel_window_s", -0.05, "expected a positive number of seconds, got -0.05"),
        ("vel_window_s", float("nan"), "expected a positive number of seconds, got nan"),
        ("vel_window_s", float("inf"), "expected a positive number of seconds, got inf"),
        ("vel_window_s", "0.05", "expected a positive number of seconds, got '0.05'"),
        ("vel_window_s", True, "expected a positive number of seconds, got True"),
    ],
)
def test_read_checks_refuse_a_bad_value_naming_the_field(field, value, problem):
    with pytest.raises(InputError) as err:
        ReadChecks(**{field: value})
    assert str(err.value) == f"ReadChecks.{field}: {problem}"


def _imu_csv(path):
    """200 Hz at rest: a duplicated stamp at row 100, 20 samples missing after row 200 (a 0.105-s gap)."""
    t = np.arange(400) * 0.005
    rows = np.concatenate([np.arange(101), np.arange(100, 201), np.arange(221, 400)])
    imu = np.column_stack([t[rows], np.zeros((rows.size, 3)), np.tile([0.0, 0.0, 9.81], (rows.size, 1))])
    np.savetxt(path, imu, delimiter=",", fmt="%.6f")
    return path


def test_flat_options_reach_the_reader_as_one_record(tmp_path, monkeypatch):
    path = _imu_csv(tmp_path / "imu.csv")
    with pytest.raises(DataError, match="duplicated time stamp"):
        read_sequence("csv", path)
    with pytest.raises(DataError, match="gap of 0.105 s"):
        read_sequence("csv", path, on_duplicate="drop")
    seen = {}

    @functools.wraps(read_csv)  # check_options reads the signature through __wrapped__
    def spy(path, **options):
        seen.update(options)
        return read_csv(path, **options)

    monkeypatch.setitem(READERS, "csv", spy)
    seq = read_sequence("csv", path, on_duplicate="drop", on_gap="keep", vel_window_s=0.1, name="rest")
    assert seen == {"checks": ReadChecks(on_duplicate="drop", on_gap="keep", vel_window_s=0.1), "name": "rest"}
    assert len(seq) == 380 and [len(p) for p in seq.split_at_gaps()] == [201, 179]


@pytest.mark.parametrize(
    "options, message",
    [
        ({"on_gap": "skip"}, "options 'on_gap': expected one of error, keep, split, got 'skip'"),
        ({"on_duplicate": 1}, "options 'on_duplicate': expected one of error, drop, got 1"),
        ({"check_frame": "no"}, "options 'check_frame': expected bool, got 'no' (str)"),
        ({"vel_window_s": 0}, "options 'vel_window_s': expected a positive number (s), got 0"),
        (
            {"checks": {}},
            "options 'checks': euroc has no such option; its options: check_frame, check_units, "
            "crop_to_gt, gravity, ground_truth, gt_file, imu_delay_s, imu_file, on_duplicate, on_gap, vel_window_s",
        ),
        ({"imu_delay_s": 50}, "options 'imu_delay_s': expected a delay (s) within +-0.5, got 50 (a value in ms?)"),
    ],
)
def test_config_options_are_checked_against_the_record(options, message):
    with pytest.raises(ConfigError) as err:
        SequenceConfig("euroc", "x", options)
    assert str(err.value) == message


@pytest.mark.parametrize(
    "reader, dataset, field, value",
    [
        (read_kitti, "kitti", "crop_to_gt", False),
        (read_kitti, "kitti", "check_frame", False),
        (read_kitti, "kitti", "vel_window_s", 0.2),
        (read_kitti_raw, "kitti_raw", "crop_to_gt", False),
        (read_kitti_raw, "kitti_raw", "vel_window_s", 0.2),
        (read_broad, "broad", "on_duplicate", "drop"),
    ],
)
def test_a_check_the_reader_cannot_honour_is_refused(tmp_path, reader, dataset, field, value):
    with pytest.raises(InputError, match=rf"^ReadChecks\.{field}: {reader.__name__} cannot honour {value!r} \("):
        reader(tmp_path, checks=ReadChecks(**{field: value}))
    with pytest.raises(DataError):  # at its default the field is no obstacle: the reader goes on to the path
        reader(tmp_path / "missing", checks=ReadChecks(**{field: getattr(ReadChecks(), field)}))
    with pytest.raises(ConfigError, match=rf"reader option '{field}': {dataset} has no such option"):
        read_sequence(dataset, tmp_path, **{field: value})


# --- registry -----------------------------------------------------------------------------------------------


def test_registry_lists_the_readers_and_rejects_unknown_names(shared_data):
    assert set(READERS) == {"euroc", "kitti", "kitti_raw", "broad", "rosbag", "csv", "tumvi"}
    known = "broad, csv, euroc, kitti, kitti_raw, rosbag, tumvi"
    with pytest.raises(ValueError, match=f"unknown dataset 'tum_vi'; known datasets: {known}"):
        read_sequence("tum_vi", shared_data)
    seq = read_sequence("kitti", shared_data / "kitti_gtsam")
    assert len(seq) == 46967
