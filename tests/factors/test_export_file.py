"""Export round trip: learned_imu writes, factors reads and validates, the factors solve a graph."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
import torch
from gtsam.symbol_shorthand import V, X

from airimu_core.errors import ExportError
from airimu_core.export import load_export
from factors import GpsFactor, gps_noise
from factors.export_file import from_export
from learned_imu import preintegrate
from learned_imu.datasets.simulator import ImuErrorModel, simulate
from learned_imu.export import export_preintegration, keyframes_every

WHITE = ImuErrorModel(1.6968e-4, 2.0e-3, 0.0, 0.0, 0.0, 0.0)  # industrial white noise, no bias


@pytest.fixture(scope="module")
def sequence():
    return simulate("drone", duration_s=30.0, error_model=WHITE, seed=3, gps_rate_hz=2.0, gps_sigma_m=0.3)


@pytest.fixture(scope="module")
def exported(sequence, tmp_path_factory):
    path = tmp_path_factory.mktemp("export") / "seq.npz"
    gyro_cov, acc_cov = WHITE.noise_densities()
    export_preintegration(path, sequence, keyframes_every(sequence, 0.5), gyro_cov, acc_cov)
    return path


def test_irregular_keyframes_equal_integrating_each_interval(sequence, tmp_path):
    keyframes = np.array([0, 50, 100, 180, 260, 262, 400])  # the shortest interval: two samples
    path = export_preintegration(tmp_path / "irregular.npz", sequence, keyframes, 1e-6, 1e-4)
    export = load_export(path)
    for k, (a, b) in enumerate(zip(keyframes[:-1], keyframes[1:], strict=True)):
        pre = preintegrate(*(torch.as_tensor(x[a:b]) for x in (sequence.gyro, sequence.acc, sequence.dt)), 1e-6, 1e-4)
        np.testing.assert_allclose(export.delta_pos[k], pre.pos[-1].numpy(), rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(export.delta_cov[k], pre.cov[-1].numpy(), rtol=1e-12, atol=1e-20)
    assert export.delta_dt[3] == pytest.approx(80 * 0.005)


def test_factors_from_an_export_solve_the_trajectory(sequence, exported):
    factors, keyframe_t = from_export(exported, backend="custom", bias_key=None)
    export = load_export(exported)
    assert len(factors) == len(keyframe_t) - 1 == 59
    graph = gtsam.NonlinearFactorGraph()
    for factor in factors:
        graph.add(factor)
    gt = sequence.gt
    initial = gtsam.Values()
    rng = np.random.default_rng(0)
    for k, i in enumerate(export.keyframe_index):
        truth = gtsam.Pose3(gtsam.Rot3(gt.rot[i]), gt.pos[i])
        initial.insert(X(k), truth.retract(rng.normal(0, 0.1, 6)))
        initial.insert(V(k), gt.vel[i] + rng.normal(0, 0.2, 3))
        fix = np.flatnonzero(np.isclose(sequence.gps.t, sequence.t[i]))
        if len(fix):
            graph.add(GpsFactor(X(k), sequence.gps.pos[fix[0]], gps_noise(0.3)))
    # at the true states the IMU factors are consistent with their covariance (chi^2 per factor ~ 9)
    truth_values = gtsam.Values()
    for k, i in enumerate(export.keyframe_index):
        truth_values.insert(X(k), gtsam.Pose3(gtsam.Rot3(gt.rot[i]), gt.pos[i]))
        truth_values.insert(V(k), gt.vel[i])
    chi2 = np.mean([2 * f.error(truth_values) for f in factors])
    assert 5 < chi2 < 14
    result = gtsam.LevenbergMarquardtOptimizer(graph, initial).optimize()
    est = np.array([result.atPose3(X(k)).translation() for k in range(len(keyframe_t))])
    ate = np.sqrt(np.mean(np.sum((est - gt.pos[export.keyframe_index]) ** 2, axis=1)))
    assert ate < 0.15  # GPS alone is 0.3 m per axis at every keyframe; the IMU chain tightens it


def _rewrite(src, dst, **changes):
    with np.load(src, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    arrays.update(changes)
    for key in [k for k, v in changes.items() if v is None]:
        del arrays[key]
    np.savez(dst, **arrays)
    return dst


def test_bad_exports_are_named(exported, tmp_path):
    cases = [
        ({"format_version": np.array(2)}, "'format_version' is 2"),
        ({"delta_cov": None}, "'delta_cov' is missing"),
        ({"delta_pos": np.zeros((3, 3))}, r"'delta_pos' has shape \(3, 3\)"),
    ]
    for changes, message in cases:
        with pytest.raises(ExportError, match=message):
            load_export(_rewrite(exported, tmp_path / "bad.npz", **changes))
    with np.load(exported) as data:
        nan_vel = data["delta_vel"].copy()
    nan_vel[4, 1] = np.nan
    with pytest.raises(ExportError, match="'delta_vel' contains NaN"):
        load_export(_rewrite(exported, tmp_path / "nan.npz", delta_vel=nan_vel))
    with np.load(exported) as data:
        cov = data["delta_cov"].copy()
    cov[7] = -np.eye(9)
    with pytest.raises(ExportError, match="interval 7: .*positive definite"):
        from_export(_rewrite(exported, tmp_path / "cov.npz", delta_cov=cov), backend="custom")


def test_corrupt_or_pickled_files_are_refused(exported, tmp_path):
    corrupt = tmp_path / "corrupt.npz"
    corrupt.write_bytes(exported.read_bytes()[:200])
    with pytest.raises(ExportError, match="corrupt.npz: not a readable"):
        load_export(corrupt)
    pickled = tmp_path / "pickled.npz"
    np.savez(pickled, format_version=np.array(1), t=np.array([{"evil": 1}], dtype=object))
    with pytest.raises(ExportError, match="pickled.npz: not a readable .npz export .*unpickling, which is refused"):
        load_export(pickled)
    text = tmp_path / "text.npz"
    text.write_text("hello\n")  # numpy takes it for a pickle; its advice to allow pickles is not passed on
    with pytest.raises(ExportError, match="text.npz: not a readable") as error:
        load_export(text)
    assert "allow_pickle" not in str(error.value)
    with pytest.raises(ExportError, match="file not found"):
        load_export(tmp_path / "missing.npz")


def test_ground_truth_is_a_typed_field_all_or_nothing(exported, sequence, tmp_path):
    export = load_export(exported)
    np.testing.assert_array_equal(export.truth.pos, sequence.gt.pos)
    assert export.truth.valid.dtype == bool and export.t.shape == (len(sequence),)
    with pytest.raises(ExportError, match="'gt_vel' is missing"):
        load_export(_rewrite(exported, tmp_path / "part.npz", gt_vel=None))
    assert (
        load_export(
            _rewrite(exported, tmp_path / "none.npz", gt_rot=None, gt_pos=None, gt_vel=None, gt_valid=None)
        ).truth
        is None
    )


def test_the_export_takes_a_correction(sequence, tmp_path):
    """A model's ``Correction`` exports its corrected samples and per-sample densities, exactly as the arrays do."""
    from airimu_core.errors import InputError
    from learned_imu.network.model import Correction

    rng = np.random.default_rng(5)
    gyro, acc = sequence.gyro + rng.normal(0, 1e-3, sequence.gyro.shape), sequence.acc + 0.01
    gyro_cov, acc_cov = np.full_like(gyro, 2e-8), rng.uniform(1e-6, 4e-6, acc.shape)
    correction = Correction(
        *(torch.as_tensor(x) for x in (gyro, acc, gyro - sequence.gyro, acc - sequence.acc, gyro_cov, acc_cov))
    )
    index = keyframes_every(sequence, 0.5)
    by_record = load_export(export_preintegration(tmp_path / "c.npz", sequence, index, correction=correction))
    by_arrays = load_export(export_preintegration(tmp_path / "a.npz", sequence, index, gyro_cov, acc_cov, gyro, acc))
    for field in ("delta_rot", "delta_pos", "delta_cov", "gyro", "acc_cov"):
        np.testing.assert_array_equal(getattr(by_record, field), getattr(by_arrays, field))
    with pytest.raises(InputError, match="not both"):
        export_preintegration(tmp_path / "x.npz", sequence, index, 1e-6, 1e-4, correction=correction)


