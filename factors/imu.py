"""Learned preintegration factor: GTSAM's ``ImuFactor`` residual with a measurement from the learned model.

Keys as ``gtsam.ImuFactor`` uses them: ``X(i)`` (``Pose3``), ``V(i)`` (world-frame velocity, ``Vector3``),
``X(j)``, ``V(j)``. Measurement: the preintegrated deltas from i to j -- ``delta_rot`` (3x3, IMU frame at j to
IMU frame at i), ``delta_pos`` and ``delta_vel`` (m, m/s, IMU frame at i), elapsed ``dt`` (s) -- and their 9x9
covariance in GTSAM's tangent order [rotation, position, velocity] (``preintMeasCov()``'s convention; what
``learned_imu.preintegrate`` returns). Gravity is the world-frame vector (default ``[0, 0, -9.81]``).

Residual, exactly GTSAM 4.3's ``ImuFactor`` with zero bias: predict the state at j from the state at i,
``R = R_i dR``, ``p = p_i + v_i dt + g dt^2 / 2 + R_i dp``, ``v = v_i + g dt + R_i dv``, then
``e = NavState.Logmap(X_j^-1 * predicted)`` in the Lie group SE_2(3). Jacobians are analytic: the chain of the
prediction's derivative and SE_2(3)'s ``Logmap`` Jacobian (GTSAM's closed form, computed in C++).
Noise, again as GTSAM 4.3 (``residualCovariance()``): the measurement covariance mapped from the tangent chart
to the residual's chart, ``T cov T^T`` with ``T = blockdiag(Jr(Log dR), dR^T, dR^T)``.

Optional bias key ``B(i)`` (``imuBias.ConstantBias``, [acc, gyro]) with the deltas' ``bias_jacobian`` (9x6, from
``learned_imu.preintegrate(..., bias_jacobian=True)``): the deltas are corrected to first order,
``dR Exp(J_rg b_g)``, ``dp + J_p b``, ``dv + J_v b``, like ``gtsam.ImuFactor``/``CombinedImuFactor`` do. Use it when
the graph keeps bias states (raw or partly corrected IMU, long runs where the bias drifts; tie consecutive biases
with a ``BetweenFactorConstantBias``). Without it the factor assumes the samples are already unbiased, which is
what the learned correction provides.

Equal to ``gtsam.ImuFactor`` to round-off at zero bias (error, Jacobians, solution). At a non-zero bias both correct
to first order, but in different charts: this factor on the manifold (Forster's ``dR Exp(J_rg b_g)``, with
``learned_imu``'s Jacobians), GTSAM 4.3's tangent preintegration by adding ``J b`` to its tangent vector before the
retraction; they differ at second order in the bias (factor errors 54.4312 against 54.4533 and solutions 2.06 cm
apart with a 0.1-0.3 rad/s gyro bias: tests/factors/test_bias_relinearisation.py). Where the bias is that large,
re-linearise (``factors.solve_relinearised``), which leaves neither first-order correction in the result.
"""

from __future__ import annotations

import gtsam
import numpy as np

from airimu_core.checks import preintegration_problem


