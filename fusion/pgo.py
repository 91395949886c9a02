"""The paper's PGO ablation (AirIMU sec. V-C): IMU + GPS pose graphs with raw or corrected IMU and fixed or
learned covariance; the settings are data, one runner.

Per evaluation sequence: the model corrects the IMU and predicts its noise; four exports are written
(samples raw | AirIMU) x (covariance fixed | learned); for each GPS rate and seed the graph is solved
(``fusion.graph``) and scored by ATE (RMSE of keyframe positions, no alignment: GPS fixes the world frame).

GPS: simulated from the ground truth (``gps_sigma_m`` per axis, seeded) at each rate, or, for a sequence with
real fixes and no ground truth (KITTI), the real fixes decimated to the rate with the seed choosing the phase,
scored against all real fixes. The fixed covariance is the VINS-Mono EuRoC setting (acc 0.08 m/s^2/sqrt(Hz),
gyro 0.004 rad/s/sqrt(Hz)), as in the paper.
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from factors import load_export
from fusion.graph import FusionSettings, Gps, Solution, build_graph, solve
from learned_imu.errors import ConfigError
from learned_imu.export import export_preintegration, keyframes_every
from learned_imu.model import Correction
from learned_imu.sequence import ImuSequence

log = logging.getLogger(__name__)
SCORE_SPANS = ("keyframes", "gps")


@dataclass(frozen=True)
class PgoSetting:
    """One setting: which samples (``"raw"`` or ``"airimu"``) and which covariance (``"fixed"`` or ``"learned"``)."""

    name: str
    samples: str
    covariance: str


SETTINGS = (
    PgoSetting("raw IMU + fixed cov", "raw", "fixed"),
    PgoSetting("AirIMU + fixed cov", "airimu", "fixed"),
    PgoSetting("raw IMU + learned cov", "raw", "learned"),
    PgoSetting("AirIMU + learned cov", "airimu", "learned"),
)


@dataclass(frozen=True)
class PgoRow:
    """ATE over seeds of one setting at one GPS rate on one sequence."""

    setting: str
    gps_hz: float
    sequence: str
    ate_mean_m: float
    ate_std_m: float


@dataclass(frozen=True)
class PgoOptions:
    """Rates, noise and seeds of the ablation; fixed densities in rad/s/sqrt(Hz) and m/s^2/sqrt(Hz)."""

    gps_hz: tuple[float, ...] = (1.0, 0.1)
    gps_sigma_m: float = 0.1
    seeds: int = 10
    keyframe_interval_s: float = 0.1
    fixed_gyro_density: float = 0.004
    fixed_acc_density: float = 0.08
    # where ATE is scored: "keyframes" (the whole keyframe span) or "gps" (from the first to the last fused fix:
    # past the last fix the graph dead-reckons, and how far depends on where the fixes fall, not on the setting)
    score_span: str = "keyframes"

    def __post_init__(self):
        if self.score_span not in SCORE_SPANS:
            raise ConfigError(f"options.score_span must be one of {', '.join(SCORE_SPANS)}, got {self.score_span!r}")


def write_exports(
    sequence: ImuSequence, correction: Correction, folder: Path, options: PgoOptions, settings=SETTINGS
) -> dict[str, Path]:
    """One export per setting for ``sequence`` (the model's ``correction``, (N, 3) float64 fields)."""
    index = keyframes_every(sequence, options.keyframe_interval_s)
    out = {}
    for setting in settings:
        gyro, acc = (None, None) if setting.samples == "raw" else (correction.gyro.numpy(), correction.acc.numpy())
        if setting.covariance == "fixed":
            covs = (options.fixed_gyro_density**2, options.fixed_acc_density**2)
        else:
            covs = (correction.gyro_cov.numpy(), correction.acc_cov.numpy())
        path = folder / f"{sequence.name}__{setting.samples}_{setting.covariance}.npz"
        out[setting.name] = export_preintegration(path, sequence, index, *covs, gyro, acc)
    return out


def gps_for(sequence: ImuSequence, rate_hz: float, sigma_m: float, seed: int) -> tuple[Gps, Gps]:
    """(GPS to fuse, GPS to score against). Simulated from ground truth when the sequence has it; else the real
    fixes decimated to ``rate_hz`` (the seed picks the phase) and scored against all of them."""
    if sequence.gt is not None:
        step = max(1, int(round(1.0 / (rate_hz * float(np.median(sequence.dt))))))
        index = np.arange(0, len(sequence), step)
        index = index[sequence.gt.valid[index]]
        rng = np.random.default_rng([seed, int(rate_hz * 1000)])
        noisy = sequence.gt.pos[index] + rng.normal(0.0, sigma_m, (len(index), 3))
        fuse = Gps(sequence.t[index], noisy, np.full((len(index), 3), sigma_m))
        truth = Gps(sequence.t, sequence.gt.pos, np.zeros((len(sequence), 3)))
        return fuse, truth
    if sequence.gps is None:
        raise ValueError(f"{sequence.name}: PGO needs ground truth or GPS fixes")
    fixes = sequence.gps
    period = float(np.median(np.diff(fixes.t)))
    step = max(1, int(round(1.0 / (rate_hz * period))))
    keep = np.arange(seed % step, len(fixes.t), step)
    return Gps(fixes.t[keep], fixes.pos[keep], fixes.sigma[keep]), Gps(fixes.t, fixes.pos, fixes.sigma)


def ate_m(solution: Solution, truth: Gps, fused: Gps | None = None) -> float:
    """RMSE, m, of the fused positions against the reference positions at the reference's own times within the
    keyframes' span (the trajectory interpolated between keyframes, ``Trajectory.position_at``; no alignment);
    with ``fused`` (the fixes that were fused), only between its first and last fix (``score_span: gps``)."""
    traj = solution.trajectory
    inside = (truth.t >= traj.t[0]) & (truth.t <= traj.t[-1])
    if fused is not None:
        inside &= (truth.t >= fused.t[0]) & (truth.t <= fused.t[-1])
    err = traj.position_at(truth.t[inside]) - truth.pos[inside]
    return float(np.sqrt(np.mean(np.sum(err**2, axis=1))))


def run_sequence(
    sequence: ImuSequence,
    correction: Correction,
    folder: Path,
    options: PgoOptions | None = None,
    fusion: FusionSettings | None = None,
    settings=SETTINGS,
) -> tuple[list[PgoRow], dict]:
    """Every setting x GPS rate x seed on one sequence; the rows, and one solution per setting at the first rate
    and seed 0 (for recordings and plots)."""
    options, fusion = options or PgoOptions(), fusion or FusionSettings()
    exports = write_exports(sequence, correction, folder, options, settings)
    rows, examples = [], {}
    for setting in settings:
        export = load_export(exports[setting.name])
        for rate in options.gps_hz:
            ates = []
            for seed in range(options.seeds):
                fuse, truth = gps_for(sequence, rate, options.gps_sigma_m, seed)
                graph, values = build_graph(export, fuse, fusion)
                solution = solve(graph, values, export.keyframe_t, fusion)
                ates.append(ate_m(solution, truth, fuse if options.score_span == "gps" else None))
                if seed == 0 and rate == options.gps_hz[0]:
                    examples[setting.name] = (solution, fuse)
            rows.append(PgoRow(setting.name, rate, sequence.name, float(np.mean(ates)), float(np.std(ates))))
            log.info("%s", asdict(rows[-1]))
    return rows, examples
