"""The scan preintegrator against GTSAM, against the sample-by-sample loop, and under autograd."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
import torch

from learned_imu import NavState, predict, preintegrate
from learned_imu.geometry import preintegration, so3
from learned_imu.geometry.preintegration_reference import preintegrate_loop, preintegrate_pair_scan

RATE_HZ = 200.0
DT = 1.0 / RATE_HZ
GYRO_DENSITY = 1e-4  # rad^2/s
ACC_DENSITY = 1e-3  # m^2/s^3


def imu_samples(n: int, max_rate: float, seed: int = 0, batch: tuple[int, ...] = ()):
    """Random IMU samples: rates uniform in [-max_rate, max_rate] rad/s, specific force around +g."""
    rng = np.random.default_rng(seed)
    gyro = rng.uniform(-max_rate, max_rate, (*batch, n, 3))
    acc = rng.normal(0.0, 2.0, (*batch, n, 3)) + np.array([0.0, 0.0, 9.81])
    return gyro, acc


def gtsam_loop(cls, gyro, acc, dt, gyro_density=GYRO_DENSITY, acc_density=ACC_DENSITY):
    """Run a GTSAM preintegration class sample by sample; return its deltas and covariance after each sample."""
    params = gtsam.PreintegrationParams.MakeSharedU(9.81)
    params.setGyroscopeCovariance(np.eye(3) * gyro_density)
    params.setAccelerometerCovariance(np.eye(3) * acc_density)
    params.setIntegrationCovariance(np.zeros((3, 3)))
    pim = cls(params, gtsam.imuBias.ConstantBias())
    rot, pos, vel, cov = [], [], [], []
    for k in range(len(gyro)):
        pim.integrateMeasurement(acc[k], gyro[k], dt)
        rot.append(pim.deltaRij().matrix())
        pos.append(pim.deltaPij())
        vel.append(pim.deltaVij())
        cov.append(pim.preintMeasCov())
    return np.array(rot), np.array(pos), np.array(vel), np.array(cov), pim


def rel_err(ours: torch.Tensor | np.ndarray, ref: np.ndarray) -> float:
    """Max-norm relative error: max |ours - ref| / max |ref|."""
    ours = ours.detach().numpy() if isinstance(ours, torch.Tensor) else ours
    return float(np.abs(ours - ref).max() / np.abs(ref).max())


def to_manifold_chart(cov: torch.Tensor, rot: torch.Tensor) -> torch.Tensor:
    """GTSAM tangent chart [theta, p, v] (start frame) -> NavState chart (body-frame errors)."""
    t = torch.zeros(*cov.shape, dtype=cov.dtype)
    t[..., :3, :3] = so3.right_jacobian(so3.log(rot))
    t[..., 3:6, 3:6] = rot.mT
    t[..., 6:, 6:] = rot.mT
    return t @ cov @ t.mT


def test_deltas_equal_gtsam_manifold_preintegration():
    gyro, acc = imu_samples(1000, max_rate=3.0)
    rot, pos, vel, _, _ = gtsam_loop(gtsam.PreintegratedImuMeasurementsManifold, gyro, acc, DT)
    out = preintegrate(torch.tensor(gyro), torch.tensor(acc), DT)
    assert rel_err(out.rot, rot) < 1e-9
    assert rel_err(out.pos, pos) < 1e-9
    assert rel_err(out.vel, vel) < 1e-9
    assert out.dt[-1].item() == pytest.approx(1000 * DT, rel=1e-12)


def test_covariance_equals_gtsam_manifold_in_its_chart():
    gyro, acc = imu_samples(400, max_rate=3.0, seed=1)
    _, _, _, cov, _ = gtsam_loop(gtsam.PreintegratedImuMeasurementsManifold, gyro, acc, DT)
    out = preintegrate(torch.tensor(gyro), torch.tensor(acc), DT, GYRO_DENSITY, ACC_DENSITY)
    assert rel_err(to_manifold_chart(out.cov, out.rot), cov) < 1e-9


@pytest.mark.parametrize("max_rate", [0.3, 1.0])
def test_covariance_matches_gtsam_default_tangent_preintegration(max_rate):
    gyro, acc = imu_samples(1000, max_rate=max_rate, seed=2)
    _, _, _, cov, _ = gtsam_loop(gtsam.PreintegratedImuMeasurements, gyro, acc, DT)
    out = preintegrate(torch.tensor(gyro), torch.tensor(acc), DT, GYRO_DENSITY, ACC_DENSITY)
    for k in (0, 9, 99, 499, 999):
        assert rel_err(out.cov[k], cov[k]) < 0.01, k


@pytest.mark.slow
def test_covariance_equals_sample_loop_with_per_sample_noise():
    gyro, acc = imu_samples(300, max_rate=3.0, seed=3, batch=(2,))
    rng = np.random.default_rng(4)
    gyro_cov = torch.tensor(rng.uniform(1e-6, 1e-3, gyro.shape))
    acc_cov = torch.tensor(rng.uniform(1e-5, 1e-2, acc.shape))
    dt = torch.tensor(rng.uniform(0.5 * DT, 1.5 * DT, gyro.shape[:-1]))
    args = (torch.tensor(gyro), torch.tensor(acc), dt, gyro_cov, acc_cov)
    scan, loop = preintegrate(*args), preintegrate_loop(*args)
    for field in ("rot", "vel", "pos", "dt", "cov"):
        assert rel_err(getattr(scan, field), getattr(loop, field).numpy()) < 1e-9, field


@pytest.mark.slow
def test_pair_scan_route_equals_sample_loop():
    gyro, acc = imu_samples(257, max_rate=3.0, seed=11, batch=(2,))
    rng = np.random.default_rng(12)
    gyro_cov = torch.tensor(rng.uniform(1e-6, 1e-3, gyro.shape))
    acc_cov = torch.tensor(rng.uniform(1e-5, 1e-2, acc.shape))
    args = (torch.tensor(gyro), torch.tensor(acc), DT, gyro_cov, acc_cov)
    assert rel_err(preintegrate_pair_scan(*args).cov, preintegrate_loop(*args).cov.numpy()) < 1e-9


def test_covariance_is_symmetric_positive_definite():
    gyro, acc = imu_samples(1000, max_rate=2.0, seed=5)
    out = preintegrate(torch.tensor(gyro), torch.tensor(acc), DT, GYRO_DENSITY, ACC_DENSITY)
    assert rel_err(out.cov, out.cov.mT.numpy()) < 1e-12
    assert torch.linalg.eigvalsh(out.cov[1:]).min() > 0


def test_float32_tracks_float64():
    gyro, acc = imu_samples(1000, max_rate=3.0, seed=6)
    ref = preintegrate(torch.tensor(gyro), torch.tensor(acc), DT, GYRO_DENSITY, ACC_DENSITY)
    f32 = preintegrate(torch.tensor(gyro).float(), torch.tensor(acc).float(), DT, GYRO_DENSITY, ACC_DENSITY)
    assert f32.cov.dtype == torch.float32
    for field in ("rot", "vel", "pos", "cov"):
        assert rel_err(getattr(f32, field).double(), getattr(ref, field).numpy()) < 1e-4, field


@pytest.mark.slow
@pytest.mark.parametrize("large_routes", [False, True])
@pytest.mark.parametrize("at", [None, -1, 4])
def test_gradcheck_deltas_and_covariance(at, large_routes, monkeypatch):
    """Every sample (cumulative sums) and one reported sample (its own route: a matrix product over all noise
    terms); small problems and, with the size thresholds at zero, the routes large problems take (odd-even
    rotation scan, three fused multiply-adds per 3x3 product). Both scans share a closed-form backward."""
    if large_routes:
        monkeypatch.setattr(preintegration, "_SMALL_SCAN", 0)
        monkeypatch.setattr(so3, "_SMALL_PRODUCT", 0)
    gyro, acc = imu_samples(7, max_rate=3.0, seed=7)
    rng = np.random.default_rng(8)
    inputs = (
        torch.tensor(gyro, requires_grad=True),
        torch.tensor(acc, requires_grad=True),
        torch.tensor(rng.uniform(1e-4, 1e-3, (7, 3)), requires_grad=True),
        torch.tensor(rng.uniform(1e-3, 1e-2, (7, 3)), requires_grad=True),
    )

    def fn(g, a, gc, ac):
        out = preintegrate(g, a, 0.01, gc, ac, at=at)
        return out.rot, out.vel, out.pos, out.cov

    assert torch.autograd.gradcheck(fn, inputs, eps=1e-6, atol=1e-7, rtol=1e-5)


@pytest.mark.slow
@pytest.mark.parametrize("at", [None, -1])
def test_gradcheck_with_constant_noise(at):
    """Densities that are not differentiated (a fixed noise, as in GTSAM's params) take a shorter backward."""
    gyro, acc = imu_samples(7, max_rate=3.0, seed=11)
    inputs = (torch.tensor(gyro, requires_grad=True), torch.tensor(acc, requires_grad=True))

    def fn(g, a):
        out = preintegrate(g, a, 0.01, 3e-4, [2e-3, 3e-3, 4e-3], at=at)
        return out.rot, out.vel, out.pos, out.cov

    assert torch.autograd.gradcheck(fn, inputs, eps=1e-6, atol=1e-7, rtol=1e-5)


def test_batch_equals_items_alone():
    gyro, acc = imu_samples(37, max_rate=2.0, seed=9, batch=(3, 2))
    g, a = torch.tensor(gyro), torch.tensor(acc)
    full = preintegrate(g, a, DT, GYRO_DENSITY, ACC_DENSITY)
    for i in range(3):
        for j in range(2):
            one = preintegrate(g[i, j], a[i, j], DT, GYRO_DENSITY, ACC_DENSITY)
            assert torch.equal(full.pos[i, j], one.pos) or rel_err(full.pos[i, j], one.pos.numpy()) < 1e-14
            assert rel_err(full.cov[i, j], one.cov.numpy()) < 1e-14


@pytest.mark.parametrize("n", [1, 2, 3, 5, 127, 129])
def test_short_and_non_power_of_two_lengths(n):
    gyro, acc = imu_samples(n, max_rate=2.0, seed=n)
    args = (torch.tensor(gyro), torch.tensor(acc), DT, GYRO_DENSITY, ACC_DENSITY)
    scan, loop = preintegrate(*args), preintegrate_loop(*args)
    assert scan.rot.shape == (n, 3, 3) and scan.cov.shape == (n, 9, 9)
    assert rel_err(scan.pos, loop.pos.numpy()) < 1e-12
    assert rel_err(scan.cov, loop.cov.numpy()) < 1e-12


@pytest.mark.parametrize("at", [slice(49, None, 50), [0, 7, 99], -1, [50], 0, torch.tensor([3, 3, 50])])
def test_reporting_selected_samples_equals_selecting_from_all(at):
    gyro, acc = imu_samples(100, max_rate=2.0, seed=13, batch=(2,))
    g, a = torch.tensor(gyro), torch.tensor(acc)
    full = preintegrate(g, a, DT, GYRO_DENSITY, ACC_DENSITY)
    some = preintegrate(g, a, DT, GYRO_DENSITY, ACC_DENSITY, at=at)
    index = torch.arange(100)[at].reshape(-1)
    assert some.cov.shape == (2, len(index), 9, 9)
    for field in ("rot", "vel", "pos", "dt", "cov"):  # equal to round-off (SIMD vs scalar lanes may differ)
        assert rel_err(getattr(some, field), getattr(full, field)[:, index].numpy()) < 1e-14, field


@pytest.mark.parametrize("at", [100, [0, 200], slice(100, None), "last"])
def test_bad_sample_selection_raises(at):
    gyro, acc = imu_samples(100, max_rate=1.0)
    with pytest.raises(ValueError, match="at="):
        preintegrate(torch.tensor(gyro), torch.tensor(acc), DT, at=at)


def test_predict_equals_gtsam_predict():
    gyro, acc = imu_samples(200, max_rate=1.0, seed=10)
    *_, pim = gtsam_loop(gtsam.PreintegratedImuMeasurementsManifold, gyro, acc, DT)
    rot_i = gtsam.Rot3.RzRyRx(0.1, -0.2, 0.3)
    state_i = gtsam.NavState(rot_i, np.array([1.0, 2.0, 3.0]), np.array([0.5, -0.4, 0.2]))
    state_j = pim.predict(state_i, gtsam.imuBias.ConstantBias())
    pre = preintegrate(torch.tensor(gyro), torch.tensor(acc), DT)
    f64 = torch.float64
    initial = NavState(
        rot=torch.tensor(rot_i.matrix()),
        vel=torch.tensor([0.5, -0.4, 0.2], dtype=f64),
        pos=torch.tensor([1.0, 2.0, 3.0], dtype=f64),
    )
    ours = predict(initial, pre, gravity=[0.0, 0.0, -9.81])
    assert rel_err(ours.rot[-1], state_j.attitude().matrix()) < 1e-9
    assert rel_err(ours.pos[-1], state_j.position()) < 1e-9
    assert rel_err(ours.vel[-1], state_j.velocity()) < 1e-9


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda g, a, dt: (g[:, :2], a, dt), "shape"),
        (lambda g, a, dt: (g, a[:-1], dt), "shape"),
        (lambda g, a, dt: (g, a, -dt), "dt must be positive"),
        (lambda g, a, dt: (g, a, 0.0), "dt must be positive"),
        (lambda g, a, dt: (g, a, torch.full((3,), dt)), "dt must be"),
        (lambda g, a, dt: (g.index_fill(0, torch.tensor([1]), float("nan")), a, dt), "gyro contains NaN"),
        (lambda g, a, dt: (g, a.index_fill(0, torch.tensor([2]), float("inf")), dt), "acc contains NaN or Inf"),
    ],
)
def test_bad_samples_raise_value_error(change, message):
    gyro, acc = imu_samples(10, max_rate=1.0)
    g, a, dt = change(torch.tensor(gyro), torch.tensor(acc), DT)
    with pytest.raises(ValueError, match=message):
        preintegrate(g, a, dt)


