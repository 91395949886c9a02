"""factors: GTSAM factors for learned IMU preintegration and GPS (gtsam + numpy; never imports torch)."""

from factors.gps import GpsFactor, gps_noise
from factors.imu import LearnedImuFactor
from factors.learned_pim import learned_pim

__all__ = ["GpsFactor", "LearnedImuFactor", "gps_noise", "learned_pim"]
