"""The PGO ablation on recorded GPS fixes (as on KITTI): keyframes at the fixes, a fix inside an IMU gap left out,
one draw per decimation phase, the gap noise, and GTSAM's example settings as a fifth row."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from airimu.experiments.pgo import GTSAM_EXAMPLE, SETTINGS, PgoOptions, fixes_on_samples, run_sequence, write_exports
from airimu_core.errors import ConfigError
from airimu_core.sequence import GroundTruth, ImuSequence
from learned_imu.datasets.simulator import simulate
from learned_imu.network.model import Correction


def with_gap(seq: ImuSequence, first: int, last: int) -> ImuSequence:
    """``seq`` without the samples ``first`` .. ``last - 1`` (a dropped stretch, as KITTI's OXTS packets)."""
    keep = np.r_[0:first, last : len(seq)]
    gt = seq.gt
    truth = GroundTruth(gt.rot[keep], gt.pos[keep], gt.vel[keep], gt.valid[keep])
    return dataclasses.replace(seq, t=seq.t[keep], gyro=seq.gyro[keep], acc=seq.acc[keep], gt=truth)


def raw_correction(seq: ImuSequence) -> Correction:
    """The raw samples as a model output, with a constant noise (the 'learned' settings then use it)."""
    gyro, acc = torch.as_tensor(seq.gyro), torch.as_tensor(seq.acc)
    zero = torch.zeros_like(gyro)
    return Correction(gyro, acc, zero, zero, torch.full_like(gyro, 1e-6), torch.full_like(acc, 1e-4))


@pytest.fixture(scope="module")
def drive():
    seq = simulate("car", duration_s=40.0, seed=5, gps_rate_hz=1.0, gps_sigma_m=0.1)
    rate = 1.0 / float(np.median(np.diff(seq.t)))
    # 1.5 s of IMU missing from t = 20.2 s: the fixes at 21 s falls inside the gap
    return with_gap(seq, int(20.2 * rate), int(21.7 * rate))


def test_keyframes_at_the_fixes_and_the_fix_in_a_gap_left_out(drive, tmp_path):
    options = PgoOptions(gps_source="recorded", keyframes="fixes")
    kept = fixes_on_samples(drive)
    assert len(kept.gps.t) == len(drive.gps.t) - 1 and 21.0 not in np.round(kept.gps.t, 6)
    exports = write_exports(kept, raw_correction(kept), tmp_path, options, SETTINGS[:1])
    keyframe_t = exports[SETTINGS[0].name].keyframe_t
    np.testing.assert_allclose(keyframe_t, kept.gps.t, atol=1e-9)  # every fix on its own keyframe


def test_gap_noise_raises_only_the_interval_across_the_gap(drive, tmp_path):
    kept = fixes_on_samples(drive)
    base = PgoOptions(gps_source="recorded", keyframes="fixes")
    covs = {}
    for name, options in {"none": base, "gap": dataclasses.replace(base, gap_noise_density=(0.06, 0.7))}.items():
        exports = write_exports(kept, raw_correction(kept), tmp_path / name, options, SETTINGS[:1])
        covs[name] = exports[SETTINGS[0].name].delta_cov
    across = int(np.searchsorted(kept.gps.t, 20.2))  # the interval from the fix at 20 s to the one at 22 s
    ratio = np.diagonal(covs["gap"], axis1=1, axis2=2) / np.diagonal(covs["none"], axis1=1, axis2=2)
    assert np.all(ratio[across - 1] > 20)  # 1.5 s at 0.06 rad/s/sqrt(Hz), 0.7 m/s^2/sqrt(Hz) against 0.004, 0.08
    np.testing.assert_allclose(np.delete(ratio, across - 1, axis=0), 1.0, rtol=1e-12)


@pytest.mark.slow
def test_recorded_rows_one_draw_per_phase_with_the_gtsam_example(drive, tmp_path):
    options = PgoOptions(
        gps_hz=(1.0, 0.2),
        seeds=10,
        gps_source="recorded",
        keyframes="fixes",
        gtsam_example=True,
        score_span="gps",
        gap_noise_density=(0.06, 0.7),
    )
    rows, examples = run_sequence(drive, raw_correction(drive), tmp_path, options)
    assert [r.setting for r in rows[::2]] == [s.name for s in (*SETTINGS, GTSAM_EXAMPLE)]
    assert set(examples) == {s.name for s in (*SETTINGS, GTSAM_EXAMPLE)}
    by = {(r.setting, r.gps_hz): r for r in rows}
    for setting in (*SETTINGS, GTSAM_EXAMPLE):
        assert by[setting.name, 1.0].ate_std_m == 0.0  # one decimation at 1 Hz: the one draw
        assert by[setting.name, 0.2].ate_std_m > 0.0  # five phases at 0.2 Hz
        assert 0.0 < by[setting.name, 1.0].ate_mean_m < by[setting.name, 0.2].ate_mean_m < 5.0
    with pytest.raises(ConfigError, match="options.keyframes"):
        PgoOptions(keyframes="gps")
    with pytest.raises(ConfigError, match="options.gps_source"):
        PgoOptions(gps_source="real")
