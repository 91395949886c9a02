"""EuRoC reader on the real MH_01_easy (IMU + TUM ground truth) and V1_02_medium (IMU excerpt + official ground
truth), and on small malformed copies of MH_01 written to tmp_path."""

from __future__ import annotations

import numpy as np
import pytest

from airimu_core.errors import DataError
from learned_imu.datasets import ReadChecks, read_sequence
from learned_imu.datasets._assemble import differentiate_positions
from learned_imu.datasets.euroc import read_euroc, read_euroc_ground_truth

MH01_IMU_ROWS = 36820
MH01_GT_ROWS = 36382  # GT stamps coincide with IMU stamps, so the overlap holds exactly this many IMU samples
V102_IMU = "mav0/imu0/data_partial_first40s.csv"


@pytest.fixture(scope="module")
def mh01(shared_data):
    return read_euroc(shared_data / "euroc" / "MH_01_easy")


def _delta_v_error(seq, window_s: float) -> tuple[float, float]:
    """rms over windows of |GT velocity change - integral of (R acc + g)|, and rms |GT velocity change|, m/s."""
    dt = seq.dt
    world_acc = np.einsum("nij,nj->ni", seq.gt.rot, seq.acc) + seq.gravity
    integral = np.concatenate([np.zeros((1, 3)), np.cumsum(world_acc * dt[:, None], axis=0)])
    k = int(round(window_s / np.median(dt)))
    i = np.arange(0, len(seq) - k, k)
    dv_gt = seq.gt.vel[i + k] - seq.gt.vel[i]
    err = np.linalg.norm(integral[i + k] - integral[i] - dv_gt, axis=1)
    return float(np.sqrt((err**2).mean())), float(np.sqrt((np.linalg.norm(dv_gt, axis=1) ** 2).mean()))


def test_mh01_counts_rate_units_and_speed(mh01):
    seq = mh01
    assert seq.name == "MH_01_easy" and len(seq) == MH01_GT_ROWS
    assert np.median(np.diff(seq.t)) == pytest.approx(0.005, abs=1e-6)
    assert np.diff(seq.t).max() < 0.0051
    assert np.linalg.norm(seq.acc, axis=1).mean() == pytest.approx(9.793, abs=0.005)  # 9.805 before the crop
    np.testing.assert_array_equal(seq.gravity, [0.0, 0.0, -9.81007])
    assert seq.gt.valid.all()
    assert seq.t[0] == pytest.approx(1403636580.83856, abs=1e-5)  # cropped to the first GT stamp


def test_mh01_velocity_from_tum_positions_agrees_with_the_imu(mh01):
    """Over 0.5 s, the GT velocity change (differentiated TUM positions) equals the integrated world-frame
    acceleration up to the accelerometer bias (~0.15 m/s^2 on EuRoC): measured 0.09 m/s rms of 0.33."""
    err, scale = _delta_v_error(mh01, 0.5)
    assert err < 0.13 and err < 0.4 * scale


def test_mh01_without_crop_marks_imu_outside_gt_invalid(shared_data):
    seq = read_euroc(shared_data / "euroc" / "MH_01_easy", checks=ReadChecks(crop_to_gt=False, check_frame=False))
    assert len(seq) == MH01_IMU_ROWS
    assert int(seq.gt.valid.sum()) == MH01_GT_ROWS
    assert not seq.gt.valid[:216].any() and seq.gt.valid[216]  # GT starts 1.08 s after the IMU


def test_v102_differentiated_velocity_matches_the_file_velocity(shared_data):
    gt = read_euroc_ground_truth(shared_data / "euroc" / "V1_02_medium" / "mav0/state_groundtruth_estimate0/data.csv")
    vel = differentiate_positions(gt.t, gt.pos)
    err = np.linalg.norm(vel - gt.vel, axis=1)
    assert np.sqrt((err**2).mean()) < 0.004  # measured 3.2 mm/s rms; the file's peak speed is 2.2 m/s
    assert np.percentile(err, 99) < 0.012  # measured 9 mm/s
    central = np.linalg.norm(np.gradient(gt.pos, gt.t, axis=0) - gt.vel, axis=1)
    assert np.sqrt((err**2).mean()) < np.sqrt((central**2).mean())  # smoothing beats plain central differences


def test_v102_excerpt_with_official_ground_truth(shared_data):
    folder = shared_data / "euroc" / "V1_02_medium"
    seq = read_euroc(folder, imu_file=V102_IMU)
    assert len(seq) == 7800 and seq.gt.valid.all()  # 7999 IMU samples, GT starts 199 samples later
    gt = read_euroc_ground_truth(folder / "mav0/state_groundtruth_estimate0/data.csv")
    rows = np.searchsorted(gt.t, seq.t)  # IMU stamps are truncated to 10 us, GT stamps are exact
    np.testing.assert_allclose(seq.gt.pos, gt.pos[rows], atol=2e-5)
    np.testing.assert_allclose(seq.gt.vel, gt.vel[rows], atol=2e-3)
    np.testing.assert_allclose(seq.gt.rot, gt.rot[rows], atol=2e-4)
    err, scale = _delta_v_error(seq, 0.5)
    assert err < 0.12 and err < 0.3 * scale  # measured 0.074 of 0.645 m/s


def test_missing_imu_file_lists_what_is_there(shared_data):
    # V1_01_easy has ground truth only in the shared data (no imu0/): the error names the folder and the option
    with pytest.raises(DataError, match="imu_file") as err:
        read_euroc(shared_data / "euroc" / "V1_01_easy")
    assert err.value.field == "imu_file" and "V1_01_easy" in str(err.value)


# --- malformed copies of MH_01 ------------------------------------------------------------------------------