def test_keyframe_specs_that_cannot_give_two_keyframes_name_the_recording(tmp_path):
    from airimu_core.errors import DataError, InputError
    from learned_imu.datasets.simulator import simulate
    from learned_imu.export import keyframes_from_spec

    seq = simulate("drone", duration_s=10.0, seed=0)
    assert len(keyframes_from_spec(seq, "1s")) == 10
    with pytest.raises(
        InputError,
        match=r"--keyframes 500s: the interval is longer than the recording, 9.995 s "
        r"\(2000 samples\).*milliseconds given as seconds\?",
    ):
        keyframes_from_spec(seq, "500s")
    times = tmp_path / "times.txt"
    times.write_text("\n".join(str(int(t * 1e9)) for t in seq.t[::200]) + "\n")  # ns, not s
    with pytest.raises(DataError, match=r"lies outside the IMU samples of .*times in ns or on another clock"):
        keyframes_from_spec(seq, str(times))
    times.write_text(f"{float(seq.t[100])!r}\n")
    with pytest.raises(DataError, match="1 keyframe time"):
        keyframes_from_spec(seq, str(times))


def test_merged_keyframes_keep_every_fix_and_two_samples_between_any_two():
    """``merge_keyframes``: a fix's sample always (one a sample after another fix is dropped), a grid's only two or
    more samples from every fix, and of two grids' indices a sample apart (1 s and 0.09 s at 100 Hz: 99 and 100) the
    later left out, so no interval is a single sample (``preintegration_export`` refuses those)."""
    from learned_imu.export import merge_keyframes

    merged = merge_keyframes(np.array([0, 50, 51]), np.array([2, 49, 99, 100, 150, 100]))
    np.testing.assert_array_equal(merged, [0, 2, 50, 99, 150])
    grids = np.concatenate([np.arange(0, 1000, 100), np.arange(0, 1000, 9)])
    merged = merge_keyframes(np.zeros(1, dtype=int), grids)
    assert np.diff(merged).min() >= 2 and merged[0] == 0 and len(merged) > 100
