"""A ``gtsam.PreintegratedImuMeasurements`` holding given deltas, covariance and bias Jacobians, so that the
built-in C++ ``gtsam.ImuFactor`` can carry a learned measurement at full speed.

GTSAM's Python wrapper has no constructor from preintegrated values, but a pim round-trips through its
``serialize()`` text archive, an ordered list of numbers: ... deltaTij, the tangent vector zeta = [theta, p, v],
H_biasAcc (9x3), H_biasOmega (9x3), preintMeasCov (9x9) (matrices column-major, each behind its size markers).
We serialise a template pim, write our values into those slots, deserialise, and read everything back: if
GTSAM's archive layout ever differs, the markers or the read-back check fail with ``PimLayoutError`` rather
than producing a wrong factor.

Conventions: as ``LearnedImuFactor`` (deltas from i to j, covariance in GTSAM's tangent order, bias Jacobian
w.r.t. a bias [acc, gyro] subtracted from the samples, gravity the world-frame vector).
"""

from __future__ import annotations

import functools
from importlib.metadata import version

import gtsam
import numpy as np

from airimu_core.errors import PimLayoutError

_GTSAM_VERSION = version("gtsam")
_SENTINEL_DT = 0.123456789  # s, a value the template's archive cannot contain by chance


def pim_from_deltas(
    delta_rot, delta_pos, delta_vel, dt, cov, bias_jacobian, gravity
) -> gtsam.PreintegratedImuMeasurements:
    """A tangent ``PreintegratedImuMeasurements`` with exactly these preintegrated values (zero bias estimate)."""
    delta_rot = np.asarray(delta_rot, dtype=float)
    theta = gtsam.Rot3.Logmap(gtsam.Rot3(delta_rot))
    to_tangent = gtsam.SO3.LogmapDerivative(theta)  # right perturbation -> theta coordinates
    jac = np.array(bias_jacobian, dtype=float)
    jac[0:3] = to_tangent @ jac[0:3]
    zeta = np.concatenate([theta, np.asarray(delta_pos, dtype=float), np.asarray(delta_vel, dtype=float)])
    cov = np.asarray(cov, dtype=float)

    params, template, i = _template(tuple(float(g) for g in np.asarray(gravity, dtype=float)))
    tokens = list(template)
    slots = {  # offset from the deltaTij token -> (expected marker tokens before, values to write)
        3: (["0", "0"], zeta),
        16: (["0", "0", "9", "3"], jac[:, 0:3].ravel(order="F")),
        45: (["9", "3"], jac[:, 3:6].ravel(order="F")),
        76: (["0", "0", "9", "9"], cov.ravel(order="F")),
    }
    tokens[i] = _fmt(float(dt))
    for offset, (marker, values) in slots.items():
        if tokens[i + offset - len(marker) : i + offset] != marker:
            raise PimLayoutError(f"gtsam {_GTSAM_VERSION}: unexpected serialisation layout at +{offset}")
        tokens[i + offset : i + offset + len(values)] = [_fmt(v) for v in values]
    pim = gtsam.PreintegratedImuMeasurements(params, gtsam.imuBias.ConstantBias())
    pim.deserialize(" ".join(tokens))
    _check_read_back(pim, dt, zeta, cov, delta_rot)
    return pim


@functools.lru_cache(maxsize=8)
def _template(gravity: tuple[float, float, float]) -> tuple[gtsam.PreintegrationParams, tuple[str, ...], int]:
    """Params for this gravity, the archive tokens of a template pim, and the index of its deltaTij token."""
    params = gtsam.PreintegrationParams(np.array(gravity))
    for setter in (params.setGyroscopeCovariance, params.setAccelerometerCovariance, params.setIntegrationCovariance):
        setter(np.eye(3))  # never used: the pim integrates nothing more
    template = gtsam.PreintegratedImuMeasurements(params, gtsam.imuBias.ConstantBias())
    template.integrateMeasurement(np.array([0.0, 0.0, 1.0]), np.zeros(3), _SENTINEL_DT)
    tokens = tuple(template.serialize().split())
    return params, tokens, _find(list(tokens), _SENTINEL_DT)


def _fmt(value: float) -> str:
    return format(value, ".17e")


def _find(tokens: list[str], value: float) -> int:
    try:
        return tokens.index(_fmt(value))
    except ValueError:
        raise PimLayoutError(f"gtsam {_GTSAM_VERSION}: deltaTij not found in the serialisation") from None


def _check_read_back(pim, dt, zeta, cov, delta_rot) -> None:
    ok = (
        abs(pim.deltaTij() - dt) <= 1e-12 * max(1.0, abs(dt))
        and np.allclose(pim.preintegrated(), zeta, rtol=1e-12, atol=1e-15)
        and np.allclose(pim.preintMeasCov(), cov, rtol=1e-12, atol=0)
        and np.allclose(pim.deltaRij().matrix(), delta_rot, atol=1e-9)
    )
    if not ok:
        raise PimLayoutError(f"gtsam {_GTSAM_VERSION}: the rebuilt preintegration does not read back")
