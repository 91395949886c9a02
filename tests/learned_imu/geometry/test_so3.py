"""SO(3) maps against GTSAM's Rot3 and numerical derivatives in float64."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
import torch

from learned_imu.geometry import so3


def rotation_vectors(seed: int, n: int = 200) -> np.ndarray:
    """Random rotation vectors from tiny (1e-9 rad) to nearly pi, in random directions."""
    rng = np.random.default_rng(seed)
    axes = rng.normal(size=(n, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.concatenate([10.0 ** rng.uniform(-9, -1, n // 2), rng.uniform(0.1, np.pi - 1e-3, n - n // 2)])
    return axes * angles[:, None]


def test_exp_and_log_equal_gtsam():
    phi = rotation_vectors(0)
    ours = so3.exp(torch.tensor(phi)).numpy()
    ref = np.array([gtsam.Rot3.Expmap(p).matrix() for p in phi])
    assert np.abs(ours - ref).max() < 1e-14
    back = so3.log(torch.tensor(ref)).numpy()
    assert np.abs(back - phi).max() < 1e-12
    assert np.abs(back - np.array([gtsam.Rot3.Logmap(gtsam.Rot3(r)) for r in ref])).max() < 1e-12


def test_log_near_pi_and_identity():
    for angle in (np.pi - 1e-7, np.pi, 1e-12, 0.0):
        phi = np.array([0.6, -0.48, 0.64]) * angle
        back = so3.log(so3.exp(torch.tensor(phi)))
        # a rotation by pi has two equal logs, +phi and -phi
        err = min(np.abs(back.numpy() - phi).max(), np.abs(back.numpy() + phi).max())
        assert err < 1e-6, angle


def test_right_jacobian_is_the_numerical_derivative_of_exp():
    for phi in rotation_vectors(1, 20):
        phi_t = torch.tensor(phi)
        base = so3.exp(phi_t)
        numeric = np.zeros((3, 3))
        for i in range(3):
            d = torch.zeros(3, dtype=torch.float64)
            d[i] = 1e-6
            plus = so3.log(base.mT @ so3.exp(phi_t + d))
            minus = so3.log(base.mT @ so3.exp(phi_t - d))
            numeric[:, i] = ((plus - minus) / 2e-6).numpy()
        jr = so3.right_jacobian(phi_t).numpy()
        assert np.abs(jr - numeric).max() < 1e-8
        assert np.abs(so3.right_jacobian_inv(phi_t).numpy() @ jr - np.eye(3)).max() < 1e-10


@pytest.mark.parametrize("fn", [so3.exp, so3.right_jacobian, so3.right_jacobian_inv])
def test_gradcheck_including_zero(fn):
    for phi in (np.zeros(3), np.array([1e-5, -2e-5, 3e-6]), np.array([0.3, -1.2, 0.7])):
        assert torch.autograd.gradcheck(fn, (torch.tensor(phi, requires_grad=True),))


def test_gradcheck_log():
    for phi in (np.array([1e-4, -2e-5, 3e-5]), np.array([0.3, -1.2, 0.7])):
        rot = so3.exp(torch.tensor(phi)).requires_grad_(True)
        assert torch.autograd.gradcheck(so3.log, (rot,))


def test_quaternion_is_wxyz_with_nonnegative_w():
    q = so3.matrix_to_quaternion_wxyz(torch.tensor(gtsam.Rot3.Rx(0.5).matrix()))
    assert np.allclose(q.numpy(), [np.cos(0.25), np.sin(0.25), 0.0, 0.0])
    many = so3.matrix_to_quaternion_wxyz(so3.exp(torch.tensor(rotation_vectors(2))))
    assert (many[:, 0] >= 0).all() and torch.allclose(many.norm(dim=-1), torch.ones(len(many), dtype=many.dtype))


def test_fused_exp_and_right_jacobian_equal_separate_functions():
    phi = torch.tensor(rotation_vectors(3))
    for dim, x in ((-1, phi), (-2, phi.mT.contiguous())):
        rot, jac = so3.exp_and_right_jacobian(x, dim=dim)
        assert torch.allclose(rot, so3.exp(x, dim=dim), rtol=0, atol=1e-15)
        assert torch.allclose(jac, so3.right_jacobian(x, dim=dim), rtol=0, atol=1e-15)


@pytest.mark.parametrize("near_pi", [False, True])
def test_fused_log_and_inverse_jacobian_equal_separate_functions(near_pi):
    phi = rotation_vectors(4)
    if not near_pi:
        phi = phi[np.linalg.norm(phi, axis=1) < 2.8]  # the skew-part route
    rot = so3.exp(torch.tensor(phi))
    for dim, r in ((-1, rot), (-2, rot.movedim(-3, -1).contiguous())):
        log, jinv = so3.log_and_right_jacobian_inv(r, dim=dim)
        ref = so3.log(r, dim=dim)
        assert (log - ref).abs().max() < 1e-12
        assert (jinv - so3.right_jacobian_inv(ref, dim=dim)).abs().max() < 1e-9


def test_gradcheck_fused_log_and_inverse_jacobian():
    for phi in (np.array([1e-4, -2e-5, 3e-5]), np.array([0.3, -1.2, 0.7])):
        rot = so3.exp(torch.tensor(phi)).requires_grad_(True)
        assert torch.autograd.gradcheck(lambda r: so3.log_and_right_jacobian_inv(r), (rot,))
