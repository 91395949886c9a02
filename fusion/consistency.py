"""After a solve, the result checked against its own noise model: the normalised residual of each kind of factor.

For every factor of a kind (GPS, IMU, bias random walk, prior) the squared whitened residual at the solution,
summed and divided by the factors' dimensions: chi-square per degree of freedom. With noise models that describe
the data it is of order 1 (somewhat below: the states absorb part of the residuals). Far from 1 it says the inputs
do not fit their own sigmas, whatever the trajectory looks like:

- GPS well above 1: fixes in another unit or frame, a clock offset between the GPS and the IMU, GPS sigmas too small,
  or an over-confident IMU (its noise given as a variance) that leaves the misfit to the GPS;
- IMU well above 1: IMU noise given as a variance where a sigma was expected (sigma^2 << sigma), a wrong unit or a
  time offset; IMU well below 1: noise given as sigma where sigma^2 was expected, or far too pessimistic.

``check`` returns one line per kind beyond ``HIGH`` or under ``LOW``, naming these causes; ``airimu fuse`` logs
them and writes every kind's number to ``summary.json``. A robust (Huber, Cauchy) GPS noise is judged by its
Gaussian core, so that outliers it down-weighted still count.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

HIGH = 10.0  # chi-square per degree of freedom above this: the inputs contradict their sigmas
LOW = 0.01  # below this: the sigmas are far larger than the residuals

CAUSES = {
    "gps": {"high": "GPS positions in another unit or frame, a clock offset between GPS and IMU, GPS sigmas too "
                    "small, or IMU noise given as a variance (an over-confident IMU leaves the misfit to the GPS)",
            "low": "GPS sigmas far too large"},
    "imu": {"high": "IMU noise given as a variance (sigma^2) where a sigma is expected, IMU samples in another unit, "
                    "or a time offset", "low": "IMU noise given as sigma where sigma^2 is expected, or far too "
                                               "pessimistic"},
    "bias": {"high": "a bias random walk too small for the sensor", "low": "a bias random walk far too large"},
}  # fmt: skip


@dataclass(frozen=True)
class Residual:
    """One kind of factor at the solution: how many, their dimensions summed, the chi-square summed."""

    kind: str
    factors: int
    dof: int
    chi2: float

    @property
    def per_dof(self) -> float:
        return self.chi2 / self.dof if self.dof else float("nan")

    def to_json_dict(self) -> dict:
        return {"factors": self.factors, "dof": self.dof, "chi2_per_dof": self.per_dof}


def kind_of(factor) -> str:
    """``"gps"``, ``"imu"``, ``"bias"`` or ``"prior"`` (anything else) by the factor's class."""
    name = type(factor).__name__
    if "GPS" in name or "Gps" in name:
        return "gps"
    if "Imu" in name or "IMU" in name:
        return "imu"
    if "ConstantBias" in name and "Between" in name:
        return "bias"
    return "prior"


def residuals(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> dict[str, Residual]:
    """Chi-square per kind of factor at ``values`` (module docstring); kinds without factors are left out."""
    sums: dict[str, list] = {}
    for i in range(graph.size()):
        factor = graph.at(i)
        if factor is None or not hasattr(factor, "dim"):
            continue
        chi2 = _chi2(factor, values)
        if chi2 is None:
            continue
        entry = sums.setdefault(kind_of(factor), [0, 0, 0.0])
        entry[0] += 1
        entry[1] += int(factor.dim())
        entry[2] += chi2
    return {kind: Residual(kind, n, dof, chi2) for kind, (n, dof, chi2) in sums.items()}


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
        side = "high" if value > HIGH else "low" if value < LOW else None
        if side is not None:
            bound = f"above {HIGH:g}" if side == "high" else f"below {LOW:g}"
            lines.append(
                f"the {kind.upper()} factors' normalised residual (chi-square per degree of freedom) is {value:.3g}, "
                f"{bound} (about 1 when the inputs fit their sigmas; {residual.factors} factors): likely "
                f"{CAUSES[kind][side]}"
            )
    return lines
