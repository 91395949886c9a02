"""``airimu fuse``: plausible mistakes are refused or warned about, never fused into a silently wrong result.
Real data: GTSAM's KITTI drive (2011_10_03_drive_0027), its OXTS ground truth and GTSAM's GPS."""

from __future__ import annotations

import dataclasses
import json
import logging
import re
import sys

import numpy as np
import pytest

from airimu.cli import main
from airimu.fuse import check_gps_units
from airimu_core.errors import DataError, InputError
from airimu_core.sequence import GpsFixes
from factors.noise import noise_mismatch, white_noise_density
from fusion.config import FuseConfig
from learned_imu.datasets.gps import read_gps_csv

DRIVE = "kitti_raw/2011_10_03_drive_0027.csv"
REPAIR = [
    "--reader-option",
    "on_backward=drop",
    "--reader-option",
    "on_duplicate=drop",
    "--reader-option",
    "on_gap=keep",
]


@pytest.fixture(scope="module")
def drive(shared_data):
    from learned_imu.datasets import read_sequence

    return read_sequence("kitti_raw", shared_data / DRIVE, on_backward="drop", on_duplicate="drop", on_gap="keep")


def gps_files(folder, seq):
    """The drive's ground truth at 1 Hz with 0.3 m noise, written as lat/lon in degrees and in radians, and as
    x/y/z in m, km, cm and mm."""
    import pymap3d

    index = np.arange(0, len(seq.t), 100)
    index = index[seq.gt.valid[index]]
    pos = seq.gt.pos[index] + np.random.default_rng(0).normal(0.0, 0.3, (len(index), 3))
    lat, lon, alt = pymap3d.enu2geodetic(pos[:, 0], pos[:, 1], pos[:, 2], 49.0115, 8.4229, 112.0)
    t = seq.t[index]
    tables = {
        "deg": ("t,lat,lon,alt", np.c_[t, lat, lon, alt]),
        "rad": ("t,lat,lon,alt", np.c_[t, np.radians(lat), np.radians(lon), alt]),
        "swapped": ("t,lat,lon,alt", np.c_[t, lon, lat, alt]),
        "m": ("t,x,y,z", np.c_[t, pos]),
        "km": ("t,x,y,z", np.c_[t, pos / 1000.0]),
        "cm": ("t,x,y,z", np.c_[t, pos * 100.0]),
        "mm": ("t,x,y,z", np.c_[t, pos * 1000.0]),
        "xy": ("t,x,y,z", np.c_[t, pos[:, [1, 0, 2]]]),
    }
    paths = {}
    for name, (header, rows) in tables.items():
        paths[name] = folder / f"{name}.csv"
        np.savetxt(paths[name], rows, delimiter=",", header=header, comments="", fmt="%.12f")
    return paths


def drive_with_fixes(shared_data, name: str):
    """A KITTI raw drive (replayed packets and duplicates dropped, gaps kept) and its ground truth at 1 Hz with 0.5 m
    noise as GPS fixes (sigma 0.5 m)."""
    from learned_imu.datasets import read_sequence

    seq = read_sequence(
        "kitti_raw", shared_data / f"kitti_raw/{name}.csv", on_backward="drop", on_duplicate="drop", on_gap="keep"
    )
    index = np.arange(0, len(seq.t), 100)
    index = index[seq.gt.valid[index]]
    pos = seq.gt.pos[index] + np.random.default_rng(0).normal(0.0, 0.5, (len(index), 3))
    return seq, GpsFixes(seq.t[index], pos, np.full((len(index), 3), 0.5))


def run(capsys, monkeypatch, *args) -> tuple[int, str]:
    monkeypatch.setattr(sys, "argv", ["airimu", *map(str, args)])
    monkeypatch.delenv("AIRIMU_DEBUG", raising=False)
    with pytest.raises(SystemExit) as ended:
        main()
    return ended.value.code, capsys.readouterr().err


