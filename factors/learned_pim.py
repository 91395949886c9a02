"""GTSAM's own preintegration fed with the learned model: corrected samples and their per-sample noise.

``gtsam.PreintegratedImuMeasurements`` (and ``PreintegratedCombinedMeasurements``) keep a shared pointer to their
params, so setting the gyroscope and accelerometer covariance before each ``integrateMeasurement`` applies that
sample's learned noise. The result drives ``gtsam.ImuFactor`` (``learned_pim``) or ``gtsam.CombinedImuFactor``
with bias states ``B(i)`` (``learned_combined_pim``) at C++ speed with the learned covariance; everything else is
GTSAM's integration, so whatever the given ``params`` hold (gravity, ``bodyPSensor``, ``omegaCoriolis``, the
integration covariance, the combined params' bias random walk) is honoured as GTSAM honours it. The caller's params
are copied, never changed.

Conventions: gyro rad/s and acc m/s^2 (specific force) in the IMU frame; noise given as continuous-time
``*_cov`` densities (sigma^2: rad^2/s, m^2/s^3) exactly as ``PreintegrationParams.setGyroscopeCovariance`` takes
them. Gravity comes from ``params`` or is given explicitly (``gravity_m_s2``: the magnitude for ``MakeSharedU``,
z-up world, or the world-frame vector); there is no default, so that a graph built with 9.8 does not get 9.81.

``biasHat``: preintegrating around a bias estimate (``bias=``) is GTSAM's re-linearisation: rebuild each interval's
preintegration at the solver's current bias, as ``IMUKittiExampleGPS.py`` does; the factor then corrects only the
(small) remaining difference to first order.
"""

from __future__ import annotations

import logging
import sys

import gtsam
import numpy as np

from airimu_core.errors import InputError, real_array
from factors.noise import noise_mismatch

# an IMU on Earth measures about g of specific force; a median below this over an interval (not a brief free fall)
# means the samples are not m/s^2 of specific force (swapped with the gyro, or in g)
MIN_MEDIAN_SPECIFIC_FORCE = 3.0  # m/s^2
MIN_SAMPLES_FOR_GRAVITY_CHECK = 10
# a constant noise above this (sigma 1 rad/s/sqrt(Hz), 10 m/s^2/sqrt(Hz)) is no IMU's: another unit, or sigma^4
MAX_COV = {"gyro_cov": 1.0, "acc_cov": 100.0}
# a median sample period above this is no IMU's (seconds given in another unit, or a total duration as dt)
MAX_MEDIAN_DT_S = 0.11  # s: an IMU slower than ~9 Hz is none (KITTI's synced OXTS, the slowest here: 0.1 s)
MIN_SAMPLES_FOR_RATE_CHECK = 3
GRAVITY_RANGE = (9.7, 9.9)  # m/s^2: Earth's gravity from the equator to the poles, sea level to 10 km
log = logging.getLogger(__name__)


def learned_pim(
    gyro,
    acc,
    dt,
    gyro_cov,
    acc_cov,
    gravity_m_s2=None,
    integration_cov: float | None = None,
    bias: gtsam.imuBias.ConstantBias | None = None,
    *,
    params: gtsam.PreintegrationParams | None = None,
) -> gtsam.PreintegratedImuMeasurements:
    """Preintegrate corrected samples with per-sample learned noise into GTSAM's tangent preintegration.

    Args:
        gyro, acc: (N, 3) corrected samples, rad/s and m/s^2, IMU frame.
        dt: (N,) or float, seconds per sample.
        gyro_cov, acc_cov: (N, 3) per-sample diagonal noise densities, sigma^2 (or (3,) / float for constant).
        gravity_m_s2: gravity magnitude for ``PreintegrationParams.MakeSharedU`` (z-up world) or the (3,) world-frame
            vector, m/s^2; give this or ``params``.
        integration_cov: GTSAM's integration covariance (m^2/s); default: ``params``' own, else 0 (which matches
            ``learned_imu.preintegrate``).
        bias: the bias estimate to preintegrate around (zero by default; the learned samples are corrected).
        params: a ``gtsam.PreintegrationParams`` (copied) for gravity, ``bodyPSensor``, ``omegaCoriolis`` and the
            integration covariance; its gyroscope and accelerometer covariances are replaced by the learned ones.
    """
    gyro, acc, dt, gyro_cov, acc_cov = _checked(gyro, acc, dt, gyro_cov, acc_cov)
    params = _params(gtsam.PreintegrationParams, params, gravity_m_s2, integration_cov)
    pim = gtsam.PreintegratedImuMeasurements(params, bias or gtsam.imuBias.ConstantBias())
    _integrate(pim, params, gyro, acc, dt, gyro_cov, acc_cov)
    return pim


