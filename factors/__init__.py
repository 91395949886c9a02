"""factors: GTSAM factors for learned IMU preintegration and GPS (gtsam + numpy; never imports torch)."""

from factors.checks import GraphError, check_values
from factors.gps import GpsFactor, gps_noise
from factors.imu import LearnedImuFactor
from factors.learned_pim import learned_pim

__all__ = ["GpsFactor", "GraphError", "LearnedImuFactor", "check_values", "gps_noise", "learned_pim"]
