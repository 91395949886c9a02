"""factors: GTSAM factors for learned IMU preintegration and GPS (gtsam + numpy; never imports torch)."""

from airimu_core.errors import ExportError, GraphError, PimLayoutError
from airimu_core.export import Export, ExportTruth, load_export
from factors.checks import check_anchored, check_values, poses_of, solve_or_explain
from factors.export_file import from_export
from factors.gps import GpsFactor, gps_noise
from factors.imu import LearnedImuFactor
from factors.learned_pim import learned_combined_pim, learned_pim
from factors.motion import MotionFactor, MotionTerms, motion_factors, solve_with_python_factors
from factors.pim_from_deltas import pim_from_deltas  # the function (the module stays importable)
from factors.relinearise import Relinearised, solve_relinearised

__all__ = [
    "Export",
    "ExportError",
    "ExportTruth",
    "GpsFactor",
    "GraphError",
    "LearnedImuFactor",
    "MotionFactor",
    "MotionTerms",
    "PimLayoutError",
    "Relinearised",
    "check_anchored",
    "check_values",
    "poses_of",
    "solve_or_explain",
    "from_export",
    "gps_noise",
    "learned_combined_pim",
    "learned_pim",
    "load_export",
    "motion_factors",
    "pim_from_deltas",
    "solve_relinearised",
    "solve_with_python_factors",
]