@pytest.mark.parametrize(
    ("gyro_cov", "acc_cov", "message"),
    [
        (-1e-4, 1e-3, "gyro_cov must be non-negative"),
        (1e-4, torch.tensor([1e-3, -1.0, 1e-3]), "acc_cov must be non-negative"),
        (torch.ones(4), 1e-3, "gyro_cov must be"),
        (1e-4, None, "both"),
        (float("nan"), 1e-3, "gyro_cov contains NaN"),
    ],
)
def test_bad_covariances_raise_value_error(gyro_cov, acc_cov, message):
    gyro, acc = imu_samples(10, max_rate=1.0)
    with pytest.raises(ValueError, match=message):
        preintegrate(torch.tensor(gyro), torch.tensor(acc), DT, gyro_cov, acc_cov)


def test_bias_jacobian_equals_numerical_derivative():
    gyro, acc = imu_samples(300, max_rate=2.0, seed=14)
    g, a = torch.tensor(gyro), torch.tensor(acc)
    at = [0, 99, 299]
    out = preintegrate(g, a, DT, at=at, bias_jacobian=True)
    eps = 1e-6
    for col in range(6):  # GTSAM's bias order: acc then gyro
        bias = torch.zeros(6, dtype=torch.float64)
        bias[col] = eps
        plus = preintegrate(g - bias[3:], a - bias[:3], DT, at=at)
        bias[col] = -eps
        minus = preintegrate(g - bias[3:], a - bias[:3], DT, at=at)
        d_rot = so3.log(minus.rot.mT @ plus.rot) / (2 * eps)  # right perturbation
        d_pos = (plus.pos - minus.pos) / (2 * eps)
        d_vel = (plus.vel - minus.vel) / (2 * eps)
        numeric = torch.cat([d_rot, d_pos, d_vel], dim=-1)
        assert (out.bias_jacobian[..., col] - numeric).abs().max() < 1e-6 * max(1.0, numeric.abs().max()), col


