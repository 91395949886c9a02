"""AirImuNet: outputs and units, exact streaming, causality, gradients."""

from __future__ import annotations

import math

import pytest
import torch

from learned_imu.model import DEFAULT_ACC_DENSITY, DEFAULT_GYRO_DENSITY, AirImuNet, correct_sequence


def samples(n: int, batch: int = 1, seed: int = 0):
    gen = torch.Generator().manual_seed(seed)
    gyro = torch.randn(batch, n, 3, generator=gen)
    acc = torch.randn(batch, n, 3, generator=gen) + torch.tensor([0.0, 0.0, 9.81])
    return gyro, acc


def trained_like(use_gru: bool = True, seed: int = 0) -> AirImuNet:
    """A model whose output layers are not zero, so that outputs depend on the inputs."""
    torch.manual_seed(seed)
    model = AirImuNet(use_gru=use_gru)
    for decoder in (model.correction, model.uncertainty):
        torch.nn.init.normal_(decoder[-1].weight, std=0.5)
    return model.eval()


def test_untrained_model_passes_raw_imu_with_initial_noise():
    gyro, acc = samples(100, batch=2)
    out = AirImuNet()(gyro, acc)
    assert out.gyro.shape == out.gyro_cov.shape == (2, 100, 3)
    assert torch.equal(out.gyro, gyro) and torch.equal(out.acc, acc)
    assert torch.allclose(out.gyro_cov, torch.full_like(out.gyro_cov, DEFAULT_GYRO_DENSITY))
    assert torch.allclose(out.acc_cov, torch.full_like(out.acc_cov, DEFAULT_ACC_DENSITY))


def test_unit_network_output_is_the_documented_correction():
    model = AirImuNet().eval()
    torch.nn.init.ones_(model.correction[-1].bias)
    out = model(*samples(20))
    assert torch.allclose(out.d_acc, torch.full_like(out.d_acc, 0.1))  # m/s^2
    assert torch.allclose(out.d_gyro, torch.full_like(out.d_gyro, math.radians(1.0)))  # rad/s


@pytest.mark.parametrize("use_gru", [True, False])
@pytest.mark.parametrize("chunk", [1, 7, 9, 100, 1000])
def test_streaming_in_chunks_equals_one_pass(use_gru, chunk):
    model = trained_like(use_gru)
    gyro, acc = samples(203)
    with torch.no_grad():
        full = model(gyro, acc)
    streamed = correct_sequence(model, gyro[0], acc[0], chunk=chunk)
    for field in ("gyro", "acc", "gyro_cov", "acc_cov"):
        assert (getattr(streamed, field) - getattr(full, field)[0]).abs().max() < 1e-5, field
    assert (full.gyro_cov > 0).all() and (full.acc_cov > 0).all()
    assert (full.d_gyro.abs() > 0).any()


def test_output_depends_only_on_samples_up_to_the_end_of_their_block():
    model = trained_like()
    gyro, acc = samples(90)
    with torch.no_grad():
        before = model(gyro, acc).gyro
        gyro2 = gyro.clone()
        gyro2[0, 40] += 1.0  # sample 40 lies in block [36, 45)
        after = model(gyro2, acc).gyro
    assert torch.equal(before[0, :36], after[0, :36])
    assert not torch.equal(before[0, 36:45], after[0, 36:45])


def test_gradients_reach_every_parameter_and_runs_are_deterministic():
    model = trained_like().train()
    gyro, acc = samples(90, batch=2)
    out = model(gyro, acc)
    (out.gyro.sum() + out.acc.sum() + out.gyro_cov.log().sum() + out.acc_cov.log().sum()).backward()
    missing = [name for name, p in model.named_parameters() if p.grad is None or not p.grad.abs().sum() > 0]
    assert not missing
    a = trained_like(seed=3)
    b = trained_like(seed=3)
    with torch.no_grad():
        assert torch.equal(a(gyro, acc).gyro_cov, b(gyro, acc).gyro_cov)


def test_bad_shapes_raise():
    gyro, acc = samples(10)
    with pytest.raises(ValueError, match=r"\(B, N, 3\)"):
        AirImuNet()(gyro[0], acc[0])
    with pytest.raises(ValueError, match="kernel_size"):
        AirImuNet(kernel_size=2, stride=3)
