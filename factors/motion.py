"""Learned body-frame velocity factor on a pose and its world-frame velocity: ``MotionFactor``, ``motion_factors``.

Keys as ``gtsam.ImuFactor`` uses them: ``X(i)`` (``Pose3``, world <- body) and ``V(i)`` (world-frame velocity,
``Vector3``, m/s). Measurement: ``v_body`` (3,), the body-frame velocity (m/s) a learned model predicts, with its
covariance ``cov``: diagonal variances (3,) or a full 3x3 covariance, (m/s)^2 (sigma^2, not sigma).

Error ``e = R_i^T v_i - v_body`` (body frame, m/s); Gaussian noise with the learned covariance, so the factor's
``error`` is ``0.5 e^T cov^-1 e``. Jacobians are analytic in GTSAM's Pose3 tangent order [rotation, translation] with
the right-multiplied perturbation ``R Exp(w)``: ``d e / d X_i = [skew(R_i^T v_i), 0_3x3]``, ``d e / d V_i = R_i^T``
(``(R Exp(w))^T v = R^T v - w x R^T v`` to first order); ``Rot3.unrotate`` computes both in C++. With a mounting
rotation ``M`` (``mount_key``, a ``Rot3`` shared by a log's factors: the IMU body frame <- the frame of the model's
velocities) ``e = M^T R_i^T v_i - v_body``: the Jacobians above times ``M^T``, and ``d e / d M = skew(M^T R_i^T v_i)``.
With a speed scale ``s`` (``scale_key``, a ``Vector`` of one shared by the factors of a stretch of the log: how much
faster the platform moves than the model reads) ``e = R_i^T v_i - s v_body`` and ``d e / d s = -v_body``: the model's
error as a slowly varying scale rather than white noise (``fusion.config.MotionSettings.scale_sigma``).

Speed. No C++ factor in gtsam 4.3's Python module has this error on (Pose3, Vector3) keys, so this is a Python
``gtsam.CustomFactor``. Inside GTSAM's own optimisers (``LevenbergMarquardtOptimizer``, ``ISAM2``) pybind11 hands the
callback a *copy* of the optimiser's whole ``Values`` (C++ objects Python does not know), so each evaluation costs
O(graph size) (~0.2 ms at 2,000 values) and N motion factors O(N^2) per iteration: 1,000 of them make a 1,000-keyframe
IMU + GPS solve ~25x slower. Called with a ``Values`` that Python owns, the callback gets it by reference (~4 us an
error, ~9 us a linearisation). Hence two routes, same error and Jacobians (``benchmarks/motion_factor.py``):

- ``solve_with_python_factors(graph, initial)``: GTSAM's Levenberg-Marquardt stepped from Python, the factors in the
  graph (~2.5x the solve without them);
- ``MotionTerms(factors)`` passed as ``extra=`` to it: the factors evaluated together in numpy (~1.8x).
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from airimu_core.checks import SYMMETRY_TOL
from airimu_core.errors import GraphError, InputError, real_array
from factors.checks import is_indeterminate, key_rows, poses_of

# GTSAM's LevenbergMarquardtParams.minModelFidelity default (its Python params have no getter): a step is kept when
# the actual decrease is above this fraction of the linearised model's
MIN_MODEL_FIDELITY = 1e-3


class MotionFactor(gtsam.CustomFactor):
    """Body-frame velocity ``v_body`` (m/s) measured at (X(i), V(i)), with its covariance ((3,) variances or 3x3,
    (m/s)^2). Error ``R_i^T v_i - v_body``, or ``M^T R_i^T v_i - v_body`` with a mounting rotation at ``mount_key``
    (module docstring), or ``... - s v_body`` with a speed scale ``s`` (a ``Vector`` of one) at ``scale_key``."""

    def __init__(
        self, pose_key: int, vel_key: int, v_body, cov, mount_key: int | None = None, scale_key: int | None = None
    ):
        self.v_body = _finite("v_body", v_body, ((3,),), "(3,) m/s")
        cov = _finite("cov", cov, ((3,), (3, 3)), "(3,) variances or (3, 3), (m/s)^2")
        problem = covariance_problem(cov)
        if problem is not None:
            raise InputError(f"MotionFactor: cov {problem}")
        self.cov = np.diag(cov) if cov.ndim == 1 else 0.5 * (cov + cov.T)
        if cov.ndim == 1:
            noise = gtsam.noiseModel.Diagonal.Variances(cov)
        else:
            noise = gtsam.noiseModel.Gaussian.Covariance(self.cov)
        self.pose_key, self.vel_key, self.mount_key, self.scale_key = pose_key, vel_key, mount_key, scale_key
        keys = [pose_key, vel_key] + [key for key in (mount_key, scale_key) if key is not None]
        super().__init__(noise, keys, self._evaluate)

    def _evaluate(self, this: gtsam.CustomFactor, values: gtsam.Values, jacobians: list | None) -> np.ndarray:
        rot = values.atPose3(self.pose_key).rotation()
        vel = values.atVector(self.vel_key)
        mount = None if self.mount_key is None else values.atRot3(self.mount_key)
        measured = self.v_body if self.scale_key is None else values.atVector(self.scale_key)[0] * self.v_body
        if jacobians is None:
            v_in_body = rot.unrotate(vel)
            return (v_in_body if mount is None else mount.unrotate(v_in_body)) - measured
        d_rot, d_vel = np.zeros((3, 3), order="F"), np.zeros((3, 3), order="F")
        v_in_body = rot.unrotate(vel, d_rot, d_vel)  # d_rot = skew(R^T v), d_vel = R^T
        d_pose = np.zeros((3, 6))
        d_pose[:, 0:3] = d_rot  # the translation does not enter
        if mount is not None:  # e = M^T u - v_body, u = R^T v: d e / d M = skew(M^T u), d e / d u = M^T
            d_mount, d_u = np.zeros((3, 3), order="F"), np.zeros((3, 3), order="F")
            v_in_body = mount.unrotate(v_in_body, d_mount, d_u)
            d_pose, d_vel = d_u @ d_pose, d_u @ d_vel
            jacobians[2] = d_mount
        if self.scale_key is not None:
            jacobians[2 if mount is None else 3] = -self.v_body[:, None]
        jacobians[0] = d_pose
        jacobians[1] = d_vel
        return v_in_body - measured


def motion_factors(
    v_body,
    cov,
    pose_key=gtsam.symbol_shorthand.X,
    vel_key=gtsam.symbol_shorthand.V,
    keys=None,
    mount_key: int | None = None,
    scale_keys=None,
) -> list[MotionFactor]:
    """One ``MotionFactor`` per row: row r on (``pose_key(k)``, ``vel_key(k)``) with ``k = keys[r]``.

    Args:
        v_body: (K, 3) body-frame velocities, m/s.
        cov: (K, 3) diagonal variances or (K, 3, 3) covariances, (m/s)^2.
        pose_key, vel_key: functions of a keyframe index giving its keys (``X``, ``V`` by default; e.g.
            ``lambda k: X(k + 1)`` to number from 1), as ``factors.from_export`` takes them.
        keys: (K,) the keyframe index of each row; default 0 .. K-1.
        mount_key: a ``Rot3`` key M shared by every factor (a mounting rotation: error ``M^T R_i^T v_i - v_body``),
            or None.
        scale_keys: (K,) the speed-scale key of each row (a ``Vector`` of one: error ``R_i^T v_i - s v_body``), or
            None for no scale.
    """
    v_body = real_array(v_body, "motion_factors: v_body")
    cov = real_array(cov, "motion_factors: cov")
    if v_body.ndim != 2 or v_body.shape[1] != 3:
        raise InputError(f"motion_factors: v_body must have shape (K, 3) (m/s), got {v_body.shape}")
    count = len(v_body)
    if cov.shape not in ((count, 3), (count, 3, 3)):
        raise InputError(
            f"motion_factors: cov must have shape ({count}, 3) (variances) or ({count}, 3, 3), got {cov.shape}"
        )
    index = np.arange(count) if keys is None else np.asarray(keys)
    if index.shape != (count,) or not np.issubdtype(index.dtype, np.integer):
        raise InputError(f"motion_factors: keys must be {count} integer keyframe indices, got {repr(keys)[:60]}")
    if scale_keys is not None and len(scale_keys) != count:
        raise InputError(f"motion_factors: scale_keys must be {count} keys, got {len(scale_keys)}")
    scales = [None] * count if scale_keys is None else [int(key) for key in scale_keys]
    factors = []
    for row, k in enumerate(index.tolist()):
        try:
            factors.append(MotionFactor(pose_key(k), vel_key(k), v_body[row], cov[row], mount_key, scales[row]))
        except InputError as error:
            raise InputError(f"motion_factors: row {row} (keyframe {k}): {error}") from None
    return factors


def covariance_problem(cov: np.ndarray) -> str | None:
    """Why finite ``cov`` ((3,) variances or 3x3, (m/s)^2) is not a covariance, or None."""
    if cov.ndim == 1:
        return None if np.all(cov > 0) else f"variances must be positive, got {cov.tolist()}"
    if np.abs(cov - cov.T).max() > SYMMETRY_TOL * np.abs(cov).max():
        return "must be symmetric"
    smallest = float(np.linalg.eigvalsh(cov).min())
    return None if smallest > 0 else f"must be positive definite, min eigenvalue {smallest:.3g}"


class MotionTerms:
    """``MotionFactor``s evaluated together in numpy: the same errors, whitening and Jacobians, for
    ``solve_with_python_factors(..., extra=(terms,))`` instead of adding the factors to the graph (module docstring:
    ~0.25 ms against ~4 ms per error of 1,000 factors, ~4 ms against ~10 ms per linearisation).

    States are read in bulk (``gtsam.utilities.extractPose3`` / ``extractVectors``); a velocity key whose symbol
    character also names non-vector values falls back to ``Values.atVector`` per key."""

    def __init__(self, factors: list[MotionFactor]):
        mounts = {f.mount_key for f in factors}
        if len(mounts) > 1:
            raise GraphError(f"MotionTerms: the factors must share one mount key (or none), got {len(mounts)}")
        self.mount_key = mounts.pop() if mounts else None
        scaled = [f.scale_key is not None for f in factors]
        if (any(scaled) and not all(scaled)) or (self.mount_key is not None and any(scaled)):
            raise GraphError(
                "MotionTerms: the factors must all have a speed scale or none, and not both a scale and a mount "
                "rotation (a JacobianFactor of four keys); add such factors to the graph instead"
            )
        self.scale_keys = np.array([f.scale_key for f in factors], dtype=np.uint64) if any(scaled) else None
        self.pose_keys = np.array([f.pose_key for f in factors], dtype=np.uint64)
        self.vel_keys = np.array([f.vel_key for f in factors], dtype=np.uint64)
        self.v_body = np.array([f.v_body for f in factors]).reshape(-1, 3)
        # W with W^T W = cov^-1 (the inverse Cholesky factor), as GTSAM's Gaussian noise whitens
        self.whiten = np.linalg.inv(np.linalg.cholesky(np.array([f.cov for f in factors]).reshape(-1, 3, 3)))
        self._unit = gtsam.noiseModel.Unit.Create(3)

    def error(self, values: gtsam.Values) -> float:
        """The sum of the factors' ``error``: 0.5 e^T cov^-1 e."""
        return 0.5 * float(np.sum(self._whitened(values)[2] ** 2))

    def linearize(self, values: gtsam.Values) -> gtsam.GaussianFactorGraph:
        """One whitened ``JacobianFactor`` per factor on (pose key, velocity key), as ``MotionFactor.linearize``."""
        rot, u, white = self._whitened(values)
        d_pose = np.zeros((len(u), 3, 6))  # [skew(R^T v), 0]
        d_pose[:, :, 0:3] = _skew(u)
        d_vel = np.swapaxes(rot, 1, 2)
        mount = self._mount(values)
        if mount is not None:  # e = M^T u - v_body: d e / d u = M^T, d e / d M = skew(M^T u)
            d_pose, d_vel = mount.T @ d_pose, mount.T @ d_vel
            a_mount = self.whiten @ _skew(u @ mount)
        a_pose, a_vel = self.whiten @ d_pose, self.whiten @ d_vel
        if self.scale_keys is not None:  # e = u - s v_body: d e / d s = -v_body
            a_scale = -(self.whiten @ self.v_body[:, :, None])
            scale_keys = self.scale_keys.tolist()
        out = gtsam.GaussianFactorGraph()
        for k, (pose_key, vel_key) in enumerate(zip(self.pose_keys.tolist(), self.vel_keys.tolist(), strict=True)):
            if self.scale_keys is not None:
                out.push_back(
                    gtsam.JacobianFactor(
                        pose_key, a_pose[k], vel_key, a_vel[k], scale_keys[k], a_scale[k], -white[k], self._unit
                    )
                )
            elif mount is None:
                out.push_back(gtsam.JacobianFactor(pose_key, a_pose[k], vel_key, a_vel[k], -white[k], self._unit))
            else:
                out.push_back(
                    gtsam.JacobianFactor(
                        pose_key, a_pose[k], vel_key, a_vel[k], self.mount_key, a_mount[k], -white[k], self._unit
                    )
                )
        return out

    def _mount(self, values: gtsam.Values) -> np.ndarray | None:
        return None if self.mount_key is None else values.atRot3(self.mount_key).matrix()

    def _whitened(self, values: gtsam.Values) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rotations R (K, 3, 3), u = R^T v (K, 3) and the whitened errors W (M^T u - v_body) (K, 3) (M: the mount
        rotation, identity without one)."""
        rot = poses_of(values, self.pose_keys, "MotionTerms")[:, :9].reshape(-1, 3, 3)
        vel = self._velocities(values)
        v_in_body = np.einsum("kji,kj->ki", rot, vel)
        mount = self._mount(values)
        measured = v_in_body if mount is None else v_in_body @ mount
        predicted = self.v_body if self.scale_keys is None else self._vectors(values, self.scale_keys, 1) * self.v_body
        return rot, v_in_body, np.einsum("kij,kj->ki", self.whiten, measured - predicted)

    def _velocities(self, values: gtsam.Values) -> np.ndarray:
        return self._vectors(values, self.vel_keys, 3)

    @staticmethod
    def _vectors(values: gtsam.Values, wanted: np.ndarray, dim: int) -> np.ndarray:
        """(len(wanted), dim) the ``Vector`` values at keys ``wanted``, read in bulk per symbol character."""
        keys = np.array(values.keys(), dtype=np.uint64)
        out = np.empty((len(wanted), dim))
        chars = wanted >> np.uint64(56)  # gtsam.Symbol: the character in the top byte
        for char in np.unique(chars):
            mine = chars == char
            named = keys[(keys >> np.uint64(56)) == char]
            rows = gtsam.utilities.extractVectors(values, chr(int(char)))
            if rows.shape == (len(named), dim):
                out[mine] = rows[key_rows(named, wanted[mine], "velocity" if dim == 3 else "scale", "MotionTerms")]
            else:  # the character also names other values: one by one
                out[mine] = [values.atVector(int(key)) for key in wanted[mine]]
        return out


def _skew(w: np.ndarray) -> np.ndarray:
    """(K, 3, 3) cross-product matrices of (K, 3) vectors."""
    out = np.zeros((len(w), 3, 3))
    out[:, 0, 1], out[:, 0, 2], out[:, 1, 2] = -w[:, 2], w[:, 1], -w[:, 0]
    out[:, 1, 0], out[:, 2, 0], out[:, 2, 1] = w[:, 2], -w[:, 1], w[:, 0]
    return out


@dataclass(frozen=True, eq=False)
class Solution:
    """``solve_with_python_factors``' result: the solved ``values``, its graph ``error`` and the accepted steps."""

    values: gtsam.Values
    error: float
    iterations: int