def test_gps_in_the_wrong_unit_is_refused_naming_the_columns_and_the_unit(drive, tmp_path):
    paths = gps_files(tmp_path, drive)
    for good in ("deg", "m"):
        check_gps_units(drive, paths[good], read_gps_csv(paths[good]))  # measured misfit 0.64 m/s: accepted
    with pytest.raises(DataError, match=r"field 'lat/lon'.*lat/lon in radians\?"):
        check_gps_units(drive, paths["rad"], read_gps_csv(paths["rad"]))  # 2.94 against 0.64 m/s re-read
    for unit in ("km", "cm", "mm"):  # cm was called "mm?": the first reading that beat as-read was named
        with pytest.raises(DataError, match=rf"field 'x/y/z'.*x/y/z in {unit}\?"):
            check_gps_units(drive, paths[unit], read_gps_csv(paths[unit]))
    # columns swapped: a mirror image of the track, which no heading explains
    with pytest.raises(DataError, match=r"field 'lat/lon'.*lat and lon swapped\?"):
        check_gps_units(drive, paths["swapped"], read_gps_csv(paths["swapped"]))
    with pytest.raises(DataError, match=r"field 'x/y/z'.*x and y swapped\?"):
        check_gps_units(drive, paths["xy"], read_gps_csv(paths["xy"]))
    radians = read_gps_csv(paths["rad"], angle_unit="rad")  # the right reading equals the degree file's
    np.testing.assert_allclose(radians.pos, read_gps_csv(paths["deg"]).pos, atol=1e-4)  # 12 decimals of a radian: 6 um


def test_an_altitude_in_feet_or_km_is_refused_where_the_road_climbs(shared_data, tmp_path):
    """The altitude alone in another unit (x/y in m): on a hilly drive the track's climb follows the car's tilt,
    so its scale shows (2011_10_03_drive_0034, 0.5 m noise: 0.908 in m, 2.84 in feet, 0.000917 in km, each
    +-3 %); the right file passes."""
    import pymap3d

    from airimu.fuse import check_gps_altitude
    from learned_imu.datasets import read_sequence

    seq, fixes = drive_with_fixes(shared_data, "2011_10_03_drive_0034")
    pos = fixes.pos
    lat, lon, alt = pymap3d.enu2geodetic(pos[:, 0], pos[:, 1], pos[:, 2], 49.0115, 8.4229, 112.0)
    paths = {}
    for unit, factor in (("m", 1.0), ("feet", 1.0 / 0.3048), ("km", 1e-3)):
        paths[unit] = tmp_path / f"alt_{unit}.csv"
        rows = np.c_[fixes.t, lat, lon, alt * factor]
        np.savetxt(paths[unit], rows, delimiter=",", header="t,lat,lon,alt", comments="", fmt="%.12f")
    check_gps_units(seq, paths["m"], read_gps_csv(paths["m"]))
    for unit in ("feet", "km"):
        with pytest.raises(DataError, match=rf"field 'alt'.*altitude in {unit}\? Convert the alt column to m"):
            check_gps_units(seq, paths[unit], read_gps_csv(paths[unit]))
    # a drone's direction of travel does not follow its tilt: EuRoC V1_03 (fixes from its truth at 1 Hz, feet
    # included) says nothing either way
    flight = read_sequence("euroc", shared_data / "euroc/V1_03_difficult")
    at = np.arange(0, len(flight.t), 200)
    for factor in (1.0, 1.0 / 0.3048):
        track = flight.gt.pos[at] * np.array([1.0, 1.0, factor])
        check_gps_altitude(flight, "gps.csv", GpsFixes(flight.t[at], track, np.full((len(at), 3), 0.3)), "z")


@pytest.mark.parametrize("late", [0.5, 1.0, 2.0, -1.5, 7.0, -30.0])  # 7 and -30 s: beyond the old +-5 s search
def test_a_gps_clock_offset_is_estimated_and_warned_about(drive, late, caplog):
    """Fixes some seconds late (or early) against the IMU's clock: the offset at which the IMU explains the track
    best is found to 0.1 s and named with the option that removes it; on time, nothing is said. (The OXTS
    positions these fixes come from fit the drive's IMU best 0.1 s later themselves: the INS solution's latency,
    seen in GTSAM's GPS file too; below the 0.3-s floor.)"""

    from airimu.fuse import check_gps_clock
    from fusion.gps_units import clock_offset

    index = np.arange(0, len(drive.t), 100)
    index = index[drive.gt.valid[index]]
    pos = drive.gt.pos[index] + np.random.default_rng(0).normal(0.0, 0.3, (len(index), 3))
    on_time = GpsFixes(drive.t[index], pos, 0.3)
    own = clock_offset(drive, on_time)[0]
    assert abs(own) <= 0.1 + 1e-9  # measured 0.05
    with caplog.at_level(logging.WARNING):
        assert check_gps_clock(drive, "on time", on_time) is None
        assert "GPS fixes look" not in caplog.text
        offset = check_gps_clock(drive, "shifted", GpsFixes(drive.t[index] + late, pos, 0.3))
    assert offset - own == pytest.approx(late, abs=0.1 + 1e-9)
    side = "late" if late > 0 else "early"
    said = re.search(rf"GPS fixes look ([0-9.]+) s {side}.*--gps-time-offset (-?[0-9.]+)", caplog.text)
    assert said and float(said.group(1)) == pytest.approx(abs(offset), abs=0.05)
    assert float(said.group(2)) == pytest.approx(offset, abs=0.05)


