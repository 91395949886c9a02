"""After a solve, the result checked against its own noise model: the normalised residual of each kind of factor.

For every factor of a kind (GPS, IMU, bias random walk, learned motion, prior) the squared whitened residual at the
solution, summed, and divided by that kind's degrees of freedom: chi-square per degree of freedom. The degrees of
freedom are the kind's share of the graph's redundancy (measurements minus states, m - n): for factor i with
whitened Jacobian A_i, ``r_i = dim_i - trace(A_i Sigma_i A_i^T)`` (Sigma_i the joint marginal covariance of its free
keys; keys held by a ``NonlinearEquality`` are known), the expected chi-square of that factor at the least-squares
solution of a linear-Gaussian graph (Foerstner's redundancy numbers; they sum to m - n). Divided by the factors'
dimensions instead, a sparsely constrained graph reads far below 1 though its inputs are right (keyframes every 0.1
s and a fix every 10 s: the states absorb nearly every IMU residual, 0.005 per dimension on the simulated drone, 2.2
per redundancy). With noise models that describe the data it is about 1. Far from 1 it says the inputs do not fit
their own sigmas, whatever the trajectory looks like:

- GPS well above 1: fixes in another unit or frame, a clock offset between the GPS and the IMU, GPS sigmas too small,
  or an over-confident IMU (its noise given as a variance) that leaves the misfit to the GPS;
- IMU well above 1: IMU noise given as a variance where a sigma was expected (sigma^2 << sigma), a wrong unit, a
  time offset, or a bias the graph does not model (the raw samples of the PGO ablation without bias states); IMU
  well below 1: noise given as sigma where sigma^2 was expected, or far too pessimistic;
- motion well above 1: a motion model on another platform than it learned, or variances too small.

``check`` returns one line per kind beyond ``HIGH`` or under ``LOW`` (under ``LOW`` only with at least ``LOW_MIN_DOF``
degrees of freedom: with fewer, a tiny chi-square is chance), naming these causes; ``airimu fuse`` logs them and
writes every kind's number to ``summary.json``, ``airimu ablate-pgo`` logs them and puts the GPS and IMU numbers in
its table. A robust (Huber, Cauchy) GPS noise is judged by its
Gaussian core, so that outliers it down-weighted still count.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

HIGH = 10.0  # chi-square per degree of freedom above this: the inputs contradict their sigmas
LOW = 0.01  # below this: the sigmas are far larger than the residuals
LOW_MIN_DOF = 5.0  # P(chi-square(5) < 0.05) ~ 1e-5; with 1.6 degrees of freedom (six fixes) it is ~2 %

CAUSES = {
    "gps": {
        "high": "GPS positions in another unit or frame, a clock offset between GPS and IMU, GPS sigmas too "
        "small, or IMU noise given as a variance (an over-confident IMU leaves the misfit to the GPS)",
        "low": "GPS sigmas far too large",
    },
    "imu": {
        "high": "IMU noise given as a variance (sigma^2) where a sigma is expected, IMU samples in another unit, "
        "a time offset, or a sensor bias the graph does not model (raw samples without bias states)",
        "low": "IMU noise given as sigma where sigma^2 is expected, or far too pessimistic",
    },
    "bias": {"high": "a bias random walk too small for the sensor", "low": "a bias random walk far too large"},
    "motion": {
        "high": "a motion model used on another platform or motion than it was trained on, or its variances too "
        "small (fusion.motion.cov_scale)",
        "low": "the motion model's variances far too large (fusion.motion.cov_scale)",
    },
}


@dataclass(frozen=True)
class Residual:
    """One kind of factor at the solution: how many, their dimensions summed, their degrees of freedom summed (the
    redundancy, module docstring; their dimensions where the graph's marginals could not be computed), the
    chi-square summed."""

    kind: str
    factors: int
    dim: int
    dof: float
    chi2: float
    exact: bool = True  # False: the dimensions stood in for the degrees of freedom (no low-side verdict then)

    @property
    def per_dof(self) -> float:
        return self.chi2 / self.dof if self.dof > 0 else float("nan")

    def to_json_dict(self) -> dict:
        return {
            "factors": self.factors,
            "dim": self.dim,
            "dof": self.dof,
            "dof_exact": self.exact,
            "chi2": self.chi2,
            "chi2_per_dof": self.per_dof,
        }


def kind_of(factor) -> str:
    """``"gps"``, ``"imu"``, ``"bias"``, ``"motion"`` or ``"prior"`` (anything else) by the factor's class."""
    name = type(factor).__name__
    if name == "MotionFactor":
        return "motion"
    if "GPS" in name or "Gps" in name:
        return "gps"
    if "Imu" in name or "IMU" in name:
        return "imu"
    if "ConstantBias" in name and "Between" in name:
        return "bias"
    return "prior"


def residuals(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> dict[str, Residual]:
    """Chi-square and degrees of freedom per kind of factor at ``values`` (module docstring); kinds without factors
    are left out."""
    factors = [graph.at(i) for i in range(graph.size())]
    factors = [f for f in factors if f is not None and hasattr(f, "dim")]
    known = {key for f in factors if type(f).__name__.startswith("NonlinearEquality") for key in f.keys()}
    try:
        marginals = gtsam.Marginals(graph, values)
    except RuntimeError:  # an indeterminate graph: no redundancy; the dimensions stand in (an upper bound)
        marginals = None  # (and ``check`` judges the high side only: a low chi-square per dimension is no evidence)
    dims = values.dims()
    rows = []  # (factor, kind, dim, chi2) per factor with a residual to judge
    for factor in factors:
        chi2 = _chi2(factor, values)
        if chi2 is not None:
            rows.append((factor, kind_of(factor), int(factor.dim()), chi2))
    exact = marginals is not None
    try:  # GTSAM may find the graph indeterminate only when a joint marginal is asked for
        dofs = [dim if marginals is None else _redundancy(f, values, marginals, known, dims) for f, _, dim, _ in rows]
    except RuntimeError:
        dofs, exact = [dim for _, _, dim, _ in rows], False
    sums: dict[str, list] = {}
    for (_, kind, dim, chi2), dof in zip(rows, dofs, strict=True):
        entry = sums.setdefault(kind, [0, 0, 0.0, 0.0])
        for j, value in enumerate((1, dim, dof, chi2)):
            entry[j] += value
    return {kind: Residual(kind, n, dim, dof, chi2, exact) for kind, (n, dim, dof, chi2) in sums.items()}


def _redundancy(factor, values: gtsam.Values, marginals: gtsam.Marginals, known: set, dims: dict) -> float:
    """``dim - trace(A Sigma A^T)`` of one factor: its expected chi-square at the solution (module docstring)."""
    linear = factor.linearize(values)
    jacobian, _ = linear.jacobian()  # whitened, the factor's keys' columns in order
    keys, columns, start = list(linear.keys()), [], 0
    for key in keys:
        if key not in known:
            columns += range(start, start + dims[key])
        start += dims[key]
    free = [key for key in keys if key not in known]
    if not free:
        return float(factor.dim())
    a = jacobian[:, columns]
    sigma = marginals.jointMarginalCovariance(gtsam.KeyVector(free)).fullMatrix()
    return float(factor.dim() - np.einsum("ij,jk,ik->", a, sigma, a))


def _chi2(factor, values: gtsam.Values) -> float | None:
    noise = factor.noiseModel() if hasattr(factor, "noiseModel") else None
    if isinstance(noise, gtsam.noiseModel.Robust):  # the Gaussian core, not the robust cost
        whitened = noise.noise().whiten(np.asarray(factor.unwhitenedError(values), dtype=float))
        return float(whitened @ whitened)
    if isinstance(noise, gtsam.noiseModel.Constrained) or factor.dim() == 0:
        return None  # an equality: no residual to judge
    return 2.0 * float(factor.error(values))  # error = 0.5 |whitened residual|^2


def check(found: dict[str, Residual]) -> list[str]:
    """One warning per kind whose chi-square per degree of freedom is above ``HIGH`` or below ``LOW``."""
    lines = []
    for kind, residual in found.items():
        value = residual.per_dof
        if kind not in CAUSES or not np.isfinite(value):
            continue
        low = value < LOW and residual.exact and residual.dof >= LOW_MIN_DOF
        side = "high" if value > HIGH else "low" if low else None
        if side is not None:
            bound = f"above {HIGH:g}" if side == "high" else f"below {LOW:g}"
            lines.append(
                f"the {kind.upper()} factors' normalised residual (chi-square per degree of freedom) is {value:.3g}, "
                f"{bound} (about 1 when the inputs fit their sigmas; {residual.factors} factors, {residual.dof:.3g} "
                f"degrees of freedom): likely "
                f"{CAUSES[kind][side]}{_motion_note(found, kind, side)}"
            )
    return lines


def _motion_note(found: dict[str, Residual], kind: str, side: str) -> str:
    """With motion factors in the graph, a high GPS or IMU residual may be theirs to answer for."""
    motion = found.get("motion")
    if motion is None or side != "high" or kind not in ("gps", "imu"):
        return ""
    return (
        f"; or the motion factors ({motion.factors}, normalised residual {motion.per_dof:.3g}) pulling the solution "
        "away: learned velocities over-weighted (fusion.motion.cov_scale) or a local minimum"
    )