class LearnedImuFactor(gtsam.CustomFactor):
    """IMU factor between (X(i), V(i)) and (X(j), V(j)) with a learned measurement and covariance."""

    def __init__(
        self,
        pose_i: int,
        vel_i: int,
        pose_j: int,
        vel_j: int,
        delta_rot,
        delta_pos,
        delta_vel,
        dt: float,
        cov,
        gravity=(0.0, 0.0, -9.81),
        bias: int | None = None,
        bias_jacobian=None,
    ):
        self.delta_rot = _matrix("delta_rot", delta_rot, (3, 3))
        self.delta_pos = _matrix("delta_pos", delta_pos, (3,))
        self.delta_vel = _matrix("delta_vel", delta_vel, (3,))
        self.gravity = _matrix("gravity", gravity, (3,))
        self.dt = float(dt)
        cov = _matrix("cov", cov, (9, 9))
        problem = preintegration_problem(self.delta_rot[None], [self.dt], cov[None])
        if problem is not None:
            raise ValueError(f"LearnedImuFactor: {problem[1]}")
        if (bias is None) != (bias_jacobian is None):
            raise ValueError("LearnedImuFactor: give both bias (a key) and bias_jacobian (9x6), or neither")
        self.bias_jacobian = None if bias_jacobian is None else _matrix("bias_jacobian", bias_jacobian, (9, 6))
        # Prediction terms that do not depend on the states.
        self._delta_rot3 = gtsam.Rot3(self.delta_rot)
        self._gravity_pos = 0.5 * self.gravity * self.dt**2
        self._gravity_vel = self.gravity * self.dt
        self._d_pred_pose_i = _prediction_jacobian(self.delta_rot, self.delta_pos, self.delta_vel)
        to_residual = np.zeros((9, 9))
        to_residual[0:3, 0:3] = gtsam.SO3.ExpmapDerivative(gtsam.Rot3.Logmap(gtsam.Rot3(self.delta_rot)))
        to_residual[3:6, 3:6] = self.delta_rot.T
        to_residual[6:9, 6:9] = self.delta_rot.T
        noise = gtsam.noiseModel.Gaussian.Covariance(to_residual @ cov @ to_residual.T)
        keys = [pose_i, vel_i, pose_j, vel_j] + ([] if bias is None else [bias])
        super().__init__(noise, keys, self._evaluate)

    def _evaluate(self, this: gtsam.CustomFactor, values: gtsam.Values, jacobians: list | None) -> np.ndarray:
        k = this.keys()
        pose_i, pose_j = values.atPose3(k[0]), values.atPose3(k[2])
        v_i, v_j = values.atVector(k[1]), values.atVector(k[3])
        rot_i, rot_j = pose_i.rotation(), pose_j.rotation()
        r_i = rot_i.matrix()
        # 0. the deltas, bias-corrected if the factor has a bias key
        d_rot3, d_pos, d_vel, d_pred_pose_i = self._delta_rot3, self.delta_pos, self.delta_vel, self._d_pred_pose_i
        if self.bias_jacobian is not None:
            bias = values.atConstantBias(k[4]).vector()  # [acc, gyro]
            rot_fix = self.bias_jacobian[0:3, 3:6] @ bias[3:]
            d_rot3 = d_rot3.compose(gtsam.Rot3.Expmap(rot_fix))
            d_pos = d_pos + self.bias_jacobian[3:6] @ bias
            d_vel = d_vel + self.bias_jacobian[6:9] @ bias
            if jacobians is not None:
                d_pred_pose_i = _prediction_jacobian(d_rot3.matrix(), d_pos, d_vel)
        # 1. predict the state at j (world frame)
        rot_p = rot_i.compose(d_rot3)
        p_p = pose_i.translation() + v_i * self.dt + self._gravity_pos + r_i @ d_pos
        v_p = v_i + self._gravity_vel + r_i @ d_vel
        # 2. error in SE_2(3): Log(X_j^-1 * predicted)
        between = gtsam.NavState(
            rot_j.between(rot_p), rot_j.unrotate(p_p - pose_j.translation()), rot_j.unrotate(v_p - v_j)
        )
        if jacobians is None:
            return gtsam.NavState.Logmap(between)
        d_log = np.zeros((9, 9), order="F")
        error = gtsam.NavState.Logmap(between, d_log)
        # 3. Jacobians: right perturbations of the predicted state (for X(i), V(i)) and of X(j), V(j)
        r_p_t = rot_p.matrix().T
        minus_ad = -(d_log @ between.inverse().AdjointMap())
        jacobians[0] = d_log @ d_pred_pose_i
        jacobians[1] = d_log[:, 3:6] @ (self.dt * r_p_t) + d_log[:, 6:9] @ r_p_t
        jacobians[2] = minus_ad[:, 0:6]
        jacobians[3] = minus_ad[:, 6:9] @ rot_j.matrix().T
        if self.bias_jacobian is not None:  # right perturbation of the prediction per bias change
            d_pred_bias = np.zeros((9, 6))
            d_pred_bias[0:3, 3:6] = gtsam.SO3.ExpmapDerivative(rot_fix) @ self.bias_jacobian[0:3, 3:6]
            corrected_t = d_rot3.matrix().T
            d_pred_bias[3:6] = corrected_t @ self.bias_jacobian[3:6]
            d_pred_bias[6:9] = corrected_t @ self.bias_jacobian[6:9]
            jacobians[4] = d_log @ d_pred_bias
        return error


def _prediction_jacobian(delta_rot: np.ndarray, delta_pos: np.ndarray, delta_vel: np.ndarray) -> np.ndarray:
    """Right perturbation of the predicted state w.r.t. X(i)'s tangent [omega, t] (9x6)."""
    rot_t = delta_rot.T
    out = np.zeros((9, 6))
    out[0:3, 0:3] = rot_t
    out[3:6, 0:3] = -rot_t @ _hat(delta_pos)
    out[3:6, 3:6] = rot_t
    out[6:9, 0:3] = -rot_t @ _hat(delta_vel)
    return out


def _hat(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _matrix(name: str, value, shape: tuple[int, ...]) -> np.ndarray:
    out = np.asarray(value, dtype=float)
    if out.shape != shape:
        raise ValueError(f"LearnedImuFactor: {name} must have shape {shape}, got {out.shape}")
    if not np.all(np.isfinite(out)):
        raise ValueError(f"LearnedImuFactor: {name} contains NaN or Inf")
    return out
