"""AirIMU's training losses, with errors taken in the chart of the propagated covariance.

Ground truth states at the start of a window (i) and at each supervised sample (j) become ground-truth deltas
(Forster's, gravity removed): ``dR = R_i^T R_j``, ``dv = R_i^T (v_j - v_i - g t)``,
``dp = R_i^T (p_j - p_i - v_i t - g t^2 / 2)``. The error vector is [theta, p, v] in GTSAM's tangent order:
``Jr^-1(Log dR) Log(dR^T dR_gt)`` (to first order ``Log(dR_gt) - Log(dR)``, the tangent coordinates of the rotation,
rad, but without that difference's 2 pi jump when one of the two angles crosses pi), ``dp_gt - dp`` (m),
``dv_gt - dv`` (m/s), all in the frame at i -- the coordinates of ``Preintegrated.cov``, so the likelihood below is
consistent.

- state loss: Huber (smooth L1) on each error block, weighted per block;
- covariance loss: Gaussian negative log-likelihood of the errors under the diagonal of the covariance,
  ``0.5 * (e^2 / sigma^2 + log sigma^2)``, weighted by epsilon (the paper uses 1e-3); it trains the uncertainty
  (the errors are detached, as in the official code, unless ``covariance_trains_corrections``);
- normalised squared errors ``e^2 / sigma^2`` per block, for calibration reports (about 1 when calibrated).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch.nn import functional

from learned_imu.geometry import so3
from learned_imu.geometry.preintegration import NavState, Preintegrated

VARIANCE_FLOOR = 1e-12  # added to predicted variances in the likelihood (units of each block squared)


@dataclass(frozen=True)
class LossWeights:
    """Per-term weights: state-loss blocks and the covariance loss (epsilon)."""

    rotation: float = 1.0
    position: float = 1.0
    velocity: float = 1.0
    covariance: float = 1e-3
    huber_delta: float = 0.005  # transition of the smooth L1 loss, in the unit of each block
    covariance_trains_corrections: bool = False
    """Let the likelihood's gradient reach the errors (hence the corrections). Off by default, as in the official
    AirIMU code's ``covaug: False`` (its EuRoC config sets it true): through the errors the NLL weights each
    window's correction gradient by 1/sigma^2, and with epsilon = 1e-3 that term outweighs the Huber loss ~10x on
    EuRoC, so the corrections end up trained by whatever the noise decoders currently believe."""
    covariance_by_block: bool = False
    """Weight each block's likelihood by that block's weight too, ``sum_b w_b (huber_b + epsilon nll_b)``, as the
    official AirIMU code does (its ``get_loss``); off: ``sum_b w_b huber_b + epsilon nll`` with the likelihood
    averaged over all nine components."""


def delta_errors(pre: Preintegrated, start: NavState, end: NavState, gravity) -> torch.Tensor:
    """(..., K, 9) errors [theta, p, v] of the deltas ``pre`` (K samples) against ground truth.

    ``start``: ground-truth state at the window start, shapes (..., 3, 3) / (..., 3); ``end``: ground-truth
    states after the K reported samples, (..., K, 3, 3) / (..., K, 3); ``gravity`` (3,) world frame.
    """
    return errors_against(pre, truth_deltas(start, end, pre.dt, gravity))


def truth_deltas(start: NavState, end: NavState, elapsed: torch.Tensor, gravity) -> Preintegrated:
    """Ground-truth deltas (module docstring) from the state at a window's start (..., 3, 3) / (..., 3) to the
    states ``end`` (..., K, 3, 3) / (..., K, 3) reached after ``elapsed`` (..., K) seconds; ``gravity`` (3,) world."""
    g = torch.as_tensor(gravity, dtype=end.pos.dtype, device=end.pos.device)
    t = elapsed[..., None]
    r_i_t = start.rot.mT[..., None, :, :]
    vel = (r_i_t @ (end.vel - start.vel[..., None, :] - g * t)[..., None])[..., 0]
    pos = r_i_t @ (end.pos - start.pos[..., None, :] - start.vel[..., None, :] * t - 0.5 * g * t * t)[..., None]
    return Preintegrated(rot=r_i_t @ end.rot, vel=vel, pos=pos[..., 0], dt=elapsed)


def errors_against(pre: Preintegrated, truth: Preintegrated) -> torch.Tensor:
    """(..., K, 9) errors [theta, p, v] of the deltas ``pre`` against ground-truth deltas ``truth`` (same shapes)."""
    # Rotation error in the chart of the covariance (GTSAM's tangent preintegration, theta = Log(dR)): to first
    # order theta_gt - theta_pred = Jr^-1(theta_pred) Log(dR_pred^T dR_gt). Written this way, not as the difference
    # of the two Logs, so that it does not jump by 2 pi when one of the two angles crosses pi and the other not.
    jr_inv = so3.log_and_right_jacobian_inv(pre.rot)[1]
    theta = (jr_inv @ so3.log(pre.rot.mT @ truth.rot)[..., None])[..., 0]
    return torch.cat([theta, truth.pos - pre.pos, truth.vel - pre.vel], dim=-1)


def state_loss(errors: torch.Tensor, weights: LossWeights, mask: torch.Tensor | None = None) -> torch.Tensor:
    """Weighted Huber loss of the [theta, p, v] errors (..., 9), averaged over everything but the block (over the
    windows where ``mask``, a bool over the leading dimensions, is True)."""
    zero = torch.zeros_like(errors)
    huber = functional.smooth_l1_loss(errors, zero, reduction="none", beta=weights.huber_delta)
    blocks = _mean(huber.unflatten(-1, (3, 3)).mean(dim=-1), mask)  # (3,)
    return weights.rotation * blocks[0] + weights.position * blocks[1] + weights.velocity * blocks[2]


def covariance_nll(
    errors: torch.Tensor, cov: torch.Tensor, mask: torch.Tensor | None = None, block_weights=None
) -> torch.Tensor:
    """Mean Gaussian negative log-likelihood of errors (..., 9) under the diagonal of ``cov`` (..., 9, 9)
    (``variance_nll``)."""
    return variance_nll(errors, torch.diagonal(cov, dim1=-2, dim2=-1), mask, block_weights)


def variance_nll(
    errors: torch.Tensor, variance: torch.Tensor, mask: torch.Tensor | None = None, block_weights=None
) -> torch.Tensor:
    """Mean Gaussian negative log-likelihood of errors (..., 9) under per-component variances (..., 9), over the
    windows where ``mask`` is True; with ``block_weights`` (rotation, position, velocity), the weighted sum of the
    three blocks' means instead."""
    variance = variance + VARIANCE_FLOOR
    per_component = _mean(0.5 * (errors.square() / variance + variance.log()), mask)  # (9,)
    if block_weights is None:
        return per_component.mean()
    blocks = per_component.unflatten(-1, (3, 3)).mean(dim=-1)
    return sum(w * b for w, b in zip(block_weights, blocks, strict=True))