def test_gps_time_offset_shifts_the_fixes(shared_data, tmp_path, capsys, monkeypatch, caplog):
    """``--gps-time-offset`` takes the estimate: the late file fused with it ends where the on-time file does."""
    from learned_imu.datasets import read_sequence

    seq = read_sequence("kitti_raw", shared_data / DRIVE, on_backward="drop", on_duplicate="drop", on_gap="keep")
    paths = gps_files(tmp_path, seq)
    rows = np.loadtxt(paths["m"], delimiter=",", skiprows=1)
    rows[:, 0] += 2.0
    late = tmp_path / "late.csv"
    np.savetxt(late, rows, delimiter=",", header="t,x,y,z", comments="", fmt="%.12f")
    summaries = {}
    for name, extra in (("as read", []), ("shifted", ["--gps-time-offset", "2"])):
        with caplog.at_level(logging.WARNING):
            caplog.clear()
            code, err = run(
                capsys,
                monkeypatch,
                "fuse",
                "--dataset",
                "kitti_raw",
                "--path",
                shared_data / DRIVE,
                *REPAIR,
                "--gps",
                late,
                "--gps-every",
                "5",
                "--out",
                tmp_path / name,
                *extra,
            )
        assert code == 0, err
        summaries[name] = json.loads((tmp_path / name / "summary.json").read_text())
        late_said = re.search(r"GPS fixes look 2\.(0|05|1|15) s late", caplog.text) is not None
        assert late_said == (name == "as read")  # 2 s and the OXTS's 0.05-0.1
    assert summaries["shifted"]["ate_aligned_m"] < 0.5 * summaries["as read"]["ate_aligned_m"]
    code, err = run(
        capsys,
        monkeypatch,
        "fuse",
        "--dataset",
        "csv",
        "--path",
        "x",
        "--out",
        tmp_path / "y",
        "--gps-time-offset",
        "nan",
    )
    assert code == 2 and "--gps-time-offset" in err


def test_gps_covering_part_of_the_drive_is_warned_about_and_still_written(drive, tmp_path, caplog):
    """Fixes for the first 2 of the drive's 8 minutes: a warning names both uncovered spans; the keyframes after the
    last fix are dead reckoning whose marginals GTSAM cannot compute: NaN covariances with a warning, every file
    written (it was a traceback)."""
    from airimu.fuse import fuse, write_outputs

    index = np.arange(0, 12000, 100)
    index = index[drive.gt.valid[index]]
    with caplog.at_level(logging.WARNING):
        result = fuse(drive, GpsFixes(drive.t[index], drive.gt.pos[index], 0.3), config=FuseConfig(keyframe_s=1.0))
        summary, written = write_outputs(result, tmp_path / "out")
    assert "the IMU runs 0 s before the first GPS fix and 3" in caplog.text and "dead reckoning" in caplog.text
    assert "marginal covariances not computed" in caplog.text
    assert {p.name for p in written} >= {"fused.tum", "marginals.npz", "fused.rrd", "fused.png", "summary.json"}
    assert np.isnan(np.load(tmp_path / "out" / "marginals.npz")["pos_cov"]).all()
    assert summary.rmse_to_gps_m < 1.0  # m: where there are fixes, the fit is what it was


def test_gtsams_own_gps_file_passes_the_unit_check(shared_data):
    from learned_imu.datasets import read_sequence

    seq = read_sequence("kitti")
    path = shared_data / "kitti_gtsam" / "KittiGps_converted.txt"
    check_gps_units(seq, path, read_gps_csv(path))


