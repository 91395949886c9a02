"""AirImuNet: sizes, outputs and units, exact streaming, causality, gradients, determinism, input checks."""

from __future__ import annotations

import math

import pytest
import torch

from learned_imu import preintegrate
from learned_imu.network.model import (
    DEFAULT_ACC_COV,
    DEFAULT_GYRO_COV,
    LOG_DENSITY_LIMIT,
    AirImuNet,
    correct_sequence,
)

DT_S = 0.005  # 200 Hz


def samples(n: int, batch: int = 1, seed: int = 0):
    gen = torch.Generator().manual_seed(seed)
    gyro = torch.randn(batch, n, 3, generator=gen)
    acc = torch.randn(batch, n, 3, generator=gen) + torch.tensor([0.0, 0.0, 9.81])
    return gyro, acc


def heads(model: AirImuNet):
    return model.acc_decoder, model.gyro_decoder, model.acc_cov_decoder, model.gyro_cov_decoder


def trained_like(use_gru: bool = True, seed: int = 0) -> AirImuNet:
    """A model whose output layers are not zero, so that outputs depend on the inputs."""
    torch.manual_seed(seed)
    model = AirImuNet(use_gru=use_gru)
    for decoder in heads(model):
        torch.nn.init.normal_(decoder[-1].weight, std=0.5)
    return model.eval()


def test_parameter_count_matches_the_official_sizes():
    # CodeNet: Conv1d 6->32->64 (k 7) + BatchNorm, GRU 64->128->256, four Linear(256,128)-GELU-Linear(128,3)
    conv = (6 * 32 * 7 + 32) + 2 * 32 + (32 * 64 * 7 + 64) + 2 * 64
    gru = 3 * (64 * 128 + 128 * 128 + 2 * 128) + 3 * (128 * 256 + 256 * 256 + 2 * 256)

    def decoders(width):
        return 4 * (width * 128 + 128 + 128 * 3 + 3)

    def count(model):
        return sum(p.numel() for p in model.parameters())

    assert count(AirImuNet()) == conv + gru + decoders(256) == 520_044
    assert count(AirImuNet(use_gru=False)) == conv + decoders(64) == 50_796


def test_untrained_model_passes_raw_imu_with_initial_densities_that_preintegrate_takes():
    gyro, acc = samples(100, batch=2)
    with torch.no_grad():
        out = AirImuNet().eval()(gyro, acc)
    for field in ("gyro", "acc", "d_gyro", "d_acc", "gyro_cov", "acc_cov"):
        assert getattr(out, field).shape == (2, 100, 3), field
    assert torch.equal(out.gyro, gyro) and torch.equal(out.acc, acc)
    assert torch.allclose(out.gyro_cov, torch.full_like(out.gyro_cov, DEFAULT_GYRO_COV), rtol=1e-5)
    assert torch.allclose(out.acc_cov, torch.full_like(out.acc_cov, DEFAULT_ACC_COV), rtol=1e-5)
    # the densities go straight into preintegrate: same covariance as the scalar densities
    learned = preintegrate(out.gyro.double(), out.acc.double(), DT_S, out.gyro_cov.double(), out.acc_cov.double())
    scalar = preintegrate(gyro.double(), acc.double(), DT_S, DEFAULT_GYRO_COV, DEFAULT_ACC_COV)
    torch.testing.assert_close(learned.cov, scalar.cov, rtol=1e-5, atol=1e-6 * scalar.cov.abs().max().item())
    # rotation variance after 1 s of white gyro noise is about density * t (rad^2)
    assert learned.cov[0, -1, 0, 0].item() == pytest.approx(DEFAULT_GYRO_COV * 100 * DT_S, rel=0.05)


def test_unit_network_output_is_the_documented_correction_and_density_factor():
    model = AirImuNet().eval()
    for decoder in heads(model)[:2]:
        torch.nn.init.ones_(decoder[-1].bias)
    for decoder in heads(model)[2:]:
        torch.nn.init.constant_(decoder[-1].bias, math.log(4.0))
    gyro, acc = samples(20)
    with torch.no_grad():
        out = model(gyro, acc)
    assert torch.allclose(out.d_acc, torch.full_like(out.d_acc, 0.1))  # m/s^2
    assert torch.allclose(out.d_gyro, torch.full_like(out.d_gyro, math.radians(1.0)))  # rad/s
    assert torch.allclose(out.gyro, gyro + math.radians(1.0)) and torch.allclose(out.acc, acc + 0.1)
    assert torch.allclose(out.gyro_cov, torch.full_like(out.gyro_cov, 4 * DEFAULT_GYRO_COV), rtol=1e-5)
    assert torch.allclose(out.acc_cov, torch.full_like(out.acc_cov, 4 * DEFAULT_ACC_COV), rtol=1e-5)


def test_densities_stay_positive_and_finite_at_extreme_network_outputs():
    model = AirImuNet().eval()
    torch.nn.init.constant_(model.gyro_cov_decoder[-1].bias, 1e4)
    torch.nn.init.constant_(model.acc_cov_decoder[-1].bias, -1e4)
    with torch.no_grad():
        out = model(*samples(9))
    largest = DEFAULT_GYRO_COV * math.exp(LOG_DENSITY_LIMIT)  # rad^2/s
    assert torch.allclose(out.gyro_cov, torch.full_like(out.gyro_cov, largest))
    assert (out.acc_cov > 0).all() and torch.isfinite(out.acc_cov).all()


