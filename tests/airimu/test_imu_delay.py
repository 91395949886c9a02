"""An IMU late against its ground truth's clock: ``measure_imu_delay`` finds the delay, ``FuseConfig.imu_delay_s``
takes it out of the preintegration (``read_later``), the readers' ``imu_delay_s`` out of what is read
(``ImuSequence.imu_delay_removed``: the samples restamped, for training and fusion alike); KITTI's OXTS: ~50 ms."""

from __future__ import annotations

import dataclasses

import gtsam
import numpy as np
import pytest

from airimu.fuse import fuse
from airimu_core.errors import ConfigError, DataError, InputError
from airimu_core.sequence import GroundTruth, ImuSequence
from fusion.config import FuseConfig
from fusion.online import OnlineFusion
from learned_imu.config import SequenceConfig
from learned_imu.datasets import read_sequence
from learned_imu.evaluation.imu_delay import measure_imu_delay
from learned_imu.network.rate import check_imu_delay

RATE = 100.0
SPEED = 10.0  # m/s
GRAVITY = np.array([0.0, 0.0, -9.81])


def turning_car(delay_s: float, duration_s: float = 60.0, seed: int = 0) -> ImuSequence:
    """A level car at 10 m/s whose heading swings psi(t) = 1.2 sin(2 pi t / 15) rad, its exact IMU (x forward) read
    ``delay_s`` late: gyro (0, 0, psi'(t - d)), acc (0, v psi'(t - d), 9.81), with a little white noise."""
    t = np.arange(0.0, duration_s, 1.0 / RATE)
    w = 2 * np.pi / 15.0

    def psi(x):
        return 1.2 * np.sin(w * x)

    def rate(x):
        return 1.2 * w * np.cos(w * x)

    fine = np.arange(0.0, duration_s, 1e-4)  # the position: the heading integrated finely
    heading = np.column_stack([np.cos(psi(fine)), np.sin(psi(fine)), np.zeros_like(fine)])
    pos = np.cumsum(SPEED * heading * 1e-4, axis=0) - SPEED * heading[0] * 1e-4
    pos = pos[np.round(t * 1e4).astype(int)]
    c, s = np.cos(psi(t)), np.sin(psi(t))
    rot = np.zeros((len(t), 3, 3))
    rot[:, 0, 0], rot[:, 0, 1], rot[:, 1, 0], rot[:, 1, 1], rot[:, 2, 2] = c, -s, s, c, 1.0
    vel = SPEED * np.column_stack([c, s, np.zeros_like(t)])
    rng = np.random.default_rng(seed)
    late = rate(t - delay_s)
    gyro = np.column_stack([np.zeros_like(t), np.zeros_like(t), late]) + rng.normal(0, 1e-4, (len(t), 3))
    acc = np.column_stack([np.zeros_like(t), SPEED * late, np.full_like(t, 9.81)]) + rng.normal(0, 1e-3, (len(t), 3))
    gt = GroundTruth(rot, pos, vel, np.ones(len(t), dtype=bool))
    return ImuSequence("turning car", t, gyro, acc, GRAVITY, gt, None, "test")


def test_imu_delay_removed_restamps_the_samples_and_reads_the_truth_there():
    seq = turning_car(0.0, duration_s=5.0)
    assert seq.imu_delay_removed(0.0) is seq
    moved = seq.imu_delay_removed(0.025)  # two and a half samples
    np.testing.assert_allclose(moved.t, seq.t[3:] - 0.025, atol=1e-12)  # three new stamps before the recording
    np.testing.assert_array_equal(moved.gyro, seq.gyro[3:])
    np.testing.assert_array_equal(moved.acc, seq.acc[3:])
    assert moved.imu_delay_s == 0.025 and moved.gt.valid.all()
    # the truth half way between the samples around each new stamp
    np.testing.assert_allclose(moved.gt.pos, 0.5 * (seq.gt.pos[:-3] + seq.gt.pos[1:-2]), atol=1e-12)
    np.testing.assert_allclose(moved.gt.vel, 0.5 * (seq.gt.vel[:-3] + seq.gt.vel[1:-2]), atol=1e-12)
    heading = np.unwrap(np.arctan2(seq.gt.rot[:, 1, 0], seq.gt.rot[:, 0, 0]))
    moved_heading = np.unwrap(np.arctan2(moved.gt.rot[:, 1, 0], moved.gt.rot[:, 0, 0]))
    np.testing.assert_allclose(moved_heading, 0.5 * (heading[:-3] + heading[1:-2]), atol=1e-12)
    # a gap: the truth at a new stamp inside it is not valid (the three samples after it), the rest is
    keep = np.r_[0:200, 231 : len(seq)]
    truth = GroundTruth(seq.gt.rot[keep], seq.gt.pos[keep], seq.gt.vel[keep], seq.gt.valid[keep])
    gappy = ImuSequence("gap", seq.t[keep], seq.gyro[keep], seq.acc[keep], GRAVITY, truth, None, "test")
    valid = gappy.imu_delay_removed(0.025).gt.valid
    assert np.flatnonzero(~valid).tolist() == [197, 198, 199]


