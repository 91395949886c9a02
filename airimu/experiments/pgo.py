"""The paper's PGO ablation (AirIMU sec. V-C): IMU + GPS pose graphs with raw or corrected IMU and fixed or
learned covariance; the settings are data, one runner.

Per evaluation sequence: the model corrects the IMU and predicts its noise; four exports are written
(samples raw | AirIMU) x (covariance fixed | learned); for each GPS rate and seed the graph is solved
(``fusion.graph``) and scored by ATE (RMSE of keyframe positions, no alignment: GPS fixes the world frame).

GPS (``options.gps_source``): simulated from the ground truth (``gps_sigma_m`` per axis, seeded) at each rate, or
the sequence's recorded fixes (their own sigma) decimated to the rate with the seed choosing the phase (so there are
only as many distinct draws as fixes per fused fix: more seeds are not run); scored against the ground truth at
its own times, or against all recorded fixes where there is none. The fixed covariance is the VINS-Mono EuRoC
setting (acc 0.08 m/s^2/sqrt(Hz), gyro 0.004 rad/s/sqrt(Hz)), as in the paper.

``options.gtsam_example`` adds a fifth row, ``GTSAM_EXAMPLE``: the settings of GTSAM's ``IMUKittiExampleGPS.py``
on the raw IMU (its noise densities from ``KittiEquivBiasedImu_metadata.txt``, integration noise 0, a bias state
per keyframe with its bias prior and its random walk counted as the example counts it, ``walk="cumulative"``), in
the same graph, keyframes, GPS fixes and noise,
first-state prior and Levenberg-Marquardt solver as the other rows (the example runs ISAM2 with a keyframe at every
1 Hz fix; ``benchmarks/kitti_gtsam_example.py`` runs it as shipped).

The product's main job end to end is ``ablate_pgo(config, out)``: it trains the configured model (or finishes its
interrupted run), corrects every evaluation sequence, runs the ablation (``run_sequence``) and returns what each
sequence produced (``SequenceResult``), from which ``record`` writes a Rerun recording and ``airimu.viz.figures.plot``
a PNG; ``write_table`` writes the rows.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import asdict, dataclass
from functools import partial
from pathlib import Path

import numpy as np

from airimu.experiments.pgo_config import GPS_SOURCES, PgoConfig, PgoOptions
from airimu.fuse import Fused, motion_on
from airimu.viz.results import SequenceResult, marginal_track, record  # noqa: F401 (re-exported)
from airimu_core.errors import ConfigError, InputError
from airimu_core.export import Export, save_export
from airimu_core.sequence import GpsFixes, ImuSequence, gap_indices
from fusion import consistency
from fusion.config import BiasStates, FusionSettings, MotionSettings
from fusion.graph import Solution, build_graph, solve
from learned_imu.config import load_config
from learned_imu.export import (  # noqa: F401
    fixes_on_samples,
    keyframes_every,
    merge_keyframes,
    nearest_samples,
    preintegration_export,
)
from learned_imu.network.checkpoint import model_from_checkpoint, motion_from_checkpoint
from learned_imu.network.inference import correct
from learned_imu.network.model import Correction
from learned_imu.training.experiment import load_sequences, train_run, with_epochs

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PgoSetting:
    """One setting: which samples (``"raw"`` or ``"airimu"``) and which covariance (``"fixed"`` or ``"learned"``).

    ``noise_density``: (gyro rad/s/sqrt(Hz), acc m/s^2/sqrt(Hz)), sigmas, of a ``"fixed"`` covariance (None: the
    options' ``fixed_*_noise_density``); ``bias``: estimate bias states (``fusion.graph.BiasStates``); ``key``: the
    export's file-name part."""

    name: str
    samples: str
    covariance: str
    noise_density: tuple[float, float] | None = None
    bias: BiasStates | None = None
    key: str = ""
    motion: bool = False  # a learned body-frame velocity factor at every keyframe (PgoConfig.motion)

    @property
    def file_key(self) -> str:
        return self.key or f"{self.samples}_{self.covariance}"


SETTINGS = (
    PgoSetting("raw IMU + fixed cov", "raw", "fixed"),
    PgoSetting("AirIMU + fixed cov", "airimu", "fixed"),
    PgoSetting("raw IMU + learned cov", "raw", "learned"),
    PgoSetting("AirIMU + learned cov", "airimu", "learned"),
)
# with a motion model (PgoConfig.motion): the learned velocity factor beside the paper's best row and the raw IMU
MOTION_SETTINGS = (
    PgoSetting("AirIMU + learned cov + motion", "airimu", "learned", motion=True, key="airimu_learned"),
    PgoSetting("raw IMU + fixed cov + motion", "raw", "fixed", motion=True, key="raw_fixed"),
)
# GTSAM's IMUKittiExampleGPS.py, from KittiEquivBiasedImu_metadata.txt: GyroscopeSigma 1.75e-4, AccelerometerSigma
# 0.01 (continuous-time sigmas), AccelerometerBiasSigma 1.67e-4 and GyroscopeBiasSigma 2.91e-6 per sample (the
# example scales them by sqrt(samples since its first keyframe): walk="cumulative"), bias prior sigmas 0.1 and 5e-5
GTSAM_EXAMPLE = PgoSetting(
    "GTSAM example (raw IMU + bias states)",
    "raw",
    "fixed",
    (1.75e-4, 0.01),
    BiasStates(1.67e-4, 2.91e-6, 0.1, 5e-5, walk="cumulative"),
    key="raw_gtsam_example",
)


@dataclass(frozen=True)
class PgoRow:
    """ATE over seeds of one setting at one GPS rate on one sequence; the solutions checked against their own noise
    model (``fusion.consistency``): the GPS and IMU factors' chi-square per degree of freedom, mean over the seeds
    (about 1 when the inputs fit their sigmas; None where the graph has no such factor)."""

    setting: str
    gps_hz: float
    sequence: str
    ate_mean_m: float
    ate_std_m: float
    gps_chi2_per_dof: float | None = None
    imu_chi2_per_dof: float | None = None


def settings_of(options: PgoOptions, motion: bool = False) -> tuple[PgoSetting, ...]:
    """The settings ``options`` run: the four of ``SETTINGS``, their bias-state twins with ``bias_states``,
    ``GTSAM_EXAMPLE`` with ``gtsam_example``, and ``MOTION_SETTINGS`` with a motion model."""
    twins = ()
    if options.bias_states is not None:
        twins = tuple(
            dataclasses.replace(s, name=f"{s.name} + bias states", bias=options.bias_states, key=f"{s.file_key}_bias")
            for s in SETTINGS
        )
    return SETTINGS + twins + ((GTSAM_EXAMPLE,) if options.gtsam_example else ()) + (MOTION_SETTINGS if motion else ())


def write_exports(
    sequence: ImuSequence, correction: Correction, folder: Path, options: PgoOptions, settings=SETTINGS
) -> dict[str, Export]:
    """One export per setting for ``sequence`` (the model's ``correction``, (N, 3) float64 fields), in memory; each
    also written to ``folder`` (``<sequence>__<setting>.npz``) for inspection or another process."""
    if options.keyframes == "fixes":
        if sequence.gps is None:
            raise ConfigError(f"options.keyframes: 'fixes' needs recorded GPS fixes; {sequence.name} has none")
        index = np.unique(nearest_samples(sequence, sequence.gps.t)[0])
    else:  # the grid, and a keyframe at the sample of every fix any rate fuses (each at its own time)
        index = merge_keyframes(_fix_samples(sequence, options), keyframes_every(sequence, options.keyframe_interval_s))
    out, by_key = {}, {}
    for setting in settings:
        if setting.file_key in by_key:  # a motion row shares its export with the row it extends
            out[setting.name] = by_key[setting.file_key]
            continue
        gyro, acc = (None, None) if setting.samples == "raw" else (correction.gyro.numpy(), correction.acc.numpy())
        if setting.covariance == "fixed":
            fixed = (options.fixed_gyro_noise_density, options.fixed_acc_noise_density)
            gyro_sigma, acc_sigma = setting.noise_density or fixed
            covs = (gyro_sigma**2, acc_sigma**2)
        else:
            covs = (correction.gyro_cov.numpy(), correction.acc_cov.numpy())
        if options.gap_noise_density is not None:
            covs = _with_gap_noise(sequence, covs, options.gap_noise_density)
        out[setting.name] = by_key[setting.file_key] = preintegration_export(sequence, index, *covs, gyro, acc)
        save_export(out[setting.name], folder / f"{sequence.name}__{setting.file_key}.npz")
    return out


def _with_gap_noise(sequence: ImuSequence, covs, gap_sigmas) -> tuple[np.ndarray, np.ndarray]:
    """Per-sample (N, 3) densities (gyro, acc) with each sample held across a time gap raised to at least
    ``gap_sigmas`` squared (``PgoOptions.gap_noise_density``)."""
    gap = gap_indices(sequence.t)
    out = []
    for cov, sigma in zip(covs, gap_sigmas, strict=True):
        cov = np.array(np.broadcast_to(cov, (len(sequence), 3)), dtype=float)
        cov[gap] = np.maximum(cov[gap], sigma**2)
        out.append(cov)
    return out[0], out[1]


def gps_for(
    sequence: ImuSequence, rate_hz: float, sigma_m: float, seed: int, source: str = "auto"
) -> tuple[GpsFixes, GpsFixes]:
    """(GPS to fuse, GPS to score against). ``source`` (module docstring): ``"simulated"`` from the ground truth,
    ``"recorded"``: the sequence's fixes decimated to ``rate_hz`` (the seed picks the phase), scored against the
    ground truth where it is valid, else against all fixes; ``"auto"``: simulated when there is ground truth."""
    if source not in GPS_SOURCES:
        raise InputError(f"gps_for: source must be one of {GPS_SOURCES}, got {source!r}")
    if source == "simulated" and sequence.gt is None:
        raise InputError(f"{sequence.name}: simulated GPS needs ground truth")
    if source != "recorded" and sequence.gt is not None:
        index = _simulated_index(sequence, rate_hz)
        rng = np.random.default_rng([seed, int(rate_hz * 1000)])
        noisy = sequence.gt.pos[index] + rng.normal(0.0, sigma_m, (len(index), 3))
        fuse = GpsFixes(sequence.t[index], noisy, np.full((len(index), 3), sigma_m))
        truth = GpsFixes(sequence.t, sequence.gt.pos, np.zeros((len(sequence), 3)))
        return fuse, truth
    if sequence.gps is None:
        raise InputError(
            f"{sequence.name}: PGO needs ground truth or GPS fixes, and the sequence was read with "
            "neither (a reader's gps_file or gps_topic option, or its ground-truth file)"
        )
    fixes = sequence.gps
    step = recorded_phases(sequence, rate_hz)
    keep = np.arange(seed % step, len(fixes.t), step)
    truth = fixes
    if sequence.gt is not None:
        valid = sequence.gt.valid
        truth = GpsFixes(sequence.t[valid], sequence.gt.pos[valid], np.zeros((int(valid.sum()), 3)))
    return fixes[keep], truth


def _simulated_index(sequence: ImuSequence, rate_hz: float) -> np.ndarray:
    """The samples simulated fixes at ``rate_hz`` lie on: every (1 / rate)-th from the first, where ground truth is
    valid."""
    step = max(1, int(round(1.0 / (rate_hz * float(np.median(sequence.dt))))))
    index = np.arange(0, len(sequence), step)
    return index[sequence.gt.valid[index]]


def _recorded(sequence: ImuSequence, options: PgoOptions) -> bool:
    """Whether the fused fixes are the sequence's recorded ones (``options.gps_source``)."""
    return options.gps_source == "recorded" or (options.gps_source == "auto" and sequence.gt is None)


def _fix_samples(sequence: ImuSequence, options: PgoOptions) -> np.ndarray:
    """The samples of every fix that some GPS rate of ``options`` fuses (``gps_for``'s sources)."""
    if _recorded(sequence, options):
        if sequence.gps is None:
            return np.zeros(0, dtype=int)
        index, on_sample = nearest_samples(sequence, sequence.gps.t)
        return index[on_sample]
    return np.unique(np.concatenate([_simulated_index(sequence, hz) for hz in options.gps_hz]))


def recorded_phases(sequence: ImuSequence, rate_hz: float) -> int:
    """How many recorded fixes there are per fused fix at ``rate_hz``: the number of distinct decimations."""
    if sequence.gps is None or len(sequence.gps.t) < 2:
        count = 0 if sequence.gps is None else len(sequence.gps.t)
        raise InputError(
            f"{sequence.name}: PGO on recorded GPS needs at least two fixes in the IMU's time span, "
            f"the sequence has {count}"
        )
    return max(1, int(round(1.0 / (rate_hz * float(np.median(np.diff(sequence.gps.t)))))))


def ate_m(solution: Solution, truth: GpsFixes, fused: GpsFixes | None = None) -> float:
    """RMSE, m, of the fused positions against the reference positions at the reference's own times within the
    keyframes' span (the trajectory interpolated between keyframes, ``Trajectory.position_at``; no alignment);
    with ``fused`` (the fixes that were fused), only between its first and last fix (``score_span: gps``)."""
    traj = solution.trajectory
    inside = (truth.t >= traj.t[0]) & (truth.t <= traj.t[-1])
    if fused is not None:
        inside &= (truth.t >= fused.t[0]) & (truth.t <= fused.t[-1])
    if not inside.any():
        raise InputError("ate_m: no reference position lies within the scored span")
    err = traj.position_at(truth.t[inside]) - truth.pos[inside]
    return float(np.sqrt(np.mean(np.sum(err**2, axis=1))))


def _solved_with(last: Fused, export: Export, fusion: FusionSettings, bias, velocities) -> Fused:
    """``last``'s graph (``export``, its fixes) with the motion factors of ``velocities``, solved from ``last``."""
    graph, values = build_graph(export, last.gps, fusion, bias=bias, motion=velocities, guess=last.solution.values)
    return Fused(solve(graph, values, export.keyframe_t, fusion), last.correction, last.gps, last.sequence)


def run_sequence(
    sequence: ImuSequence,
    correction: Correction,
    folder: Path,
    options: PgoOptions | None = None,
    fusion: FusionSettings | None = None,
    settings=None,
    motion=None,
    motion_settings: MotionSettings | None = None,
) -> tuple[list[PgoRow], dict]:
    """Every setting (default: ``settings_of(options)``, with the motion rows when ``motion``, a ``MotionNet``, is
    given) x GPS rate x seed on one sequence; the rows, and one solution per setting at the first rate and seed 0
    (for recordings and plots). A motion row solves the graph ``motion_settings.passes`` more times, each with the
    model's velocities on the previous solution's attitude (the first: the row without them), never ground truth."""
    options, fusion = options or PgoOptions(), fusion or FusionSettings()
    motion_settings = motion_settings or MotionSettings()
    settings = settings or settings_of(options, motion is not None)
    if options.keyframes == "fixes":
        sequence = fixes_on_samples(sequence)
    exports = write_exports(sequence, correction, folder, options, settings)
    recorded = _recorded(sequence, options)
    rows, examples = [], {}
    for setting in settings:
        export = exports[setting.name]
        for rate in options.gps_hz:
            ates, fits = [], []
            seeds = min(options.seeds, recorded_phases(sequence, rate)) if recorded else options.seeds
            for seed in range(seeds):
                fuse, truth = gps_for(sequence, rate, options.gps_sigma_m, seed, options.gps_source)
                if len(fuse.t) < 2:
                    raise ConfigError(
                        f"options.gps_hz: at {rate:g} Hz {sequence.name} ({sequence.t[-1] - sequence.t[0]:.4g} s) gets "
                        f"{len(fuse.t)} GPS fix; a pose graph scored between fixes needs at least two"
                    )
                graph, values = build_graph(export, fuse, fusion, bias=setting.bias)
                solution = solve(graph, values, export.keyframe_t, fusion)
                passes = motion_settings.passes if setting.motion else 0
                for k in range(passes):  # the speed envelope checked in the last pass (airimu.fuse.motion_on)
                    fused = Fused(solution, correction, fuse, sequence)
                    solve_with = partial(_solved_with, fused, export, fusion, setting.bias)
                    velocities = motion_on(fused, motion, motion_settings, solve_with if k == passes - 1 else None)
                    solution = solve_with(velocities).solution
                ates.append(ate_m(solution, truth, fuse if options.score_span == "gps" else None))
                fits.append(consistency.residuals(solution.graph, solution.values))
                if seed == 0 and rate == options.gps_hz[0]:
                    examples[setting.name] = (solution, fuse)
            chi2 = {kind: _mean_per_dof(fits, kind) for kind in ("gps", "imu")}
            rows.append(
                PgoRow(
                    setting.name,
                    rate,
                    sequence.name,
                    float(np.mean(ates)),
                    float(np.std(ates)),
                    chi2["gps"],
                    chi2["imu"],
                )
            )
            log.info("%s", asdict(rows[-1]))
            for kind in ("gps", "imu"):
                # the raw samples of the paper's rows carry the sensor's bias on purpose, which a setting without bias
                # states does not model: their IMU misfit is the ablation's point, said at INFO, not a warning
                expected = kind == "imu" and setting.samples == "raw" and setting.bias is None
                for message in consistency.check({kind: fits[0][kind]} if kind in fits[0] else {}):
                    log.log(
                        logging.INFO if expected else logging.WARNING,
                        "%s, %s at %g Hz GPS (seed 0): %s%s",
                        sequence.name,
                        setting.name,
                        rate,
                        message,
                        " (expected: raw samples without bias states)" if expected else "",
                    )
    return rows, examples


def _mean_per_dof(fits: list[dict], kind: str) -> float | None:
    """The mean over seeds of one kind's chi-square per degree of freedom, None where no seed's graph has it."""
    values = [fit[kind].per_dof for fit in fits if kind in fit]
    return float(np.mean(values)) if values else None


def ablate_pgo(
    config: PgoConfig,
    out: str | Path,
    progress: bool = True,
    data_root: str | Path | None = None,
    epochs: int | None = None,
) -> list[SequenceResult]:
    """Run the PGO ablation of ``config`` (see the module docstring); exports go to ``out/exports``."""
    out = Path(out)
    experiment = load_config(config.experiment, data_root=data_root)
    if epochs:
        experiment = with_epochs(experiment, epochs)
    model, _ = model_from_checkpoint(correction_checkpoint(config.run, experiment, progress))
    motion = motion_from_checkpoint(config.motion)[0] if config.motion else None
    specs = config.sequences or experiment.data.evaluate or experiment.data.val
    results = []
    for sequence in load_sequences(specs, experiment.data.root):
        correction = correct(model, sequence, experiment.train.remove_gravity)
        rows, examples = run_sequence(
            sequence, correction, out / "exports", config.options, config.fusion, None, motion, config.motion_settings
        )
        results.append(SequenceResult(sequence, correction, rows, examples))
    return results


def correction_checkpoint(run: str, experiment, progress: bool = True) -> Path:
    """The AirIMU checkpoint of a PGO config's ``run``: a shipped model's file when ``run`` names one and is no
    folder here (``airimu models``; nothing is trained), else ``run/best.pt``, trained -- or resumed, its epochs
    drawn into ``run/training.rrd`` -- from ``experiment`` first (at once if finished)."""
    from learned_imu.network.shipped import shipped_path

    shipped = None if Path(run).exists() else shipped_path(run)
    if shipped is not None:
        return shipped
    from airimu.viz.recording import write_training_recording

    train_run(experiment, Path(run), progress=progress, on_epoch=write_training_recording)
    return Path(run) / "best.pt"


def paper_ate(row: PgoRow) -> float | None:
    """The paper's ATE (m) for a row's sequence, GPS rate and setting, or None where it has none."""
    from learned_imu.evaluation.paper import EUROC_PGO

    return EUROC_PGO.get(row.sequence, {}).get(row.gps_hz, {}).get(row.setting)


def write_table(rows: list[PgoRow], json_path: str | Path | None = None, csv_path: str | Path | None = None) -> None:
    """The ablation rows as JSON (keys setting, gps_hz, sequence, ate_mean_m, ate_std_m, gps_chi2_per_dof,
    imu_chi2_per_dof, paper_ate_m) and/or CSV,
    atomically; ``paper_ate_m`` is the AirIMU paper's published ATE for that cell (``learned_imu.evaluation.paper``),
    or null."""
    from dataclasses import asdict

    from airimu_core.io import write_csv_atomic, write_json_atomic

    records = [{**asdict(r), "paper_ate_m": paper_ate(r)} for r in rows]
    if json_path:
        write_json_atomic(json_path, records)
    if csv_path:
        write_csv_atomic(csv_path, records)