def solve_with_python_factors(
    graph: gtsam.NonlinearFactorGraph,
    initial: gtsam.Values,
    params: gtsam.LevenbergMarquardtParams | None = None,
    extra: tuple = (),
) -> Solution:
    """``gtsam.LevenbergMarquardtOptimizer(graph, initial, params).optimize()``, stepped from Python so that Python
    factors (``MotionFactor``, ``LearnedImuFactor``) get the ``Values`` by reference instead of a copy each
    (module docstring). GTSAM's rules: COLAMD ordering (of the whole linear system), identity damping
    ``sqrt(lambda) I`` per variable, multifrontal Cholesky (or QR, as ``params`` say; an indeterminate damped system
    is a failed try), a step kept when the model fidelity exceeds ``minModelFidelity`` (then lambda / factor), else
    lambda * factor up to ``lambdaUpperBound``; stop on the relative / absolute decrease or ``maxIterations``. Only
    those modes: diagonal damping, an adaptive lambda factor, another linear solver or ordering raise. (GTSAM 4.3's
    own LM eliminates in place, which Python cannot call: on a 1,000-keyframe IMU + GPS graph this loop takes ~1.4x
    its time.)

    ``extra``: terms evaluated in bulk besides ``graph``, each with ``error(values) -> float`` and
    ``linearize(values) -> gtsam.GaussianFactorGraph`` (whitened, as a factor's ``linearize`` gives it)."""
    params = params or gtsam.LevenbergMarquardtParams()
    if (
        params.getDiagonalDamping()
        or not params.getUseFixedLambdaFactor()
        or params.getLinearSolverType() not in ("MULTIFRONTAL_CHOLESKY", "MULTIFRONTAL_QR")
        or params.getOrderingType() != "COLAMD"
    ):
        raise InputError(
            "solve_with_python_factors: only GTSAM's default LM modes (identity damping, fixed lambda factor, "
            "MULTIFRONTAL_CHOLESKY or _QR, COLAMD); use gtsam.LevenbergMarquardtOptimizer for the others"
        )

    def total_error(at: gtsam.Values) -> float:
        return graph.error(at) + sum(term.error(at) for term in extra)

    values = gtsam.Values(initial)  # owned by Python: the callbacks get it by reference

    def linearize(at: gtsam.Values) -> gtsam.GaussianFactorGraph:
        linear = graph.linearize(at)
        for term in extra:
            linear.push_back(term.linearize(at))
        return linear

    # COLAMD of the whole system, as GTSAM's LM orders a graph holding every factor: ordering ``graph`` alone would
    # eliminate a variable only ``extra`` ties to the rest (the motion factors' mounting rotation) first, filling in
    # everything (KITTI seq 04: 56 s against 1.4 s)
    linear = linearize(values)
    ordering = gtsam.Ordering.ColamdGaussianFactorGraph(linear)
    if params.getLinearSolverType() == "MULTIFRONTAL_QR":

        def solve_linear(system):
            return system.eliminateMultifrontal(ordering, gtsam.EliminateQR).optimize()

    else:

        def solve_linear(system):
            return system.optimize(ordering)

    damping = _Damping(values)
    lam, error, iterations = params.getlambdaInitial(), total_error(values), 0
    while iterations < params.getMaxIterations() and error > params.getErrorTol():
        linear = linear if iterations == 0 else linearize(values)
        new_values, new_error, lam = _lm_step(total_error, linear, values, error, lam, params, damping, solve_linear)
        if new_values is None:  # no step: the decrease is negligible, or lambda reached its bound
            break
        iterations += 1
        decrease = error - new_error
        values, error = new_values, new_error
        if decrease <= params.getAbsoluteErrorTol() or decrease <= params.getRelativeErrorTol() * (error + decrease):
            break
    return Solution(values, error, iterations)


