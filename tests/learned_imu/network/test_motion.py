"""The motion model: streaming is the one pass, targets are the body-frame velocity at block ends, the attitude
augmentation only tilts, training learns velocity, and its checkpoints are told apart from the correction model's."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from airimu.cli import app
from airimu_core.errors import ConfigError, DataError, InputError
from learned_imu.config import MotionConfig
from learned_imu.datasets.simulator import simulate
from learned_imu.network.checkpoint import build_motion_model, model_from_checkpoint, motion_from_checkpoint
from learned_imu.network.motion import Motion, MotionNet, block_ends, motion_sequence, up_in_body
from learned_imu.training.losses import LossWeights
from learned_imu.training.motion import (
    _tilted,
    collapse_warning,
    concat_motion_chunks,
    make_motion_chunks,
    output_spread,
)
from learned_imu.training.train import Trainer


def random_model() -> MotionNet:
    torch.manual_seed(0)
    model = MotionNet(conv_channels=(8, 16), gru_sizes=(16,), decoder_hidden=16)
    for decoder in (model.vel_decoder, model.var_decoder):
        torch.nn.init.normal_(decoder[-1].weight, std=0.1)
    return model.eval()


@pytest.mark.parametrize("n", [900, 1000, 1001])
def test_streaming_equals_one_pass_and_outputs_sit_at_block_ends(n):
    model = random_model()
    gen = torch.Generator().manual_seed(n)
    gyro, acc = torch.randn(n, 3, generator=gen), torch.randn(n, 3, generator=gen) + torch.tensor([0.0, 0.0, 9.8])
    up = torch.nn.functional.normalize(torch.randn(n, 3, generator=gen), dim=-1)
    one = model(gyro[None], acc[None], up[None])
    streamed = motion_sequence(model, gyro, acc, up, chunk=77)
    ends = block_ends(n, model.block)
    assert one.vel.shape[1] == streamed.vel.shape[0] == len(ends) == math.ceil(n / 9)
    assert ends[-1] == n - 1 and (ends[:-1] % 9 == 8).all()
    torch.testing.assert_close(streamed.vel, one.vel[0], atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(streamed.vel_var, one.vel_var[0], atol=1e-6, rtol=1e-5)
    # causal: the first half's outputs do not change when the second half does
    other = motion_sequence(model, gyro, acc, torch.cat([up[: n // 2], -up[n // 2 :]]), chunk=1000)
    keep = n // 2 // 9
    torch.testing.assert_close(other.vel[:keep], streamed.vel[:keep], atol=1e-5, rtol=1e-5)
    assert not torch.allclose(other.vel[-1], streamed.vel[-1])


def test_untrained_model_gives_zero_velocity_with_its_initial_variance():
    model = MotionNet(init_var=0.3).eval()
    out = model(torch.randn(1, 90, 3), torch.randn(1, 90, 3), torch.randn(1, 90, 3))
    assert torch.all(out.vel == 0) and torch.allclose(out.vel_var, torch.full_like(out.vel_var, 0.3))
    with pytest.raises(InputError, match="must all be"):
        model(torch.randn(1, 90, 3), torch.randn(1, 90, 3), torch.randn(1, 80, 3))
    with pytest.raises(InputError, match="eval"):
        MotionNet().train().stream(*(torch.zeros(1, 9, 3),) * 3, MotionNet().initial_state())


def test_chunk_targets_are_the_body_frame_velocity_at_block_ends():
    seq = simulate("car", duration_s=30.0, seed=3)
    chunks = make_motion_chunks(seq, length=900, stride=450, context=90, block=9)
    assert len(chunks) == (len(seq) - 990 - 1) // 450 + 1 and chunks.target.shape[1] == 100
    first_end = 90 + 8  # the first block end after the context of chunk 0
    expected = seq.gt.rot[first_end].T @ seq.gt.vel[first_end]
    np.testing.assert_allclose(chunks.target[0, 0].numpy(), expected, rtol=1e-5, atol=1e-5)
    last = 450 + 90 + 899
    np.testing.assert_allclose(chunks.target[1, -1].numpy(), seq.gt.rot[last].T @ seq.gt.vel[last], atol=1e-5)
    with pytest.raises(InputError, match="whole number of 9-sample blocks"):
        make_motion_chunks(seq, length=1000, stride=450, context=90, block=9)
    seq.gt.valid[200] = False  # a hole in the truth: chunks touching it go
    holed = make_motion_chunks(seq, length=900, stride=450, context=90, block=9)
    assert len(holed) == len(chunks) - 1


def test_the_attitude_augmentation_tilts_by_the_configured_angle_and_keeps_rotations():
    rot = torch.as_tensor(simulate("drone", duration_s=2.0, seed=1).gt.rot[:50], dtype=torch.float64)
    batch = rot[None].expand(4000, -1, -1, -1)
    torch.manual_seed(0)
    tilted = _tilted(batch, math.radians(2.0))
    eye = torch.eye(3, dtype=torch.float64)
    assert torch.allclose(tilted.mT @ tilted, eye.expand_as(tilted), atol=1e-12)
    # the up axis moves by the tilt angle (about a horizontal world axis), the same angle for all samples of a chunk
    cos = (up_in_body(tilted) * up_in_body(batch)).sum(-1).clamp(-1, 1)
    angle = torch.rad2deg(torch.acos(cos))
    assert torch.allclose(angle, angle[:, :1], atol=1e-5)
    rms = float(angle[:, 0].square().mean().sqrt())
    assert 1.9 < rms < 2.1  # N(0, 2 deg)


def test_training_learns_the_velocity():
    """On unseen simulated flights of the same drone the squared velocity error falls well below the untrained
    model's (which says 0 m/s: the mean squared speed per axis)."""
    flights = [make_motion_chunks(simulate("drone", duration_s=120.0, seed=s), 450, 90, 90, 9, 0.035) for s in (1, 2)]
    val = make_motion_chunks(simulate("drone", duration_s=60.0, seed=3), 450, 450, 90, 9)
    torch.manual_seed(0)
    model = MotionNet(gru_sizes=(64,), decoder_hidden=32)
    trainer = Trainer(model, concat_motion_chunks(flights), val, 16, 3e-3, weights=LossWeights(covariance=0.1))
    before = trainer.validation_loss()
    for _ in range(10):
        trainer.epoch()
    after = trainer.validation_loss()
    assert after < 0.7 * before, (before, after)  # measured 1.43 -> 0.81 (m/s)^2