def learned_combined_pim(
    gyro,
    acc,
    dt,
    gyro_cov,
    acc_cov,
    params: gtsam.PreintegrationCombinedParams,
    bias: gtsam.imuBias.ConstantBias | None = None,
) -> gtsam.PreintegratedCombinedMeasurements:
    """As ``learned_pim``, into GTSAM's ``PreintegratedCombinedMeasurements`` for ``gtsam.CombinedImuFactor``
    (keys X(i), V(i), X(j), V(j), B(i), B(j)); the bias random walk (``setBiasAccCovariance``,
    ``setBiasOmegaCovariance``, continuous-time sigma^2) and everything else come from ``params`` (copied)."""
    if not isinstance(params, gtsam.PreintegrationCombinedParams):
        raise TypeError(
            "learned_combined_pim: params must be a gtsam.PreintegrationCombinedParams (it holds the bias random "
            f"walk), got {type(params).__name__}"
        )
    gyro, acc, dt, gyro_cov, acc_cov = _checked(gyro, acc, dt, gyro_cov, acc_cov)
    params = _params(gtsam.PreintegrationCombinedParams, params, None, None)
    pim = gtsam.PreintegratedCombinedMeasurements(params, bias or gtsam.imuBias.ConstantBias())
    _integrate(pim, params, gyro, acc, dt, gyro_cov, acc_cov)
    return pim


def _integrate(pim, params, gyro, acc, dt, gyro_cov, acc_cov) -> None:
    for k in range(len(gyro)):
        params.setGyroscopeCovariance(np.diag(gyro_cov[k]))
        params.setAccelerometerCovariance(np.diag(acc_cov[k]))
        pim.integrateMeasurement(acc[k], gyro[k], dt[k])


def _params(kind, given, gravity_m_s2, integration_cov):
    """A private params object of ``kind``: a copy of ``given``, or new for ``gravity_m_s2``."""
    if given is None and gravity_m_s2 is None:
        raise ValueError("learned_pim: give params= (a gtsam.PreintegrationParams) or gravity_m_s2=: no default")
    if given is not None and gravity_m_s2 is not None:
        raise ValueError("learned_pim: give either params= or gravity_m_s2=, not both (params hold the gravity)")
    if given is not None:
        if not isinstance(given, gtsam.PreintegrationParams):
            raise TypeError(f"learned_pim: params must be a gtsam.PreintegrationParams, got {type(given).__name__}")
        params = kind(np.zeros(3))
        params.deserialize(given.serialize())  # a copy: the per-sample covariances must not reach the caller's
    elif np.ndim(gravity_m_s2) == 0:
        params = kind.MakeSharedU(float(gravity_m_s2))
    else:
        params = kind(np.asarray(gravity_m_s2, dtype=float).reshape(3))
    gravity = float(np.linalg.norm(params.n_gravity))
    if not GRAVITY_RANGE[0] <= gravity <= GRAVITY_RANGE[1]:
        where = "params.n_gravity" if given is not None else "gravity_m_s2"
        raise ValueError(
            f"learned_pim: {where} has magnitude {gravity:.4g} m/s^2, not Earth's gravity ({GRAVITY_RANGE[0]:g}-"
            f"{GRAVITY_RANGE[1]:g}): give it in m/s^2 (9.81, not 1 g), as the magnitude or the world-frame vector"
        )
    if integration_cov is not None:
        if not (np.isfinite(integration_cov) and integration_cov >= 0):
            raise ValueError(f"learned_pim: integration_cov must be finite and >= 0, got {integration_cov!r}")
        params.setIntegrationCovariance(np.eye(3) * integration_cov)
    elif given is None:
        params.setIntegrationCovariance(np.zeros((3, 3)))
    return params


