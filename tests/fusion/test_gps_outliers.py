"""GPS outliers: with 10 % of the fixes displaced by 50 m, the robust GPS factor (Huber or Cauchy) keeps the fused
trajectory's ATE within 2x of the clean run, while the Gaussian factor is pulled far off by the same outliers.

The IMU is simulated with white noise only and exported raw with its true densities (no model): the IMU factors
are then exactly right, so the test isolates what the GPS factor does with outliers."""

from __future__ import annotations

import numpy as np
import pytest

from airimu.experiments.pgo import ate_m, gps_for
from airimu_core.sequence import GpsFixes
from factors import load_export
from fusion.config import FusionSettings
from fusion.graph import build_graph, solve
from learned_imu.datasets.simulator import ImuErrorModel, simulate
from learned_imu.export import export_preintegration, keyframes_every

GYRO_DENSITY, ACC_DENSITY = 1e-4, 1e-3  # rad/s/sqrt(Hz), m/s^2/sqrt(Hz): the simulated white noise
WHITE = ImuErrorModel(GYRO_DENSITY, ACC_DENSITY, 0.0, 0.0, 0.0, 0.0)
GPS_HZ, GPS_SIGMA_M = 1.0, 0.1
OUTLIER_FRACTION, OUTLIER_M = 0.1, 50.0


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    seq = simulate("drone", duration_s=60.0, error_model=WHITE, seed=3)
    path = tmp_path_factory.mktemp("outliers") / "sim.npz"
    export_preintegration(path, seq, keyframes_every(seq, 0.1), GYRO_DENSITY**2, ACC_DENSITY**2)
    return seq, load_export(path)


def with_outliers(gps: GpsFixes, seed: int) -> tuple[GpsFixes, np.ndarray]:
    """``gps`` with ``OUTLIER_FRACTION`` of its fixes (seeded choice) moved ``OUTLIER_M`` in seeded random 3-D
    directions; returns the fixes and the outliers' indices."""
    rng = np.random.default_rng([seed, 50])
    count = round(OUTLIER_FRACTION * len(gps.t))
    index = rng.choice(len(gps.t), count, replace=False)
    direction = rng.normal(size=(count, 3))
    pos = gps.pos.copy()
    pos[index] += OUTLIER_M * direction / np.linalg.norm(direction, axis=1, keepdims=True)
    return GpsFixes(gps.t, pos, gps.sigma), index


def fused_ate(export, fixes: GpsFixes, truth: GpsFixes, robust: str | None) -> float:
    settings = FusionSettings(gps_robust=robust)
    graph, values = build_graph(export, fixes, settings)
    return ate_m(solve(graph, values, export.keyframe_t, settings), truth)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1])
def test_robust_gps_factor_keeps_ate_within_twice_the_clean_run(setup, seed):
    seq, export = setup
    fixes, truth = gps_for(seq, GPS_HZ, GPS_SIGMA_M, seed)
    outliers, index = with_outliers(fixes, seed)
    assert len(index) == 6 and np.allclose(np.linalg.norm(outliers.pos - fixes.pos, axis=1)[index], OUTLIER_M)

    clean = fused_ate(export, fixes, truth, None)  # Gaussian factor, clean fixes: the reference
    ate = {robust: fused_ate(export, outliers, truth, robust) for robust in ("huber", "cauchy", None)}
    # measured (seed 0 / 1): clean 0.080 / 0.080 m; Huber 0.080 / 0.094, Cauchy 0.082 / 0.081, Gaussian 4.3 / 5.4
    assert clean < GPS_SIGMA_M  # fusion beats one fix's noise (0.17 m rms in 3-D)
    assert ate["huber"] < 2.0 * clean, ate
    assert ate["cauchy"] < 2.0 * clean, ate
    assert ate[None] > 10.0 * clean, ate  # without a robust loss the outliers drag the trajectory metres away
