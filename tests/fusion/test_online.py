"""Online fusion: fed sample by sample it ends on the batch LM solution of the same data, its state is available
after every update, and bad input is refused by name."""

from __future__ import annotations

import dataclasses
import logging
import subprocess
import sys

import gtsam
import numpy as np
import pytest
import torch

from airimu.experiments.pgo import ate_m, gps_for
from airimu_core.errors import ConfigError, InputError
from airimu_core.sequence import GpsFixes
from factors import load_export
from fusion.config import FuseConfig, OnlineSettings
from fusion.graph import Solution, build_graph, solve
from fusion.online import OnlineFusion
from learned_imu.datasets.simulator import simulate
from learned_imu.export import export_preintegration, keyframes_every, merge_keyframes, nearest_samples
from learned_imu.network.checkpoint import TrainedOn
from learned_imu.network.model import AirImuNet, correct_sequence
from tests.helpers import REPO

X, V = gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.V
SIGMAS = (1e-3, 1e-2)  # rad/s/sqrt(Hz), m/s^2/sqrt(Hz): inflated over the consumer grade's white noise for its biases
DENSITIES = (SIGMAS[0] ** 2, SIGMAS[1] ** 2)  # the same as sigma^2: rad^2/s, m^2/s^3
KEYFRAME_S = 0.5
BLOCK = 10  # IMU samples per add_imu call, as a driver delivers them


@pytest.fixture(scope="module", autouse=True)
def one_thread():
    """Small torch calls run fastest (and least disturbed by other processes) on one thread."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def sequence():
    # 59.525 s = 11,905 samples: the last keyframe (sample 11,900) closes an interval whose model block is incomplete
    return simulate("drone", duration_s=59.525, seed=1)


def small_model() -> AirImuNet:
    """A small untrained model whose decoders are random, so corrections and densities vary block by block."""
    torch.manual_seed(0)
    model = AirImuNet(
        conv_channels=(8, 16),
        gru_sizes=(16, 32),
        decoder_hidden=16,
        init_gyro_cov=DENSITIES[0],
        init_acc_cov=DENSITIES[1],
    )
    for decoder in (model.acc_decoder, model.gyro_decoder, model.acc_cov_decoder, model.gyro_cov_decoder):
        torch.nn.init.normal_(decoder[-1].weight, std=0.1)
    return model.eval()


def config(smoother: str = "isam2", lag_s: float = 10.0) -> FuseConfig:
    """The raw samples' densities, keyframes every KEYFRAME_S."""
    online = OnlineSettings(keyframe_s=KEYFRAME_S, smoother=smoother, lag_s=lag_s)
    return FuseConfig(gyro_noise_density=SIGMAS[0], acc_noise_density=SIGMAS[1], online=online)


def first_state(seq):
    return gtsam.NavState(gtsam.Pose3(gtsam.Rot3(seq.gt.rot[0]), seq.gt.pos[0]), seq.gt.vel[0])


def batch_solution(seq, model, gps: GpsFixes, tmp_path) -> tuple[Solution, float]:
    """The batch LM solution on an export of the same data; and the largest gyro correction, rad/s."""
    noise, samples, largest = DENSITIES, (None, None), 0.0
    if model is not None:
        out = correct_sequence(model, *(torch.as_tensor(x, dtype=torch.float32) for x in (seq.gyro, seq.acc)))
        noise = (out.gyro_cov.double().numpy(), out.acc_cov.double().numpy())
        samples = (out.gyro.double().numpy(), out.acc.double().numpy())
        largest = float(out.d_gyro.abs().max())
    index = merge_keyframes(nearest_samples(seq, gps.t)[0], keyframes_every(seq, KEYFRAME_S))  # as airimu fuse
    path = export_preintegration(tmp_path / "e.npz", seq, index, *noise, *samples)
    export = load_export(path)
    graph, values = build_graph(export, gps, initial_state=first_state(seq))
    return solve(graph, values, export.keyframe_t), largest