def test_output_spread_tells_a_constant_model_from_one_that_follows_the_motion():
    """A model whose velocity does not depend on its input (the untrained one: zero) has spread 0 and is named; one
    that gives the truth has spread 1 and is not."""
    chunks = make_motion_chunks(simulate("drone", duration_s=30.0, seed=4), 450, 450, 90, 9)
    spread = output_spread(MotionNet(gru_sizes=(16,)), chunks)
    assert np.all(spread < 1e-6)
    assert "hardly vary" in collapse_warning(spread, "run/best.pt") and "vel_scale_m_s" in collapse_warning(spread, "x")

    class Truth(torch.nn.Module):  # the targets, after the context's outputs
        def forward(self, gyro, acc, up):
            vel = torch.cat([torch.zeros(len(chunks), chunks.context_blocks, 3), chunks.target], dim=1)
            return Motion(vel, torch.ones_like(vel))

    assert output_spread(Truth(), chunks, batch_size=len(chunks)) == pytest.approx(np.ones(3))
    assert collapse_warning(np.array([0.05, 0.1, 0.3]), "x") is None


def test_motion_config_is_checked():
    assert float(build_motion_model(MotionConfig(vel_scale_m_s=10.0)).vel_scale) == 10.0
    with pytest.raises(ConfigError, match="motion.vel_scale_m_s"):
        MotionConfig(vel_scale_m_s=0.0)
    with pytest.raises(ConfigError, match="motion.chunk"):
        MotionConfig(chunk=1000)
    with pytest.raises(ConfigError, match="motion.tilt_noise_deg"):
        MotionConfig(tilt_noise_deg=-1.0)