@pytest.mark.parametrize("use_gru", [True, False])
@pytest.mark.parametrize("chunk", [1, 7, 9, 100, 1000])
def test_streaming_in_chunks_equals_one_pass(use_gru, chunk):
    model = trained_like(use_gru)
    gyro, acc = samples(203)  # 22 whole blocks of 9 and a tail of 5
    with torch.no_grad():
        full = model(gyro, acc)
    streamed = correct_sequence(model, gyro[0], acc[0], chunk=chunk)
    for field in ("gyro", "acc", "d_gyro", "d_acc"):
        assert (getattr(streamed, field) - getattr(full, field)[0]).abs().max() < 1e-5, field
    for field in ("gyro_cov", "acc_cov"):  # densities are ~1e-6: compare relatively
        assert (getattr(streamed, field) / getattr(full, field)[0] - 1).abs().max() < 1e-5, field
    assert (full.gyro_cov > 0).all() and (full.acc_cov > 0).all()
    assert full.d_gyro.abs().min() > 0 and full.gyro_cov.std() > 0  # the outputs do depend on the inputs


def test_stream_returns_complete_blocks_and_carries_a_batch():
    model = trained_like()
    gyro, acc = samples(50, batch=2, seed=1)
    with torch.no_grad():
        full = model(gyro, acc)
        state = model.initial_state(batch=2)
        parts, sizes = [], []
        for first, last in ((0, 4), (4, 4), (4, 20), (20, 41), (41, 50)):
            out, state = model.stream(gyro[:, first:last], acc[:, first:last], state, flush=last == 50)
            parts.append(out)
            sizes.append(out.acc_cov.shape[1])
    assert sizes == [0, 0, 18, 18, 14]  # only whole blocks of 9 until the flush
    assert state.pending_gyro.shape == (2, 0, 3)
    assert (torch.cat([p.gyro for p in parts], dim=1) - full.gyro).abs().max() < 1e-5
    assert (torch.cat([p.acc_cov for p in parts], dim=1) / full.acc_cov - 1).abs().max() < 1e-5


def test_output_depends_only_on_samples_up_to_the_end_of_their_block():
    for use_gru in (True, False):
        model = trained_like(use_gru)
        gyro, acc = samples(90)
        with torch.no_grad():
            before = model(gyro, acc)
            gyro2 = gyro.clone()
            gyro2[0, 40] += 1.0  # sample 40 lies in block [36, 45)
            after = model(gyro2, acc)
        assert torch.equal(before.d_gyro[0, :36], after.d_gyro[0, :36])
        assert torch.equal(before.acc_cov[0, :36], after.acc_cov[0, :36])
        assert not torch.equal(before.d_gyro[0, 36:45], after.d_gyro[0, 36:45])


def test_gradients_reach_every_parameter():
    model = trained_like().train()
    gyro, acc = samples(90, batch=2)
    out = model(gyro, acc)
    (out.gyro.sum() + out.acc.sum() + out.gyro_cov.log().sum() + out.acc_cov.log().sum()).backward()
    missing = [name for name, p in model.named_parameters() if p.grad is None or not p.grad.abs().sum() > 0]
    assert not missing
    fresh = AirImuNet().train()  # zero last layers: the encoder's gradient is zero, but every one exists
    out = fresh(gyro, acc)
    (out.gyro.sum() + out.acc.sum() + out.acc_cov.log().sum() + out.gyro_cov.log().sum()).backward()
    assert all(p.grad is not None for p in fresh.parameters())
    assert all(head[-1].weight.grad.abs().sum() > 0 for head in heads(fresh))


def test_construction_and_outputs_are_deterministic_for_a_seed():
    gyro, acc = samples(90, batch=2)
    a, b, c = trained_like(seed=3), trained_like(seed=3), trained_like(seed=4)
    with torch.no_grad():
        assert torch.equal(a(gyro, acc).gyro_cov, b(gyro, acc).gyro_cov)
        assert not torch.equal(a(gyro, acc).gyro_cov, c(gyro, acc).gyro_cov)


def test_bad_inputs_raise_with_clear_messages():
    gyro, acc = samples(10)
    model = AirImuNet().eval()
    with pytest.raises(ValueError, match=r"\(B, N, 3\); got \(10, 3\)"):
        model(gyro[0], acc[0])
    with pytest.raises(ValueError, match=r"\(B, N, 3\)"):
        model(gyro, acc[:, :9])
    with pytest.raises(ValueError, match="at least 1 sample"):
        model(gyro[:, :0], acc[:, :0])
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        correct_sequence(model, gyro, acc)
    with pytest.raises(ValueError, match="chunk"):
        correct_sequence(model, gyro[0], acc[0], chunk=0)
    with pytest.raises(ValueError, match="kernel_size"):
        AirImuNet(kernel_size=2, stride=3)
    with pytest.raises(ValueError, match=r"model\.eval\(\)"):
        AirImuNet().train().stream(gyro, acc, model.initial_state())
