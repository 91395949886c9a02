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

from airimu_core.errors import InputError
from learned_imu.geometry import so3

# Up to this many (batch x samples) products the rotation scan uses Hillis-Steele doubling (fewer launches).
_SMALL_SCAN = 4096


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
    bias_jacobian: torch.Tensor | None = None
    """(..., N, 9, 6) derivative of the deltas w.r.t. a bias b = [b_acc (m/s^2), b_gyro (rad/s)] (GTSAM's
    order) subtracted from the samples, rows [rotation, position, velocity]: to first order the deltas of
    ``(gyro - b_gyro, acc - b_acc)`` are ``rot Exp(J[:3] b)``, ``pos + J[3:6] b``, ``vel + J[6:] b`` (Forster
    et al.'s bias correction)."""
    variance: torch.Tensor | None = None
    """(..., N, 9) the diagonal of the covariance, where only that was asked for
    (``learned_imu.geometry.windowed.preintegrate_windows(..., diagonal=True)``; ``cov`` is then None)."""


@dataclass(frozen=True, eq=False, kw_only=True)
class NavState:
    """Navigation state in the world frame: ``rot`` world <- IMU (..., 3, 3), ``vel`` and ``pos`` (..., 3).

    Keyword-only (``NavState(rot=..., vel=..., pos=...)``): ``gtsam.NavState(R, p, v)`` orders position before
    velocity, so a state built positionally the GTSAM way fails instead of swapping them."""

    rot: torch.Tensor
    vel: torch.Tensor
    pos: torch.Tensor


def preintegrate(gyro, acc, dt, gyro_cov=None, acc_cov=None, at=None, bias_jacobian=False) -> Preintegrated:
    """Preintegrate IMU samples, optionally propagating their noise into a 9x9 covariance per sample.

    Args:
        gyro: (..., N, 3) angular rate, rad/s, IMU frame.
        acc: (..., N, 3) specific force, m/s^2, IMU frame.
        dt: time step of each sample, s: a float or (..., N).
        gyro_cov: gyroscope noise density (rad^2/s): a float, a (3,) diagonal or per sample (..., N, 3).
        acc_cov: accelerometer noise density (m^2/s^3): a float, a (3,) diagonal or per sample (..., N, 3).
        at: which samples to report, as an index, a slice or a 1-D sequence of indices into N (e.g.
            ``slice(49, None, 50)`` for every 50th, as AirIMU supervises); default every sample. Reporting
            fewer samples skips their covariance chart mapping, the costliest part after the scan.
        bias_jacobian: also return the deltas' bias Jacobians (``Preintegrated.bias_jacobian``).

    Returns:
        ``Preintegrated`` after each reported sample (K of them: shapes (..., K, ...)); ``cov`` only if both
        densities are given.
    """
    gyro, acc, dt = _check_samples(gyro, acc, dt)
    index = _check_index(at, gyro.shape[-2])
    if (gyro_cov is None) != (acc_cov is None):
        raise InputError("preintegrate: give both gyro_cov and acc_cov, or neither")
    with_cov = gyro_cov is not None
    if with_cov:
        gyro_cov = _samples_last(_check_density("gyro_cov", gyro_cov, gyro))
        acc_cov = _samples_last(_check_density("acc_cov", acc_cov, acc))
    h, step_jacobian, rot, rot_before, force, vel, pos = _integrate(gyro, acc, dt)
    cov = None
    if with_cov:
        cov = _propagate_covariance(step_jacobian, h, rot, rot_before, force, gyro_cov, acc_cov, index)
    jac = _bias_jacobian(step_jacobian, h, rot, rot_before, force, index) if bias_jacobian else None
    if index is not None:
        rot, vel, pos = rot[..., index], vel[..., index], pos[..., index]
    elapsed = torch.cumsum(dt, dim=-1)
    return Preintegrated(
        rot=_samples_first(rot, 2),
        vel=_samples_first(vel, 1),
        pos=_samples_first(pos, 1),
        dt=elapsed if index is None else elapsed[..., index],
        cov=None if cov is None else _samples_first(cov, 2),
        bias_jacobian=None if jac is None else _samples_first(jac, 2),
    )


