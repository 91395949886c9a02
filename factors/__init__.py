"""factors: GTSAM factors for learned IMU preintegration and GPS (gtsam + numpy; never imports torch)."""

from factors.checks import GraphError, check_anchored, check_values, solve_or_explain
from factors.export_file import Export, ExportError, ExportTruth, from_export, load_export
from factors.gps import GpsFactor, gps_noise
from factors.imu import LearnedImuFactor
from factors.learned_pim import learned_combined_pim, learned_pim
from factors.pim_from_deltas import PimLayoutError, pim_from_deltas  # the function (the module stays importable)
from factors.relinearise import Relinearised, solve_relinearised

__all__ = [
    "Export",
    "ExportError",
    "ExportTruth",
    "GpsFactor",
    "GraphError",
    "LearnedImuFactor",
    "PimLayoutError",
    "Relinearised",
    "check_anchored",
    "check_values",
    "solve_or_explain",
    "from_export",
    "gps_noise",
    "learned_combined_pim",
    "learned_pim",
    "load_export",
    "pim_from_deltas",
    "solve_relinearised",
]