def test_white_noise_density_recovers_a_known_density_under_slow_motion():
    rng = np.random.default_rng(3)
    dt, density = 0.005, 2e-3
    t = np.arange(20000) * dt
    motion = np.stack([np.sin(0.5 * t), np.cos(0.3 * t), 0.2 * t], axis=1)  # slow: cancels in second differences
    samples = motion + rng.normal(0.0, density / np.sqrt(dt), (len(t), 3))
    assert white_noise_density(samples, dt) == pytest.approx(density, rel=0.03)
    assert white_noise_density(samples[:20], dt) is None  # too few samples to judge


def test_noise_densities_the_samples_contradict_are_named_with_both_numbers(shared_data):
    from learned_imu.datasets import read_sequence

    seq = read_sequence("kitti")  # measured white noise: gyro 8.2e-5 rad/s/sqrt(Hz), acc 3.2e-3 m/s^2/sqrt(Hz)
    message = noise_mismatch("gyro", 3.1e-8, seq.gyro, seq.dt)  # GTSAM's example sigma 1.75e-4 squared: 2600x below
    assert message is not None and "3.1e-08" in message and "below" in message and "8.2e-05" in message
    assert "a variance (sigma^2) given where a sigma is expected?" in message
    # 0.004^2 given as a sigma is only 5x below: no sigma rule tells it from a datasheet value on a vibrating platform
    # (EuRoC's, below); the chi-square after the solve does (test_fuse_warns_about_a_variance_given_as_a_sigma)
    assert noise_mismatch("gyro", 1.6e-5, seq.gyro, seq.dt) is None
    assert noise_mismatch("gyro", 1.75e-4, seq.gyro, seq.dt) is None  # GTSAM's example setting: 2.1x
    assert "an acc noise density" in noise_mismatch("acc", 0.5, seq.acc, seq.dt) and "above" in noise_mismatch(
        "acc", 0.5, seq.acc, seq.dt
    )


def test_documented_noise_of_the_shared_recordings_is_not_warned_about(shared_data):
    """EuRoC's ADIS16448 datasheet densities (docs/preintegration.md: 1.7e-4 rad/s/sqrt(Hz), 2.0e-3 m/s^2/sqrt(Hz))
    lie 3-50x under the MH flights' own white noise (rotor vibration): no mistake, no warning; GTSAM's KITTI example
    values on its drive neither."""
    from learned_imu.datasets import read_sequence
    from learned_imu.datasets.euroc import read_euroc

    for flight in ("MH_01_easy", "MH_04_difficult", "V1_03_difficult", "V2_02_medium"):
        seq = read_euroc(shared_data / "euroc" / flight)
        assert noise_mismatch("gyro", 1.6968e-4, seq.gyro, seq.dt) is None, flight
        assert noise_mismatch("acc", 2.0e-3, seq.acc, seq.dt) is None, flight
    seq = read_sequence("kitti")
    assert noise_mismatch("gyro", 1.75e-4, seq.gyro, seq.dt) is None
    assert noise_mismatch("acc", 0.01, seq.acc, seq.dt) is None


@pytest.mark.slow
def test_fuse_warns_about_a_variance_given_as_a_sigma(shared_data, tmp_path, capsys, monkeypatch, caplog):
    args = [
        "fuse",
        "--dataset",
        "kitti",
        "--path",
        shared_data / "kitti_gtsam",
        "--gps-every",
        "10",
        "--keyframes",
        "1s",
        "--gyro-noise-density",
        "1.6e-05",
        "--acc-noise-density",
        "0.0064",
        "--out",
        tmp_path / "f",
    ]
    with caplog.at_level(logging.WARNING, logger="airimu.fuse"):
        code, _ = run(capsys, monkeypatch, *args)
    assert code == 0
    # after the solve: the IMU misfit, with the densities given and the samples' own white noise named
    assert any(
        "gyro_noise_density 1.6e-05 (the samples' own white noise 8.2e-05)" in r.getMessage() for r in caplog.records
    )