def total_loss(
    errors: torch.Tensor, variance: torch.Tensor | None, weights: LossWeights, mask: torch.Tensor | None = None
) -> torch.Tensor:
    """State loss plus, when the errors' variances (..., 9) are given (the diagonal of their covariance), epsilon
    times their negative log-likelihood; ``mask`` as in ``state_loss``."""
    loss = state_loss(errors, weights, mask)
    if variance is not None and weights.covariance > 0:
        seen = errors if weights.covariance_trains_corrections else errors.detach()
        by_block = (weights.rotation, weights.position, weights.velocity) if weights.covariance_by_block else None
        loss = loss + weights.covariance * variance_nll(seen, variance, mask, by_block)
    return loss


def _mean(x: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
    """Mean over all but the last axis of x (..., C); with a bool ``mask`` over x's leading axes, over the entries
    it marks only (the others may hold anything finite)."""
    if mask is None:
        return x.flatten(0, -2).mean(dim=0)
    weight = mask.to(x.dtype).reshape(mask.shape + (1,) * (x.ndim - mask.ndim))
    count = weight.sum() * (x[..., 0].numel() / mask.numel())
    return (x * weight).flatten(0, -2).sum(dim=0) / count


def normalised_squared_errors(errors: torch.Tensor, cov: torch.Tensor) -> torch.Tensor:
    """(3,) mean of e^2 / sigma^2 over the rotation, position and velocity blocks (1 when calibrated)."""
    return normalised_squared_errors_of_variance(errors, torch.diagonal(cov, dim1=-2, dim2=-1))


def normalised_squared_errors_of_variance(errors: torch.Tensor, variance: torch.Tensor) -> torch.Tensor:
    """``normalised_squared_errors`` under per-component variances (..., 9) instead of a covariance."""
    ratio = (errors.square() / (variance + VARIANCE_FLOOR)).unflatten(-1, (3, 3))
    return ratio.mean(dim=tuple(range(ratio.ndim - 2)) + (-1,))