def _integrate(gyro: torch.Tensor, acc: torch.Tensor, dt: torch.Tensor, rotation: torch.Tensor | None = None):
    """The scan itself, samples last (vectors (..., 3, N), matrices (..., 3, 3, N); see so3's docstring), on checked
    samples: ``h`` dt as (..., 1, N), each step's ``Jr(w dt)``, ``dR`` after and before each sample, the specific
    force in the start frame ``dR_k a_k``, and ``dv``, ``dp`` after each sample. ``rotation`` (samples last, the
    rotation at each sample): integrate velocity and position with it instead of ``dR_k``."""
    w, a, h = _samples_last(gyro), _samples_last(acc), dt[..., None, :]
    step, step_jacobian = so3.exp_and_right_jacobian(w * h, dim=-2)
    rot = _cumulative_rotation(step)  # dR after each sample
    rot_before = torch.cat([_eye_like(rot[..., :1]), rot[..., :-1]], dim=-1)
    force = so3.matvec(rot_before if rotation is None else rotation, a, dim=-2)  # dR_k a_k, start frame
    vel = torch.cumsum(force * h, dim=-1)
    vel_before = vel - force * h
    pos = torch.cumsum(vel_before * h + 0.5 * force * h * h, dim=-1)
    return h, step_jacobian, rot, rot_before, force, vel, pos


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


def _samples_last(x: torch.Tensor) -> torch.Tensor:
    """(..., N, 3) -> contiguous (..., 3, N); a (3,) diagonal -> (3, 1), which broadcasts."""
    return x[:, None] if x.ndim == 1 else x.mT.contiguous()


def _samples_first(x: torch.Tensor, item_ndim: int) -> torch.Tensor:
    """Samples-last (..., *item, N) -> contiguous (..., N, *item)."""
    if torch.is_grad_enabled() and x.requires_grad:
        return _SamplesFirst.apply(x, item_ndim)
    return x.movedim(-1, -1 - item_ndim).contiguous()


class _SamplesFirst(torch.autograd.Function):
    """Samples-last (..., *shape, N) -> contiguous (..., N, *shape), and gradients back to contiguous
    samples-last, so that the backward pass through the scan runs on contiguous rows (a strided gradient would
    slow every op after it)."""

    @staticmethod
    def forward(ctx, x, item_ndim):
        ctx.axis = -1 - item_ndim
        return x.movedim(-1, ctx.axis).contiguous()

    @staticmethod
    def backward(ctx, grad):
        return grad.movedim(ctx.axis, -1).contiguous(), None


def _cumulative_rotation(steps: torch.Tensor) -> torch.Tensor:
    """Inclusive prefix product ``S_0 S_1 ... S_k`` of rotation matrices (..., 3, 3, N), differentiable."""
    if torch.is_grad_enabled() and steps.requires_grad:
        return _CumulativeRotation.apply(steps)
    return _cumulative_product(steps)


class _CumulativeRotation(torch.autograd.Function):
    """The rotation scan with a closed-form backward instead of autograd through its O(log N) rounds.

    With ``R_k = S_0 ... S_k`` and orthogonal factors, ``S_{j+1} ... S_k = R_j^T R_k``, so the gradient of
    a loss with ``G_k = dL/dR_k`` is ``dL/dS_j = R_{j-1}^T (sum_{k>=j} G_k R_k^T) R_j``: three 3x3 products
    and one reverse cumulative sum, where autograd through the scan would replay every round backwards.
    Valid for rotations only (it uses ``R^-1 = R^T``).
    """

    @staticmethod
    def forward(ctx, steps):
        rot = _cumulative_product(steps)
        ctx.save_for_backward(rot)
        return rot

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad):
        (rot,) = ctx.saved_tensors
        terms = _mm(grad.contiguous(), rot, True)  # G_k R_k^T
        suffix = _after(terms) + terms  # sum over k >= j
        rot_before = torch.cat([_eye_like(rot[..., :1]), rot[..., :-1]], dim=-1)
        return _mm(_mm(_tr(rot_before), suffix), rot)