def test_measure_imu_delay_finds_a_known_delay():
    found = measure_imu_delay([turning_car(0.037), turning_car(0.037, seed=1)])
    # the sample read d later stands for the rate over [t_k, t_k+1]: the delay plus half a step
    assert found.delay_s == pytest.approx(0.037 + 0.5 / RATE, abs=1e-3)
    name, own, at_delay, at_zero = found.sequences[0]
    assert name == "turning car" and own == pytest.approx(0.04, abs=0.005) and at_delay < 0.01 * at_zero
    again = measure_imu_delay([turning_car(0.037).imu_delay_removed(found.delay_s)])
    assert abs(again.delay_s) <= 1e-3
    with pytest.raises(InputError, match="has no ground truth"):
        measure_imu_delay([dataclasses.replace(turning_car(0.0, 2.0), gt=None)])
    with pytest.raises(InputError, match="max_s"):
        measure_imu_delay([turning_car(0.0, 2.0)], max_s=0.0)


def test_fuse_takes_a_measured_delay_out():
    """Dead reckoning a late IMU from the ground-truth start: its heading lags in every turn and the track bends off
    (here 2.8x the end error of the same IMU on time); with the measured delay taken out it is the on-time IMU's."""

    def end_error(seq, removed):
        config = FuseConfig(gyro_noise_density=1e-5, acc_noise_density=1e-4, keyframe_s=1.0, imu_delay_s=removed)
        end = fuse(seq, None, None, config, start="ground-truth").solution.trajectory.pos[-1]
        return float(np.linalg.norm(end - seq.gt.pos[-1]))

    late = turning_car(0.05)
    delay = measure_imu_delay([late]).delay_s
    on_time = end_error(turning_car(0.0), 0.0)
    assert end_error(late, 0.0) > 2.5 * on_time
    assert end_error(late, delay) < 1.05 * on_time, (on_time, end_error(late, delay))


def test_fuse_refuses_a_delay_given_twice():
    """The readers' option and ``FuseConfig.imu_delay_s`` would add up: refused, naming both values."""
    read = turning_car(0.05, duration_s=5.0).imu_delay_removed(0.05)
    config = FuseConfig(gyro_noise_density=1e-5, acc_noise_density=1e-4, keyframe_s=1.0, imu_delay_s=0.05)
    with pytest.raises(InputError, match=r"readers' imu_delay_s \(0.05 s\) and the fuse config .*0.05 s.*add up"):
        fuse(read, None, None, config, start="ground-truth")


def test_a_ground_truth_start_begins_at_the_first_sample_with_truth(caplog):
    """A log that begins without truth (KITTI seq 00's drive: a 1.9-s gap first) starts at its first sample with
    truth, from the truth there, and says so; outages still count from the log's first sample."""
    seq = turning_car(0.0, duration_s=10.0)
    gt = dataclasses.replace(seq.gt, valid=np.arange(len(seq)) >= 150)
    seq = dataclasses.replace(seq, gt=gt)
    config = FuseConfig(gyro_noise_density=1e-5, acc_noise_density=1e-4, keyframe_s=1.0)
    with caplog.at_level("WARNING"):
        result = fuse(seq, None, None, config, start="ground-truth", outages=((3.0, 2.0),))
    assert "no ground truth for the first 1.50 s (150 samples)" in caplog.text
    assert result.sequence.t[0] == seq.t[150]
    traj = result.solution.trajectory
    np.testing.assert_allclose(traj.pos[0], seq.gt.pos[150], atol=1e-6)
    assert abs(result.outage_ends[0][0] - 5.0) < 0.02  # 3 + 2 s from the log's first sample, not the run's
    blind = dataclasses.replace(seq, gt=dataclasses.replace(gt, valid=np.zeros(len(seq), dtype=bool)))
    with pytest.raises(DataError, match="field 'ground truth': --start ground-truth: no sample of the log has it"):
        fuse(blind, None, None, config, start="ground-truth")
    later = fuse(seq.between(float(seq.t[150]), float(seq.t[-1])), None, None, config, start="ground-truth")
    np.testing.assert_allclose(traj.pos, later.solution.trajectory.pos, atol=1e-9)  # the log cut there


def test_imu_delay_s_is_checked_and_batch_only():
    assert FuseConfig().imu_delay_s == 0.0
    for bad in (55.0, -0.6, float("nan"), True, "0.05"):
        with pytest.raises(ConfigError, match="imu_delay_s must be a delay"):
            FuseConfig(imu_delay_s=bad)
    config = FuseConfig(imu_delay_s=0.05)
    with pytest.raises(InputError, match="imu_delay_s is batch only"):
        OnlineFusion(None, GRAVITY, gtsam.NavState(gtsam.Pose3(), np.zeros(3)), config)


