"""Sample-by-sample preintegration: the "iterative" integrator of the AirIMU paper.

It evaluates the same discrete model as ``learned_imu.preintegrate`` with a Python loop over samples and the
textbook 9x9 recursion ``Sigma <- A Sigma A^T + B_g (Q_g / dt) B_g^T + B_a (Q_a / dt) B_a^T`` in the body-frame
error state (as GTSAM's ``NavState::update`` linearises it), mapped to the tangent chart at every step. It is
O(N) deep: use it as a reference in tests and a baseline in benchmarks, not in training.
"""

from __future__ import annotations

import torch

from learned_imu import so3
from learned_imu.preintegration import Preintegrated, _check_density, _check_samples


def preintegrate_loop(gyro, acc, dt, gyro_cov=None, acc_cov=None) -> Preintegrated:
    """Same arguments, conventions and result as ``learned_imu.preintegrate``, one sample at a time."""
    gyro, acc, dt = _check_samples(gyro, acc, dt)
    with_cov = gyro_cov is not None and acc_cov is not None
    if with_cov:
        gyro_cov = _check_density("gyro_cov", gyro_cov, gyro).expand(gyro.shape)
        acc_cov = _check_density("acc_cov", acc_cov, acc).expand(acc.shape)
    batch, n = gyro.shape[:-2], gyro.shape[-2]
    opts = {"dtype": gyro.dtype, "device": gyro.device}
    r = torch.eye(3, **opts).expand(*batch, 3, 3)
    v, p = torch.zeros(*batch, 3, **opts), torch.zeros(*batch, 3, **opts)
    sigma = torch.zeros(*batch, 9, 9, **opts)  # body-frame error [dtheta, dv, dp] of NavState::retract
    rots, vels, poss, covs = [], [], [], []
    for k in range(n):
        w, a, h = gyro[..., k, :], acc[..., k, :], dt[..., k, None]
        step = so3.exp(w * h)
        if with_cov:
            sigma = _propagate_one(sigma, w, a, h, step, gyro_cov[..., k, :], acc_cov[..., k, :])
        force = (r @ a[..., None])[..., 0]
        p = p + v * h + 0.5 * force * h * h
        v = v + force * h
        r = r @ step
        rots.append(r)
        vels.append(v)
        poss.append(p)
        if with_cov:
            covs.append(_to_tangent_chart(sigma, r))
    cov = torch.stack(covs, dim=-3) if with_cov else None
    return Preintegrated(
        rot=torch.stack(rots, dim=-3),
        vel=torch.stack(vels, dim=-2),
        pos=torch.stack(poss, dim=-2),
        dt=torch.cumsum(dt, dim=-1),
        cov=cov,
    )


def _propagate_one(sigma, w, a, h, step, gyro_cov, acc_cov):
    """One step of the body-frame error recursion for [dtheta, dv, dp] (each in the current IMU frame)."""
    batch = sigma.shape[:-2]
    opts = {"dtype": sigma.dtype, "device": sigma.device}
    zero = torch.zeros(*batch, 3, 3, **opts)
    hh = h[..., None]
    step_t = step.mT
    ahat = so3.hat(a)
    # dtheta' = step^T dtheta; dv' = step^T (dv - [a]x dt dtheta); dp' = step^T (dp + dv dt - [a]x dt^2/2 dtheta)
    big_a = torch.cat(
        [
            torch.cat([step_t, zero, zero], dim=-1),
            torch.cat([-step_t @ ahat * hh, step_t, zero], dim=-1),
            torch.cat([-0.5 * step_t @ ahat * hh * hh, step_t * hh, step_t], dim=-1),
        ],
        dim=-2,
    )
    b_g = torch.cat([so3.right_jacobian(w * h) * hh, zero, zero], dim=-2)
    b_a = torch.cat([zero, step_t * hh, 0.5 * step_t * hh * hh], dim=-2)
    q_g = torch.diag_embed(gyro_cov / h)
    q_a = torch.diag_embed(acc_cov / h)
    return big_a @ sigma @ big_a.mT + b_g @ q_g @ b_g.mT + b_a @ q_a @ b_a.mT


def _to_tangent_chart(sigma, rot):
    """Body-frame [dtheta, dv, dp] covariance -> GTSAM tangent chart [theta, p, v] (start frame)."""
    batch = sigma.shape[:-2]
    zero = torch.zeros(*batch, 3, 3, dtype=sigma.dtype, device=sigma.device)
    to_theta = so3.right_jacobian_inv(so3.log(rot))
    t = torch.cat(
        [
            torch.cat([to_theta, zero, zero], dim=-1),
            torch.cat([zero, zero, rot], dim=-1),
            torch.cat([zero, rot, zero], dim=-1),
        ],
        dim=-2,
    )
    return t @ sigma @ t.mT
