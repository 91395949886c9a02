"""SO(3) maps in torch, batched over leading dimensions and safe to differentiate at zero.

Conventions: rotation vectors ``phi`` in radians; right Jacobian as in Forster et al. and GTSAM
(``Exp(phi + d) ~= Exp(phi) Exp(Jr(phi) d)``, GTSAM's ``SO3::ExpmapDerivative``); its inverse is GTSAM's
``SO3::LogmapDerivative``.

Layout: by default vectors are (..., 3) and matrices (..., 3, 3). With ``dim=-2`` the component axis is the
second to last, vectors (..., 3, N) and matrices (..., 3, 3, N): "samples last", the layout the preintegrator
uses because elementwise kernels on long contiguous rows are much faster than batched 3x3 matmuls.
"""

from __future__ import annotations

import torch

# Below this squared angle (rad^2) the closed forms lose accuracy and Taylor series are used instead;
# truncation error of the series there is below 1e-15.
_SMALL_ANGLE_SQ = 1e-4


def hat(v: torch.Tensor, dim: int = -1) -> torch.Tensor:
    """Skew-symmetric matrices ``[v]x`` of vectors ``v`` (component axis ``dim``)."""
    x, y, z = v.unbind(dim)
    o = torch.zeros_like(x)
    return torch.stack([o, -z, y, z, o, -x, -y, x, o], dim=dim).unflatten(dim, (3, 3))


def matmul(a: torch.Tensor, b: torch.Tensor, dim: int = -1, transpose_b: bool = False) -> torch.Tensor:
    """Batched 3x3 products ``a @ b`` (or ``a @ b^T``) with matrix axes (dim - 1, dim).

    ``dim=-2`` is the samples-last layout (..., 3, 3, N): there the product is three fused multiply-adds of
    outer products over contiguous rows, several times faster than ``bmm`` on many tiny matrices, with a
    hand-written backward (the same kernel) so autograd does not materialise a gradient per slice.
    """
    if dim == -1:
        return a @ (b.mT if transpose_b else b)
    if dim != -2:
        raise ValueError(f"so3.matmul: dim must be -1 or -2, got {dim}")
    if torch.is_grad_enabled() and (a.requires_grad or b.requires_grad):
        return _SamplesLastMatmul.apply(a, b, transpose_b)
    return _mm_samples_last(a, b, False, transpose_b)


# Up to this many elements per operand a 3x3 product is one broadcast multiply and a sum (fewest kernel
# launches); above it, three fused multiply-adds (least memory traffic).
_SMALL_PRODUCT = 9 * 4096


def _mm_samples_last(a: torch.Tensor, b: torch.Tensor, ta: bool, tb: bool) -> torch.Tensor:
    """op(a) @ op(b) for (..., 3, 3, N) operands, op = transpose where asked; a sum of three outer products."""
    if ta:
        a = a.transpose(-3, -2)
    if tb:
        b = b.transpose(-3, -2)
    if max(a.numel(), b.numel()) <= _SMALL_PRODUCT:
        return (a.unsqueeze(-2) * b.unsqueeze(-4)).sum(-3)  # (..., i, k, 1, N) * (..., 1, k, j, N)
    col = [c.unsqueeze(-2) for c in a.unbind(-2)]  # columns of op(a), (..., 3, 1, N)
    row = [r.unsqueeze(-3) for r in b.unbind(-3)]  # rows of op(b), (..., 1, 3, N)
    out = col[0] * row[0]
    out = torch.addcmul(out, col[1], row[1])
    return torch.addcmul(out, col[2], row[2])


class _SamplesLastMatmul(torch.autograd.Function):
    @staticmethod
    def forward(ctx, a, b, transpose_b):
        ctx.save_for_backward(a, b)
        ctx.transpose_b = transpose_b
        return _mm_samples_last(a, b, False, transpose_b)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad):
        a, b = ctx.saved_tensors
        grad_a = grad_b = None
        if ctx.transpose_b:  # C = A B^T: dA = G B, dB = G^T A
            if ctx.needs_input_grad[0]:
                grad_a = _mm_samples_last(grad, b, False, False)
            if ctx.needs_input_grad[1]:
                grad_b = _mm_samples_last(grad, a, True, False)
        else:  # C = A B: dA = G B^T, dB = A^T G
            if ctx.needs_input_grad[0]:
                grad_a = _mm_samples_last(grad, b, False, True)
            if ctx.needs_input_grad[1]:
                grad_b = _mm_samples_last(a, grad, True, False)
        return _unbroadcast(grad_a, a), _unbroadcast(grad_b, b), None


def _unbroadcast(grad: torch.Tensor | None, like: torch.Tensor) -> torch.Tensor | None:
    """Sum a gradient over the dimensions along which ``like`` was broadcast."""
    if grad is None or grad.shape == like.shape:
        return grad
    extra = grad.ndim - like.ndim
    grad = grad.sum(dim=tuple(range(extra))) if extra else grad
    dims = tuple(i for i, n in enumerate(like.shape) if n == 1 and grad.shape[i] != 1)
    return grad.sum(dim=dims, keepdim=True) if dims else grad


