"""``learned_pim``: typed noise and time steps that the samples contradict (a sigma given as ``gyro_cov``,
0.5, or dt = 10 s were all accepted). Real samples: GTSAM's KITTI IMU file."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from factors import learned_pim


@pytest.fixture(scope="module")
def kitti(shared_data):
    table = np.loadtxt(shared_data / "kitti_gtsam" / "KittiEquivBiasedImu.txt", skiprows=1)
    rows = table[1000:1500]  # columns: Time dt accelX accelY accelZ omegaX omegaY omegaZ
    return rows[:, 5:8], rows[:, 2:5], rows[:, 0]  # gyro rad/s, acc m/s^2, t s


def test_a_sigma_typed_as_a_covariance_is_warned_about_with_both_numbers(kitti, caplog):
    gyro, acc, _ = kitti
    with caplog.at_level(logging.WARNING, logger="factors.learned_pim"):
        learned_pim(gyro, acc, 0.01, 1.75e-4**2, 0.01**2, 9.8)  # GTSAM's example densities, squared: no warning
        assert not caplog.records
        learned_pim(gyro, acc, 0.01, 1.75e-4, 0.01**2, 9.8)  # the gyro sigma given as sigma^2
    assert len(caplog.records) == 1
    text = caplog.records[0].getMessage()
    assert "gyro_cov 0.000175" in text and "above" in text and "white noise of the samples" in text


def test_a_model_s_per_sample_noise_is_not_judged_by_the_white_noise(kitti, caplog):
    gyro, acc, _ = kitti
    with caplog.at_level(logging.WARNING, logger="factors.learned_pim"):
        learned_pim(gyro, acc, 0.01, np.full_like(gyro, 1e-2), np.full_like(acc, 1e-2), 9.8)  # a model may distrust
    assert not caplog.records


def test_a_time_step_slower_than_any_imu_is_refused(kitti):
    gyro, acc, _ = kitti
    with pytest.raises(ValueError, match=r"median dt is 10 s.*t\[i\+1\] - t\[i\]"):
        learned_pim(gyro, acc, 10.0, 1e-8, 1e-4, 9.8)
    # the keyframe interval (0.5 s) given for 100-Hz samples: named as such, not as a noise given as a variance
    with pytest.raises(ValueError, match=r"median dt is 0.5 s .* is it the keyframe interval"):
        learned_pim(gyro, acc, 0.5, 1e-8, 1e-4, 9.8)
    learned_pim(gyro[::10], acc[::10], 0.1, 1e-8, 1e-4, 9.8)  # a 10-Hz IMU (KITTI's synced OXTS): accepted
    gaps = np.full(len(gyro), 0.01)
    gaps[100] = 5.0  # one real gap among 100 Hz samples: accepted
    learned_pim(gyro, acc, gaps, 1e-8, 1e-4, 9.8)
    # a stream's interval of two samples, the second across a 1.58-s gap (KITTI seq 00 online): accepted; the same
    # two with the keyframe interval as one dt for both: still refused
    learned_pim(gyro[:2], acc[:2], np.array([0.01, 1.58]), 1e-8, 1e-4, 9.8)
    with pytest.raises(ValueError, match=r"median dt is 0.5 s"):
        learned_pim(gyro[:2], acc[:2], 0.5, 1e-8, 1e-4, 9.8)


def test_ragged_complex_or_text_inputs_are_refused_by_name_not_by_numpy():
    """numpy would say "setting an array element with a sequence", or cast complex numbers to their real part
    with a warning: the factor API and GpsFixes name the argument instead."""
    from airimu_core.sequence import GpsFixes

    gyro, acc = [[0.0, 0.0, 0.0]] * 2, [[0.0, 0.0, 9.8]] * 2
    cases = [
        (
            lambda: learned_pim([[0.0, 0.0, 0.0], [0.0, 0.0]], acc, 0.005, 1e-4, 1e-3, gravity_m_s2=9.81),
            "learned_pim: gyro: expected an array of real numbers, got a ragged nesting",
        ),
        (
            lambda: learned_pim(gyro, acc, 0.005 + 0j, 1e-4, 1e-3, gravity_m_s2=9.81),
            "learned_pim: dt: expected real numbers, got complex values",
        ),
        (
            lambda: learned_pim(gyro, acc, 0.005, "1e-4 rad", 1e-3, gravity_m_s2=9.81),
            "learned_pim: gyro_cov: expected an array of real numbers",
        ),
        (
            lambda: GpsFixes(np.array([0.0, 1.0]), [[1, 2, 3], [1, 2]], 1.0),
            "GpsFixes.pos: expected an array of real numbers, got a ragged nesting",
        ),
        (
            lambda: GpsFixes(np.array([0.0, 1.0]), np.zeros((2, 3)) + 1j, 1.0),
            "GpsFixes.pos: expected real numbers, got complex values",
        ),
    ]
    for build, message in cases:
        with pytest.raises(ValueError, match=message):  # learned_pim's refusals are ValueErrors, GpsFixes' InputErrors
            build()


def test_a_warning_comes_once_per_calling_line_not_per_interval(kitti, caplog):
    """A loop over 232 intervals printed 232 warnings; now one per line that calls learned_pim."""
    gyro, acc, _ = kitti
    with caplog.at_level(logging.WARNING, logger="factors.learned_pim"):
        for _ in range(5):
            learned_pim(gyro, acc, 0.01, 3e-8**2, 0.01**2, 9.8)  # far below: a variance given as a sigma
        learned_pim(gyro, acc, 0.01, 3e-8**2, 0.01**2, 9.8)  # another line
    assert len(caplog.records) == 2
    assert "test_learned_pim_inputs.py" in caplog.records[0].getMessage()


@pytest.mark.parametrize("gravity", [1.0, 0.0, 98.1, [0.0, 0.0, -1.0]])
def test_gravity_in_another_unit_is_refused(kitti, gravity):
    gyro, acc, _ = kitti
    with pytest.raises(ValueError, match="not Earth's gravity"):
        learned_pim(gyro, acc, 0.01, 1e-8, 1e-6, gravity)