@pytest.mark.slow
def test_airimu_train_trains_either_model_and_checkpoints_say_which(tmp_path):
    config = tmp_path / "tiny.yaml"
    config.write_text(
        "name: tiny\ndata:\n"
        "  train: [{dataset: simulator, options: {profile: drone, duration_s: 40.0, seed: 1}}]\n"
        "  val: [{dataset: simulator, options: {profile: drone, duration_s: 20.0, seed: 2}}]\n"
        "model: {gru_sizes: [16, 16]}\nmotion: {gru_sizes: [16], chunk: 900, chunk_stride: 450}\n"
        "train: {window: 200, batch_size: 4, epochs: 1, calibration_steps: 0}\n"
    )
    result = CliRunner().invoke(app, ["train", "--config", str(config), "--out", str(tmp_path / "run"), "--model",
                                      "both", "--no-progress"])  # fmt: skip
    assert result.exit_code == 0, result.output
    model, _ = motion_from_checkpoint(tmp_path / "run" / "motion" / "best.pt")
    assert isinstance(model, MotionNet) and model.trained_on.rate_hz == pytest.approx(200.0)
    model_from_checkpoint(tmp_path / "run" / "correction" / "best.pt")
    with pytest.raises(DataError, match="holds a motion model, not a correction model"):
        model_from_checkpoint(tmp_path / "run" / "motion" / "best.pt")
    with pytest.raises(DataError, match="holds a correction model, not a motion model"):
        motion_from_checkpoint(tmp_path / "run" / "correction" / "best.pt")


def test_frame_rotation_turns_inputs_and_target_alike():
    """The augmentation is one proper rotation per chunk applied to gyro, acc, up and target: lengths and the angles
    between them are kept, the vectors themselves move."""
    from learned_imu.training.motion import _random_rotations

    torch.manual_seed(0)
    q = _random_rotations(64, math.radians(10.0), torch.zeros(1, dtype=torch.float64))
    assert torch.allclose(q @ q.mT, torch.eye(3, dtype=torch.float64).expand(64, 3, 3), atol=1e-12)
    assert torch.allclose(torch.linalg.det(q), torch.ones(64, dtype=torch.float64))
    chunks = make_motion_chunks(simulate("drone", duration_s=20.0, seed=1), 450, 450, 90, 9, 0.0, False, 0.2)
    seen = {}

    class Probe(torch.nn.Module):
        def forward(self, gyro, acc, up):
            seen.update(gyro=gyro, acc=acc, up=up)
            blocks = gyro.shape[1] // 9
            return Motion(torch.zeros(gyro.shape[0], blocks, 3), torch.ones(gyro.shape[0], blocks, 3))

    out, target, world = chunks._predict(Probe(), perturb=True)
    ends = chunks.rot[:, 90 + 8 :: 9]
    truth_world = (ends @ chunks.target[..., None])[..., 0]
    torch.testing.assert_close((world @ target[..., None])[..., 0], truth_world, atol=1e-4, rtol=0)
    up = up_in_body(chunks.rot)
    assert torch.allclose(seen["up"].norm(dim=-1), up.norm(dim=-1), atol=1e-5)
    assert torch.allclose(target.norm(dim=-1), chunks.target.norm(dim=-1), atol=1e-4)
    angle_before = torch.sum(chunks.acc[:, :1] * up[:, :1], dim=-1)
    assert torch.allclose(torch.sum(seen["acc"][:, :1] * seen["up"][:, :1], dim=-1), angle_before, atol=1e-4)
    assert (seen["up"] - up).abs().max() > 0.05  # and they did turn