def transpose(a: torch.Tensor, dim: int = -1) -> torch.Tensor:
    """Matrix transpose with matrix axes (dim - 1, dim)."""
    return a.transpose(dim - 1, dim)


def matvec(a: torch.Tensor, v: torch.Tensor, dim: int = -1) -> torch.Tensor:
    """Matrix-vector products ``a @ v`` for matrices with axes (dim - 1, dim) and vectors with axis ``dim``."""
    return (a * v.unsqueeze(dim - 1)).sum(dim)


def _angle_terms(phi: torch.Tensor, dim: int):
    """theta^2 (for the series), a safe theta^2 and theta (1 where small, for the closed forms), and the
    small-angle mask, shaped to broadcast against matrices. The safe values keep the unused branch finite
    under autograd."""
    theta_sq = (phi * phi).sum(dim, keepdim=True).unsqueeze(dim)
    small = theta_sq < _SMALL_ANGLE_SQ
    safe_sq = torch.where(small, torch.ones_like(theta_sq), theta_sq)
    return theta_sq, safe_sq, torch.sqrt(safe_sq), small


def _basis(phi: torch.Tensor, dim: int):
    """Identity (broadcastable), ``[phi]x`` and ``phi phi^T`` with matrix axes (dim - 1, dim); dim is negative."""
    eye_shape = [1] * (phi.ndim + 1)
    eye_shape[dim - 1] = 3
    eye_shape[dim] = 3
    eye = torch.eye(3, dtype=phi.dtype, device=phi.device).view(eye_shape)
    return eye, hat(phi, dim), phi.unsqueeze(dim) * phi.unsqueeze(dim - 1)


def _compose(phi: torch.Tensor, theta_sq, beta, gamma, dim: int) -> torch.Tensor:
    """``I + beta [phi]x + gamma [phi]x^2``, using ``[phi]x^2 = phi phi^T - theta^2 I`` (no inner matmul)."""
    eye, k, outer = _basis(phi, dim)
    return (1 - gamma * theta_sq) * eye + beta * k + gamma * outer


def exp(phi: torch.Tensor, dim: int = -1) -> torch.Tensor:
    """Rodrigues' formula: rotation matrices of rotation vectors."""
    theta_sq, safe_sq, theta, small = _angle_terms(phi, dim)
    half_sin = torch.sin(0.5 * theta)
    a = torch.where(small, 1 - theta_sq / 6 + theta_sq**2 / 120, torch.sin(theta) / theta)
    # (1 - cos t) / t^2 written as 2 sin^2(t/2) / t^2 to avoid cancellation
    b = torch.where(small, 0.5 - theta_sq / 24 + theta_sq**2 / 720, 2 * half_sin * half_sin / safe_sq)
    return _compose(phi, theta_sq, a, b, dim)


def exp_and_right_jacobian(phi: torch.Tensor, dim: int = -1) -> tuple[torch.Tensor, torch.Tensor]:
    """``(exp(phi), right_jacobian(phi))`` sharing their angle terms (fewer kernel launches)."""
    theta_sq, safe_sq, theta, small = _angle_terms(phi, dim)
    half_sin = torch.sin(0.5 * theta)
    sin = torch.sin(theta)
    a = torch.where(small, 1 - theta_sq / 6 + theta_sq**2 / 120, sin / theta)
    b = torch.where(small, 0.5 - theta_sq / 24 + theta_sq**2 / 720, 2 * half_sin * half_sin / safe_sq)
    c = torch.where(small, 1 / 6 - theta_sq / 120 + theta_sq**2 / 5040, (theta - sin) / (theta * safe_sq))
    eye, k, outer = _basis(phi, dim)
    rot = (1 - b * theta_sq) * eye + a * k + b * outer
    jac = (1 - c * theta_sq) * eye - b * k + c * outer
    return rot, jac


def right_jacobian(phi: torch.Tensor, dim: int = -1) -> torch.Tensor:
    """Right Jacobian ``Jr(phi)`` = I - (1 - cos t)/t^2 [phi]x + (t - sin t)/t^3 [phi]x^2."""
    theta_sq, safe_sq, theta, small = _angle_terms(phi, dim)
    half_sin = torch.sin(0.5 * theta)
    b = torch.where(small, 0.5 - theta_sq / 24 + theta_sq**2 / 720, 2 * half_sin * half_sin / safe_sq)
    c = torch.where(small, 1 / 6 - theta_sq / 120 + theta_sq**2 / 5040, (theta - torch.sin(theta)) / theta**3)
    return _compose(phi, theta_sq, -b, c, dim)


def right_jacobian_inv(phi: torch.Tensor, dim: int = -1) -> torch.Tensor:
    """Inverse right Jacobian = I + [phi]x / 2 + (1/t^2 - (1 + cos t)/(2 t sin t)) [phi]x^2.

    Valid for angles below pi (the tangent chart is singular at pi).
    """
    theta_sq, safe_sq, theta, small = _angle_terms(phi, dim)
    # (1 + cos t) / (2 t sin t) = cot(t/2) / (2 t)
    d = torch.where(
        small,
        1 / 12 + theta_sq / 720 + theta_sq**2 / 30240,
        1 / safe_sq - 0.5 / (theta * torch.tan(0.5 * theta)),
    )
    return _compose(phi, theta_sq, torch.full_like(d, 0.5), d, dim)


