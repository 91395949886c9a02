"""Losses: exact errors on a perfect IMU, calibrated covariance on white noise, likelihood properties."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from learned_imu import NavState, predict, preintegrate
from learned_imu.datasets.simulator import ImuErrorModel, simulate_with_truth
from learned_imu.training.losses import (
    VARIANCE_FLOOR,
    LossWeights,
    covariance_nll,
    delta_errors,
    normalised_squared_errors,
    state_loss,
    total_loss,
)

WINDOW, EVERY = 200, 50  # samples per window, supervised every 50th


def windows(sim, gyro, acc, gyro_cov=None, acc_cov=None):
    seq = sim.sequence
    starts = np.arange(0, len(seq) - WINDOW, WINDOW)
    take = starts[:, None] + np.arange(WINDOW)
    at = slice(EVERY - 1, None, EVERY)
    t = torch.as_tensor
    pre = preintegrate(t(gyro[take]), t(acc[take]), t(seq.dt[take]), gyro_cov, acc_cov, at=at)
    after = (take + 1)[:, at]
    gt = seq.gt
    start = NavState(rot=t(gt.rot[starts]), vel=t(gt.vel[starts]), pos=t(gt.pos[starts]))
    end = NavState(rot=t(gt.rot[after]), vel=t(gt.vel[after]), pos=t(gt.pos[after]))
    return pre, start, end, t(seq.gravity)


def test_perfect_imu_has_zero_errors_and_errors_match_predict():
    sim = simulate_with_truth("handheld", duration_s=20.0, seed=0)
    pre, start, end, g = windows(sim, sim.clean_gyro, sim.clean_acc)
    assert delta_errors(pre, start, end, g).abs().max() < 1e-9
    noisy = windows(sim, sim.sequence.gyro, sim.sequence.acc)
    errors = delta_errors(*noisy)
    world = predict(noisy[1], noisy[0], noisy[3])
    # the position block, rotated to the world frame, is the world position error
    pos_world = (noisy[1].rot[:, None] @ errors[..., 3:6, None])[..., 0]
    assert torch.allclose(pos_world, noisy[2].pos - world.pos, atol=1e-9)


def test_rotation_error_is_continuous_where_the_delta_angle_crosses_pi():
    """Predicted delta just below pi, true delta just above: the error is their small difference (in the chart
    of the covariance), not 2 pi minus it (the two Logs alone would jump to opposite axes)."""
    n, dt = 100, 0.01
    gyro = torch.zeros(1, n, 3, dtype=torch.float64)
    gyro[..., 2] = (np.pi - 0.003) / (n * dt)
    acc = torch.zeros_like(gyro)
    pre = preintegrate(gyro, acc, dt, at=[n - 1])
    true_angle = np.pi + 0.004
    c, s_ = np.cos(true_angle), np.sin(true_angle)
    rot_gt = torch.tensor([[[[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]]]], dtype=torch.float64)
    eye = torch.eye(3, dtype=torch.float64)[None]
    start = NavState(rot=eye, vel=torch.zeros(1, 3, dtype=torch.float64), pos=torch.zeros(1, 3, dtype=torch.float64))
    end = NavState(rot=rot_gt, vel=pre.vel, pos=pre.pos)
    theta = delta_errors(pre, start, end, torch.zeros(3, dtype=torch.float64))[0, 0, :3]
    # d theta = Jr^-1(theta) d phi; about the rotation axis itself Jr^-1 is the identity: 0.007 rad about z
    assert torch.allclose(theta, torch.tensor([0.0, 0.0, 0.007], dtype=torch.float64), atol=1e-9), theta


def test_propagated_covariance_is_calibrated_on_white_noise():
    model = ImuErrorModel(3e-3, 3e-2, 0.0, 0.0, 0.0, 0.0)  # white noise only, loud enough to dominate
    sim = simulate_with_truth("drone", duration_s=400.0, error_model=model, seed=1)
    gyro_density, acc_density = model.noise_densities()
    pre, start, end, g = windows(sim, sim.sequence.gyro, sim.sequence.acc, gyro_density, acc_density)
    nees = normalised_squared_errors(delta_errors(pre, start, end, g), pre.cov)
    assert torch.all((nees > 0.8) & (nees < 1.25)), nees  # 1 when the covariance is right


def test_likelihood_is_minimal_at_the_true_variance():
    errors = torch.full((1000, 9), 0.3, dtype=torch.float64)
    values = [covariance_nll(errors, torch.eye(9, dtype=torch.float64) * s2).item() for s2 in (0.05, 0.09, 0.2)]
    assert values[1] < values[0] and values[1] < values[2]


def test_state_loss_weights_and_total():
    errors = torch.zeros(4, 9)
    errors[:, 0:3] = 1.0  # rotation error only, well past the Huber transition
    weights = LossWeights(rotation=2.0, position=5.0, velocity=7.0, covariance=0.0)
    assert state_loss(errors, weights).item() == pytest.approx(2.0 * (1.0 - 0.5 * weights.huber_delta))
    assert state_loss(torch.zeros(4, 9), weights).item() == 0.0
    cov = torch.eye(9).expand(4, 9, 9)
    variance = torch.diagonal(cov, dim1=-2, dim2=-1)
    assert total_loss(errors, variance, weights).item() == pytest.approx(state_loss(errors, weights).item())
    with_cov = LossWeights(covariance=1e-3)
    assert total_loss(errors, variance, with_cov).item() == pytest.approx(
        state_loss(errors, with_cov).item() + 1e-3 * covariance_nll(errors, cov).item(), rel=1e-6
    )


def test_the_official_loss_weights_each_blocks_likelihood_by_its_block_weight():
    """``covariance_by_block``: sum_b w_b (huber_b + epsilon nll_b), the official ``get_loss``."""
    g = torch.Generator().manual_seed(0)
    errors = 0.01 * torch.randn(5, 4, 9, generator=g, dtype=torch.float64)
    variance = 1e-4 * (1 + torch.rand(5, 4, 9, generator=g, dtype=torch.float64))
    weights = LossWeights(rotation=5.0, position=0.5, velocity=0.05, covariance=0.04, covariance_by_block=True)
    nll = 0.5 * (errors.square() / (variance + VARIANCE_FLOOR) + torch.log(variance + VARIANCE_FLOOR))
    blocks = nll.unflatten(-1, (3, 3)).mean(dim=(0, 1, 3))
    expected = state_loss(errors, weights) + 0.04 * (5.0 * blocks[0] + 0.5 * blocks[1] + 0.05 * blocks[2])
    assert total_loss(errors, variance, weights).item() == pytest.approx(expected.item(), rel=1e-12)
    mask = torch.tensor([True, False, True, True, False])  # a masked mean is the mean of the windows kept
    assert total_loss(errors, variance, weights, mask).item() == pytest.approx(
        total_loss(errors[mask], variance[mask], weights).item(), rel=1e-12
    )


def test_covariance_loss_trains_the_uncertainty_not_the_corrections_by_default():
    """As the official code (``covaug: False``): the NLL's gradient reaches the covariance, not the errors."""
    errors = torch.randn(4, 9, dtype=torch.float64, requires_grad=True)
    variance = (torch.rand(4, 9, dtype=torch.float64) * 1e-4 + 1e-6).requires_grad_(True)
    for through in (False, True):
        weights = LossWeights(covariance_trains_corrections=through)
        grad_e, grad_c = torch.autograd.grad(total_loss(errors, variance, weights), (errors, variance))
        (grad_state,) = torch.autograd.grad(state_loss(errors, weights), errors)
        assert grad_c.abs().max() > 0
        assert torch.allclose(grad_e, grad_state) != through
