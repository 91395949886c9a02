"""Seeded IMU simulator: the embedded default data source for demos, examples and tests.

A smooth trajectory (profile ``"drone"``, ``"handheld"``, ``"car"``, or ``"still"``: at rest) gives ground truth at
the sample times;
the clean IMU is defined so that the standard discrete integrator reproduces it exactly:

    gyro_k = Log(R_k^T R_{k+1}) / dt,   acc_k = R_k^T ((v_{k+1} - v_k) / dt - g),
    p_{k+1} = p_k + (v_k + v_{k+1}) dt / 2,

(``R_{k+1} = R_k Exp(gyro_k dt)``, ``v_{k+1} = v_k + (R_k acc_k + g) dt``, ``p_{k+1} = p_k + v_k dt +
(R_k acc_k + g) dt^2 / 2``), so integrating the clean IMU from the true start state tracks the ground truth to
float64 round-off, and every error a test sees is the error model's. The error model (``ImuErrorModel``, values
from named grades; a zero field switches that effect off), per sensor:

    measured = M (clean + G acc_clean [gyro only]) + turn-on bias + random walk + instability + drift
               + vibration + white noise

with M = I + scale-factor and misalignment errors, G the gyro's g-sensitivity, the bias instability a first-order
Gauss-Markov process, the drift a slow temperature-like sinusoid and vibration intermittent bursts of a
high-frequency oscillation. Conventions are ``airimu_core.sequence``'s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from airimu_core.errors import InputError
from airimu_core.sequence import GpsFixes, GroundTruth, ImuSequence

GRAVITY_M_S2 = 9.81
PROFILES = ("drone", "handheld", "car", "still")  # still: a parked IMU (for airimu noise)


@dataclass(frozen=True)
class ImuErrorModel:
    """IMU errors. Densities are continuous-time (as GTSAM takes them after squaring): white noise in
    rad/s/sqrt(Hz) and m/s^2/sqrt(Hz), bias random walk in rad/s^2/sqrt(Hz) and m/s^3/sqrt(Hz); turn-on bias
    one-sigma in rad/s and m/s^2."""

    gyro_noise_density_rad_s_sqrthz: float
    acc_noise_density_m_s2_sqrthz: float
    gyro_bias_rw_rad_s2_sqrthz: float
    acc_bias_rw_m_s3_sqrthz: float
    gyro_turn_on_bias_rad_s: float
    acc_turn_on_bias_m_s2: float
    gyro_bias_instability_rad_s: float = 0.0  # stationary std of the Gauss-Markov bias
    acc_bias_instability_m_s2: float = 0.0
    bias_correlation_time_s: float = 100.0
    gyro_scale_misalignment: float = 0.0  # std of the entries of M - I (dimensionless)
    acc_scale_misalignment: float = 0.0
    gyro_g_sensitivity_rad_s_per_m_s2: float = 0.0  # std of the entries of G
    gyro_temperature_drift_rad_s: float = 0.0  # amplitude of the slow drift
    acc_temperature_drift_m_s2: float = 0.0
    temperature_period_s: float = 600.0
    vibration_gyro_rad_s: float = 0.0  # amplitude during a burst
    vibration_acc_m_s2: float = 0.0
    vibration_hz: float = 37.0
    vibration_duty: float = 0.0  # fraction of the time in bursts (bursts last VIBRATION_BURST_S)

    @classmethod
    def from_grade(cls, grade: str) -> ImuErrorModel:
        """Typical datasheet values of a grade: ``consumer`` (phone-class MEMS), ``industrial`` (ADIS16448-class,
        as on EuRoC), ``tactical`` (FOG/high-end MEMS), ``navigation`` (ring-laser class)."""
        if grade not in GRADES:
            raise InputError(f"unknown IMU grade {grade!r}; known grades: {', '.join(GRADES)}")
        return GRADES[grade]

    def noise_densities(self) -> tuple[np.ndarray, np.ndarray]:
        """(gyro, acc) white-noise variance densities (3,), rad^2/s and m^2/s^3: what
        ``gtsam.PreintegrationParams.setGyroscopeCovariance`` and ``learned_imu.preintegrate`` take."""
        return (
            np.full(3, self.gyro_noise_density_rad_s_sqrthz**2),
            np.full(3, self.acc_noise_density_m_s2_sqrthz**2),
        )


_DEG = np.pi / 180
_PER_SQRT_HOUR = 1 / 60  # 1 deg/sqrt(h) = (1/60) deg/sqrt(s)
_G = GRAVITY_M_S2
VIBRATION_BURST_S = 2.0
GRADES = {
    # phone-class MEMS: ~0.017 deg/s/sqrt(Hz), 300 ug/sqrt(Hz), turn-on bias 0.5 deg/s and 5 mg, instability
    # 10 deg/h, 0.5 % scale/misalignment, 0.1 deg/s/g g-sensitivity, vibration bursts 10 % of the time
    "consumer": ImuErrorModel(
        3e-4,
        3e-3,
        4e-5,
        6e-3,
        0.5 * _DEG,
        0.05,
        gyro_bias_instability_rad_s=10 * _DEG / 3600,
        acc_bias_instability_m_s2=1e-3 * _G,
        gyro_scale_misalignment=5e-3,
        acc_scale_misalignment=5e-3,
        gyro_g_sensitivity_rad_s_per_m_s2=0.1 * _DEG / _G,
        gyro_temperature_drift_rad_s=0.05 * _DEG,
        acc_temperature_drift_m_s2=0.01,
        vibration_gyro_rad_s=0.5 * _DEG,
        vibration_acc_m_s2=0.5,
        vibration_duty=0.1,
    ),
    # ADIS16448 as calibrated for EuRoC (imu0/sensor.yaml): turn-on bias 0.1 deg/s and 2 mg, instability
    # 14.5 deg/h (datasheet), 0.1 % scale/misalignment, 0.01 deg/s/g
    "industrial": ImuErrorModel(
        1.6968e-4,
        2.0e-3,
        1.9393e-5,
        3.0e-3,
        0.1 * _DEG,
        0.02,
        gyro_bias_instability_rad_s=14.5 * _DEG / 3600,
        acc_bias_instability_m_s2=0.25e-3 * _G,
        gyro_scale_misalignment=1e-3,
        acc_scale_misalignment=1e-3,
        gyro_g_sensitivity_rad_s_per_m_s2=0.01 * _DEG / _G,
        gyro_temperature_drift_rad_s=0.01 * _DEG,
        acc_temperature_drift_m_s2=2e-3,
    ),
    # tactical: ARW 0.15 deg/sqrt(h), 50 ug/sqrt(Hz), bias 1 deg/h and 0.1 mg, 100 ppm scale/misalignment
    "tactical": ImuErrorModel(
        0.15 * _DEG * _PER_SQRT_HOUR,
        5e-4,
        1e-6,
        1e-4,
        1.0 * _DEG / 3600,
        1e-3,
        gyro_bias_instability_rad_s=0.5 * _DEG / 3600,
        acc_bias_instability_m_s2=50e-6 * _G,
        gyro_scale_misalignment=1e-4,
        acc_scale_misalignment=1e-4,
    ),
    # navigation (ring-laser class): ARW 0.002 deg/sqrt(h), 5 ug/sqrt(Hz), bias 0.01 deg/h and 10 ug
    "navigation": ImuErrorModel(
        0.002 * _DEG * _PER_SQRT_HOUR,
        5e-5,
        1e-8,
        1e-5,
        0.01 * _DEG / 3600,
        1e-4,
        gyro_bias_instability_rad_s=0.005 * _DEG / 3600,
        acc_bias_instability_m_s2=5e-6 * _G,
        gyro_scale_misalignment=5e-6,
        acc_scale_misalignment=5e-6,
    ),
}


@dataclass(frozen=True, eq=False)
class SimulatedSequence:
    """A simulated sequence with what produced it: the clean IMU and the true per-sample biases."""

    sequence: ImuSequence
    clean_gyro: np.ndarray  # (N, 3) rad/s
    clean_acc: np.ndarray  # (N, 3) m/s^2
    gyro_bias: np.ndarray  # (N, 3) rad/s
    acc_bias: np.ndarray  # (N, 3) m/s^2


def simulate(
    profile: str = "drone",
    duration_s: float = 60.0,
    rate_hz: float = 200.0,
    grade: str = "consumer",
    seed: int = 0,
    gps_rate_hz: float | None = None,
    gps_sigma_m: float = 0.1,
    error_model: ImuErrorModel | None = None,
    device_seed: int | None = None,
) -> ImuSequence:
    """A seeded ``ImuSequence`` with ground truth (and GPS fixes if ``gps_rate_hz`` is given).

    ``device_seed``: recordings with the same device seed come from the same physical IMU -- they share its
    turn-on biases, scale/misalignment and g-sensitivity (as EuRoC's sequences share most of their bias) while
    ``seed`` draws the motion and the random processes. None: everything from ``seed``.
    """
    return simulate_with_truth(
        profile, duration_s, rate_hz, grade, seed, gps_rate_hz, gps_sigma_m, error_model, device_seed
    ).sequence


def simulate_with_truth(
    profile: str = "drone",
    duration_s: float = 60.0,
    rate_hz: float = 200.0,
    grade: str = "consumer",
    seed: int = 0,
    gps_rate_hz: float | None = None,
    gps_sigma_m: float = 0.1,
    error_model: ImuErrorModel | None = None,
    device_seed: int | None = None,
) -> SimulatedSequence:
    """Like ``simulate`` but also returns the clean IMU and the true biases."""
    if profile not in PROFILES:
        raise InputError(f"unknown trajectory profile {profile!r}; known profiles: {', '.join(PROFILES)}")
    if not duration_s > 0 or not rate_hz > 0:
        raise InputError(f"duration_s and rate_hz must be positive, got {duration_s}, {rate_hz}")
    model = error_model or ImuErrorModel.from_grade(grade)
    rng = np.random.default_rng(seed)
    device = rng if device_seed is None else np.random.default_rng([device_seed, 0x1D])  # the IMU's constants
    dt = 1.0 / rate_hz
    n = int(round(duration_s * rate_hz))
    t = np.arange(n + 1) * dt  # one more state than samples: sample k acts between states k and k+1
    rot, vel = _trajectory(profile, t, rng)
    gravity = np.array([0.0, 0.0, -GRAVITY_M_S2])
    pos = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (vel[:-1] + vel[1:]) * dt, axis=0)])
    clean_gyro = _log(np.einsum("nji,njk->nik", rot[:-1], rot[1:])) / dt
    clean_acc = np.einsum("nji,nj->ni", rot[:-1], (vel[1:] - vel[:-1]) / dt - gravity)

    sqrt_rate = np.sqrt(rate_hz)
    ts = t[:-1]
    phase = rng.uniform(0, 2 * np.pi)
    drift = np.sin(2 * np.pi * ts / model.temperature_period_s + phase)[:, None] * np.array([1.0, -0.7, 0.4])
    gyro_bias = (
        device.normal(0, model.gyro_turn_on_bias_rad_s, 3)
        + np.cumsum(rng.normal(0, model.gyro_bias_rw_rad_s2_sqrthz * np.sqrt(dt), (n, 3)), axis=0)
        + _gauss_markov(rng, n, dt, model.gyro_bias_instability_rad_s, model.bias_correlation_time_s)
        + model.gyro_temperature_drift_rad_s * drift
    )
    acc_bias = (
        device.normal(0, model.acc_turn_on_bias_m_s2, 3)
        + np.cumsum(rng.normal(0, model.acc_bias_rw_m_s3_sqrthz * np.sqrt(dt), (n, 3)), axis=0)
        + _gauss_markov(rng, n, dt, model.acc_bias_instability_m_s2, model.bias_correlation_time_s)
        + model.acc_temperature_drift_m_s2 * drift
    )
    gyro_m = np.eye(3) + device.normal(0, model.gyro_scale_misalignment, (3, 3))
    acc_m = np.eye(3) + device.normal(0, model.acc_scale_misalignment, (3, 3))
    g_sens = device.normal(0, model.gyro_g_sensitivity_rad_s_per_m_s2, (3, 3))
    burst = _bursts(rng, ts, model.vibration_duty)
    shake = burst[:, None] * np.sin(2 * np.pi * model.vibration_hz * ts[:, None] + rng.uniform(0, 2 * np.pi, 3))
    gyro = (
        (clean_gyro + clean_acc @ g_sens.T) @ gyro_m.T
        + gyro_bias
        + model.vibration_gyro_rad_s * shake
        + rng.normal(0, model.gyro_noise_density_rad_s_sqrthz * sqrt_rate, (n, 3))
    )
    acc = (
        clean_acc @ acc_m.T
        + acc_bias
        + model.vibration_acc_m_s2 * shake
        + rng.normal(0, model.acc_noise_density_m_s2_sqrthz * sqrt_rate, (n, 3))
    )

    gt = GroundTruth(rot=rot[:-1], pos=pos[:-1], vel=vel[:-1], valid=np.ones(n, dtype=bool))
    gps = None
    if gps_rate_hz:
        every = max(1, int(round(rate_hz / gps_rate_hz)))
        idx = np.arange(0, n, every)
        sigma = np.full((len(idx), 3), gps_sigma_m)
        gps = GpsFixes(t=t[idx], pos=pos[idx] + rng.normal(0, gps_sigma_m, (len(idx), 3)), sigma=sigma)
    name = f"sim_{profile}_{grade}_seed{seed}"
    seq = ImuSequence(name=name, t=t[:-1], gyro=gyro, acc=acc, gravity=gravity, gt=gt, gps=gps, source="simulator")
    return SimulatedSequence(seq, clean_gyro, clean_acc, gyro_bias, acc_bias)


def _gauss_markov(rng: np.random.Generator, n: int, dt: float, sigma: float, tau_s: float) -> np.ndarray:
    """First-order Gauss-Markov process (n, 3), stationary std ``sigma``, correlation time ``tau_s``."""
    if sigma == 0:
        return np.zeros((n, 3))
    phi = np.exp(-dt / tau_s)
    drive = rng.normal(0, sigma * np.sqrt(1 - phi**2), (n, 3))
    drive[0] = rng.normal(0, sigma, 3)  # start in the stationary distribution
    # x_k = phi x_{k-1} + w_k, as a scaled cumulative sum: x_k = phi^k sum_{j<=k} w_j phi^-j (chunked for range)
    out = np.empty((n, 3))
    chunk = max(1, int(50 * tau_s / dt))  # keep phi^-j well inside float64
    carry = np.zeros(3)
    for start in range(0, n, chunk):
        w = drive[start : start + chunk]
        powers = phi ** np.arange(1, len(w) + 1)
        out[start : start + chunk] = powers[:, None] * (carry + np.cumsum(w / powers[:, None], axis=0))
        carry = out[start + len(w) - 1]
    return out


def _bursts(rng: np.random.Generator, t: np.ndarray, duty: float) -> np.ndarray:
    """(N,) 0/1 mask of vibration bursts of ``VIBRATION_BURST_S`` covering about ``duty`` of the time."""
    if duty <= 0:
        return np.zeros_like(t)
    n_bursts = max(1, int(round(duty * (t[-1] - t[0]) / VIBRATION_BURST_S)))
    starts = rng.uniform(t[0], t[-1], n_bursts)
    events = np.zeros(len(t) + 1)
    np.add.at(events, np.searchsorted(t, starts), 1.0)
    np.add.at(events, np.searchsorted(t, starts + VIBRATION_BURST_S), -1.0)
    return (np.cumsum(events)[:-1] > 0).astype(float)


def _trajectory(profile: str, t: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """World <- IMU rotations (N, 3, 3) and velocities (N, 3) of a smooth, seeded profile (sums of sinusoids);
    ``"still"``: a level IMU at rest, at a seeded heading."""
    if profile == "still":
        yaw = np.full(len(t), rng.uniform(-np.pi, np.pi))
        return _rpy_to_matrix(np.zeros(len(t)), np.zeros(len(t)), yaw), np.zeros((len(t), 3))
    speed, tilt, yaw_rate, freq = {
        "drone": (2.0, 0.25, 0.4, 0.15),
        "handheld": (1.2, 0.6, 1.5, 0.5),
        "car": (15.0, 0.03, 0.15, 0.05),
    }[profile]
    phase = rng.uniform(0, 2 * np.pi, 6)
    w = 2 * np.pi * freq
    vel = np.stack(
        [
            speed * np.cos(w * t + phase[0]),
            speed * np.sin(0.7 * w * t + phase[1]),
            (0.05 if profile == "car" else 0.4) * speed * np.sin(1.3 * w * t + phase[2]),
        ],
        axis=1,
    )
    yaw = yaw_rate / (0.5 * w) * np.sin(0.5 * w * t + phase[3])
    roll = tilt * np.sin(1.1 * w * t + phase[4])
    pitch = tilt * np.sin(0.9 * w * t + phase[5])
    return _rpy_to_matrix(roll, pitch, yaw), vel


def _rpy_to_matrix(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll), (N, 3, 3)."""
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    return np.stack(
        [
            np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
            np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
            np.stack([-sp, cp * sr, cp * cr], -1),
        ],
        axis=-2,
    )


def _log(rot: np.ndarray) -> np.ndarray:
    """Rotation vectors of small rotations (N, 3, 3) -> (N, 3) (angles well below pi between samples)."""
    v = 0.5 * np.stack([rot[:, 2, 1] - rot[:, 1, 2], rot[:, 0, 2] - rot[:, 2, 0], rot[:, 1, 0] - rot[:, 0, 1]], 1)
    sin = np.linalg.norm(v, axis=1, keepdims=True)
    cos = 0.5 * (np.trace(rot, axis1=1, axis2=2)[:, None] - 1)
    angle = np.arctan2(sin, cos)
    scale = np.where(sin > 1e-12, angle / np.maximum(sin, 1e-300), 1.0)
    return v * scale