def test_time_reversal_plays_a_chunk_backwards_with_the_kinematics_intact():
    """motion.time_reversal: a reversed chunk is the same path flown the other way: samples in reverse order, the
    angular rate and the velocity negated; d(v_b)/dt = f - g R^T e_z - w x v_b holds for it (the clean simulated
    IMU), the target is its velocity at its own block ends, and a draw reverses about half the chunks."""
    import dataclasses

    from learned_imu.datasets.simulator import simulate_with_truth

    sim = simulate_with_truth("drone", duration_s=12.0, seed=2)
    seq = dataclasses.replace(sim.sequence, gyro=sim.clean_gyro, acc=sim.clean_acc)
    chunks = make_motion_chunks(seq, 450, 90, 90, 9, time_reversal=True).double()
    assert chunks.vel.shape == chunks.gyro.shape and not make_motion_chunks(seq, 450, 90, 90, 9).time_reversal
    dt, g = float(np.median(np.diff(seq.t))), float(np.linalg.norm(seq.gravity))

    def residual(gyro, acc, rot, vel):
        dv = (vel[:, 2:] - vel[:, :-2]) / (2 * dt)
        return dv - (acc - g * up_in_body(rot) - torch.cross(gyro, vel, dim=-1))[:, 1:-1]

    before = residual(chunks.gyro, chunks.acc, chunks.rot, chunks.vel).norm(dim=-1)
    assert before.max() < 0.05  # m/s^2
    back = torch.ones(len(chunks), dtype=torch.bool)
    gyro, acc, rot, target = chunks._reversed(back)
    vel = -chunks.vel.flip(1)
    after = residual(gyro, acc, rot, vel).norm(dim=-1)
    torch.testing.assert_close(after, before.flip(1), atol=1e-9, rtol=0)
    naive = residual(chunks.gyro.flip(1), acc, rot, vel).norm(dim=-1)  # forgetting to negate the rate
    assert naive.max() > 10 * before.max()
    torch.testing.assert_close(target, vel[:, 90 + 8 :: 9])
    torch.testing.assert_close(target[:, -1], -chunks.vel[:, 0])  # the last target: the chunk's first sample
    mixed = chunks._reversed(torch.arange(len(chunks)) % 2 == 0)
    torch.testing.assert_close(mixed[3][1::2], chunks.target[1::2])
    torch.testing.assert_close(mixed[3][0::2], target[0::2])
    torch.manual_seed(0)
    model = MotionNet(conv_channels=(8, 16), gru_sizes=(16,), decoder_hidden=16)
    _, drawn, _ = chunks._predict(model.double(), perturb=True)
    flipped = (drawn - chunks.target).abs().amax(dim=(1, 2)) > 1e-9
    assert 0 < int(flipped.sum()) < len(chunks)


def test_symmetry_maps_keep_the_body_frame_kinematics():
    """motion.mirror_axis / spin_axis: the mapped chunk is the motion of a mirrored or spun IMU, so the body-frame
    kinematics d(v_b)/dt = f - g R^T e_z - w x v_b hold for it as for the original (a reflection flips the angular
    rate once more, a pseudo-vector: mapping it like the other vectors leaves a residual of 2 |w x v_b|)."""
    from learned_imu.datasets.simulator import simulate_with_truth
    from learned_imu.training.motion import _symmetry_maps

    sim = simulate_with_truth("drone", duration_s=5.0, seed=2)
    seq = sim.sequence
    rot, dt = torch.as_tensor(seq.gt.rot), float(np.median(np.diff(seq.t)))
    v_b = torch.einsum("nji,nj->ni", rot, torch.as_tensor(seq.gt.vel))
    gyro, acc, up = torch.as_tensor(sim.clean_gyro), torch.as_tensor(sim.clean_acc), up_in_body(rot)

    def residual(gyro, acc, up, v_b):
        dv = (v_b[2:] - v_b[:-2]) / (2 * dt)
        gravity_b = -float(np.linalg.norm(seq.gravity)) * up
        return dv - (acc + gravity_b - torch.cross(gyro, v_b, dim=-1))[1:-1]

    before = residual(gyro, acc, up, v_b).norm(dim=-1)
    assert before.max() < 0.05  # m/s^2: the clean simulated IMU is consistent with its truth
    torch.manual_seed(0)
    q = _symmetry_maps(8, 1, 0, gyro)
    assert (torch.linalg.det(q) < 0).any() and (torch.linalg.det(q) > 0).any()
    for qi in q:
        mapped = [x @ qi.T for x in (gyro, acc, up, v_b)]
        mapped[0] = mapped[0] * torch.linalg.det(qi)  # as MotionChunks._predict maps the gyro
        after = residual(*mapped).norm(dim=-1)
        assert torch.allclose(after, before, atol=1e-9)
        if torch.linalg.det(qi) < 0:  # the pseudo-vector's sign matters
            naive = residual(gyro @ qi.T, *mapped[1:]).norm(dim=-1)
            assert naive.max() > 10 * before.max()
    with pytest.raises(ConfigError, match="motion.mirror_axis"):
        MotionConfig(mirror_axis=3)
    with pytest.raises(ConfigError, match="motion.time_reversal"):
        MotionConfig(time_reversal="yes")