def test_noise_flags_with_a_checkpoint_are_refused(tmp_path, capsys, monkeypatch):
    code, err = run(
        capsys,
        monkeypatch,
        "fuse",
        "--dataset",
        "csv",
        "--path",
        tmp_path / "x.csv",
        "--out",
        tmp_path / "f",
        "--checkpoint",
        tmp_path / "best.pt",
        "--gyro-noise-density",
        "0.004",
    )
    assert code == 2 and err.count("\n") == 1 and "apply without --checkpoint only" in err
    # airimu export ignored the flag beside --checkpoint (a byte-identical export); now the same one-line refusal
    args = ["export", "--dataset", "csv", "--path", tmp_path / "x.csv", "--out", tmp_path / "e.npz"]
    code, err = run(capsys, monkeypatch, *args, "--checkpoint", tmp_path / "best.pt", "--acc-noise-density", "0.08")
    assert code == 2 and err.count("\n") == 1 and "apply without --checkpoint only" in err
    from airimu.fuse import fuse
    from learned_imu.datasets.simulator import simulate

    with pytest.raises(InputError, match="without a model only"):
        fuse(simulate("car", duration_s=5.0), model=object(), config=FuseConfig(0.002, 0.04))


def test_typer_parsing_errors_are_one_line(capsys, monkeypatch):
    code, err = run(capsys, monkeypatch, "fuse", "--dataset", "csv", "--path", "x", "--out", "y", "--gps-every", "abc")
    assert code == 2 and err.count("\n") == 1 and err.startswith("airimu: error: Invalid value for '--gps-every'")
    assert "airimu fuse --help" in err and "╭" not in err
    code, err = run(capsys, monkeypatch, "fuse", "--dataset", "csv")
    assert code == 2 and err.count("\n") == 1 and "Missing option" in err


@pytest.mark.slow
def test_ate_is_scored_in_one_frame_and_the_imu_rate_file_is_what_evo_reads(shared_data, tmp_path, capsys, monkeypatch):
    """GTSAM's GPS file lives in its own frame, the OXTS ground truth in ENU: the unaligned ATE is large, the
    SE(3)-aligned one is evo's on ``fused_imu_rate.tum``."""
    from evo.core import metrics, sync
    from evo.core.trajectory import PoseTrajectory3D
    from evo.tools import file_interface

    from airimu_core.rotations import matrix_to_quat_wxyz
    from learned_imu.datasets import read_sequence

    out = tmp_path / "f"
    code, err = run(
        capsys,
        monkeypatch,
        "fuse",
        "--dataset",
        "kitti_raw",
        "--path",
        shared_data / DRIVE,
        *REPAIR,
        "--gps",
        shared_data / "kitti_gtsam" / "KittiGps_converted.txt",
        "--gps-every",
        "10",
        "--keyframes",
        "1s",
        "--out",
        out,
    )
    assert code == 0, err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["ate_aligned_m"] < 3.0 < 10.0 < summary["ate_unaligned_m"]  # measured 2.19 and 14.2 m
    dense = file_interface.read_tum_trajectory_file(str(out / "fused_imu_rate.tum"))
    keyframes = file_interface.read_tum_trajectory_file(str(out / "fused.tum"))
    assert dense.num_poses > 50 * keyframes.num_poses
    at_keyframes = np.searchsorted(dense.timestamps, keyframes.timestamps)
    np.testing.assert_allclose(dense.positions_xyz[at_keyframes], keyframes.positions_xyz, atol=1e-9)
    seq = read_sequence("kitti_raw", shared_data / DRIVE, on_backward="drop", on_duplicate="drop", on_gap="keep")
    ok = seq.gt.valid
    truth = PoseTrajectory3D(seq.gt.pos[ok], matrix_to_quat_wxyz(seq.gt.rot[ok]), seq.t[ok])  # evo: w x y z
    truth, est = sync.associate_trajectories(truth, dense, max_diff=1e-4)
    est.align(truth, correct_scale=False)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((truth, est))
    assert ape.get_statistic(metrics.StatisticsType.rmse) == pytest.approx(summary["ate_aligned_m"], rel=1e-3)


def test_csv_reader_drops_backward_stamps_on_request_and_names_the_line(tmp_path):
    from learned_imu.datasets import read_sequence

    rows = [f"{0.01 * k:.2f},0,0,0,0,0,9.81" for k in range(100)]
    rows.insert(50, "0.30,0,0,0,0,0,9.81")  # a replayed stamp
    path = tmp_path / "imu.csv"
    path.write_text("\n".join(rows) + "\n")
    with pytest.raises(DataError, match=r"line 51: field .time.: time goes backwards.*on_backward='drop'"):
        read_sequence("csv", path)
    assert len(read_sequence("csv", path, on_backward="drop").t) == 100


