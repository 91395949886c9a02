"""Two other routes to ``learned_imu.preintegrate``'s result, kept as references for tests and benchmarks.

- ``preintegrate_loop``: the "iterative" integrator of the AirIMU paper. A Python loop over samples with the
  textbook 9x9 recursion ``Sigma <- A Sigma A^T + B_g (Q_g / dt) B_g^T + B_a (Q_a / dt) B_a^T`` in the body-frame
  error state (as GTSAM's ``NavState::update`` linearises it), mapped to the tangent chart at every step. O(N) deep.
- ``preintegrate_pair_scan``: the covariance by an associative scan over the pairs (A_k, Q_k) of the start-frame
  recursion, ``(A2, Q2) o (A1, Q1) = (A2 A1, A2 Q1 A2^T + Q2)``, Hillis-Steele style: O(log N) deep but
  O(N log N) 9x9 products. ``preintegrate`` instead unrolls the same recursion into cumulative sums (O(N) work).
"""

from __future__ import annotations

import torch

from learned_imu.geometry import so3
from learned_imu.geometry.preintegration import Preintegrated, _check_density, _check_samples, preintegrate


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


def preintegrate_pair_scan(gyro, acc, dt, gyro_cov, acc_cov) -> Preintegrated:
    """Same arguments and result as ``learned_imu.preintegrate`` (covariance required), by a scan over pairs."""
    pre = preintegrate(gyro, acc, dt)
    gyro, acc, dt = _check_samples(gyro, acc, dt)
    gyro_cov = _check_density("gyro_cov", gyro_cov, gyro).expand(gyro.shape)
    acc_cov = _check_density("acc_cov", acc_cov, acc).expand(acc.shape)
    rot = pre.rot
    eye = torch.eye(3, dtype=rot.dtype, device=rot.device).expand(*rot.shape[:-3], 1, 3, 3)
    rot_before = torch.cat([eye, rot[..., :-1, :, :]], dim=-3)
    h = dt[..., None, None]
    zero = torch.zeros_like(rot)
    eye_n = eye.expand(rot.shape)
    # Start-frame error state [phi, v, p]: phi' = phi + n_g; v' = v + M phi + n_v; p' = p + dt v + dt/2 M phi + n_p
    m = -so3.hat((rot_before @ acc[..., None])[..., 0]) * h
    big_a = torch.cat(
        [
            torch.cat([eye_n, zero, zero], dim=-1),
            torch.cat([m, eye_n, zero], dim=-1),
            torch.cat([0.5 * h * m, h * eye_n, eye_n], dim=-1),
        ],
        dim=-2,
    )
    lever = rot @ so3.right_jacobian(gyro * dt[..., None]) * h  # d phi' / d(gyro noise)
    b_g = torch.cat([lever, zero, zero], dim=-2)
    b_a = torch.cat([zero, rot_before * h, 0.5 * rot_before * h * h], dim=-2)
    q_g, q_a = (gyro_cov / dt[..., None])[..., None, :], (acc_cov / dt[..., None])[..., None, :]  # discrete
    q = (b_g * q_g) @ b_g.mT + (b_a * q_a) @ b_a.mT
    shift, n = 1, rot.shape[-3]
    while shift < n:  # inclusive scan: pair k <- pair k o pair (k - shift)
        a_prev, q_prev = big_a[..., :-shift, :, :], q[..., :-shift, :, :]
        a_cur, q_cur = big_a[..., shift:, :, :], q[..., shift:, :, :]
        big_a = torch.cat([big_a[..., :shift, :, :], a_cur @ a_prev], dim=-3)
        q = torch.cat([q[..., :shift, :, :], a_cur @ q_prev @ a_cur.mT + q_cur], dim=-3)
        shift *= 2
    # Start frame [phi, v, p] -> GTSAM tangent chart [theta, p, v].
    to_theta = so3.right_jacobian_inv(so3.log(rot)) @ rot.mT
    t = torch.cat(
        [
            torch.cat([to_theta, zero, zero], dim=-1),
            torch.cat([zero, zero, eye_n], dim=-1),
            torch.cat([zero, eye_n, zero], dim=-1),
        ],
        dim=-2,
    )
    return Preintegrated(rot=pre.rot, vel=pre.vel, pos=pre.pos, dt=pre.dt, cov=t @ q @ t.mT)
