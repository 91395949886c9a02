"""SO(3) maps in torch, batched over leading dimensions and safe to differentiate at zero.

Conventions: rotation vectors ``phi`` (..., 3) in radians; matrices (..., 3, 3); right Jacobian as in
Forster et al. and GTSAM (``Exp(phi + d) ~= Exp(phi) Exp(Jr(phi) d)``; GTSAM's ``SO3::ExpmapDerivative``),
its inverse is GTSAM's ``SO3::LogmapDerivative``.
"""

from __future__ import annotations

import torch

# Below this squared angle (rad^2) the closed forms lose accuracy and Taylor series are used instead;
# truncation error of the series there is below 1e-15.
_SMALL_ANGLE_SQ = 1e-4


def hat(v: torch.Tensor) -> torch.Tensor:
    """Skew-symmetric matrix ``[v]x`` (..., 3, 3) of vectors (..., 3)."""
    x, y, z = v.unbind(-1)
    o = torch.zeros_like(x)
    return torch.stack([o, -z, y, z, o, -x, -y, x, o], dim=-1).unflatten(-1, (3, 3))


def _angle_terms(phi: torch.Tensor):
    """theta^2 (for the series), a safe theta^2 and theta (1 where small, for the closed forms), and the
    small-angle mask, all shaped (..., 1, 1). The safe values keep the unused branch finite under autograd."""
    theta_sq = (phi * phi).sum(-1)[..., None, None]
    small = theta_sq < _SMALL_ANGLE_SQ
    safe_sq = torch.where(small, torch.ones_like(theta_sq), theta_sq)
    return theta_sq, safe_sq, torch.sqrt(safe_sq), small


def exp(phi: torch.Tensor) -> torch.Tensor:
    """Rodrigues' formula: rotation matrices (..., 3, 3) of rotation vectors (..., 3)."""
    theta_sq, safe_sq, theta, small = _angle_terms(phi)
    half_sin = torch.sin(0.5 * theta)
    a = torch.where(small, 1 - theta_sq / 6 + theta_sq**2 / 120, torch.sin(theta) / theta)
    # (1 - cos t) / t^2 written as 2 sin^2(t/2) / t^2 to avoid cancellation
    b = torch.where(small, 0.5 - theta_sq / 24 + theta_sq**2 / 720, 2 * half_sin * half_sin / safe_sq)
    k = hat(phi)
    eye = torch.eye(3, dtype=phi.dtype, device=phi.device)
    return eye + a * k + b * (k @ k)


def right_jacobian(phi: torch.Tensor) -> torch.Tensor:
    """Right Jacobian ``Jr(phi)`` (..., 3, 3) = I - (1 - cos t)/t^2 [phi]x + (t - sin t)/t^3 [phi]x^2."""
    theta_sq, safe_sq, theta, small = _angle_terms(phi)
    half_sin = torch.sin(0.5 * theta)
    b = torch.where(small, 0.5 - theta_sq / 24 + theta_sq**2 / 720, 2 * half_sin * half_sin / safe_sq)
    c = torch.where(small, 1 / 6 - theta_sq / 120 + theta_sq**2 / 5040, (theta - torch.sin(theta)) / theta**3)
    k = hat(phi)
    eye = torch.eye(3, dtype=phi.dtype, device=phi.device)
    return eye - b * k + c * (k @ k)


def right_jacobian_inv(phi: torch.Tensor) -> torch.Tensor:
    """Inverse right Jacobian (..., 3, 3) = I + [phi]x / 2 + (1/t^2 - (1 + cos t)/(2 t sin t)) [phi]x^2.

    Valid for angles below pi (the tangent chart is singular at pi).
    """
    theta_sq, safe_sq, theta, small = _angle_terms(phi)
    # (1 + cos t) / (2 t sin t) = cot(t/2) / (2 t)
    d = torch.where(
        small,
        1 / 12 + theta_sq / 720 + theta_sq**2 / 30240,
        1 / safe_sq - 0.5 / (theta * torch.tan(0.5 * theta)),
    )
    k = hat(phi)
    eye = torch.eye(3, dtype=phi.dtype, device=phi.device)
    return eye + 0.5 * k + d * (k @ k)


def matrix_to_quaternion_wxyz(rot: torch.Tensor) -> torch.Tensor:
    """Unit quaternions (..., 4), order (w, x, y, z), with w >= 0, of rotation matrices (..., 3, 3).

    Shepperd's method: of the four algebraically equal candidates, the one with the largest denominator is kept.
    """
    m = rot
    tr = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    diag = torch.stack([tr, m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]], dim=-1)
    # candidate i has 4 * q_i^2 = 1 + 2 * diag_i - tr (with diag_0 = tr)
    four_q_sq = 1 + 2 * diag - tr[..., None]
    best = four_q_sq.argmax(-1, keepdim=True)
    r = torch.sqrt(torch.clamp(four_q_sq.gather(-1, best), min=1e-30))  # = 2 |q_best|
    s32, s02, s10 = m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]
    p01, p02, p12 = m[..., 0, 1] + m[..., 1, 0], m[..., 0, 2] + m[..., 2, 0], m[..., 1, 2] + m[..., 2, 1]
    # numerators 4 q_best q_j for each candidate row (w, x, y, z)
    cand = torch.stack(
        [
            torch.stack([r[..., 0] ** 2, s32, s02, s10], -1),
            torch.stack([s32, r[..., 0] ** 2, p01, p02], -1),
            torch.stack([s02, p01, r[..., 0] ** 2, p12], -1),
            torch.stack([s10, p02, p12, r[..., 0] ** 2], -1),
        ],
        dim=-2,
    )
    row = cand.gather(-2, best[..., None].expand(*best.shape[:-1], 1, 4)).squeeze(-2)
    q = row / (2 * r)
    return q * torch.where(q[..., :1] < 0, -1.0, 1.0).to(q.dtype)


def log(rot: torch.Tensor) -> torch.Tensor:
    """Rotation vectors (..., 3), angle in [0, pi], of rotation matrices (..., 3, 3); robust near 0 and pi."""
    q = matrix_to_quaternion_wxyz(rot)
    w, v = q[..., :1], q[..., 1:]
    sin_half_sq = (v * v).sum(-1, keepdim=True)
    small = sin_half_sq < _SMALL_ANGLE_SQ
    sin_half = torch.sqrt(torch.where(small, torch.ones_like(sin_half_sq), sin_half_sq))
    # theta / sin(theta/2) with theta = 2 atan2(|v|, w); for small |v| = s it is 2 asin(s) / s, a series in s^2
    s2 = sin_half_sq
    scale = torch.where(
        small,
        2 * (1 + s2 / 6 + 3 * s2**2 / 40 + 5 * s2**3 / 112),
        2 * torch.atan2(sin_half, w) / sin_half,
    )
    return scale * v
