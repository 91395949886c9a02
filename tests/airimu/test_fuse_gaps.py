"""Gaps in the IMU samples: ``ImuSequence.bridge_gaps`` fills them linearly, ``FuseConfig.imu_gaps`` chooses it, and
on a real KITTI drive with 1.6-s gaps in its turns it keeps the heading that holding the last sample loses."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from airimu.fuse import fuse
from airimu_core.errors import ConfigError
from fusion.config import FuseConfig
from learned_imu.datasets import read_sequence
from learned_imu.datasets.simulator import simulate


def with_a_gap(seq, first: int, last: int):
    """``seq`` without its samples first..last-1."""
    keep = np.r_[0:first, last : len(seq.t)]
    gt = dataclasses.replace(
        seq.gt, rot=seq.gt.rot[keep], pos=seq.gt.pos[keep], vel=seq.gt.vel[keep], valid=seq.gt.valid[keep]
    )
    return dataclasses.replace(seq, t=seq.t[keep], gyro=seq.gyro[keep], acc=seq.acc[keep], gt=gt)


def test_bridge_gaps_fills_each_gap_linearly_at_the_median_step():
    seq = simulate("car", duration_s=10.0, seed=2)
    assert seq.bridge_gaps() is seq  # no gap: the same object
    gapped = with_a_gap(seq, 300, 460)  # 0.8 s at 200 Hz
    bridged = gapped.bridge_gaps()
    assert len(bridged.t) == len(seq.t)
    np.testing.assert_allclose(bridged.t, seq.t, atol=1e-9)
    inside = slice(300, 460)
    for name in ("gyro", "acc"):
        before, after = getattr(gapped, name)[299], getattr(gapped, name)[300]
        share = (seq.t[inside] - seq.t[299])[:, None] / (seq.t[460] - seq.t[299])
        np.testing.assert_allclose(getattr(bridged, name)[inside], before + share * (after - before), atol=1e-12)
        np.testing.assert_array_equal(getattr(bridged, name)[:300], getattr(seq, name)[:300])
    assert not bridged.gt.valid[inside].any() and bridged.gt.valid[:300].all() and bridged.gt.valid[460:].all()
    np.testing.assert_array_equal(bridged.gt.rot[460:], seq.gt.rot[460:])


def test_imu_gaps_is_hold_or_interpolate():
    assert FuseConfig().imu_gaps == "hold"
    with pytest.raises(ConfigError, match="imu_gaps must be one of hold, interpolate"):
        FuseConfig(imu_gaps="linear")


def test_interpolated_gaps_keep_the_heading_through_a_real_drives_turns(shared_data):
    """KITTI 2011_10_03_drive_0027 (seq 00), 195-245 s: four 1.6-s gaps of the OXTS stream, in turns. Dead reckoning
    from the ground-truth start with GTSAM's example noise: the heading error at the end (measured 19.3 deg holding
    the sample before each gap, 4.2 deg interpolating)."""
    seq = read_sequence(
        "kitti_raw", shared_data / "kitti_raw/2011_10_03_drive_0027.csv", on_backward="drop", on_duplicate="drop",
        on_gap="keep",
    )  # fmt: skip
    part = dataclasses.replace(seq.between(seq.t[0] + 195.0, seq.t[0] + 245.0), gps=None)
    assert np.sum(np.diff(part.t) > 1.0) == 4
    errors = {}
    for gaps in ("hold", "interpolate"):
        config = FuseConfig(gyro_noise_density=1.75e-4, acc_noise_density=0.01, keyframe_s=1.0, imu_gaps=gaps)
        end = fuse(part, None, None, config, start="ground-truth").solution.trajectory.rot[-1]
        truth = part.gt.rot[-1]
        yaw = np.arctan2(end[1, 0], end[0, 0]) - np.arctan2(truth[1, 0], truth[0, 0])
        errors[gaps] = abs(np.degrees(np.angle(np.exp(1j * yaw))))
    assert errors["hold"] > 10.0 and errors["interpolate"] < 0.5 * errors["hold"], errors