def test_drift_term_weighs_a_constant_bias_over_noise_of_the_same_size():
    """motion.drift: the loss adds the squared world-frame mean velocity error over every prefix of the chunk (by
    hand here); a constant bias costs more than an alternating error of the same mean square, which the plain
    squared error cannot tell apart. On mirrored chunks the map back to the world undoes the reflection."""
    seq = simulate("drone", duration_s=20.0, seed=3)
    chunks = make_motion_chunks(seq, 450, 900, 90, 9, 0.0, False, 0.0, 1, None, False, 2.0).double()
    bias = torch.tensor([0.1, -0.05, 0.02], dtype=torch.float64)
    blocks = chunks.target.shape[1]
    alternate = torch.tensor([1.0, -1.0], dtype=torch.float64).repeat(blocks)[:blocks, None]

    class Offset(torch.nn.Module):
        def __init__(self, err):
            super().__init__()
            self.err = err

        def forward(self, gyro, acc, up):
            head = torch.zeros_like(chunks.target[:, : chunks.context_blocks])
            vel = torch.cat([head, chunks.target + self.err], dim=1)
            return Motion(vel, torch.ones_like(vel))

    losses = []
    for err in (bias.expand_as(chunks.target), alternate * bias):
        model = Offset(err).eval()  # not training: no perturbation, the target as made
        losses.append(float(chunks.loss(model, covariance=0.0)))
        world = chunks.rot[:, 90 + 8 :: 9]
        mean = (world @ err[..., None])[..., 0].cumsum(1) / torch.arange(1, blocks + 1)[:, None]
        by_hand = err.square().mean() + 2.0 * mean.square().mean()
        assert abs(losses[-1] - float(by_hand)) < 1e-9
    assert losses[0] > 2 * losses[1]  # same squared error (the first term), the drift term apart

    class Probe(torch.nn.Module):
        def forward(self, gyro, acc, up):
            n = gyro.shape[1] // 9
            return Motion(torch.zeros(gyro.shape[0], n, 3), torch.ones(gyro.shape[0], n, 3))

    torch.manual_seed(0)
    _, target, world = chunks._predict(Probe(), perturb=True)
    assert (target - chunks.target).abs().amax() > 0.1  # some chunks mirrored
    truth = (chunks.rot[:, 90 + 8 :: 9] @ chunks.target[..., None])[..., 0]
    torch.testing.assert_close((world @ target[..., None])[..., 0], truth, atol=1e-9, rtol=0)
    with pytest.raises(ConfigError, match="motion.drift"):
        MotionConfig(drift=-1.0)


def test_axis_weights_leave_a_weightless_axis_out_of_both_terms():
    """motion.axis_weights: an error on an axis of weight 0 costs nothing (squared error and drift term alike), the
    other axes' as before; validation reads the same loss, so the weightless axis does not pick the epoch."""
    seq = simulate("drone", duration_s=20.0, seed=3)
    blocks_of = lambda c: c.target.shape[1]  # noqa: E731

    class Offset(torch.nn.Module):
        def __init__(self, chunks, err):
            super().__init__()
            self.chunks, self.err = chunks, err

        def forward(self, gyro, acc, up):
            c = self.chunks
            vel = torch.cat([torch.zeros_like(c.target[:, : c.context_blocks]), c.target + self.err], dim=1)
            return Motion(vel, torch.ones_like(vel))

    losses = {}
    for weights in ((1.0, 1.0, 1.0), (0.0, 1.0, 1.0)):
        chunks = make_motion_chunks(seq, 450, 900, 90, 9, drift=2.0, axis_weights=weights).double()
        for name, err in (("x", torch.tensor([0.3, 0.0, 0.0])), ("y", torch.tensor([0.0, 0.3, 0.0]))):
            err = err.double().expand(len(chunks), blocks_of(chunks), 3)
            losses[weights, name] = float(chunks.loss(Offset(chunks, err).eval(), covariance=0.0))
    assert losses[(0.0, 1.0, 1.0), "x"] == 0.0 and losses[(1.0, 1.0, 1.0), "x"] > 0.09 / 3
    assert losses[(0.0, 1.0, 1.0), "y"] == losses[(1.0, 1.0, 1.0), "y"] > 0.09 / 3
    for bad in ((1.0, 1.0), (0.0, 0.0, 0.0), (1.0, -1.0, 1.0)):
        with pytest.raises(ConfigError, match="motion.axis_weights"):
            MotionConfig(axis_weights=bad)