def run_online(seq, fusion: OnlineFusion, gps: GpsFixes, check_states: bool = True) -> int:
    """Feed ``seq`` in blocks with each fix once the IMU has passed its time; check the state after every keyframe
    update. Returns the number of keyframes before ``flush``."""
    fix = 0
    for start in range(0, len(seq), BLOCK):
        block = slice(start, start + BLOCK)
        added = fusion.add_imu(seq.t[block], seq.gyro[block], seq.acc[block])
        if added and check_states:
            state = fusion.current_state()
            assert state.t == fusion.trajectory().t[-1]
            assert np.linalg.eigvalsh(state.pose_cov).min() > 0 and np.linalg.eigvalsh(state.vel_cov).min() > 0
            assert np.sqrt(np.trace(state.pos_cov)) < 1.0  # m: GPS at 1 Hz keeps it well below
        while fix < len(gps.t) and gps.t[fix] <= seq.t[block][-1]:
            fusion.add_gps(gps.t[fix], gps.pos[fix], gps.sigma[fix])
            fix += 1
    return fusion.keyframes


@pytest.mark.parametrize("with_model", [False, True], ids=["raw", "model"])
def test_online_ends_on_the_batch_solution(sequence, with_model, tmp_path):
    seq = sequence
    gps, truth = gps_for(seq, 1.0, 0.1, seed=0)
    if not with_model:  # fixes 0.3 s after whole seconds: each gets its own keyframe between the grid's
        index = np.arange(60, len(seq), 200)
        noise = np.random.default_rng(0).normal(0.0, 0.1, (len(index), 3))
        gps = GpsFixes(seq.t[index], seq.gt.pos[index] + noise, np.full((len(index), 3), 0.1))
    model = small_model() if with_model else None
    batch, largest = batch_solution(seq, model, gps, tmp_path)
    fusion = OnlineFusion(model, seq.gravity, first_state(seq), config())
    before_flush = run_online(seq, fusion, gps)
    added = fusion.flush()
    online = fusion.trajectory()
    state = fusion.current_state()

    keyframes = len(batch.trajectory.t)
    assert keyframes == (120 if with_model else 180)  # the 0.5-s grid, and with the raw samples a keyframe per fix
    # the model holds back the last, incomplete block: the last keyframe needs flush
    assert (before_flush, added) == ((keyframes - 1, 1) if with_model else (keyframes, 0))
    np.testing.assert_array_equal(online.t, batch.trajectory.t)
    diff = np.abs(online.pos - batch.trajectory.pos).max()
    assert diff < 0.01  # m; measured 1.8 mm (raw) and 2.0 mm (model)
    assert np.abs(online.vel - batch.trajectory.vel).max() < 0.01  # m/s
    rot_diff = [
        np.linalg.norm(gtsam.Rot3.Logmap(gtsam.Rot3(a.T @ b)))
        for a, b in zip(online.rot, batch.trajectory.rot, strict=True)
    ]
    assert max(rot_diff) < 1e-3  # rad
    assert ate_m(batch, truth) < 0.5  # m: the problem is a sensible one (measured 0.23 m)
    if with_model:
        assert largest > 1e-4  # rad/s: the random model does change the samples
    # the last state's covariances are the batch graph's marginals (to 2 % of the standard deviations' product;
    # measured 0.6 % (raw) and 0.01 % (model): ISAM2 linearises at a point within mm of LM's)
    marginals = gtsam.Marginals(batch.graph, batch.values)
    for online_cov, key in ((state.pose_cov, X(keyframes - 1)), (state.vel_cov, V(keyframes - 1))):
        batch_cov = marginals.marginalCovariance(key)
        scale = np.sqrt(np.outer(np.diag(batch_cov), np.diag(batch_cov)))
        assert np.max(np.abs(online_cov - batch_cov) / scale) < 0.02


