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
    AirIMU code (its ``covaug: False`` detaches the errors): through the errors the NLL weights each window's
    correction gradient by 1/sigma^2, and with epsilon = 1e-3 that term outweighs the Huber loss ~10x on EuRoC,
    so the corrections end up trained by whatever the noise decoders currently believe."""


def delta_errors(pre: Preintegrated, start: NavState, end: NavState, gravity) -> torch.Tensor:
    """(..., K, 9) errors [theta, p, v] of the deltas ``pre`` (K samples) against ground truth.

    ``start``: ground-truth state at the window start, shapes (..., 3, 3) / (..., 3); ``end``: ground-truth
    states after the K reported samples, (..., K, 3, 3) / (..., K, 3); ``gravity`` (3,) world frame.
    """
    g = torch.as_tensor(gravity, dtype=pre.pos.dtype, device=pre.pos.device)
    t = pre.dt[..., None]
    r_i_t = start.rot.mT[..., None, :, :]
    rot_gt = r_i_t @ end.rot
    vel_gt = (r_i_t @ (end.vel - start.vel[..., None, :] - g * t)[..., None])[..., 0]
    pos_gt = (r_i_t @ (end.pos - start.pos[..., None, :] - start.vel[..., None, :] * t - 0.5 * g * t * t)[..., None])[
        ..., 0
    ]
    # Rotation error in the chart of the covariance (GTSAM's tangent preintegration, theta = Log(dR)): to first
    # order theta_gt - theta_pred = Jr^-1(theta_pred) Log(dR_pred^T dR_gt). Written this way, not as the difference
    # of the two Logs, so that it does not jump by 2 pi when one of the two angles crosses pi and the other not.
    jr_inv = so3.log_and_right_jacobian_inv(pre.rot)[1]
    theta = (jr_inv @ so3.log(pre.rot.mT @ rot_gt)[..., None])[..., 0]
    return torch.cat([theta, pos_gt - pre.pos, vel_gt - pre.vel], dim=-1)


def state_loss(errors: torch.Tensor, weights: LossWeights) -> torch.Tensor:
    """Weighted Huber loss of the [theta, p, v] errors (..., 9), averaged over everything but the block."""
    zero = torch.zeros_like(errors)
    huber = functional.smooth_l1_loss(errors, zero, reduction="none", beta=weights.huber_delta)
    blocks = huber.unflatten(-1, (3, 3)).mean(dim=tuple(range(huber.ndim - 1)) + (-1,))  # (3,)
    return weights.rotation * blocks[0] + weights.position * blocks[1] + weights.velocity * blocks[2]


def covariance_nll(errors: torch.Tensor, cov: torch.Tensor) -> torch.Tensor:
    """Mean Gaussian negative log-likelihood of errors (..., 9) under the diagonal of ``cov`` (..., 9, 9)."""
    variance = torch.diagonal(cov, dim1=-2, dim2=-1) + VARIANCE_FLOOR
    return 0.5 * (errors.square() / variance + variance.log()).mean()


def total_loss(errors: torch.Tensor, cov: torch.Tensor | None, weights: LossWeights) -> torch.Tensor:
    """State loss plus, when a covariance is given, epsilon times its negative log-likelihood."""
    loss = state_loss(errors, weights)
    if cov is not None and weights.covariance > 0:
        seen = errors if weights.covariance_trains_corrections else errors.detach()
        loss = loss + weights.covariance * covariance_nll(seen, cov)
    return loss


def normalised_squared_errors(errors: torch.Tensor, cov: torch.Tensor) -> torch.Tensor:
    """(3,) mean of e^2 / sigma^2 over the rotation, position and velocity blocks (1 when calibrated)."""
    return normalised_squared_errors_of_variance(errors, torch.diagonal(cov, dim1=-2, dim2=-1))


def normalised_squared_errors_of_variance(errors: torch.Tensor, variance: torch.Tensor) -> torch.Tensor:
    """``normalised_squared_errors`` under per-component variances (..., 9) instead of a covariance."""
    ratio = (errors.square() / (variance + VARIANCE_FLOOR)).unflatten(-1, (3, 3))
    return ratio.mean(dim=tuple(range(ratio.ndim - 2)) + (-1,))
