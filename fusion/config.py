"""The fusion's settings, every default written once: ``FuseConfig`` (``configs/fuse.yaml`` is its documented
default, ``airimu fuse --config`` reads another, CLI flags override it) for the batch graph (``airimu.fuse``) and
``OnlineFusion`` alike. Its sections: the IMU noise without a model, the GPS, the bias states, the graph and solver
(``FusionSettings``: robust loss, lever arm, priors, Levenberg-Marquardt) and the online smoother.

Noise conventions: ``*_noise_density`` is sigma (rad/s/sqrt(Hz), m/s^2/sqrt(Hz), as Kalibr writes it); GTSAM's
setters and ``OnlineFusion``'s internals take sigma^2.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from airimu_core.config import check_noise_density, config_path, from_dict, read_yaml
from airimu_core.errors import ConfigError
from airimu_core.sequence import GPS_SIGMA_UNKNOWN_M, MAX_IMU_DELAY_S, is_imu_delay


@dataclass(frozen=True)
class FusionSettings:
    """The graph and its solver: GPS robust loss and lever arm, the prior on the first state, Levenberg-Marquardt
    (``FuseConfig.graph``; ``configs/pgo_*.yaml``'s ``fusion`` block)."""

    backend: Literal["gtsam", "custom"] = "gtsam"  # C++ ImuFactor, or factors.LearnedImuFactor
    # robust loss of the GPS factors (factors.gps_noise); None: Gaussian, as GTSAM's examples and the paper's graph.
    # Huber keeps a bad fix from bending the track (tests/fusion/test_gps_outliers.py) but, where the IMU's own
    # errors make fixes look wrong, trusts the IMU over good fixes: on a simulated consumer drone (0.1-m fixes at
    # 1 Hz) ATE 0.51 m against 0.22 Gaussian, and ISAM2 then ends 0.48 m from the batch solution (2 mm Gaussian)
    gps_robust: Literal["huber", "cauchy"] | None = None
    lever_arm_m: tuple[float, float, float] = (0.0, 0.0, 0.0)  # antenna in the IMU frame
    prior_rot_sigma_rad: float = 0.01
    prior_pos_sigma_m: float = 0.1
    prior_vel_sigma_m_s: float = 0.1
    max_iterations: int = 100
    relative_error_tol: float = 1e-6
    absolute_error_tol: float = 1e-6
    init_window: int = 100  # keyframes per window of the sequential initialisation

    def __post_init__(self):
        for key in ("prior_rot_sigma_rad", "prior_pos_sigma_m", "prior_vel_sigma_m_s"):
            value = getattr(self, key)
            if not (np.isfinite(value) and value > 0):
                raise ConfigError(f"fusion.{key} must be a positive sigma, got {value!r}")
        for key in ("relative_error_tol", "absolute_error_tol"):
            value = getattr(self, key)
            if not (np.isfinite(value) and value >= 0):
                raise ConfigError(f"fusion.{key} must be a number >= 0, got {value!r}")
        for key in ("max_iterations", "init_window"):
            if getattr(self, key) < 1:
                raise ConfigError(f"fusion.{key} must be a whole number >= 1, got {getattr(self, key)!r}")
        if self.backend not in ("gtsam", "custom"):
            raise ConfigError(f"fusion.backend must be one of gtsam, custom, got {self.backend!r}")
        if self.gps_robust not in (None, "huber", "cauchy"):
            raise ConfigError(f"fusion.gps_robust must be null, huber or cauchy, got {self.gps_robust!r}")
        if len(self.lever_arm_m) != 3 or not all(np.isfinite(self.lever_arm_m)):
            raise ConfigError(f"fusion.lever_arm_m must be 3 finite numbers (m), got {list(self.lever_arm_m)!r}")


BIAS_WALKS = ("per_interval", "cumulative")


@dataclass(frozen=True)
class BiasStates:
    """A bias state per keyframe: ``B(k) - B(k+1)`` is zero-mean with sigma ``sqrt(count) * walk_sigma`` per axis and
    ``B(0)`` has a zero-mean prior. Sigmas (standard deviations): acc in m/s^2, gyro in rad/s; ``walk_sigma`` is per
    IMU sample.

    ``walk``: what ``count`` is. ``"per_interval"`` (default): the samples between the two keyframes, which is a
    per-sample random walk (its standard deviation over n samples is ``sqrt(n) * walk_sigma``). ``"cumulative"``:
    the samples from the first keyframe to keyframe k+1, GTSAM's ``IMUKittiExampleGPS.py`` rule (its
    ``included_imu_measurement_count`` is never reset), a walk that loosens with the time since the start (about 20x
    at the end of its 470-s drive); use it to run that example's settings exactly
    (``airimu.experiments.pgo.GTSAM_EXAMPLE``)."""

    # GTSAM's IMUKittiExampleGPS.py walk sigmas and acc prior; a gyro prior of 0.01 rad/s (the example's 5e-5 cannot
    # absorb a learned model's constant offset: BENCHMARKS.md, PGO on KITTI 0027)
    acc_walk_sigma: float = 1.67e-4
    gyro_walk_sigma: float = 2.91e-6
    acc_prior_sigma: float = 0.1
    gyro_prior_sigma: float = 0.01
    # "between": gtsam.ImuFactor per interval and a BetweenFactorConstantBias of the random walk (the example's
    # graph); "combined": gtsam.CombinedImuFactor, whose preintegration carries the same random walk (as a
    # continuous-time density, walk_sigma^2 / dt) and the learned per-sample noise (factors.learned_combined_pim)
    factor: str = "between"
    walk: str = "per_interval"

    def __post_init__(self):
        if self.factor not in ("between", "combined"):
            raise ConfigError(f"BiasStates.factor must be 'between' or 'combined', got {self.factor!r}")
        if self.walk not in BIAS_WALKS:
            raise ConfigError(f"BiasStates.walk must be one of {', '.join(BIAS_WALKS)}, got {self.walk!r}")
        if self.factor == "combined" and self.walk != "per_interval":
            raise ConfigError(
                "BiasStates.walk: 'cumulative' needs factor 'between' (a CombinedImuFactor's preintegration carries "
                "the walk over its own interval only)"
            )
        for name in ("acc_walk_sigma", "gyro_walk_sigma", "acc_prior_sigma", "gyro_prior_sigma"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ConfigError(f"BiasStates.{name} must be a positive number, got {value!r}")

    def walk_sigmas(self, samples: np.ndarray) -> np.ndarray:
        """(K, 6) sigmas [acc x3, gyro x3] of the walk over K intervals of ``samples`` (K,) IMU samples each."""
        count = np.cumsum(samples) if self.walk == "cumulative" else np.asarray(samples)
        return np.sqrt(count)[:, None] * np.array([self.acc_walk_sigma] * 3 + [self.gyro_walk_sigma] * 3)


SMOOTHERS = ("isam2", "fixed_lag")


@dataclass(frozen=True)
class OnlineSettings:
    """``OnlineFusion``'s smoother: a keyframe every ``keyframe_s`` (each costs CPU time: BENCHMARKS.md, "Online
    fusion"); ``"isam2"`` keeps every keyframe, ``"fixed_lag"`` the last ``lag_s`` seconds; ISAM2's relinearisation
    threshold (rad, m, m/s); with bias states, an interval is preintegrated again once its bias estimate moved more
    than ``bias_relinearize_tol`` (rad/s, m/s^2) from the one it was preintegrated around."""

    keyframe_s: float = 1.0
    smoother: Literal["isam2", "fixed_lag"] = "isam2"
    lag_s: float = 10.0
    # ISAM2 relinearises a variable whose update exceeds this, checked from the root down only as far as cliques need
    # it (partial check: a full check relinearised far-back stretches and made updates several times slower). GTSAM's
    # default 0.1 left the online solution further from the batch LM one (BENCHMARKS.md, "Design measurements")
    relinearize_threshold: float = 0.01
    bias_relinearize_tol: float = 0.01

    def __post_init__(self):
        if self.smoother not in SMOOTHERS:
            raise ConfigError(f"online.smoother must be one of {', '.join(SMOOTHERS)}, got {self.smoother!r}")
        for key in ("keyframe_s", "relinearize_threshold", "bias_relinearize_tol"):
            value = getattr(self, key)
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"online.{key} must be a positive number, got {value!r}")
        if not (math.isfinite(self.lag_s) and self.lag_s >= 2 * self.keyframe_s):
            raise ConfigError(
                f"online.lag_s must be at least 2 keyframes ({2 * self.keyframe_s:g} s), got {self.lag_s!r}"
            )


@dataclass(frozen=True)
class MotionSettings:
    """The learned motion factors (``airimu fuse --motion``; ``factors.MotionFactor``): where they go and how much
    they are trusted.

    - ``keyframe_s``: with a motion model, a keyframe (each carrying a motion factor) every this many seconds besides
      the graph's own (one per fix, or ``keyframe_s``); null: only the graph's own.
    - ``passes``: how often the model is run and the graph solved with its velocities, each pass reading the
      attitude of the previous solution (the first: the graph without motion factors), never ground truth.
    - ``cov_scale``: every predicted variance is multiplied by this (AirIO's EKF uses 0.1; 1: as predicted); one
      number, or three, one per body axis of the model's output (``[1.0e6, 1, 1]`` leaves a car's forward speed,
      axis x, to the IMU: sigma x 1000).
    - ``mount_sigma_rad``: null, or a mounting-rotation state shared by every motion factor of a log (the rotation
      from the IMU's body frame to the frame the model's velocities are in), with a prior at identity of this sigma
      (rad; one, or three: roll, pitch, yaw): for a model used on an IMU mounted otherwise than in its training.
      On KITTI's drives (one car) it does not help: the model reads the drive's pitch off gravity (BENCHMARKS.md).
    - ``speed_envelope``: in the last pass the graph is solved once with every factor's along-track axis left to
      the IMU; where that solution is faster than this times the model's training speed (``trained_on.speed_m_s``
      of its checkpoint: the highest in its training data), the along-track axis stays free
      (``BodyVelocities.outside_envelope``; ``OnlineFusion``: each keyframe's predicted speed): a network does not
      know speeds it never saw (KITTI's highway, seq 01, at 24 m/s against 20 in training: 7 m/s low). null: never;
      a model without the record (trained before it was kept) is not checked.
    - ``scale_sigma``: null, or speed-scale states: the model's velocities times a scale ``s`` (one per
      ``scale_interval_s`` of the log, ``factors.MotionFactor``'s ``scale_key``) with a prior at 1 of this sigma and
      a random walk of ``scale_walk`` per sqrt(s) between them: a model that reads a drive a few percent slow all the
      way (KITTI seq 04) is an error correlated over minutes, not white noise, and the IMU then sets the scale.
      Batch only.
    """

    keyframe_s: float | None = 0.2
    passes: int = 2
    cov_scale: float | tuple[float, float, float] = 1.0
    mount_sigma_rad: float | tuple[float, float, float] | None = None
    speed_envelope: float | None = 1.0
    scale_sigma: float | None = None
    scale_walk: float = 0.01
    scale_interval_s: float = 10.0

    def __post_init__(self):
        if self.keyframe_s is not None and not (math.isfinite(self.keyframe_s) and self.keyframe_s > 0):
            raise ConfigError(f"motion.keyframe_s must be a positive interval (s) or null, got {self.keyframe_s!r}")
        if not (isinstance(self.passes, int) and 1 <= self.passes <= 10):
            raise ConfigError(f"motion.passes must be a whole number in [1, 10], got {self.passes!r}")
        scale = _one_or_three(self.cov_scale, lambda v: v > 0)
        if scale is None:
            raise ConfigError(
                f"motion.cov_scale must be a positive factor or three (one per body axis), got {self.cov_scale!r}"
            )
        object.__setattr__(self, "cov_scale", scale)
        if self.mount_sigma_rad is not None:
            sigma = _one_or_three(self.mount_sigma_rad, lambda v: 0 < v <= 1)
            if sigma is None:
                raise ConfigError(
                    f"motion.mount_sigma_rad must be null or a sigma in (0, 1] rad, one or three (roll, pitch, yaw), "
                    f"got {self.mount_sigma_rad!r}"
                )
            object.__setattr__(self, "mount_sigma_rad", sigma)
        envelope = self.speed_envelope
        if envelope is not None and not (_is_number(envelope) and envelope > 0):
            raise ConfigError(f"motion.speed_envelope must be a positive factor or null, got {envelope!r}")
        if envelope is not None:
            object.__setattr__(self, "speed_envelope", float(envelope))
        if self.scale_sigma is not None and not (_is_number(self.scale_sigma) and self.scale_sigma > 0):
            raise ConfigError(f"motion.scale_sigma must be a positive sigma or null, got {self.scale_sigma!r}")
        if not (_is_number(self.scale_walk) and self.scale_walk >= 0):
            raise ConfigError(f"motion.scale_walk must be a sigma >= 0 (per sqrt(s)), got {self.scale_walk!r}")
        if not (_is_number(self.scale_interval_s) and self.scale_interval_s > 0):
            raise ConfigError(f"motion.scale_interval_s must be a positive interval (s), got {self.scale_interval_s!r}")
        for name in ("scale_sigma", "scale_walk", "scale_interval_s"):
            if getattr(self, name) is not None:
                object.__setattr__(self, name, float(getattr(self, name)))

    def speed_scale(self) -> tuple[float, float, float] | None:
        """(prior sigma, random walk per sqrt(s), interval s) of the speed-scale states, or None (none)."""
        return None if self.scale_sigma is None else (self.scale_sigma, self.scale_walk, self.scale_interval_s)

    def speed_limit_m_s(self, motion_model) -> float | None:
        """The speed (m/s) above which ``motion_model``'s along-track velocity is left to the IMU, or None (no
        envelope set, or a model without its training speed)."""
        trained = getattr(getattr(motion_model, "trained_on", None), "speed_m_s", None)
        return None if self.speed_envelope is None or trained is None else self.speed_envelope * trained


def _is_number(value) -> bool:
    """A finite int or float (not a bool)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _one_or_three(value, allowed: Callable[[float], bool]) -> float | tuple[float, float, float] | None:
    """A setting of one number or three (one per axis) as the dataclass holds it: one number however given (a list of
    one from YAML or argparse), three as a tuple of floats; None when it is neither or a number is not finite and
    ``allowed``."""
    numbers = list(value) if isinstance(value, (tuple, list)) else [value]
    if not (
        len(numbers) in (1, 3)
        and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in numbers)
        and all(math.isfinite(v) and allowed(v) for v in numbers)
    ):
        return None
    return float(numbers[0]) if len(numbers) == 1 else tuple(map(float, numbers))


IMU_GAPS = ("hold", "interpolate")  # FuseConfig.imu_gaps


@dataclass(frozen=True)
class FuseConfig:
    """What ``airimu fuse`` (``airimu.fuse.fuse``) and ``OnlineFusion`` fuse with; ``configs/fuse.yaml`` holds these
    defaults, commented.

    - ``gyro_noise_density``, ``acc_noise_density``: sigma of the raw IMU's white noise, used without a model (a model
      predicts its own); default VINS-Mono's EuRoC setting, a consumer MEMS (rad/s/sqrt(Hz), m/s^2/sqrt(Hz)).
    - ``gps_sigma_m``: one-sigma GPS noise per axis (m) for fixes whose file gives none.
    - ``keyframe_s``: a keyframe at every fused fix (each fix constrains the state at its own time), and one every
      this many seconds between them; null: the fixes' alone (batch only).
    - ``estimate_bias``: a bias state per keyframe, with the sigmas and factor of ``bias``.
    - ``still_start``: without a model, a still start (``fusion.still``: the IMU quiet and the GPS or the given
      start velocity still) gives the raw gyro's bias, taken out of every sample.
    - ``imu_gaps``: ``"hold"``: a gap in the IMU samples (a step over 5 median steps) is integrated with the sample
      before it held (GTSAM's ``integrateMeasurement(acc, gyro, dt)``); ``"interpolate"``: filled with samples linear
      between the two either side (``ImuSequence.bridge_gaps``: the trapezoidal rule over the gap; batch only).
    - ``imu_delay_s``: how late (s) the IMU's samples are against the clock of the GPS and the start state: the
      preintegration reads each sample ``imu_delay_s`` later (``airimu_core.sequence.read_later``), the networks
      read them as recorded (their training's timing); batch only. KITTI's OXTS gyro lags the same packets'
      navigation solution by ~50 ms (``learned_imu.evaluation.imu_delay.measure_imu_delay`` on its training drives:
      BENCHMARKS.md); 0: none.
    - ``graph``: robust loss, lever arm, priors and the solver; ``online``: the smoother of ``OnlineFusion``;
      ``motion``: the learned motion factors, used when a motion model is given (``MotionSettings``).
    """

    gyro_noise_density: float = 0.004
    acc_noise_density: float = 0.08
    gps_sigma_m: float = GPS_SIGMA_UNKNOWN_M
    keyframe_s: float | None = None
    estimate_bias: bool = False
    still_start: bool = True
    imu_gaps: str = "hold"
    imu_delay_s: float = 0.0
    bias: BiasStates = field(default_factory=BiasStates)
    graph: FusionSettings = field(default_factory=FusionSettings)
    online: OnlineSettings = field(default_factory=OnlineSettings)
    motion: MotionSettings = field(default_factory=MotionSettings)

    def __post_init__(self):
        check_noise_density("gyro", self.gyro_noise_density, "gyro_noise_density")
        check_noise_density("acc", self.acc_noise_density, "acc_noise_density")
        if not (math.isfinite(self.gps_sigma_m) and self.gps_sigma_m > 0):
            raise ConfigError(f"gps_sigma_m must be a positive sigma (m), got {self.gps_sigma_m!r}")
        if self.keyframe_s is not None and not (math.isfinite(self.keyframe_s) and self.keyframe_s > 0):
            raise ConfigError(f"keyframe_s must be a positive interval (s) or null, got {self.keyframe_s!r}")
        if not isinstance(self.still_start, bool):
            raise ConfigError(f"still_start must be true or false, got {self.still_start!r}")
        if self.imu_gaps not in IMU_GAPS:
            raise ConfigError(f"imu_gaps must be one of {', '.join(IMU_GAPS)}, got {self.imu_gaps!r}")
        if not is_imu_delay(self.imu_delay_s):
            raise ConfigError(
                f"imu_delay_s must be a delay (s) within +-{MAX_IMU_DELAY_S:g}, got {self.imu_delay_s!r} (a value in "
                "ms?)"
            )
        object.__setattr__(self, "imu_delay_s", float(self.imu_delay_s))

    @property
    def noise_density(self) -> tuple[float, float]:
        """(gyro, acc) sigmas, rad/s/sqrt(Hz) and m/s^2/sqrt(Hz)."""
        return self.gyro_noise_density, self.acc_noise_density

    @property
    def noise_is_default(self) -> bool:
        """True while the noise densities are the defaults (only densities someone chose are judged against the
        samples' own white noise: the defaults are a guess for an unknown IMU)."""
        return self.noise_density == (FuseConfig.gyro_noise_density, FuseConfig.acc_noise_density)

    @property
    def bias_states(self) -> BiasStates | None:
        """``bias`` when ``estimate_bias``, else None."""
        return self.bias if self.estimate_bias else None


def load_fuse_config(path: str | Path = "fuse.yaml") -> FuseConfig:
    """Read a fusion config (YAML; a shipped config by name too: ``fuse.yaml`` is the documented default); every
    key checked (``ConfigError`` naming the file and the key)."""
    path = config_path(path)
    data = read_yaml(path)
    return from_dict(FuseConfig, {} if data is None else data, source=str(path))


def with_overrides(config: FuseConfig, **changes) -> FuseConfig:
    """``config`` with the given top-level fields replaced (``None`` values left as they are: a flag not given)."""
    given = {k: v for k, v in changes.items() if v is not None}
    return dataclasses.replace(config, **given) if given else config