def test_first_state_carries_the_prior(sequence):
    seq = sequence
    fusion = OnlineFusion(None, seq.gravity, first_state(seq), config())
    assert fusion.add_imu(seq.t[0], seq.gyro[0], seq.acc[0]) == 0
    state = fusion.current_state()
    assert state.t == seq.t[0]
    np.testing.assert_allclose(state.pos, seq.gt.pos[0])
    # GTSAM's Pose3 tangent order: rotation (0.01 rad), then translation (0.1 m); velocity 0.1 m/s
    np.testing.assert_allclose(state.pose_cov, np.diag([1e-4] * 3 + [1e-2] * 3), rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(state.vel_cov, np.diag([1e-2] * 3), rtol=1e-9, atol=1e-15)


def test_fixed_lag_bounds_the_window_and_stays_close(sequence, tmp_path):
    seq = sequence
    gps, truth = gps_for(seq, 1.0, 0.1, seed=0)
    batch, _ = batch_solution(seq, None, gps, tmp_path)
    lag_s = 3.0
    fusion = OnlineFusion(None, seq.gravity, first_state(seq), config(smoother="fixed_lag", lag_s=lag_s))
    run_online(seq, fusion, gps, check_states=False)
    fusion.flush()
    online = fusion.trajectory()
    np.testing.assert_array_equal(online.t, batch.trajectory.t)
    # the latest state has seen the same data as the batch's last one; older ones lack later fixes
    assert np.abs(online.pos[-1] - batch.trajectory.pos[-1]).max() < 0.01  # m; measured 3.2 mm
    assert ate_m(Solution(online, None, None, 0, 0.0), truth) < 1.1 * ate_m(batch, truth)  # measured 0.215, 0.219
    window = fusion.smoother.calculateEstimate().size()  # X, V and B per keyframe
    assert window <= 3 * (lag_s / KEYFRAME_S + 2)  # measured 21 (7 keyframes)
    assert fusion.current_state().t == online.t[-1]
    assert fusion.add_gps(5.0, seq.gt.pos[1000], 0.1) is False  # a fix for a keyframe that left: dropped


def test_bad_input_is_refused_by_name(sequence, caplog):
    seq = sequence
    fusion = OnlineFusion(None, seq.gravity, first_state(seq), config())
    with pytest.raises(InputError, match="precedes the first IMU sample"):
        fusion.add_gps(0.0, [0.0, 0.0, 0.0], 0.1)
    fusion.add_imu(seq.t[:5], seq.gyro[:5], seq.acc[:5])
    with pytest.raises(InputError, match="precedes the first IMU sample"):
        fusion.add_gps(seq.t[0] - 0.1, [0.0, 0.0, 0.0], 0.1)
    with pytest.raises(InputError, match="strictly increasing"):
        fusion.add_imu(seq.t[[6, 5]], seq.gyro[5:7], seq.acc[5:7])  # within a block
    with pytest.raises(InputError, match="strictly increasing"):
        fusion.add_imu(seq.t[4], seq.gyro[4], seq.acc[4])  # repeats the last sample
    bad = seq.gyro[5:7].copy()
    bad[1, 2] = np.nan
    with pytest.raises(InputError, match="NaN"):
        fusion.add_imu(seq.t[5:7], bad, seq.acc[5:7])
    with pytest.raises(InputError, match=r"\(M, 3\)"):
        fusion.add_imu(seq.t[5:7], seq.gyro[5:8], seq.acc[5:7])
    with pytest.raises(InputError, match="sigma"):
        fusion.add_gps(seq.t[1], [0.0, 0.0, 0.0], -1.0)
    with pytest.raises(InputError, match=r"sigma_m as a float or \(3,\), got shapes \(\) and \(2,\)"):
        fusion.add_gps(seq.t[1], [0.0, 0.0, 0.0], [0.1, 0.1])  # was numpy's broadcast error
    with pytest.raises(InputError, match="add_gps: t: expected an array of real numbers"):
        fusion.add_gps("12:00:01", [0.0, 0.0, 0.0], 0.1)  # was float()'s ValueError
    with pytest.raises(InputError, match="add_imu: gyro: expected real numbers, got complex"):
        fusion.add_imu(seq.t[5:7], seq.gyro[5:7] + 1e-3j, seq.acc[5:7])  # was cast to its real part with a warning
    # refused blocks left nothing behind: the stream goes on to its first keyframe
    assert fusion.add_imu(seq.t[5:101], seq.gyro[5:101], seq.acc[5:101]) == 1
    assert fusion.trajectory().t.tolist() == [seq.t[0], seq.t[100]]
    # a fix far after the last sample waits for a keyframe that never comes: flush says so and keeps its time
    assert fusion.add_gps(seq.t[100] + 30.0, seq.gt.pos[100], 0.5) is False
    with caplog.at_level(logging.WARNING):
        fusion.flush()
    assert "1 GPS fix(es)" in caplog.text and "were not used" in caplog.text
    assert fusion.unused_fixes == (seq.t[100] + 30.0,)
    with pytest.raises(InputError, match="flushed"):
        fusion.add_imu(seq.t[101], seq.gyro[101], seq.acc[101])
    with pytest.raises(InputError, match="eval"):
        OnlineFusion(small_model().train(), seq.gravity, first_state(seq))
    with pytest.raises(ConfigError, match="online.smoother must be one of isam2, fixed_lag"):
        OnlineFusion(None, seq.gravity, first_state(seq), config(smoother="ekf"))
    gravity_reader = small_model().eval()
    gravity_reader.removes_gravity = True  # as model_from_checkpoint sets it for train.remove_gravity
    with pytest.raises(InputError, match="trained with remove_gravity"):
        OnlineFusion(gravity_reader, seq.gravity, first_state(seq))
    slow = small_model().eval()
    slow.trained_on = TrainedOn(rate_hz=100.0, datasets=("kitti_raw",))  # as model_from_checkpoint sets it
    fusion = OnlineFusion(slow, seq.gravity, first_state(seq))
    with pytest.raises(InputError, match=r"sampled at 200.0 Hz, but the model was trained at 100.0 Hz \(kitti_raw\)"):
        fusion.add_imu(seq.t[:30], seq.gyro[:30], seq.acc[:30])


def test_given_densities_the_stream_contradicts_are_warned_about(sequence, caplog):
    """A sigma 216x the stream's own white noise (0.0632, a sigma^2 of 0.004 mistaken for a sigma the other way) is
    warned about once 400 samples are in, naming both numbers; the defaults (a deliberate, conservative choice) are
    not."""
    seq = sequence
    for gyro_sigma, expect in ((0.004**0.5, True), (None, False)):
        caplog.clear()
        chosen = FuseConfig() if gyro_sigma is None else FuseConfig(gyro_noise_density=gyro_sigma)
        fusion = OnlineFusion(
            None, seq.gravity, first_state(seq), dataclasses.replace(chosen, online=OnlineSettings(KEYFRAME_S))
        )
        with caplog.at_level(logging.WARNING):
            for start in range(0, 600, BLOCK):
                fusion.add_imu(
                    seq.t[start : start + BLOCK], seq.gyro[start : start + BLOCK], seq.acc[start : start + BLOCK]
                )
        assert ("gyro_noise_density 0.0632" in caplog.text and "above the white noise" in caplog.text) == expect
    with pytest.raises(ConfigError, match=r"gyro_noise_density: \[1e-06, 1e-06\] is not a gyro noise density sigma"):
        OnlineFusion(None, seq.gravity, first_state(seq), FuseConfig(gyro_noise_density=[1e-6, 1e-6]))


@pytest.mark.slow
def test_isam2_example_runs_and_fuses():
    run = subprocess.run(
        [sys.executable, str(REPO / "examples" / "isam2_learned_factors.py")],
        capture_output=True,
        text=True,
        timeout=300,
        check=True,
    )
    values = dict(line.split(": ", 1) for line in run.stdout.splitlines() if ": " in line)
    gps_error, fused = (float(values[key].split()[0]) for key in ("GPS alone error", "fused ATE"))
    assert fused < 0.6 * gps_error  # measured 0.351 m vs 0.852 m


def test_a_fix_gets_its_own_keyframe_unless_it_comes_after_one_past_it(sequence, caplog):
    """A fix added while its sample is buffered gets a keyframe there (between the 0.5-s grid's); one added after a
    keyframe past its time entered the graph is applied at the nearest keyframe, with a warning naming the offset."""
    seq = sequence
    fusion = OnlineFusion(None, seq.gravity, first_state(seq), config())
    fusion.add_imu(seq.t[:150], seq.gyro[:150], seq.acc[:150])  # keyframes at 0 and 0.5 s in the graph
    assert fusion.add_gps(seq.t[130], seq.gt.pos[130], 0.1) is False  # buffered: a keyframe of its own, waiting
    fusion.add_imu(seq.t[150:300], seq.gyro[150:300], seq.acc[150:300])
    assert list(fusion.trajectory().t) == [seq.t[0], seq.t[100], seq.t[130], seq.t[200]]
    with caplog.at_level("WARNING"):
        assert fusion.add_gps(seq.t[160], seq.gt.pos[160], 0.1) is True  # after the keyframe at 200 (1.0 s)
    assert list(fusion.trajectory().t) == [seq.t[0], seq.t[100], seq.t[130], seq.t[200]]
    assert "applied there, 0.15 s from its own time" in caplog.text


def test_a_car_stream_with_its_gyro_shrunk_is_warned_about(shared_data, caplog):
    """Two minutes into a stream the gyro's unit is checked as the readers check a log without ground truth (KITTI
    2011_10_03_drive_0027's first 121 s: 13 turns): a rad/s gyro converted as if deg/s is named; read right, no word."""
    from learned_imu.datasets import read_sequence

    kitti = {"on_backward": "drop", "on_duplicate": "drop", "on_gap": "keep"}
    drive = read_sequence("kitti_raw", shared_data / "kitti_raw/2011_10_03_drive_0027.csv", **kitti)
    end = int(np.searchsorted(drive.t, drive.t[0] + 121.0))
    settings = FuseConfig(online=OnlineSettings(keyframe_s=5.0))  # few keyframes: the check is what is tested
    for factor, warned in ((1.0, False), (np.pi / 180.0, True)):
        fusion = OnlineFusion(None, drive.gravity, first_state(drive), settings)
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="fusion.online"):
            for start in range(0, end, 100):
                block = slice(start, min(start + 100, end))
                fusion.add_imu(drive.t[block], drive.gyro[block] * factor, drive.acc[block])
        said = [r.getMessage() for r in caplog.records if "gyro" in r.getMessage()]
        assert bool(said) == warned, said
        if warned:
            assert "converted as if deg/s" in said[0] and "OnlineFusion.add_imu" in said[0]


