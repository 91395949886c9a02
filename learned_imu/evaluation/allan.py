"""Noise densities of an IMU from a still recording: the Allan deviation of each axis and its fitted lines.

``allan_noise(samples, rate_hz)`` computes the overlapping Allan deviation of each axis of (N, 3) rate samples
(gyro rad/s, acc m/s^2) with ``allantools.oadev`` (the reference implementation of the IEEE 1139 / 952 estimators,
maintained since 2014, with confidence intervals we do not need here: chosen over our own loop so that the numbers
are the ones a user of Kalibr's ``allan_variance_ros`` or of a datasheet plot would compute), on log-spaced averaging
times from one sample to a ninth of the record, and reads the three lines of the classical noise model off it:

- white noise N (``*_noise_density``: rad/s/sqrt(Hz), m/s^2/sqrt(Hz); the sigma a continuous-time model and GTSAM's
  ``PreintegrationParams`` take squared): the slope -1/2 line (adev at tau = 1 s on it);
- rate random walk K (``*_random_walk``: rad/s^2/sqrt(Hz), m/s^3/sqrt(Hz), Kalibr's bias random walk): the slope +1/2
  line (adev at tau = 3 s on it); None when the record is too short to show it;
- bias instability B (rad/s, m/s^2): the flat floor, min adev / sqrt(2 ln 2 / pi) = min adev / 0.664.

N and K come from one fit of the model's Allan variance N^2 / tau + C + K^2 tau / 3 (C: the floor) to adev^2 over
every averaging time, each weighted by its relative error (non-negative least squares): the -1/2 and +1/2 lines
without choosing where they hold.

``from_datasheet(value, unit)`` converts a datasheet's units to these: deg/sqrt(h) (angle random walk), deg/h (bias
instability), deg/s/sqrt(Hz), ug/sqrt(Hz), mg, ug, m/s/sqrt(h) (velocity random walk).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from airimu_core.errors import InputError

G0 = 9.80665  # m/s^2 per g (datasheets' g)
MIN_SAMPLES = 100
BIAS_INSTABILITY_FACTOR = math.sqrt(2.0 * math.log(2.0) / math.pi)  # 0.664

DATASHEET_UNITS = {  # to rad/s/sqrt(Hz), rad/s, m/s^2/sqrt(Hz), m/s^2 (SI of the noise model)
    "rad/s/sqrt(Hz)": 1.0,
    "deg/s/sqrt(Hz)": math.pi / 180.0,
    "deg/sqrt(h)": math.pi / 180.0 / 60.0,  # angle random walk: deg/sqrt(h) = (deg/60) / sqrt(s)
    "deg/h": math.pi / 180.0 / 3600.0,  # bias instability
    "rad/s": 1.0,
    "m/s^2/sqrt(Hz)": 1.0,
    "ug/sqrt(Hz)": G0 * 1e-6,
    "mg/sqrt(Hz)": G0 * 1e-3,
    "m/s/sqrt(h)": 1.0 / 60.0,  # velocity random walk
    "mg": G0 * 1e-3,
    "ug": G0 * 1e-6,
    "m/s^2": 1.0,
}


def from_datasheet(value: float, unit: str) -> float:
    """``value`` in a datasheet ``unit`` (a key of ``DATASHEET_UNITS``) in the noise model's SI unit."""
    if unit not in DATASHEET_UNITS:
        raise InputError(f"datasheet unit {unit!r}: expected one of {', '.join(DATASHEET_UNITS)}")
    if not (math.isfinite(value) and value > 0):
        raise InputError(f"datasheet value {value!r} {unit}: expected a positive number")
    return float(value) * DATASHEET_UNITS[unit]


@dataclass(frozen=True)
class AxisNoise:
    """One axis: the averaging times ``tau`` (s) and Allan deviation ``adev`` (the samples' unit), and the fitted
    ``white`` (N, unit/sqrt(Hz)), ``bias_instability`` (B, unit, at ``bias_tau`` s) and ``random_walk`` (K,
    unit*sqrt(Hz)/s; None when no +1/2 slope shows)."""

    tau: np.ndarray
    adev: np.ndarray
    white: float
    bias_instability: float
    bias_tau: float
    random_walk: float | None