def test_list_reader_options_take_both_spellings(tmp_path, capsys, monkeypatch):
    path = tmp_path / "imu.csv"
    path.write_text("\n".join(f"{0.01 * k:.2f},0,0,0,0,0,9.81" for k in range(300)) + "\n")
    for spelling in ("gt_pos=7,8,9", "gt_pos=[7,8,9]"):  # only gt_pos: refused for the missing gt_quat, not parsed
        code, err = run(
            capsys, monkeypatch, "evaluate", "--dataset", "csv", "--path", path, "--reader-option", spelling
        )
        assert code == 2 and "gt_pos and gt_quat" in err, err


def test_gps_fixes_take_a_scalar_sigma_and_refuse_a_wrong_shape():
    t, pos = np.arange(4.0), np.zeros((4, 3))
    assert GpsFixes(t, pos, 0.1).sigma.shape == (4, 3) and np.all(GpsFixes(t, pos, 0.1).sigma == 0.1)
    np.testing.assert_array_equal(GpsFixes(t, pos, [1.0, 2.0, 3.0]).sigma[2], [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(GpsFixes(t, pos, np.arange(4.0)).sigma[:, 1], np.arange(4.0))
    with pytest.raises(InputError, match="sigma must be a float"):
        GpsFixes(t, pos, np.ones(5))


def test_a_byte_order_mark_is_read_as_the_imu_readers_read_it(tmp_path):
    """Spreadsheets save CSV with a UTF-8 byte-order mark: the GPS reader takes the header after it, and a table
    without a header reads its first row."""
    from airimu_core.table import read_table

    gps = tmp_path / "gps.csv"
    gps.write_bytes(b"\xef\xbb\xbft,x,y,z\n0,1,2,3\n1,1,2,4\n")
    fixes = read_gps_csv(gps, sigma_m=1.0)
    np.testing.assert_array_equal(fixes.t, [0.0, 1.0])
    bare = tmp_path / "bare.csv"
    bare.write_bytes(b"\xef\xbb\xbf0,1,2,3\n1,1,2,3\n")
    np.testing.assert_array_equal(read_table(bare).data[:, 0], [0.0, 1.0])


def test_a_second_fuse_into_a_folder_being_written_is_refused_naming_the_writer(
    shared_data, capsys, monkeypatch, tmp_path
):
    from airimu_core.io import folder_lock

    out = tmp_path / "f"
    with folder_lock(out):  # another airimu fuse (or train, ablate-pgo) writing there
        code, err = run(
            capsys,
            monkeypatch,
            "fuse",
            "--dataset",
            "kitti_raw",
            "--path",
            shared_data / DRIVE,
            *REPAIR,
            "--gps",
            shared_data / "kitti_gtsam" / "KittiGps_converted.txt",
            "--gps-every",
            "10",
            "--keyframes",
            "1s",
            "--out",
            out,
        )
    assert code != 0 and "another writer holds it" in err and str(out) in err
    assert not (out / "summary.json").exists()


def test_a_model_that_fits_the_gps_far_worse_than_the_raw_imu_is_refused(tmp_path, monkeypatch):
    """A checkpoint that made the track 1000x worse than the raw IMU was used with only chi-square warnings; now
    ``run_fuse`` compares how much of the GPS track's motion the corrected and the raw samples leave unexplained
    (``fusion.gps_units.track_misfit``) and refuses the model 3x worse, naming the checkpoint, unless
    ``--trust-model``."""
    import torch

    from airimu.fuse import FuseRequest, check_model_against_raw, run_fuse
    from learned_imu.datasets.simulator import simulate
    from learned_imu.network.inference import correct
    from learned_imu.network.model import AirImuNet

    seq = simulate("car", duration_s=120.0, grade="industrial", seed=4, gps_rate_hz=1.0, gps_sigma_m=0.3)
    torch.manual_seed(0)
    model = AirImuNet().eval()
    # an untrained model corrects nearly nothing: accepted
    check_model_against_raw(seq, correct(model, seq), seq.gps, "fresh.pt")
    with torch.no_grad():
        model.gyro_decoder[2].bias.fill_(3.0)  # 0.052 rad/s added to every axis: misfit 3.97 m/s against 0.72 raw
    with pytest.raises(DataError, match=r"broken\.pt.*far worse than the raw samples.*--trust-model"):
        check_model_against_raw(seq, correct(model, seq), seq.gps, "broken.pt")
    from airimu.fuse import fuse

    with pytest.raises(DataError, match=r"the model: field 'model'.*far worse"):  # the library call checks it too
        fuse(seq, model=model)
    import learned_imu.network.checkpoint as checkpoint_module

    monkeypatch.setattr(checkpoint_module, "model_from_checkpoint", lambda path: (model, None))
    request = FuseRequest(seq, "sim", tmp_path / "f", FuseConfig(), checkpoint="broken.pt", trust_model=True)
    done = run_fuse(request)  # insisted on: fused, and the result shows what the model does
    assert done.summary.rmse_to_gps_m > 20.0  # measured 54.6 m; the untrained model fuses to 2.2 m


def test_gps_times_in_another_unit_or_time_base_name_the_gps_file():
    """GPS times in us were reported as the IMU file's problem ("field 'gps': fewer than 2 fixes"); now the GPS
    file's field 't' is named, with the unit when the times read so fall inside the IMU's span, else both spans."""
    from airimu.fuse import check_gps_times
    from learned_imu.datasets.simulator import simulate

    seq = simulate("car", duration_s=60.0, seed=2, gps_rate_hz=1.0, gps_sigma_m=0.5)
    fixes = seq.gps
    check_gps_times(seq, "gps.csv", fixes)  # seconds: accepted
    for unit, scale in (("ms", 1e3), ("us", 1e6), ("ns", 1e9)):
        shifted = GpsFixes((fixes.t + 1000.0) * scale, fixes.pos, fixes.sigma)
        moved = dataclasses.replace(seq, t=seq.t + 1000.0)
        with pytest.raises(DataError, match=rf"gps\.csv: field 't'.*read as {unit}: convert the GPS times"):
            check_gps_times(moved, "gps.csv", shifted)
    far = GpsFixes(fixes.t + 1e6, fixes.pos, fixes.sigma)  # 1 Hz fixes 1e6 s later: not ms (they would be 1 kHz)
    with pytest.raises(DataError, match=r"gps\.csv: field 't'.*Another time base.*1000000 aligns"):
        check_gps_times(seq, "gps.csv", far)


def test_a_gps_sigma_column_in_mm_is_refused_naming_the_file_and_column(drive, tmp_path):
    """Sigmas in mm read as m left the GPS out of the graph ("under-constrained", naming neither file nor column).
    Real drive, 1 Hz fixes with 0.5 m noise: sigma 0.5 accepted; 500 (mm) refused; 3-m fixes with sigmas in mm
    too (the track's own scatter, 2.6 m, is the yardstick)."""
    index = np.arange(0, len(drive.t), 100)
    index = index[drive.gt.valid[index]]
    cases = ((0.5, 0.5, False), (0.5, 50.0, True), (0.5, 500.0, True), (3.0, 3000.0, True), (3.0, 3.0, False))
    for noise, sigma, refused in cases:  # 50 and 500: 0.5 m in cm and in mm
        pos = drive.gt.pos[index] + np.random.default_rng(1).normal(0.0, noise, (len(index), 3))
        path = tmp_path / "gps.csv"
        rows = np.c_[drive.t[index], pos, np.full(len(index), sigma)]
        np.savetxt(path, rows, delimiter=",", header="t,x,y,z,sigma", comments="", fmt="%.6f")
        if refused:
            with pytest.raises(DataError, match=r"gps\.csv: field 'sigma'.*in cm or mm, not m\?"):
                read_gps_csv(path)
        else:
            np.testing.assert_allclose(read_gps_csv(path).sigma, sigma)


@pytest.mark.parametrize(
    ("scale", "named"), [(180.0 / np.pi, "deg/s"), (1000.0, "mrad/s"), (1.0, None)]
)  # a car's gyro in deg/s reads as plausible rad/s: only the GPS track can tell
def test_a_gyro_in_another_unit_is_refused_by_the_gps_track_without_ground_truth(drive, scale, named):
    from airimu.experiments.pgo import gps_for
    from airimu.fuse import check_imu_units, fuse

    part = drive.between(drive.t[0], drive.t[0] + 300.0)
    fixes = gps_for(part, 1.0, 0.5, seed=0, source="simulated")[0]
    blind = dataclasses.replace(part, gyro=part.gyro * scale, gt=None, gps=None)
    if named is None:
        check_imu_units(blind, fixes, "drive.csv")  # the right unit: accepted
        return
    with pytest.raises(DataError) as refused:
        fuse(blind, fixes, None, FuseConfig(keyframe_s=1.0))
    message = str(refused.value)
    assert "field 'gyro'" in message and f"gyro {named}" in message.split("? ")[0] + "?"
    assert "gyro_unit=deg/s" in message if named == "deg/s" else "by 1000" in message


def test_a_car_gyro_shrunk_57x_or_negated_is_refused_by_the_tracks_turns(shared_data):
    """A mostly straight drive (2011_10_03_drive_0047) barely needs its gyro, so a rad/s gyro converted as if deg/s
    (57x small) fit the track misfit as well as the right one; the track's turns against the gyro's tell (slope
    0.99 +- 0.12 as recorded, 57 +- 7 shrunk, -0.99 negated, at 1-Hz fixes with 0.5 m noise)."""
    from airimu.fuse import check_imu_units

    seq, fixes = drive_with_fixes(shared_data, "2011_10_03_drive_0047")
    blind = dataclasses.replace(seq, gt=None, gps=None)
    check_imu_units(blind, fixes, "imu.csv")
    shrunk = dataclasses.replace(blind, gyro=blind.gyro * np.pi / 180.0)
    with pytest.raises(DataError, match=r"imu\.csv: field 'gyro'.*turns .* as far as the gyro.*converted as if deg/s"):
        check_imu_units(shrunk, fixes, "imu.csv")
    with pytest.raises(DataError, match=r"field 'gyro'.*sign is flipped"):
        check_imu_units(dataclasses.replace(blind, gyro=-blind.gyro), fixes, "imu.csv")


def test_a_gps_outage_over_a_turn_does_not_read_as_a_flipped_gyro(shared_data):
    """KITTI seq 06 (2011_09_30_drive_0020) with 1-Hz fixes and none for 60 s from 27.6 s: the chord over the gap
    held a whole turn, which the course's wrap flipped, and that one pair of chords refused the right gyro as
    "sign flipped" (slope -1.04, R^2 0.98). Chords over a gap are left out: accepted, and a flipped gyro still
    refused."""
    from airimu.experiments.pgo import gps_for
    from airimu.fuse import _outside_outages, check_imu_units
    from fusion.gps_units import heading_scale
    from learned_imu.datasets import read_sequence

    seq = read_sequence(
        "kitti_raw", shared_data / "kitti_raw/2011_09_30_drive_0020.csv", on_backward="drop", on_duplicate="drop",
        on_gap="keep",
    )  # fmt: skip
    seq = seq.between(seq.t[0], seq.t[0] + 113.4)  # AI-IMU's seq 06 range (rows 0-11347)
    fixes = _outside_outages(gps_for(seq, 1.0, 0.3, seed=0, source="simulated")[0], seq.t[0], ((27.6, 60.0),))
    blind = dataclasses.replace(seq, gt=None, gps=None)
    found = heading_scale(blind, fixes)
    assert found is not None and not (found.decided and found.scale < 0), found
    check_imu_units(blind, fixes, "imu.csv")
    flipped = dataclasses.replace(blind, gyro=-blind.gyro)
    with pytest.raises(DataError, match=r"field 'gyro'.*sign is flipped"):
        check_imu_units(flipped, gps_for(seq, 1.0, 0.3, seed=0, source="simulated")[0], "imu.csv")


def test_the_gyro_unit_check_is_quiet_on_euroc_and_skips_sparse_fixes(shared_data):
    """EuRoC's raw gyro (biased: as read it explains the track worse than no rotation at all, before its median is
    taken out) is accepted with 1-Hz fixes; with a fix every 10 s the check does not run."""
    from airimu.experiments.pgo import gps_for
    from airimu.fuse import check_imu_units
    from learned_imu.datasets import read_sequence

    for name in ("MH_04_difficult", "V1_03_difficult", "V2_02_medium"):
        seq = read_sequence("euroc", shared_data / "euroc" / name)
        check_imu_units(seq, gps_for(seq, 1.0, 0.5, seed=0, source="simulated")[0], name)
        sparse = gps_for(seq, 0.1, 0.5, seed=0, source="simulated")[0]
        check_imu_units(dataclasses.replace(seq, gyro=seq.gyro * 1000.0), sparse, name)  # not checked: no refusal