def test_a_stream_with_a_gap_anywhere_in_a_keyframe_interval_is_fused():
    """KITTI's OXTS stream loses 1-2 s at times: wherever the gap falls, the interval across it (down to one sample
    before the gap and the one after) is preintegrated with the sample before it held, not refused."""
    seq = simulate("car", duration_s=6.0, seed=2, rate_hz=100.0)
    pose = gtsam.Pose3(gtsam.Rot3(seq.gt.rot[0]), seq.gt.pos[0])
    config = FuseConfig(online=OnlineSettings(keyframe_s=0.05, smoother="fixed_lag", lag_s=1.0))
    for offset in range(5):  # the gap's start against the keyframes (every 5 samples)
        keep = np.ones(len(seq.t), dtype=bool)
        keep[300 + offset : 458 + offset] = False  # 1.58 s lost
        fusion = OnlineFusion(None, seq.gravity, gtsam.NavState(pose, seq.gt.vel[0]), config)
        t, gyro, acc = seq.t[keep], seq.gyro[keep], seq.acc[keep]
        for first in range(0, len(t), 7):
            fusion.add_imu(t[first : first + 7], gyro[first : first + 7], acc[first : first + 7])
        fusion.flush()
        track = fusion.trajectory()
        assert t[-1] - track.t[-1] < 0.05 and np.all(np.isfinite(track.pos))  # to the last keyframe