def matrix_to_quaternion_wxyz(rot: torch.Tensor, dim: int = -1) -> torch.Tensor:
    """Unit quaternions, order (w, x, y, z) along ``dim``, with w >= 0, of rotation matrices.

    Shepperd's method: of the four algebraically equal candidates, the one with the largest denominator is kept.
    """
    m = [row.unbind(dim) for row in rot.unbind(dim - 1)]  # entries (...)
    tr = m[0][0] + m[1][1] + m[2][2]
    # candidate i has 4 q_i^2 = 1 + 2 diag_i - tr (with diag_0 = tr)
    four_q_sq = torch.stack([1 + tr, 1 + 2 * m[0][0] - tr, 1 + 2 * m[1][1] - tr, 1 + 2 * m[2][2] - tr], -1)
    best = four_q_sq.argmax(-1, keepdim=True)
    r = torch.sqrt(torch.clamp(four_q_sq.gather(-1, best), min=1e-30))[..., 0]  # = 2 |q_best|
    r_sq = r * r
    s32, s02, s10 = m[2][1] - m[1][2], m[0][2] - m[2][0], m[1][0] - m[0][1]
    p01, p02, p12 = m[0][1] + m[1][0], m[0][2] + m[2][0], m[1][2] + m[2][1]
    # numerators 4 q_best q_j of each candidate row (w, x, y, z)
    cand = torch.stack(
        [
            torch.stack([r_sq, s32, s02, s10], -1),
            torch.stack([s32, r_sq, p01, p02], -1),
            torch.stack([s02, p01, r_sq, p12], -1),
            torch.stack([s10, p02, p12, r_sq], -1),
        ],
        dim=-2,
    )
    row = cand.gather(-2, best[..., None].expand(*best.shape[:-1], 1, 4)).squeeze(-2)
    q = row / (2 * r[..., None])
    q = q * torch.where(q[..., :1] < 0, -1.0, 1.0).to(q.dtype)
    return q if dim == -1 else q.movedim(-1, dim)


def log(rot: torch.Tensor, dim: int = -1) -> torch.Tensor:
    """Rotation vectors, angle in [0, pi], of rotation matrices; robust near 0 and pi."""
    q = matrix_to_quaternion_wxyz(rot, dim)
    w, v = q.narrow(dim, 0, 1), q.narrow(dim, 1, 3)
    sin_half_sq = (v * v).sum(dim, keepdim=True)
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


# Below this cosine of the angle (about 172 deg) the skew-part formula of ``log`` loses accuracy.
_NEAR_PI_COS = -0.99


def log_and_right_jacobian_inv(rot: torch.Tensor, dim: int = -1) -> tuple[torch.Tensor, torch.Tensor]:
    """``(log(rot), right_jacobian_inv(log(rot)))`` from the trace and skew part of ``rot``, sharing cos and sin.

    Falls back to the quaternion route of ``log`` when any angle is within ~8 deg of pi.
    """
    m = [row.unbind(dim) for row in rot.unbind(dim - 1)]
    cos = 0.5 * (m[0][0] + m[1][1] + m[2][2] - 1)
    if bool((cos < _NEAR_PI_COS).any()):
        phi = log(rot, dim)
        return phi, right_jacobian_inv(phi, dim)
    v = 0.5 * torch.stack([m[2][1] - m[1][2], m[0][2] - m[2][0], m[1][0] - m[0][1]], dim)  # sin(theta) * axis
    sin_sq = (v * v).sum(dim, keepdim=True)
    cos = cos.unsqueeze(dim)
    small = sin_sq < _SMALL_ANGLE_SQ
    safe_sin_sq = torch.where(small, torch.ones_like(sin_sq), sin_sq)
    sin = torch.sqrt(safe_sin_sq)
    theta = torch.atan2(sin, cos)
    # theta / sin(theta) = asin(s)/s for small s = sin(theta) (cos > 0 there): 1 + s^2/6 + 3 s^4/40 + 5 s^6/112
    scale = torch.where(small, 1 + sin_sq / 6 + 3 * sin_sq**2 / 40 + 5 * sin_sq**3 / 112, theta / sin)
    phi = scale * v
    theta_sq = (scale * scale * sin_sq).unsqueeze(dim)
    # 1/t^2 - (1 + cos t) / (2 t sin t), with cos and sin straight from the matrix
    d = torch.where(
        small.unsqueeze(dim),
        1 / 12 + theta_sq / 720 + theta_sq**2 / 30240,
        (1 / (theta * theta) - (1 + cos) / (2 * theta * sin)).unsqueeze(dim),
    )
    eye, k, outer = _basis(phi, dim)
    return phi, (1 - d * theta_sq) * eye + 0.5 * k + d * outer
