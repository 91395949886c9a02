"""``airimu demo``: the embedded default job, on the simulator, no files needed.

Today it shows the differentiable preintegrator on a simulated flight: one batched call integrates every window
from its ground-truth start state with covariance, the result is checked against GTSAM's own preintegration, and
the drift is compared with the propagated uncertainty. (Training, export and the IMU+GPS pose graph join it as
they land.)
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class DemoResult:
    """What the demo measured: per-window end errors of raw integration and their predicted sigmas."""

    n_windows: int
    window_s: float
    pos_err_m: np.ndarray  # (W,) position error at each window end, m
    pos_sigma_m: np.ndarray  # (W,) predicted 1-sigma (sqrt of trace/3 of the position covariance), m
    max_rel_diff_vs_gtsam: float  # ours vs gtsam.PreintegratedImuMeasurements on the first window (covariance)
    seconds: float  # wall time of the batched preintegration


def run_demo(duration_s: float = 60.0, seed: int = 0, window_s: float = 1.0, grade: str = "consumer") -> DemoResult:
    """Simulate a drone flight, integrate all windows at once with covariance, compare with GTSAM and print."""
    import torch

    from learned_imu import NavState, predict, preintegrate
    from learned_imu.simulator import ImuErrorModel, simulate

    seq = simulate(profile="drone", duration_s=duration_s, grade=grade, seed=seed)
    model = ImuErrorModel.from_grade(grade)
    gyro_density, acc_density = model.noise_densities()
    per_window = int(round(window_s / float(np.median(seq.dt))))
    n_windows = (len(seq) - 1) // per_window
    starts = np.arange(n_windows) * per_window
    take = starts[:, None] + np.arange(per_window)[None, :]

    as_t = torch.as_tensor
    gyro, acc, dt = as_t(seq.gyro[take]), as_t(seq.acc[take]), as_t(seq.dt[take])
    clock = time.perf_counter()
    pre = preintegrate(gyro, acc, dt, gyro_cov=as_t(gyro_density), acc_cov=as_t(acc_density))
    seconds = time.perf_counter() - clock
    start = NavState(rot=as_t(seq.gt.rot[starts]), vel=as_t(seq.gt.vel[starts]), pos=as_t(seq.gt.pos[starts]))
    end = predict(start, pre, gravity=as_t(seq.gravity))
    ends = starts + per_window  # ground truth after the window's last sample
    pos_err = np.linalg.norm(end.pos[:, -1].numpy() - seq.gt.pos[ends], axis=-1)
    pos_cov = pre.cov[:, -1, 3:6, 3:6].numpy()
    pos_sigma = np.sqrt(np.trace(pos_cov, axis1=1, axis2=2) / 3)

    diff = _compare_with_gtsam(
        seq.gyro[take[0]], seq.acc[take[0]], seq.dt[take[0]], gyro_density, acc_density, pre.cov[0, -1].numpy()
    )
    result = DemoResult(n_windows, window_s, pos_err, pos_sigma, diff, seconds)
    _print(result, len(seq), grade)
    return result


def _compare_with_gtsam(gyro, acc, dt, gyro_density, acc_density, cov) -> float:
    import gtsam

    params = gtsam.PreintegrationParams.MakeSharedU(9.81)
    params.setGyroscopeCovariance(np.diag(gyro_density))
    params.setAccelerometerCovariance(np.diag(acc_density))
    params.setIntegrationCovariance(np.zeros((3, 3)))
    pim = gtsam.PreintegratedImuMeasurements(params, gtsam.imuBias.ConstantBias())
    for k in range(len(dt)):
        pim.integrateMeasurement(acc[k], gyro[k], dt[k])
    ref = pim.preintMeasCov()
    return float(np.abs(cov - ref).max() / np.abs(ref).max())


def _print(result: DemoResult, n_samples: int, grade: str) -> None:
    from rich.console import Console
    from rich.table import Table

    console = Console()
    console.print(
        f"Simulated drone flight, {grade}-grade IMU: {n_samples} samples; {result.n_windows} windows of "
        f"{result.window_s:g} s preintegrated with covariance in one batched call: {result.seconds * 1e3:.1f} ms."
    )
    console.print(
        f"Covariance vs gtsam.PreintegratedImuMeasurements (first window): {result.max_rel_diff_vs_gtsam:.2e}"
        " relative (max-norm)."
    )
    table = Table(title="Raw IMU integrated from the ground-truth state, error at window end")
    for col in ("statistic", "position error, m", "predicted 1-sigma (white noise only), m"):
        table.add_column(col)
    for name, fn in (("median", np.median), ("90th percentile", lambda x: np.percentile(x, 90)), ("max", np.max)):
        table.add_row(name, f"{fn(result.pos_err_m):.4f}", f"{fn(result.pos_sigma_m):.4f}")
    console.print(table)
    console.print(
        "The gap between error and sigma is the IMU's bias and deterministic errors, which the AirIMU "
        "model learns to remove (and its uncertainty to cover)."
    )