class _Damping:
    """GTSAM LM's damping, ``sqrt(lambda) I`` on every variable: one unit ``JacobianFactor`` per key built once,
    whose noise sigma ``1 / sqrt(lambda)`` is set in place per try (~4x cheaper than building them again)."""

    def __init__(self, values: gtsam.Values):
        self.factors = []
        self.graph = gtsam.GaussianFactorGraph()
        unit = {}
        for key, dim in values.dims().items():
            if dim not in unit:
                unit[dim] = (np.eye(dim), np.zeros(dim), gtsam.noiseModel.Unit.Create(dim))
            factor = gtsam.JacobianFactor(key, *unit[dim])
            self.factors.append((factor, dim))
            self.graph.push_back(factor)  # shared, not copied: setModel below reaches the graph
        self.dims = set(unit)

    def damped(self, linear: gtsam.GaussianFactorGraph, lam: float) -> gtsam.GaussianFactorGraph:
        sigmas = {dim: np.full(dim, 1.0 / np.sqrt(lam)) for dim in self.dims}
        for factor, dim in self.factors:
            factor.setModel(False, sigmas[dim])
        out = gtsam.GaussianFactorGraph()
        out.push_back(linear)  # the factors are shared; elimination does not change them
        out.push_back(self.graph)
        return out


