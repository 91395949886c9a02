"""BROAD reader on the real trials in shared/data/broad: units, NaN masking, frame self-check on every trial."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.io

from airimu_core.errors import DataError
from learned_imu.datasets._checks import frame_score
from learned_imu.datasets.broad import read_broad

RATE = 2000 / 7  # Hz, 285.714 (the files store 285.71428571)
TRIAL = "02_undisturbed_slow_rotation_B.mat"


def _trials(shared_data: Path) -> list[Path]:
    return sorted((shared_data / "broad").glob("*.mat"))


@pytest.mark.slow
def test_all_trials_pass_the_frame_self_check_and_mask_exactly_the_nan_rows(shared_data):
    trials = _trials(shared_data)
    assert len(trials) == 17
    for path in trials:
        seq = read_broad(path)  # raises if the frame self-check fails
        mat = scipy.io.loadmat(path, variable_names=["opt_quat", "opt_pos", "imu_acc"])
        nan = ~(np.isfinite(mat["opt_quat"]).all(axis=1) & np.isfinite(mat["opt_pos"]).all(axis=1))
        rows = np.rint(seq.t * RATE).astype(int)
        assert np.all(np.abs(rows / RATE - seq.t) < 1e-6), path.name  # t = k / rate
        np.testing.assert_array_equal(seq.gt.valid, ~nan[rows], err_msg=path.name)
        assert not nan[rows[0]] and not nan[rows[-1]]  # cropped to the first/last valid optical sample
        np.testing.assert_array_equal(seq.acc, mat["imu_acc"][rows])
        score = frame_score(seq.t, seq.gyro, seq.acc, seq.gt.rot, seq.gt.valid, seq.gravity)
        assert score.acc < 0.02 and score.gyro < 0.2, path.name  # measured at most 0.008 and 0.17


def test_one_trial_in_detail(shared_data):
    seq = read_broad(shared_data / "broad" / TRIAL)
    assert seq.name == "02_undisturbed_slow_rotation_B"
    assert len(seq) == 51539  # 53,240 samples, 1,701 NaN rows at the ends cropped away
    assert 1.0 / np.median(np.diff(seq.t)) == pytest.approx(RATE, abs=1e-3)
    assert int((~seq.gt.valid).sum()) == 5
    np.testing.assert_array_equal(seq.gravity, [0.0, 0.0, -9.81])
    # positions are metres in a mocap volume, not mm
    valid_pos = seq.gt.pos[seq.gt.valid]
    assert np.ptp(valid_pos, axis=0).max() < 3.0 and np.ptp(valid_pos, axis=0).max() > 0.01
    # a slow rotation trial without translation: the marker moves slowly
    assert np.percentile(np.linalg.norm(seq.gt.vel[seq.gt.valid], axis=1), 95) < 1.0


def test_rest_at_the_start_is_level_in_enu(shared_data):
    """During the initial rest phase R_gt @ acc points up with |g|: the optical world frame is z-up ENU."""
    seq = read_broad(shared_data / "broad" / TRIAL)
    rest = slice(0, 200)
    assert np.linalg.norm(seq.gyro[rest], axis=1).max() < 0.1
    up = np.einsum("nij,nj->ni", seq.gt.rot[rest], seq.acc[rest]).mean(axis=0)
    np.testing.assert_allclose(up, [0.0, 0.0, 9.81], atol=0.15)


def test_translation_trial_velocity_from_mocap_agrees_with_the_imu(shared_data):
    seq = read_broad(shared_data / "broad" / "15_undisturbed_fast_translation_A.mat")
    dt = seq.dt
    world_acc = np.einsum("nij,nj->ni", seq.gt.rot, seq.acc) + seq.gravity
    integral = np.concatenate([np.zeros((1, 3)), np.cumsum(world_acc * dt[:, None], axis=0)])
    k = 143  # 0.5 s
    i = np.arange(0, len(seq) - k, k)
    i = i[seq.gt.valid[i] & seq.gt.valid[i + k]]
    dv_gt = seq.gt.vel[i + k] - seq.gt.vel[i]
    err = np.linalg.norm(integral[i + k] - integral[i] - dv_gt, axis=1)
    scale = np.sqrt((np.linalg.norm(dv_gt, axis=1) ** 2).mean())
    assert np.sqrt((err**2).mean()) < 0.25 * scale


@pytest.mark.parametrize("rate_as_attribute", [False, True])
def test_hdf5_copy_reads_the_same_as_the_mat_file(shared_data, tmp_path, rate_as_attribute):
    import h5py

    mat_path = shared_data / "broad" / "02_undisturbed_slow_rotation_B.mat"
    mat = scipy.io.loadmat(mat_path)
    h5_path = tmp_path / "02_undisturbed_slow_rotation_B.hdf5"
    with h5py.File(h5_path, "w") as f:
        for name in ("imu_gyr", "imu_acc", "opt_quat", "opt_pos"):
            f.create_dataset(name, data=mat[name])
        rate = float(np.asarray(mat["sampling_rate"]).ravel()[0])
        if rate_as_attribute:
            f.attrs["sampling_rate"] = rate
        else:
            f.create_dataset("sampling_rate", data=rate)
    from_mat, from_h5 = read_broad(mat_path), read_broad(h5_path)
    assert len(from_h5) == len(from_mat) > 1000
    for field in ("t", "gyro", "acc"):
        np.testing.assert_array_equal(getattr(from_h5, field), getattr(from_mat, field))
    np.testing.assert_array_equal(from_h5.gt.rot, from_mat.gt.rot)
    np.testing.assert_array_equal(from_h5.gt.valid, from_mat.gt.valid)


def test_corrupt_hdf5_names_the_file(tmp_path):
    bad = tmp_path / "trial.hdf5"
    bad.write_bytes(b"not an hdf5 file")
    with pytest.raises(DataError, match="trial.hdf5.*not a readable HDF5 file"):
        read_broad(bad)


def test_missing_field_is_named(shared_data, tmp_path):
    mat = scipy.io.loadmat(shared_data / "broad" / TRIAL)
    del mat["opt_quat"]
    path = tmp_path / "trial.mat"
    scipy.io.savemat(path, {k: v for k, v in mat.items() if not k.startswith("__")})
    with pytest.raises(DataError, match="missing from the file") as err:
        read_broad(path)
    assert err.value.field == "opt_quat"


def test_quaternion_order_mistake_is_caught(shared_data, tmp_path):
    mat = scipy.io.loadmat(shared_data / "broad" / TRIAL)
    mat["opt_quat"] = mat["opt_quat"][:, [1, 2, 3, 0]]  # stored scalar-last, but the reader expects w, x, y, z
    path = tmp_path / "trial.mat"
    scipy.io.savemat(path, {k: v for k, v in mat.items() if not k.startswith("__")})
    with pytest.raises(DataError, match="file is scalar-last") as err:
        read_broad(path)
    assert err.value.field == "gt.rot"
