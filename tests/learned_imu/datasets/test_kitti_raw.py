"""KITTI raw OXTS reader on the 39 real drives of the shared data (CSV layout) and on an official ``oxts/`` folder the
test writes from one real drive's rows."""

from __future__ import annotations

from datetime import timedelta

import numpy as np
import pytest

from airimu_core.errors import DataError, InputError
from learned_imu.config import SequenceConfig
from learned_imu.datasets import read_sequence
from learned_imu.datasets.kitti_raw import OXTS_FIELDS
from learned_imu.training.experiment import load_sequence

REPAIR = {"on_backward": "drop", "on_duplicate": "drop", "on_gap": "keep"}


def drives(shared_data):
    return sorted((shared_data / "kitti_raw").glob("*.csv"))


@pytest.mark.slow
def test_every_shared_drive_reads_and_passes_the_frame_self_check(shared_data):
    paths = drives(shared_data)
    assert len(paths) == 39
    for path in paths:  # build_sequence runs the frame self-check (raises on a misread convention)
        seq = read_sequence("kitti_raw", path, **REPAIR)
        assert seq.gt is not None and len(seq) > 2000 and np.all(np.diff(seq.t) > 0), path.name


def test_ground_truth_velocity_and_attitude_come_from_the_file(shared_data):
    path = shared_data / "kitti_raw" / "2011_09_30_drive_0016.csv"  # clean time stamps: every row kept
    raw = np.loadtxt(path, delimiter=",", comments="#")
    seq = read_sequence("kitti_raw", path)
    assert len(seq) == len(raw)
    np.testing.assert_array_equal(seq.gt.vel, raw[:, 13:16])  # ENU velocity, not differentiated
    np.testing.assert_array_equal(seq.gt.pos, raw[:, 7:10])
    roll, pitch, yaw = raw[:, 10:13].T
    rot = seq.gt.rot
    np.testing.assert_allclose(np.arctan2(rot[:, 1, 0], rot[:, 0, 0]), yaw, atol=1e-9)  # Rz(yaw) Ry(pitch) Rx(roll)
    np.testing.assert_allclose(-np.arcsin(rot[:, 2, 0]), pitch, atol=1e-9)
    np.testing.assert_allclose(np.arctan2(rot[:, 2, 1], rot[:, 2, 2]), roll, atol=1e-9)
    np.testing.assert_array_equal(seq.gyro, raw[:, 1:4])
    assert seq.gravity[2] == pytest.approx(-9.80655)


def test_timestamp_anomalies_get_clear_errors_and_the_repair_options(shared_data):
    path = shared_data / "kitti_raw" / "2011_09_26_drive_0014.csv"  # 2 backward steps, 2 gaps of 70 ms
    # the README's anomaly table: row 502 (0-based) steps back to row 503, which is file line 505 (after the header)
    with pytest.raises(DataError, match=r"2011_09_26_drive_0014\.csv.*line 505.*time goes backwards.*on_backward"):
        read_sequence("kitti_raw", path)
    with pytest.raises(DataError, match=r"duplicated time stamp.*on_duplicate='drop'"):
        read_sequence("kitti_raw", path, on_backward="drop")
    with pytest.raises(DataError, match=r"gap of .* s.*pass on_gap='keep' \(then split_at_gaps\(\)"):
        read_sequence("kitti_raw", path, on_backward="drop", on_duplicate="drop")
    whole = read_sequence("kitti_raw", path, on_backward="drop", on_duplicate="drop", on_gap="keep")
    parts = whole.split_at_gaps()
    assert len(parts) == 3 and all(np.all(np.diff(p.t) < 0.02) for p in parts)
    assert sum(len(p) for p in parts) == len(whole) and [p.name for p in parts][-1].endswith("_part2")
    # readers return one sequence
    with pytest.raises(InputError, match=r"ReadChecks\.on_gap: 'split' is a step of its own"):
        read_sequence("kitti_raw", path, on_backward="drop", on_duplicate="drop", on_gap="split")
    spec = SequenceConfig("kitti_raw", str(path), {"on_backward": "drop", "on_duplicate": "drop", "on_gap": "split"})
    assert [len(p) for p in load_sequence(spec, ".")] == [len(p) for p in parts]  # a config's on_gap: split
    with pytest.raises(ValueError, match="reader option 'on_backward': expected one of error, drop"):
        read_sequence("kitti_raw", path, on_backward="sort")


def write_oxts_folder(folder, raw, lat0=49.011, lon0=8.416, alt0=112.0):
    """An official KITTI raw drive folder (``oxts/timestamps.txt`` + ``oxts/data/NNNNNNNNNN.txt``) from rows of
    the shared CSV; lat / lon / alt from its ENU positions about an origin near Karlsruhe."""
    import pymap3d

    data = folder / "oxts" / "data"
    data.mkdir(parents=True)
    lat, lon, alt = pymap3d.enu2geodetic(raw[:, 7], raw[:, 8], raw[:, 9], lat0, lon0, alt0)
    stamps = []
    for k, row in enumerate(raw):
        fields = np.zeros(OXTS_FIELDS)
        fields[[0, 1, 2]] = lat[k], lon[k], alt[k]
        fields[[3, 4, 5]] = row[10:13]  # roll, pitch, yaw
        fields[[6, 7, 10]] = row[14], row[13], row[15]  # vn, ve, vu
        fields[[11, 12, 13]] = row[4:7]  # ax, ay, az
        fields[[17, 18, 19]] = row[1:4]  # wx, wy, wz
        fields[25:] = [4, 10, 5, 5, 6]  # navstat, numsats, posmode, velmode, orimode
        (data / f"{k:010d}.txt").write_text(" ".join(f"{v:.17g}" for v in fields) + "\n")
        clock = timedelta(seconds=float(row[0]))
        whole = int(clock.total_seconds())
        nanos = int(round((row[0] - whole) * 1e9))
        stamps.append(f"2011-09-30 {whole // 3600:02d}:{whole % 3600 // 60:02d}:{whole % 60:02d}.{nanos:09d}")
    (folder / "oxts" / "timestamps.txt").write_text("\n".join(stamps) + "\n")