def test_bias_jacobian_matches_gtsam_manifold_predict():
    gyro, acc = imu_samples(400, max_rate=2.0, seed=15)
    *_, pim = gtsam_loop(gtsam.PreintegratedImuMeasurementsManifold, gyro, acc, DT)
    state = gtsam.NavState(gtsam.Rot3.RzRyRx(0.3, -0.1, 0.2), np.array([1.0, 2.0, 3.0]), np.array([0.5, 0.1, -0.2]))
    h_state, h_bias = np.zeros((9, 9), order="F"), np.zeros((9, 6), order="F")
    pim.predict(state, gtsam.imuBias.ConstantBias(), h_state, h_bias)
    out = preintegrate(torch.tensor(gyro), torch.tensor(acc), DT, at=-1, bias_jacobian=True)
    jac = out.bias_jacobian[0].numpy()
    d_rot = out.rot[0].numpy()
    # GTSAM's Jacobian is of the predicted NavState in its retract chart: position/velocity rows in the body
    # frame at j, i.e. rotated by dR^T; and it is w.r.t. the bias *estimate* (subtracted), like ours.
    expected = np.vstack([jac[:3], d_rot.T @ jac[3:6], d_rot.T @ jac[6:]])
    assert rel_err(expected, h_bias) < 1e-9