def _lm_step(total_error, linear, values, error, lam, params, damping: _Damping, solve_linear):
    """GTSAM's ``tryLambda`` loop: (new values, new error, next lambda), or (None, error, lambda) to stop."""
    old_linear_error = linear.error(values.zeroVectors())
    while True:
        try:
            delta = solve_linear(damping.damped(linear, lam))
        except RuntimeError as failure:  # GTSAM's tryLambda: an indeterminate damped system is a failed try
            if not is_indeterminate(failure):
                raise
            delta = None
        linear_change = -1.0 if delta is None else old_linear_error - linear.error(delta)
        if linear_change >= 0:
            new_values = values.retract(delta)
            new_error = total_error(new_values)
            cost_change = error - new_error
            fidelity_ok = linear_change > np.finfo(float).eps * old_linear_error
            if fidelity_ok and cost_change / linear_change > MIN_MODEL_FIDELITY:
                return new_values, new_error, max(params.getlambdaLowerBound(), lam / params.getlambdaFactor())
            if abs(cost_change) < params.getRelativeErrorTol() * error:
                return None, error, lam
        lam *= params.getlambdaFactor()
        if lam >= params.getlambdaUpperBound():
            return None, error, lam


def _finite(name: str, value, shapes: tuple[tuple[int, ...], ...], expected: str) -> np.ndarray:
    out = real_array(value, f"MotionFactor: {name}")
    if out.shape not in shapes:
        raise InputError(f"MotionFactor: {name} must have shape {expected}, got {out.shape}")
    if not np.all(np.isfinite(out)):
        raise InputError(f"MotionFactor: {name} contains NaN or Inf")
    return out