def test_official_oxts_layout_reads_like_the_csv(tmp_path, shared_data):
    path = shared_data / "kitti_raw" / "2011_09_30_drive_0016.csv"
    raw = np.loadtxt(path, delimiter=",", comments="#")[:600]
    folder = tmp_path / "2011_09_30_drive_0016_extract"
    write_oxts_folder(folder, raw)
    seq = read_sequence("kitti_raw", folder)
    assert seq.name == "2011_09_30_drive_0016_extract" and len(seq) == 600
    np.testing.assert_allclose(seq.t, raw[:, 0], atol=1e-6)
    np.testing.assert_array_equal(seq.acc, raw[:, 4:7])
    np.testing.assert_array_equal(seq.gt.vel, raw[:, 13:16])
    np.testing.assert_allclose(seq.gt.pos, raw[:, 7:10] - raw[0, 7:10], atol=1e-3)  # WGS-84 ENU via pymap3d
    assert read_sequence("kitti_raw", folder / "oxts").name == "2011_09_30_drive_0016_extract"


def test_malformed_official_layout_names_the_file_and_line(tmp_path, shared_data):
    raw = np.loadtxt(shared_data / "kitti_raw" / "2011_09_30_drive_0016.csv", delimiter=",", comments="#")[:300]
    folder = tmp_path / "drive"
    write_oxts_folder(folder, raw)
    stamps = folder / "oxts" / "timestamps.txt"
    lines = stamps.read_text().splitlines()
    stamps.write_text("\n".join([*lines[:7], "2011-09-30 25:61:00.1", *lines[8:]]) + "\n")
    with pytest.raises(DataError, match=r"timestamps\.txt.*line 8.*not a time stamp"):
        read_sequence("kitti_raw", folder)
    stamps.write_text("\n".join(lines) + "\n")
    (folder / "oxts" / "data" / "0000000005.txt").write_text("1 2 3\n")
    with pytest.raises(DataError, match=r"0000000005\.txt.*expected 30 finite OXTS fields, got 3"):
        read_sequence("kitti_raw", folder)
    (folder / "oxts" / "data" / "0000000005.txt").unlink()
    with pytest.raises(DataError, match="299 packet files for 300 time stamps"):
        read_sequence("kitti_raw", folder)
    with pytest.raises(DataError, match="no KITTI oxts layout here"):
        read_sequence("kitti_raw", tmp_path)


def test_gtsam_gps_fixes_map_into_the_drive_ground_truth_frame(shared_data, tmp_path):
    path = shared_data / "kitti_raw" / "2011_10_03_drive_0027.csv"  # the drive GTSAM ships
    gps_file = "../kitti_gtsam/KittiGps_converted.txt"  # relative to the drive's folder
    seq = read_sequence("kitti_raw", path, **REPAIR, gps_file=gps_file)
    fixes = seq.gps
    assert len(fixes.t) == 470 and np.allclose(fixes.sigma, np.sqrt(0.07))  # GTSAM's example noise
    truth = np.column_stack([np.interp(fixes.t, seq.t, seq.gt.pos[:, i]) for i in range(3)])
    rms = np.sqrt(np.mean((fixes.pos - truth) ** 2, axis=0))
    assert np.all(rms < 0.02), rms  # a per-axis scale and offset (README caveat 6) leave 8 / 7 / 0.6 mm
    as_is = read_sequence("kitti_raw", path, **REPAIR, gps_file=gps_file, gps_frame="as_is").gps
    assert np.all(np.abs(np.mean(as_is.pos - truth, axis=0)[:2]) > 5.0)  # GTSAM's frame: origin 6.8 m / 11.9 m off

    raw = np.loadtxt(shared_data / "kitti_gtsam" / "KittiGps_converted.txt", delimiter=",", skiprows=1)
    swapped = tmp_path / "swapped.txt"  # X and Y exchanged: no scale and offset maps them onto this drive
    np.savetxt(swapped, raw[:, [0, 2, 1, 3]], delimiter=",", header="Time,X,Y,Z", comments="")
    with pytest.raises(DataError, match=r"swapped.txt: field 'X'.*do not belong to this drive"):
        read_sequence("kitti_raw", path, **REPAIR, gps_file=swapped)
    other = shared_data / "kitti_raw" / "2011_09_30_drive_0016.csv"  # another day: no fix in its time span
    with pytest.raises(DataError, match="0 fixes lie within the drive's time span"):
        read_sequence("kitti_raw", other, gps_file=path.parent / gps_file)
    with pytest.raises(DataError, match="needs it"):
        read_sequence("kitti_raw", path, **REPAIR, ground_truth=False, gps_file=gps_file)
    with pytest.raises(ValueError, match="gps_frame"):
        read_sequence("kitti_raw", path, **REPAIR, gps_file=gps_file, gps_frame="enu")
