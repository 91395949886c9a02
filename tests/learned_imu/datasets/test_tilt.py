"""The gyro's unit from gravity and a car's turns, with no ground truth and no GPS (``learned_imu.datasets._tilt``),
on real logs."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from airimu_core.errors import DataError
from learned_imu.datasets import read_sequence
from learned_imu.datasets._tilt import (
    TILT_MIN_SPREAD,
    TURN_MAX_SPEED,
    TURN_MIN_WINDOWS,
    check_gyro_unit,
    gravity_spread,
    turn_speeds,
)

KITTI = {"on_backward": "drop", "on_duplicate": "drop", "on_gap": "keep"}
LOGS = [  # a car, a drone on its most aggressive flight, a hand-held sensor turned about, a hand-held camera
    ("kitti_raw", "kitti_raw/2011_10_03_drive_0047.csv", KITTI),
    ("euroc", "euroc/V1_03_difficult", {}),
    ("broad", "broad/01_undisturbed_slow_rotation_A.mat", {}),
    ("tumvi", "tumvi/dataset-room4_512_16", {}),
]


@pytest.fixture(scope="module", params=LOGS, ids=lambda log: log[1].split("/")[1])
def log(request, shared_data):
    dataset, path, options = request.param
    return read_sequence(dataset, shared_data / path, **options)


def _refusal(seq, factor) -> str | None:
    try:
        check_gyro_unit(seq.t, seq.gyro * factor, seq.acc, "imu.csv")
    except DataError as error:
        return str(error)
    return None


def test_right_gyro_passes_and_deg_or_mrad_per_s_is_refused(log):
    as_read = gravity_spread(log.t, log.gyro, log.acc)
    assert as_read is not None and as_read.spread < TILT_MIN_SPREAD / 1.4  # a margin below the refusal
    assert _refusal(log, 1.0) is None
    for factor, unit in ((180.0 / np.pi, "deg/s"), (1000.0, "mrad/s")):
        message = _refusal(log, factor)
        assert message is not None, unit
        assert "imu.csv" in message and "gyro" in message and unit in message.split("gyro in ")[1]


def test_the_fitted_bias_is_the_gyro_bias(shared_data):
    """EuRoC's raw gyro bias tilts a 20-s stretch by up to a radian; the fit finds it (ground truth's mean bias on
    MH_04: about (-0.002, 0.021, 0.076) rad/s) and the spread as read is then the drone's own accelerations."""
    seq = read_sequence("euroc", shared_data / "euroc/MH_04_difficult")
    fit = gravity_spread(seq.t, seq.gyro, seq.acc)
    assert np.abs(fit.bias[1:] - [0.021, 0.076]).max() < 0.01
    no_bias_fit = dataclasses.replace(seq, gyro=seq.gyro - fit.bias)
    assert gravity_spread(no_bias_fit.t, no_bias_fit.gyro, no_bias_fit.acc).spread == pytest.approx(fit.spread, 0.2)


def test_gyro_shrunk_on_a_platform_that_tilts(shared_data):
    """A rad/s file converted as if deg/s, on a sensor turned through gravity (BROAD): named from gravity. On a
    drone it is not decidable (module docstring), and nothing is said there."""
    seq = read_sequence("broad", shared_data / "broad/01_undisturbed_slow_rotation_A.mat")
    message = _refusal(seq, np.pi / 180.0)
    assert message is not None and "converted as if deg/s" in message and "gravity" in message
    drone = read_sequence("euroc", shared_data / "euroc/V1_03_difficult")
    assert _refusal(drone, np.pi / 180.0) is None


@pytest.mark.parametrize("drive", ["2011_10_03_drive_0047", "2011_09_30_drive_0028"])
def test_gyro_shrunk_on_a_car_is_named_by_its_turns(shared_data, drive):
    """A car's turns: force over yaw rate is its speed (a city drive: 5-15 m/s); a rad/s gyro converted as if deg/s
    puts it 57x higher, and the message names that reading. 0047 is 87 s with the fewest turns that decide."""
    car = read_sequence("kitti_raw", shared_data / f"kitti_raw/{drive}.csv", **KITTI)
    speeds = turn_speeds(car.t, car.gyro, car.acc)
    assert len(speeds) >= TURN_MIN_WINDOWS and 4.0 < np.median(speeds) < 16.0
    assert _refusal(car, 1.0) is None
    message = _refusal(car, np.pi / 180.0)
    assert message is not None and "imu.csv" in message and "centripetal" in message
    assert "gyro in rad/s converted as if deg/s?" in message
    shrunk = turn_speeds(car.t, car.gyro * np.pi / 180.0, car.acc)  # R^2 and force do not see the gyro's scale
    assert len(shrunk) == len(speeds) and np.median(shrunk) > TURN_MAX_SPEED


def test_turns_decide_nothing_on_a_drone_or_a_hand_held_camera(shared_data):
    """Where the force does not follow the yaw, too few windows hold to decide, whatever the gyro's scale."""
    for dataset, path in (("euroc", "euroc/MH_04_difficult"), ("tumvi", "tumvi/dataset-room6_512_16")):
        seq = read_sequence(dataset, shared_data / path)
        assert len(turn_speeds(seq.t, seq.gyro, seq.acc)) < TURN_MIN_WINDOWS, path


def test_reader_without_ground_truth_refuses_a_deg_per_s_gyro(shared_data, tmp_path):
    """The readers run the check on every log without ground truth: a user's CSV of a KITTI drive, gyro in deg/s."""
    seq = read_sequence("kitti_raw", shared_data / "kitti_raw/2011_10_03_drive_0047.csv", **KITTI)
    path = tmp_path / "imu.csv"
    np.savetxt(path, np.column_stack([seq.t, np.degrees(seq.gyro), seq.acc]), delimiter=",")
    with pytest.raises(DataError, match=r"imu\.csv.*gyro.*deg/s"):
        read_sequence("csv", path, on_gap="keep")
    assert len(read_sequence("csv", path, on_gap="keep", gyro_unit="deg/s").t) == len(seq.t)
    right = tmp_path / "imu_rad.csv"  # a rad/s file read with gyro_unit=deg/s: the car's turns name it
    np.savetxt(right, np.column_stack([seq.t, seq.gyro, seq.acc]), delimiter=",")
    with pytest.raises(DataError, match=r"imu_rad\.csv.*gyro.*converted as if deg/s"):
        read_sequence("csv", right, on_gap="keep", gyro_unit="deg/s")


def test_dead_reckoning_refuses_a_deg_per_s_gyro(shared_data):
    """``fuse()`` without GPS on a sequence built in code (no reader ran): the same check."""
    import gtsam

    from airimu.fuse import fuse

    seq = read_sequence("euroc", shared_data / "euroc/V2_02_medium")
    start = gtsam.NavState(gtsam.Rot3(seq.gt.rot[0]), seq.gt.pos[0], seq.gt.vel[0])
    wrong = dataclasses.replace(seq, gyro=np.degrees(seq.gyro), gt=None, gps=None)
    with pytest.raises(DataError, match="deg/s"):
        fuse(wrong, None, start=start)