IMU_HEADER_LINES = 1
GT_HEADER_LINES = 1


def _copy(shared_data, tmp_path, imu_edit=None, gt_edit=None, imu_rows=1600, gt_rows=1200):
    """A small MH_01 folder: the header and first rows of the real files, optionally edited (lists of lines)."""
    src = shared_data / "euroc" / "MH_01_easy" / "mav0"
    folder = tmp_path / "MH_01_small"
    for rel, rows, edit in (
        ("imu0/data.csv", imu_rows, imu_edit),
        ("state_groundtruth_estimate0/groundtruth_tum.txt", gt_rows, gt_edit),
    ):
        lines = (src / rel).read_text().splitlines()[: 1 + rows]
        if edit is not None:
            lines = edit(lines)
        (folder / "mav0" / rel).parent.mkdir(parents=True, exist_ok=True)
        (folder / "mav0" / rel).write_text("\n".join(lines) + "\n")
    return folder


def test_small_copy_reads(shared_data, tmp_path):
    seq = read_euroc(_copy(shared_data, tmp_path))
    assert len(seq) == 1200 and seq.gt.valid.all()


def test_truncated_imu_line_reports_its_line_number(shared_data, tmp_path):
    def truncate(lines):
        lines[500] = lines[500][:30]
        return lines

    with pytest.raises(DataError) as err:
        read_euroc(_copy(shared_data, tmp_path, imu_edit=truncate))
    assert err.value.line == 501 and err.value.path.name == "data.csv"
    assert "expected 7 columns" in str(err.value)


def test_nan_in_imu_reports_its_line_number(shared_data, tmp_path):
    def nan(lines):
        cells = lines[700].split(",")
        lines[700] = ",".join([*cells[:4], "nan", *cells[5:]])
        return lines

    with pytest.raises(DataError, match="non-finite") as err:
        read_euroc(_copy(shared_data, tmp_path, imu_edit=nan))
    assert err.value.line == 701


def test_duplicated_imu_stamp_raises_or_is_dropped(shared_data, tmp_path):
    def duplicate(lines):
        return lines[:400] + [lines[399]] + lines[400:]

    folder = _copy(shared_data, tmp_path, imu_edit=duplicate)
    with pytest.raises(DataError, match="duplicated time stamp") as err:
        read_euroc(folder)
    assert err.value.line == 401 and err.value.field == "t"
    assert len(read_euroc(folder, checks=ReadChecks(on_duplicate="drop"))) == 1200


def test_imu_gap_raises_or_splits(shared_data, tmp_path):
    def gap(lines):
        return lines[:800] + lines[830:]  # 30 samples (150 ms) missing

    folder = _copy(shared_data, tmp_path, imu_edit=gap)
    with pytest.raises(DataError, match="gap of 0.155 s") as err:
        read_euroc(folder)
    assert err.value.line == 801  # the first line after the gap
    parts = read_euroc(folder, checks=ReadChecks(on_gap="keep")).split_at_gaps()
    assert [p.name for p in parts] == ["MH_01_small_part0", "MH_01_small_part1"]
    assert sum(len(p) for p in parts) == 1200 - 30
    assert parts[0].t[-1] < parts[1].t[0] - 0.15


def test_gt_gap_marks_imu_samples_invalid(shared_data, tmp_path):
    def gap(lines):
        return lines[:500] + lines[600:]  # GT rows 499..598 (0.5 s) missing

    seq = read_euroc(_copy(shared_data, tmp_path, gt_edit=gap))
    assert len(seq) == 1200
    invalid = np.flatnonzero(~seq.gt.valid)
    np.testing.assert_array_equal(invalid, np.arange(499, 599))  # IMU and GT stamps coincide in MH_01


def test_ground_truth_that_does_not_overlap_raises(shared_data, tmp_path):
    def shift(lines):
        out = lines[:1]
        for line in lines[1:]:
            stamp, rest = line.split(" ", 1)
            out.append(f"{float(stamp) + 1000:.5f} {rest}")
        return out

    with pytest.raises(DataError, match="does not overlap the IMU") as err:
        read_euroc(_copy(shared_data, tmp_path, gt_edit=shift))
    assert err.value.field == "t" and err.value.path.name == "groundtruth_tum.txt"


def test_tum_quaternion_in_the_wrong_order_is_named(shared_data, tmp_path):
    def to_wxyz(lines):
        out = lines[:1]
        for line in lines[1:]:
            c = line.split()
            out.append(" ".join(c[:4] + [c[7], c[4], c[5], c[6]]))
        return out

    with pytest.raises(DataError, match="file is scalar-first") as err:
        read_euroc(_copy(shared_data, tmp_path, gt_edit=to_wxyz))
    assert err.value.field == "gt.rot" and err.value.path.name == "groundtruth_tum.txt"


def test_a_ground_truth_folder_without_a_known_file_is_named(shared_data, tmp_path, caplog):
    import logging

    from airimu_core.errors import InputError
    from learned_imu.evaluation.evaluate import evaluate

    folder = tmp_path / "V1_02" / "mav0"
    (folder / "imu0").mkdir(parents=True)
    (folder / "imu0" / "data.csv").symlink_to(shared_data / "euroc" / "V1_02_medium" / "mav0" / "imu0" / "data.csv")
    (folder / "state_groundtruth_estimate0" / "old").mkdir(parents=True)
    with caplog.at_level(logging.WARNING):
        seq = read_sequence("euroc", tmp_path / "V1_02")
    assert seq.gt is None
    assert "state_groundtruth_estimate0: no ground truth read: the folder holds ['old']" in caplog.text
    with pytest.raises(InputError, match="evaluation needs ground truth.*gt_file"):
        evaluate(seq, 1.0)
