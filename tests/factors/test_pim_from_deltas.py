"""pim_from_deltas: the built-in gtsam.ImuFactor carrying a learned measurement equals LearnedImuFactor."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
import torch
from gtsam.symbol_shorthand import B, V, X

from airimu_core.errors import PimLayoutError
from airimu_core.export import load_export
from factors import LearnedImuFactor
from factors.export_file import from_export
from factors.pim_from_deltas import _check_read_back, pim_from_deltas
from learned_imu import preintegrate
from learned_imu.datasets.simulator import simulate
from learned_imu.export import export_preintegration, keyframes_every


def measurement(seed: int):
    rng = np.random.default_rng(seed)
    gyro = rng.uniform(-1.5, 1.5, (150, 3))
    acc = rng.normal(0, 2, (150, 3)) + [0, 0, 9.81]
    pre = preintegrate(torch.tensor(gyro), torch.tensor(acc), 0.005, 1e-4, 1e-3, at=-1, bias_jacobian=True)
    return [x[0].numpy() for x in (pre.rot, pre.pos, pre.vel)] + [
        pre.dt[0].item(),
        pre.cov[0].numpy(),
        pre.bias_jacobian[0].numpy(),
    ]


def random_values(rng):
    values = gtsam.Values()
    for key in (X(0), X(1)):
        values.insert(key, gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3)), rng.normal(size=3)))
    for key in (V(0), V(1)):
        values.insert(key, rng.normal(size=3))
    values.insert(B(0), gtsam.imuBias.ConstantBias())
    return values


def test_rebuilt_imu_factor_equals_learned_imu_factor():
    rng = np.random.default_rng(0)
    for seed in range(5):
        rot, pos, vel, dt, cov, jac = measurement(seed)
        gravity = [0.0, 0.0, -9.81]
        fast = gtsam.ImuFactor(X(0), V(0), X(1), V(1), B(0), pim_from_deltas(rot, pos, vel, dt, cov, jac, gravity))
        ours = LearnedImuFactor(X(0), V(0), X(1), V(1), rot, pos, vel, dt, cov, gravity, bias=B(0), bias_jacobian=jac)
        values = random_values(rng)
        e_fast, e_ours = fast.unwhitenedError(values), ours.unwhitenedError(values)
        assert np.abs(e_fast - e_ours).max() < 1e-12 * np.abs(e_ours).max()
        (a_fast, b_fast), (a_ours, b_ours) = fast.linearize(values).jacobian(), ours.linearize(values).jacobian()
        assert np.abs(a_fast - a_ours).max() < 1e-9 * np.abs(a_ours).max()  # bias columns included
        assert np.abs(b_fast - b_ours).max() < 1e-9 * np.abs(b_ours).max()


def test_read_back_check_catches_a_wrong_pim():
    rot, pos, vel, dt, cov, jac = measurement(1)
    pim = pim_from_deltas(rot, pos, vel, dt, cov, jac, [0.0, 0.0, -9.81])
    with pytest.raises(PimLayoutError, match="does not read back"):
        _check_read_back(pim, dt, np.zeros(9), cov, rot)


def test_export_to_gtsam_backend(tmp_path):
    seq = simulate("drone", duration_s=5.0, seed=2)
    path = export_preintegration(tmp_path / "e.npz", seq, keyframes_every(seq, 0.5), 1e-6, 1e-4)
    fast, times = from_export(load_export(path), bias_key=lambda k: B(0))  # an Export, the default C++ backend
    custom, _ = from_export(path, bias_key=lambda k: B(0), backend="custom")
    assert all(isinstance(f, gtsam.ImuFactor) for f in fast) and len(fast) == len(custom) == len(times) - 1
    values = gtsam.Values()
    for k, i in enumerate(np.arange(0, 1000, 100)):
        values.insert(X(k), gtsam.Pose3(gtsam.Rot3(seq.gt.rot[i]), seq.gt.pos[i]))
        values.insert(V(k), seq.gt.vel[i])
    values.insert(B(0), gtsam.imuBias.ConstantBias())
    for f, c in zip(fast, custom, strict=True):
        assert f.error(values) == pytest.approx(c.error(values), rel=1e-9)
    with pytest.raises(ValueError, match="pass bias_key"):
        from_export(path, bias_key=None)