def _checked(gyro, acc, dt, gyro_cov, acc_cov):
    gyro = _samples("gyro", gyro)
    acc = _samples("acc", acc)
    n = len(gyro)
    if acc.shape != gyro.shape:
        raise ValueError(f"learned_pim: gyro {gyro.shape} and acc {acc.shape} must both be (N, 3)")
    dt = np.broadcast_to(real_array(dt, "learned_pim: dt"), (n,))
    if not np.all(np.isfinite(dt)) or np.any(dt <= 0):
        raise ValueError("learned_pim: dt must be positive and finite for every sample")
    step = float(np.median(dt))
    # one or two samples of which one spans a gap (a stream's interval across KITTI's 1-2-s losses) have no median
    # that tells the gap from a wrong unit; with one step for every sample, or three and more, it does
    if step > MAX_MEDIAN_DT_S and (n >= MIN_SAMPLES_FOR_RATE_CHECK or np.all(dt == dt[0])):
        raise ValueError(
            f"learned_pim: the median dt is {step:.3g} s ({n} samples: {step * n:.3g} s preintegrated), slower than "
            f"any IMU ({1 / MAX_MEDIAN_DT_S:.0f} Hz): is it the keyframe interval? dt is each sample's own step, "
            "t[i+1] - t[i], in seconds"
        )
    force = float(np.median(np.linalg.norm(acc, axis=1)))
    if n >= MIN_SAMPLES_FOR_GRAVITY_CHECK and force < MIN_MEDIAN_SPECIFIC_FORCE:
        raise ValueError(
            f"learned_pim: the median |acc| is {force:.3g} m/s^2, far from gravity (~9.8) for a specific force: "
            "are gyro and acc swapped, or is acc in g? (arguments: gyro rad/s first, then acc m/s^2)"
        )
    covs = _densities("gyro_cov", gyro_cov, n), _densities("acc_cov", acc_cov, n)
    for sensor, given, cov, samples in (("gyro", gyro_cov, covs[0], gyro), ("acc", acc_cov, covs[1], acc)):
        if np.ndim(given) <= 1:  # a constant someone typed (a model's per-sample noise rightly differs from it)
            sigma = float(np.sqrt(cov.max()))
            message = noise_mismatch(sensor, sigma, samples, dt)
            site = _call_site()
            if message and (site, sensor) not in _WARNED:  # once per calling line, not once per interval
                _WARNED.add((site, sensor))
                log.warning(
                    "learned_pim (called from %s:%d): %s_cov %.3g (sigma %.3g): %s",
                    *site,
                    sensor,
                    sigma**2,
                    sigma,
                    message,
                )
    return gyro, acc, dt, *covs


_WARNED: set = set()  # (call site, sensor) pairs warned about


def _call_site() -> tuple[str, int]:
    """(file, line) of the first caller outside this module."""
    frame = sys._getframe(1)
    while frame is not None and frame.f_code.co_filename == __file__:
        frame = frame.f_back
    return ("?", 0) if frame is None else (frame.f_code.co_filename, frame.f_lineno)


def _samples(name: str, value) -> np.ndarray:
    out = real_array(value, f"learned_pim: {name}")
    if out.ndim != 2 or out.shape[1] != 3 or len(out) == 0:
        raise ValueError(f"learned_pim: {name} must be (N, 3) with N >= 1, got shape {out.shape}")
    if not np.all(np.isfinite(out)):
        raise ValueError(f"learned_pim: {name} contains NaN or Inf")
    return out


def _densities(name: str, value, n: int) -> np.ndarray:
    try:
        out = np.broadcast_to(real_array(value, f"learned_pim: {name}"), (n, 3))
    except InputError:
        raise
    except ValueError:
        raise ValueError(f"learned_pim: {name} must be a float, (3,) or (N, 3); got {np.shape(value)}") from None
    if not np.all(np.isfinite(out)) or np.any(out <= 0):
        raise ValueError(
            f"learned_pim: {name} must be finite and positive (a noise density, sigma^2): zero would make GTSAM's "
            "noise model a sigma-0 constraint"
        )
    limit = MAX_COV[name]
    # only a constant (float or (3,)) is a value someone typed; a per-sample array is a model's output, which may
    # rightly be huge where it distrusts a sample (the KITTI model gives 596 m^2/s^3 inside GTSAM's gap rows)
    if np.ndim(value) <= 1 and np.any(out > limit):
        raise ValueError(
            f"learned_pim: {name} {float(out.max()):.3g} is above {limit:g}, orders of magnitude beyond any IMU: "
            "a sigma^2 is expected (rad^2/s, m^2/s^3); is it in other units?"
        )
    return out