def test_against_gtsams_default_tangent_preintegration_on_a_large_turn():
    """The README's statement: equal to the Manifold preintegration to round-off (tests above); GTSAM's default
    tangent ``PreintegratedImuMeasurements`` discretises differently: ~1e-6 on a 0.85 rad, 1-s turn at 200 Hz."""
    n, dt = 200, 0.005
    rng = np.random.default_rng(0)
    gyro = np.tile([0.2, -0.3, 0.77], (n, 1)) + rng.normal(0, 0.05, (n, 3))
    acc = np.tile([0.5, 0.2, 9.8], (n, 1)) + rng.normal(0, 0.5, (n, 3))
    ours = preintegrate(torch.tensor(gyro), torch.tensor(acc), dt, GYRO_DENSITY, ACC_DENSITY)
    rot_g, pos_g, vel_g = gtsam_loop(gtsam.PreintegratedImuMeasurements, gyro, acc, dt)[:3]
    rot = ours.rot[-1].numpy()
    assert np.linalg.norm(gtsam.Rot3.Logmap(gtsam.Rot3(rot))) > 0.8
    angle = np.linalg.norm(gtsam.Rot3.Logmap(gtsam.Rot3(rot_g[-1].T @ rot)))
    assert 1e-9 < angle < 1e-5  # measured 9.7e-7 rad: not round-off, but far below any IMU's noise
    assert np.abs(pos_g[-1] - ours.pos[-1].numpy()).max() < 1e-5  # measured 2.9e-7 m
    assert np.abs(vel_g[-1] - ours.vel[-1].numpy()).max() < 1e-5  # measured 9.5e-7 m/s


def test_nav_state_is_keyword_only_so_the_gtsam_order_cannot_swap_position_and_velocity():
    rot, p, v = torch.eye(3, dtype=torch.float64), torch.ones(3, dtype=torch.float64), torch.zeros(3)
    with pytest.raises(TypeError):
        NavState(rot, p, v)  # gtsam.NavState(R, p, v)'s order, positionally
    state = NavState(rot=rot, pos=p, vel=v)  # any keyword order
    assert state.pos is p and state.vel is v