def allan_noise(samples, rate_hz: float) -> list[AxisNoise]:
    """The fitted noise of each axis of (N, 3) still ``samples`` taken at ``rate_hz`` (module docstring)."""
    import allantools

    x = np.asarray(samples, dtype=float)
    if x.ndim != 2 or x.shape[1] != 3 or len(x) < MIN_SAMPLES or not np.all(np.isfinite(x)):
        raise InputError(f"allan_noise: need (N, 3) finite samples with N >= {MIN_SAMPLES}, got shape {x.shape}")
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise InputError(f"allan_noise: rate_hz must be positive, got {rate_hz}")
    top = len(x) / 9.0 / rate_hz  # the longest averaging time with at least 9 clusters
    taus = np.unique(np.round(np.logspace(0.0, math.log10(len(x) / 9.0), 60)).astype(int)) / rate_hz
    out = []
    for axis in range(3):
        tau, adev, _, _ = allantools.oadev(x[:, axis], rate=rate_hz, data_type="freq", taus=taus[taus <= top])
        out.append(_fit(np.asarray(tau), np.asarray(adev)))
    return out


def _fit(tau: np.ndarray, adev: np.ndarray) -> AxisNoise:
    """The model's Allan variance N^2 / tau + C + K^2 tau / 3 fitted to adev^2 by non-negative least squares, each
    averaging time weighted by its relative error (every decade counts alike); B from the floor of the data."""
    from scipy.optimize import nnls

    avar = adev**2
    design = np.stack([1.0 / tau, np.ones_like(tau), tau / 3.0], axis=1) / avar[:, None]
    (white2, _, walk2), _ = nnls(design, np.ones_like(tau))
    floor = int(np.argmin(adev))
    walk = math.sqrt(walk2) if walk2 > 0 else None
    instability = float(adev[floor] / BIAS_INSTABILITY_FACTOR)
    return AxisNoise(tau, adev, math.sqrt(white2), instability, float(tau[floor]), walk)


def kalibr_yaml(gyro: list[AxisNoise], acc: list[AxisNoise], rate_hz: float) -> dict:
    """Kalibr's ``imu.yaml`` fields (the mean over the three axes; a random walk the record cannot show: null)."""

    def mean(values):
        values = [v for v in values if v is not None]
        return float(np.mean(values)) if len(values) == 3 else None

    return {
        "accelerometer_noise_density": mean(a.white for a in acc),  # m/s^2/sqrt(Hz)
        "accelerometer_random_walk": mean(a.random_walk for a in acc),  # m/s^3/sqrt(Hz)
        "gyroscope_noise_density": mean(g.white for g in gyro),  # rad/s/sqrt(Hz)
        "gyroscope_random_walk": mean(g.random_walk for g in gyro),  # rad/s^2/sqrt(Hz)
        "update_rate": float(rate_hz),  # Hz
    }


def gtsam_covariances(kalibr: dict) -> dict:
    """GTSAM ``PreintegrationCombinedParams``' continuous-time covariances (sigma^2 on the diagonal) from Kalibr's
    densities: ``setGyroscopeCovariance`` (rad^2/s), ``setAccelerometerCovariance`` (m^2/s^3),
    ``setBiasOmegaCovariance`` (rad^2/s^3), ``setBiasAccCovariance`` (m^2/s^5); null where the density is."""

    def squared(key):
        value = kalibr[key]
        return None if value is None else float(value) ** 2

    return {
        "gyroscope_covariance": squared("gyroscope_noise_density"),
        "accelerometer_covariance": squared("accelerometer_noise_density"),
        "bias_omega_covariance": squared("gyroscope_random_walk"),
        "bias_acc_covariance": squared("accelerometer_random_walk"),
    }