def test_kittis_oxts_stream_is_about_fifty_ms_late(shared_data):
    """KITTI 2011_09_30_drive_0027 (seq 07, a drive with many turns): its OXTS gyro against the same packets'
    navigation solution is 45-65 ms late (BENCHMARKS.md: 49 ms pooled over the training drives)."""
    seq = read_sequence(
        "kitti_raw", shared_data / "kitti_raw/2011_09_30_drive_0027.csv", on_backward="drop", on_duplicate="drop",
        on_gap="keep",
    )  # fmt: skip
    found = measure_imu_delay([seq])
    assert 0.045 <= found.delay_s <= 0.065, found.delay_s
    assert found.sequences[0][2] < 0.6 * found.sequences[0][3]  # the squared rate error: 8.6e-4 -> 4.5e-4


def test_euroc_imu_is_on_time(shared_data):
    """EuRoC V1_02_medium (200 Hz, the IMU and the Vicon on one clock): half a sample step, 2.5 ms, as for an IMU
    without delay (``test_measure_imu_delay_finds_a_known_delay``)."""
    found = measure_imu_delay([read_sequence("euroc", shared_data / "euroc/V1_02_medium")])
    assert found.delay_s == pytest.approx(0.0025, abs=1e-3)


def test_every_reader_takes_imu_delay_s_and_the_sequence_says_it(shared_data):
    """The readers' ``imu_delay_s`` option: the sequence ``imu_delay_removed`` gives (KITTI 2011_09_26_drive_0019, a
    validation drive of configs/kitti_motion_loo.yaml: the samples as recorded, stamped 49 ms earlier),
    ``ImuSequence.imu_delay_s`` saying so through ``part``; a value in ms, or the option on the simulator, is refused
    naming the key."""
    path = shared_data / "kitti_raw/2011_09_26_drive_0019.csv"
    options = {"on_backward": "drop", "on_duplicate": "drop", "on_gap": "keep"}
    recorded = read_sequence("kitti_raw", path, **options)
    late = read_sequence("kitti_raw", path, imu_delay_s=0.049, **options)
    assert recorded.imu_delay_s == 0.0 and late.imu_delay_s == 0.049
    dropped = len(recorded) - len(late)
    assert 4 <= dropped <= 6  # the samples stamped before the recording began (100 Hz)
    np.testing.assert_array_equal(late.gyro, recorded.gyro[dropped:])
    np.testing.assert_array_equal(late.t, recorded.t[dropped:] - 0.049)
    np.testing.assert_array_equal(late.gt.pos, recorded.imu_delay_removed(0.049).gt.pos)
    assert late.part(0.2, 0.6).imu_delay_s == 0.049 and late.bridge_gaps().imu_delay_s == 0.049
    with pytest.raises(ConfigError, match=r"imu_delay_s': expected a delay \(s\) within \+-0.5, got 49"):
        read_sequence("kitti_raw", path, imu_delay_s=49, **options)
    with pytest.raises(ConfigError, match="simulator has no such option"):
        SequenceConfig("simulator", options={"imu_delay_s": 0.05})


def test_a_model_trained_on_delayed_samples_says_so_and_a_log_read_otherwise_is_warned_about(tmp_path, caplog):
    """``TrainedOn.imu_delay_s`` comes from the stored config's training sequences (``DataConfig.imu_delay_s``;
    None for a mix); ``airimu fuse`` warns, naming both delays, when the log is read with another."""
    from learned_imu.config import DataConfig, ExperimentConfig, MotionConfig, TrainConfig
    from learned_imu.network.checkpoint import (
        Checkpoint,
        TrainedOn,
        build_motion_model,
        motion_from_checkpoint,
        save_checkpoint,
    )

    small = MotionConfig(conv_channels=(8, 16), gru_sizes=(16,), decoder_hidden=16)
    late = SequenceConfig("kitti_raw", "a.csv", options={"imu_delay_s": 0.049})
    data = DataConfig(train=(late, dataclasses.replace(late, path="b.csv")), val=(late,))
    assert data.imu_delay_s == 0.049
    assert dataclasses.replace(data, train=(late, SequenceConfig("kitti_raw", "c.csv"))).imu_delay_s is None
    config = ExperimentConfig("late", data, motion=small, train=TrainConfig(model="motion"))
    weights = build_motion_model(small).state_dict()
    on = TrainedOn(rate_hz=RATE, datasets=("kitti_raw",))
    path = save_checkpoint(tmp_path / "m.pt", Checkpoint(config, {"model": weights}, trained_on=on))
    net = motion_from_checkpoint(path)[0]
    assert net.trained_on.imu_delay_s == 0.049
    seq = turning_car(0.0, duration_s=30.0)
    caplog.set_level("WARNING")
    check_imu_delay(net, seq.imu_delay_removed(0.049), "on time")
    assert not caplog.records
    check_imu_delay(net, seq, "car.csv")
    message = caplog.records[-1].getMessage()
    assert "car.csv: read with imu_delay_s 0.000 s" in message and "imu_delay_s 0.049 s" in message
    assert "imu_delay_s=0.049" in message
