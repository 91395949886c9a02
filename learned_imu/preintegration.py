"""Differentiable IMU preintegration with covariance propagation, in O(log N) depth.

The model is Forster et al.'s discrete preintegration, exactly as GTSAM integrates one sample
(``NavState::update``, used by ``PreintegratedImuMeasurementsManifold``)::

    dR_{k+1} = dR_k Exp(w_k dt_k)
    dv_{k+1} = dv_k + dR_k a_k dt_k
    dp_{k+1} = dp_k + dv_k dt_k + 1/2 dR_k a_k dt_k^2

Rotations are composed by a parallel prefix product (Hillis-Steele, log2 N rounds); velocity and position are
cumulative sums. For the covariance, the rotation error is expressed in the start frame, ``phi_k = dR_k dtheta_k``:
there it is a random walk, and the velocity and position errors are linear in it, so the recursion
``Sigma_{k+1} = A_k Sigma_k A_k^T + B_k Q_k B_k^T`` unrolls into six cascaded ``cumsum``s of 3x3 products
(O(N) work, no loop over samples). The result is finally mapped to GTSAM's default (tangent) preintegration
chart: rotation error ``J_r^{-1}(theta_k) dR_k^T phi_k`` in the tangent of ``theta_k = Log(dR_k)``, velocity and
position errors in the start frame; order [rotation, position, velocity] as in ``preintMeasCov()``.

Noise convention: ``gyro_cov`` and ``acc_cov`` are continuous-time noise densities (rad^2/s, m^2/s^3), exactly what
``gtsam.PreintegrationParams.setGyroscopeCovariance`` / ``setAccelerometerCovariance`` take; one sample's
discrete covariance is density / dt.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from learned_imu import so3
from learned_imu.errors import InputError


@dataclass(frozen=True, eq=False)
class Preintegrated:
    """Preintegrated IMU deltas from sample 0 to after each sample k (Forster's gravity-free deltas).

    Shapes: ``rot (..., N, 3, 3)``, ``vel (..., N, 3)``, ``pos (..., N, 3)``, ``dt (..., N)`` (elapsed time, s),
    ``cov (..., N, 9, 9)`` or None. ``rot`` rotates vectors from the IMU frame at sample k+1 into the frame at 0;
    ``vel`` and ``pos`` are expressed in the frame at sample 0. ``cov`` is in GTSAM's tangent order
    [rotation, position, velocity] (rad, m, m/s).
    """

    rot: torch.Tensor
    vel: torch.Tensor
    pos: torch.Tensor
    dt: torch.Tensor
    cov: torch.Tensor | None = None


@dataclass(frozen=True, eq=False)
class NavState:
    """Navigation state in the world frame: ``rot`` world <- IMU (..., 3, 3), ``vel`` and ``pos`` (..., 3)."""

    rot: torch.Tensor
    vel: torch.Tensor
    pos: torch.Tensor


def preintegrate(gyro, acc, dt, gyro_cov=None, acc_cov=None) -> Preintegrated:
    """Preintegrate IMU samples, optionally propagating their noise into a 9x9 covariance per sample.

    Args:
        gyro: (..., N, 3) angular rate, rad/s, IMU frame.
        acc: (..., N, 3) specific force, m/s^2, IMU frame.
        dt: time step of each sample, s: a float or (..., N).
        gyro_cov: gyroscope noise density (rad^2/s): a float, a (3,) diagonal or per sample (..., N, 3).
        acc_cov: accelerometer noise density (m^2/s^3): a float, a (3,) diagonal or per sample (..., N, 3).

    Returns:
        ``Preintegrated`` after every sample; ``cov`` only if both densities are given.
    """
    gyro, acc, dt = _check_samples(gyro, acc, dt)
    step = so3.exp(gyro * dt[..., None])
    rot = _cumulative_product(step)  # dR after each sample
    rot_before = torch.cat([_eye_like(rot[..., :1, :, :]), rot[..., :-1, :, :]], dim=-3)
    force = (rot_before @ acc[..., None])[..., 0]  # dR_k a_k, start frame
    vel = torch.cumsum(force * dt[..., None], dim=-2)
    vel_before = vel - force * dt[..., None]
    pos = torch.cumsum(vel_before * dt[..., None] + 0.5 * force * (dt * dt)[..., None], dim=-2)
    elapsed = torch.cumsum(dt, dim=-1)

    if gyro_cov is None and acc_cov is None:
        return Preintegrated(rot=rot, vel=vel, pos=pos, dt=elapsed)
    if gyro_cov is None or acc_cov is None:
        raise InputError("preintegrate: give both gyro_cov and acc_cov, or neither")
    gyro_cov = _check_density("gyro_cov", gyro_cov, gyro)
    acc_cov = _check_density("acc_cov", acc_cov, acc)
    cov = _propagate_covariance(gyro, dt, rot, rot_before, force, gyro_cov, acc_cov)
    return Preintegrated(rot=rot, vel=vel, pos=pos, dt=elapsed, cov=cov)


def predict(initial: NavState, pre: Preintegrated, gravity) -> NavState:
    """World-frame states after each sample from a start state and deltas (AirIMU eq. 3, GTSAM ``predict``).

    ``R_j = R_i dR``, ``v_j = v_i + g t + R_i dv``, ``p_j = p_i + v_i t + g t^2 / 2 + R_i dp`` with ``t`` the
    elapsed time. ``initial`` has shapes (..., 3, 3) and (..., 3); ``gravity`` is the world-frame vector (3,)
    (e.g. ``[0, 0, -9.81]``). Returns states shaped like ``pre`` (..., N, ...).
    """
    r_i = initial.rot[..., None, :, :]
    v_i = initial.vel[..., None, :]
    p_i = initial.pos[..., None, :]
    g = torch.as_tensor(gravity, dtype=pre.vel.dtype, device=pre.vel.device)
    t = pre.dt[..., None]
    rot = r_i @ pre.rot
    vel = v_i + g * t + (r_i @ pre.vel[..., None])[..., 0]
    pos = p_i + v_i * t + 0.5 * g * t * t + (r_i @ pre.pos[..., None])[..., 0]
    return NavState(rot=rot, vel=vel, pos=pos)


def _cumulative_product(mats: torch.Tensor) -> torch.Tensor:
    """Inclusive prefix product ``M_0 M_1 ... M_k`` along dim -3, by Hillis-Steele doubling (log2 N rounds)."""
    n = mats.shape[-3]
    shift = 1
    while shift < n:
        mats = torch.cat([mats[..., :shift, :, :], mats[..., :-shift, :, :] @ mats[..., shift:, :, :]], dim=-3)
        shift *= 2
    return mats


def _propagate_covariance(gyro, dt, rot, rot_before, force, gyro_cov, acc_cov) -> torch.Tensor:
    """Covariance after each sample, GTSAM tangent chart, [rotation, position, velocity]; see module docstring."""
    tt = dt[..., None, None]
    # Per-sample noise injected into the start-frame error state [phi, v, p].
    lever = rot @ so3.right_jacobian(gyro * dt[..., None])  # d phi_{k+1} / d(gyro noise) / dt
    g_phi = (lever * (gyro_cov * dt[..., None])[..., None, :]) @ lever.mT  # Cov of phi increment
    q_acc = (rot_before * (acc_cov * dt[..., None])[..., None, :]) @ rot_before.mT  # Cov of v increment
    m = -so3.hat(force) * tt  # d v_{k+1} / d phi_k

    # Each line: Sigma block before sample k (exclusive cumsum), from blocks already known before k.
    p_inc, p_ex = _cumsums(g_phi)  # Sigma_phi,phi
    mp = m @ p_ex
    x_inc, x_ex = _cumsums(mp)  # Sigma_v,phi
    xm = x_ex @ m.mT
    mpm = mp @ m.mT
    v_inc, v_ex = _cumsums(xm + xm.mT + mpm + q_acc)  # Sigma_v,v
    y_inc, y_ex = _cumsums(tt * x_ex + 0.5 * tt * mp)  # Sigma_p,phi
    half_xm = 0.5 * (xm + xm.mT)
    z_inc, z_ex = _cumsums(y_ex @ m.mT + tt * (v_ex + xm + 0.5 * xm.mT + 0.5 * mpm + 0.5 * q_acc))  # Sigma_p,v
    ym = y_ex @ m.mT
    w_term = tt * (z_ex + z_ex.mT) + 0.5 * tt * (ym + ym.mT) + tt * tt * (v_ex + half_xm + 0.25 * mpm + 0.25 * q_acc)
    w_inc, _ = _cumsums(w_term)  # Sigma_p,p

    # Map the rotation error from the start frame to GTSAM's tangent chart at theta_k = Log(dR_k).
    to_tangent = so3.right_jacobian_inv(so3.log(rot)) @ rot.mT
    rr = to_tangent @ p_inc @ to_tangent.mT
    rp = to_tangent @ y_inc.mT
    rv = to_tangent @ x_inc.mT
    top = torch.cat([rr, rp, rv], dim=-1)
    mid = torch.cat([rp.mT, w_inc, z_inc], dim=-1)
    bottom = torch.cat([rv.mT, z_inc.mT, v_inc], dim=-1)
    return torch.cat([top, mid, bottom], dim=-2)


def _cumsums(terms: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Inclusive and exclusive cumulative sums over samples (dim -3) of per-sample 3x3 terms."""
    inclusive = torch.cumsum(terms, dim=-3)
    return inclusive, inclusive - terms


def _eye_like(ref: torch.Tensor) -> torch.Tensor:
    return torch.eye(3, dtype=ref.dtype, device=ref.device).expand(ref.shape)


def _check_samples(gyro, acc, dt):
    if not isinstance(gyro, torch.Tensor) or not isinstance(acc, torch.Tensor):
        raise InputError("preintegrate: gyro and acc must be torch tensors of shape (..., N, 3)")
    if gyro.ndim < 2 or gyro.shape[-1] != 3 or acc.shape != gyro.shape:
        raise InputError(
            f"preintegrate: gyro and acc must both have shape (..., N, 3); got {tuple(gyro.shape)} "
            f"and {tuple(acc.shape)}"
        )
    if not gyro.is_floating_point() or acc.dtype != gyro.dtype:
        raise InputError(f"preintegrate: gyro and acc must share a floating dtype; got {gyro.dtype}, {acc.dtype}")
    if gyro.shape[-2] == 0:
        raise InputError("preintegrate: at least one sample is needed (N = 0)")
    dt = torch.as_tensor(dt, dtype=gyro.dtype, device=gyro.device)
    if dt.ndim == 0:
        dt = dt.expand(gyro.shape[:-1])
    elif dt.shape != gyro.shape[:-1]:
        raise InputError(f"preintegrate: dt must be a float or shaped {tuple(gyro.shape[:-1])}; got {tuple(dt.shape)}")
    for name, value in (("gyro", gyro), ("acc", acc), ("dt", dt)):
        if not torch.isfinite(value).all():
            raise InputError(f"preintegrate: {name} contains NaN or Inf")
    if (dt <= 0).any():
        raise InputError("preintegrate: dt must be positive for every sample")
    return gyro, acc, dt


def _check_density(name: str, value, samples: torch.Tensor) -> torch.Tensor:
    value = torch.as_tensor(value, dtype=samples.dtype, device=samples.device)
    if value.ndim == 0:
        value = value.expand(3)
    if value.shape != (3,):
        try:
            value = value.expand(samples.shape)
        except RuntimeError:
            raise InputError(
                f"preintegrate: {name} must be a float, (3,) or (..., N, 3) like the samples "
                f"{tuple(samples.shape)}; got {tuple(value.shape)}"
            ) from None
    if not torch.isfinite(value).all():
        raise InputError(f"preintegrate: {name} contains NaN or Inf")
    if (value < 0).any():
        raise InputError(f"preintegrate: {name} must be non-negative (a noise density, rad^2/s or m^2/s^3)")
    return value
