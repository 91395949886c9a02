"""The frame and motion self-checks take a real accelerometer bias for what it is, and still refuse the
convention and unit mistakes (issue: a gentle EuRoC flight with its 0.55 m/s^2 bias was refused as a unit error)."""

from __future__ import annotations

import numpy as np
import pytest

from airimu_core.errors import DataError
from learned_imu.datasets import read_sequence
from learned_imu.datasets._checks import check_frame

FLIGHTS = (
    "MH_01_easy",
    "MH_03_medium",
    "MH_04_difficult",
    "MH_05_difficult",
    "V1_02_medium",
    "V1_03_difficult",
    "V2_01_easy",
    "V2_02_medium",
    "V2_03_difficult",
)  # every shared flight with its IMU


def _check(seq, acc=None, gyro=None, pos=None) -> None:
    gt = seq.gt
    check_frame(
        seq.t,
        seq.gyro if gyro is None else gyro,
        seq.acc if acc is None else acc,
        gt.rot,
        gt.valid,
        seq.gravity,
        seq.source,
        "gt",
        gt.vel,
        pos=gt.pos if pos is None else pos,
        vel_given=True,
    )


@pytest.mark.slow
@pytest.mark.parametrize("flight", FLIGHTS)
def test_a_biased_accelerometer_passes_and_the_usual_mistakes_are_still_refused(shared_data, flight):
    seq = read_sequence("euroc", shared_data / "euroc" / flight, check_frame=False)
    _check(seq)
    for axis in range(3):
        for bias in (0.55, 1.0):  # m/s^2, EuRoC's own bias and about twice it
            acc = seq.acc.copy()
            acc[:, axis] += bias
            _check(seq, acc=acc)
    mistakes = {
        "gt.rot": {"acc": seq.acc[:, [1, 0, 2]]},  # acc axes permuted (x <-> y)
        "acc": {"acc": seq.acc / 9.80665},  # acc in g
        "gyro": {"gyro": np.degrees(seq.gyro)},  # gyro in deg/s
        "gt.pos": {"pos": seq.gt.pos * 1000.0},  # positions in mm
    }
    for field, change in mistakes.items():
        with pytest.raises(DataError, match=f"field '{field}'"):
            _check(seq, **change)
    with pytest.raises(DataError, match="field 'gt.rot'"):
        _check(seq, acc=seq.acc[:, [2, 1, 0]])  # x <-> z


def test_v2_01_with_the_bias_of_v1_01_reads_by_default(shared_data, tmp_path):
    """The issue's case through the reader: V2_01_easy with 0.55 m/s^2 added to acc y was refused."""
    source = shared_data / "euroc" / "V2_01_easy" / "mav0"
    imu = np.loadtxt(source / "imu0" / "data.csv", delimiter=",", comments="#")
    imu[:, 5] += 0.55
    folder = tmp_path / "V2_01_biased" / "mav0"
    (folder / "imu0").mkdir(parents=True)
    np.savetxt(folder / "imu0" / "data.csv", imu, delimiter=",", fmt=["%d"] + ["%.17g"] * 6)
    (folder / "state_groundtruth_estimate0").mkdir()
    (folder / "state_groundtruth_estimate0" / "data.csv").symlink_to(
        source / "state_groundtruth_estimate0" / "data.csv"
    )
    seq = read_sequence("euroc", tmp_path / "V2_01_biased")
    assert seq.gt.valid.mean() > 0.99


def test_positions_in_mm_on_a_parked_car_are_refused(shared_data):
    """KITTI 2011_09_28_drive_0039: the car hardly moves (1-s displacements of the integrated velocity 0.09 m rms,
    too little to judge a scale) while its GNSS/INS position wanders by 0.36 m rms: accepted in m; in mm the ground
    truth moves hundreds of "metres" a second against a still IMU and is refused naming the unit."""
    path = shared_data / "kitti_raw" / "2011_09_28_drive_0039.csv"
    options = {"on_duplicate": "drop", "on_gap": "keep", "on_backward": "drop"}
    seq = read_sequence("kitti_raw", path, check_frame=False, **options)
    gt = seq.gt

    def run(scale: float) -> None:
        check_frame(
            seq.t,
            seq.gyro,
            seq.acc,
            gt.rot,
            gt.valid,
            seq.gravity,
            seq.source,
            "gt",
            gt.vel,
            pos=gt.pos * scale,
            vel_given=True,
            interval_s=0.3,
        )

    run(1.0)
    expected = (
        r"field 'gt.pos': motion self-check failed: .* displacement is 36\d(\.\d)? m rms while that of the "
        r"integrated velocity is 0.0\d+ m: positions in mm or cm"
    )
    with pytest.raises(DataError, match=expected):
        run(1000.0)


def test_an_infinite_ground_truth_value_is_refused_and_nan_stays_a_missing_sample(shared_data, tmp_path):
    source = shared_data / "euroc" / "V1_02_medium" / "mav0"
    folder = tmp_path / "V1_02" / "mav0"
    (folder / "imu0").mkdir(parents=True)
    (folder / "imu0" / "data.csv").symlink_to(source / "imu0" / "data.csv")
    (folder / "state_groundtruth_estimate0").mkdir()
    lines = (source / "state_groundtruth_estimate0" / "data.csv").read_text().splitlines()
    gt_file = folder / "state_groundtruth_estimate0" / "data.csv"
    for marker, accepted in (("nan", True), ("inf", False), ("-inf", False)):
        edited = list(lines)
        fields = edited[500].split(",")
        fields[1] = marker
        edited[500] = ",".join(fields)
        gt_file.write_text("\n".join(edited) + "\n")
        if accepted:
            assert (~read_sequence("euroc", tmp_path / "V1_02").gt.valid).sum() >= 1
        else:
            with pytest.raises(DataError, match="field 'gt': ground-truth sample 499 .* holds an infinite value"):
                read_sequence("euroc", tmp_path / "V1_02")