def _cumulative_product(mats: torch.Tensor) -> torch.Tensor:
    """Inclusive prefix product ``M_0 M_1 ... M_k`` of (..., 3, 3, N) along the last axis, in O(log N) rounds.

    Small problems use Hillis-Steele doubling (N log N products in log2 N rounds: fewest kernel launches);
    large ones a work-efficient odd-even scan (2N products in 2 log2 N rounds: least memory traffic).
    """
    if mats[..., 0, 0, :].numel() <= _SMALL_SCAN:
        n, shift = mats.shape[-1], 1
        while shift < n:
            head, tail = mats[..., :shift], so3.matmul(mats[..., :-shift], mats[..., shift:], dim=-2)
            mats = torch.cat([head, tail], dim=-1)
            shift *= 2
        return mats
    return _odd_even_scan(mats)


def _odd_even_scan(mats: torch.Tensor) -> torch.Tensor:
    """Multiply neighbours pairwise, scan the N/2 pair products recursively, then fill in even positions."""
    n = mats.shape[-1]
    if n == 1:
        return mats
    half = n // 2
    pairs = so3.matmul(mats[..., 0 : 2 * half : 2], mats[..., 1 : 2 * half : 2], dim=-2)
    odd = _odd_even_scan(pairs)  # products up to samples 1, 3, 5, ...
    even = so3.matmul(odd[..., : (n - 1) // 2], mats[..., 2::2], dim=-2)  # up to samples 2, 4, ...
    even = torch.cat([mats[..., :1], even], dim=-1)
    out = torch.stack([even[..., :half], odd], dim=-1).flatten(-2)
    return torch.cat([out, even[..., half:]], dim=-1) if n % 2 else out


def _propagate_covariance(step_jacobian, h, rot, rot_before, force, gyro_cov, acc_cov, index) -> torch.Tensor:
    """Covariance (..., 9, 9, K) in GTSAM's tangent chart after the samples ``index`` (all if None); see the
    module docstring. Samples-last layout throughout; ``h`` is dt shaped (..., 1, N)."""
    if index is not None and index.numel() == 1:  # only the samples up to it matter
        end = int(index) + 1
        first = (t[..., :end] for t in (rot, step_jacobian, rot_before, force, h, gyro_cov, acc_cov))
        rot, step_jacobian, rot_before, force, h, gyro_cov, acc_cov = first  # a (3, 1) diagonal stays as it is
        lever = _mm(rot, step_jacobian)
        return _final_covariance(rot[..., -1], lever, rot_before, force, h, gyro_cov * h, acc_cov * h)[..., None]
    hh = h[..., None, :, :]  # dt for matrices, (..., 1, 1, N)
    # Per-sample noise injected into the start-frame error state [phi, v, p].
    lever = _mm(rot, step_jacobian)  # d phi_{k+1} / d(gyro noise dt), Jr(w dt) of each step
    g_phi = _mm(lever * (gyro_cov * h)[..., None, :, :], lever, True)  # Cov of the phi increment
    q_acc = _mm(rot_before * (acc_cov * h)[..., None, :, :], rot_before, True)  # Cov of the v increment
    m = -so3.hat(force, dim=-2) * hh  # d v_{k+1} / d phi_k
    # Each line: a block of Sigma before sample k (exclusive cumsum), from blocks already known before k.
    p_inc, p_ex = _cumsums(g_phi)  # Sigma_phi,phi
    mp = _mm(m, p_ex)
    x_inc, x_ex = _cumsums(mp)  # Sigma_v,phi
    xm, mpm = _mm(x_ex, m, True), _mm(mp, m, True)
    xm_sym = xm + _tr(xm)
    v_inc, v_ex = _cumsums(xm_sym + mpm + q_acc)  # Sigma_v,v
    y_inc, y_ex = _cumsums(hh * (x_ex + 0.5 * mp))  # Sigma_p,phi
    ym = _mm(y_ex, m, True)
    z_inc, z_ex = _cumsums(ym + hh * (v_ex + xm + 0.5 * (_tr(xm) + mpm + q_acc)))  # Sigma_p,v
    w_term = hh * (z_ex + _tr(z_ex) + 0.5 * (ym + _tr(ym))) + hh * hh * (v_ex + 0.5 * xm_sym + 0.25 * (mpm + q_acc))
    w_inc = torch.cumsum(w_term, dim=-1)  # Sigma_p,p
    blocks = (p_inc, x_inc, v_inc, y_inc, z_inc, w_inc)
    if index is not None:
        rot, blocks = rot[..., index], tuple(t[..., index] for t in blocks)
    return _to_tangent_chart(rot, blocks)


def _final_covariance(rot_end, lever, rot_before, force, h, gyro_var, acc_var) -> torch.Tensor:
    """The covariance (..., 9, 9) after the last sample only, as one matrix product over all noise terms.

    The start-frame errors after the last sample are linear in the independent per-sample noises: the gyro noise
    of sample j enters the rotation error through ``L_j`` (``lever``), the velocity error through
    ``[uv_j]x L_j`` and the position error through ``[up_j]x L_j``, with ``uv_j = -sum_{i>j} f_i dt_i`` and
    ``up_j = -sum_{i>j} c_i f_i dt_i`` (``f``: specific force in the start frame, ``c_i`` the time after sample
    i plus dt_i / 2); the acc noise enters velocity through ``R_j`` (``rot_before``) and position through
    ``c_j R_j``. With these blocks of every sample side by side (gyro W_g: 9 x 3N, acc W_a: 6 x 3N), the
    covariance is ``W_g diag(var_g) W_g^T + W_a diag(var_a) W_a^T``: two GEMMs with an inner size of 3N instead
    of per-sample 3x3 products.
    ``gyro_var``, ``acc_var``: per-sample discrete variances of the integrated noise (density * dt).
    """
    c = _after(h) + 0.5 * h  # (..., 1, N), s
    impulse = force * h
    uv, up = -_after(impulse), -_after(c * impulse)
    gyro_rows = torch.cat([lever, _cross(up, lever), _cross(uv, lever)], dim=-3)  # (..., 9, 3, N)
    acc_rows = torch.cat([c[..., None, :, :] * rot_before, rot_before], dim=-3)  # (..., 6, 3, N), p and v
    cov = _gram(gyro_rows, gyro_var) + torch.nn.functional.pad(_gram(acc_rows, acc_var), (3, 0, 3, 0))
    # rotation rows and columns to GTSAM's tangent chart at theta = Log(dR)
    to_tangent = so3.log_and_right_jacobian_inv(rot_end)[1] @ rot_end.mT
    cov = torch.cat([to_tangent @ cov[..., :3, :], cov[..., 3:, :]], dim=-2)
    return torch.cat([cov[..., :3] @ to_tangent.mT, cov[..., 3:]], dim=-1)


def _cross(u: torch.Tensor, mats: torch.Tensor) -> torch.Tensor:
    """``[u]x M`` for samples-last vectors (..., 3, N) and matrices (..., 3, 3, N): u crossed with each column."""
    u0, u1, u2 = (x[..., None, :] for x in u.unbind(-2))  # (..., 1, N), broadcast over the columns
    m0, m1, m2 = mats.unbind(-3)  # rows, (..., 3, N)
    return torch.stack([u1 * m2 - u2 * m1, u2 * m0 - u0 * m2, u0 * m1 - u1 * m0], dim=-3)


def _gram(rows: torch.Tensor, var: torch.Tensor) -> torch.Tensor:
    """``sum_j W_j diag(var_j) W_j^T`` for samples-last W (..., R, 3, N) and var (..., 3, N): (..., R, R)."""
    return _Gram.apply(rows.flatten(-2), var.flatten(-2))


class _Gram(torch.autograd.Function):
    """``S = W diag(v) W^T`` for W (..., R, K), v (..., K), with a backward that keeps every GEMM in its fast
    layout: ``dW = (G + G^T) W diag(v)``, ``dv_k = 1/2 sum_i W_ik ((G + G^T) W)_ik``."""

    @staticmethod
    def forward(ctx, w, v):
        wv = w * v[..., None, :]
        ctx.save_for_backward(w, v, wv)
        return wv @ w.mT

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad):
        w, v, wv = ctx.saved_tensors
        sym = grad + grad.mT
        if not ctx.needs_input_grad[1]:  # constant noise: dW = (G + G^T) (W diag(v)), one GEMM
            return sym @ wv, None
        gw = sym @ w
        grad_w = gw * v[..., None, :] if ctx.needs_input_grad[0] else None
        return grad_w, 0.5 * (gw * w).sum(dim=-2)


def _after(terms: torch.Tensor) -> torch.Tensor:
    """Exclusive reverse cumulative sum over samples: sum of the terms after each sample."""
    inclusive = torch.cumsum(terms, dim=-1)
    return inclusive[..., -1:] - inclusive


def _to_tangent_chart(rot, blocks) -> torch.Tensor:
    """Start-frame blocks (phi,phi; v,phi; v,v; p,phi; p,v; p,p) -> (..., 9, 9, K) with the rotation error in
    GTSAM's tangent chart at theta_k = Log(dR_k), order [rotation, position, velocity]."""
    p_inc, x_inc, v_inc, y_inc, z_inc, w_inc = blocks
    to_tangent = _mm(so3.log_and_right_jacobian_inv(rot, dim=-2)[1], rot, True)
    rp, rv = _mm(to_tangent, y_inc, True), _mm(to_tangent, x_inc, True)
    rows = (
        (_mm(_mm(to_tangent, p_inc), to_tangent, True), rp, rv),
        (_tr(rp), w_inc, z_inc),
        (_tr(rv), _tr(z_inc), v_inc),
    )
    # cat, not slice assignment: the backward of a slice assignment copies the whole 9x9xN gradient per block
    return torch.cat([torch.cat(row, dim=-2) for row in rows], dim=-3)


def _mm(x, y, transpose_y=False):
    """Samples-last 3x3 products (..., 3, 3, N)."""
    return so3.matmul(x, y, dim=-2, transpose_b=transpose_y)


def _tr(x):
    return x.transpose(-3, -2)


def _bias_jacobian(step_jacobian, h, rot, rot_before, force, index) -> torch.Tensor:
    """(..., 9, 6, K) bias Jacobians after the samples ``index`` (all if None); see ``Preintegrated``.

    A gyro bias change db_g perturbs the start-frame rotation error by ``-C_k db_g`` with
    ``C_k = sum_{j<=k} dR_{j+1} Jr_j dt_j``; velocity and position follow by cumulative sums like the covariance.
    """
    hh = h[..., None, :, :]
    lever_dt = _mm(rot, step_jacobian) * hh
    c_inc, c_ex = _cumsums(lever_dt)
    m = -so3.hat(force, dim=-2) * hh  # -[dR_k a_k]x dt
    dv_acc = -rot_before * hh  # change of each velocity increment per acc bias
    dv_gyro = -_mm(m, c_ex)  # ... per gyro bias, through the rotation error before the sample
    va_inc, va_ex = _cumsums(dv_acc)
    vg_inc, vg_ex = _cumsums(dv_gyro)
    pa_inc = torch.cumsum(hh * (va_ex + 0.5 * dv_acc), dim=-1)
    pg_inc = torch.cumsum(hh * (vg_ex + 0.5 * dv_gyro), dim=-1)
    rg = -_mm(_tr(rot), c_inc)  # rotation error in the frame after the sample
    if index is not None:
        rg, pa_inc, pg_inc, va_inc, vg_inc = (t[..., index] for t in (rg, pa_inc, pg_inc, va_inc, vg_inc))
    rows = ((torch.zeros_like(rg), rg), (pa_inc, pg_inc), (va_inc, vg_inc))
    return torch.cat([torch.cat(row, dim=-2) for row in rows], dim=-3)


def _cumsums(terms: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Inclusive and exclusive cumulative sums over samples (last axis) of per-sample terms."""
    inclusive = torch.cumsum(terms, dim=-1)
    return inclusive, inclusive - terms


def _eye_like(ref: torch.Tensor) -> torch.Tensor:
    """Identity matrices shaped like ``ref`` (..., 3, 3, n)."""
    return torch.eye(3, dtype=ref.dtype, device=ref.device)[..., None].expand(ref.shape)


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


def _check_index(at, n: int) -> torch.Tensor | None:
    """``at`` -> a 1-D index tensor into N samples (None for all samples)."""
    if at is None:
        return None
    try:
        if not isinstance(at, int | slice | torch.Tensor):
            at = torch.as_tensor(at, dtype=torch.long)  # a sequence of indices; a string fails here
        index = torch.arange(n)[at]
    except (IndexError, TypeError, ValueError, RuntimeError) as err:
        raise InputError(f"preintegrate: at={at!r} does not index {n} samples: {err}") from None
    index = index.reshape(-1)
    if index.numel() == 0:
        raise InputError(f"preintegrate: at={at!r} selects no sample of {n}")
    return index


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
