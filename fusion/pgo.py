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
per keyframe with its per-sample random walk and bias prior), in the same graph, keyframes, GPS fixes and noise,
first-state prior and Levenberg-Marquardt solver as the other rows (the example runs ISAM2 with a keyframe at every
1 Hz fix; ``benchmarks/kitti_gtsam_example.py`` runs it as shipped).

The product's main job end to end is ``ablate_pgo(config, out)``: it trains the configured model (or finishes its
interrupted run), corrects every evaluation sequence, runs the ablation (``run_sequence``) and returns what each
sequence produced (``SequenceResult``), from which ``record`` writes a Rerun recording and ``fusion.figures.plot``
a PNG; ``write_table`` writes the rows.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import typing
import weakref
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np

from factors import load_export
from fusion.graph import BiasStates, FusionSettings, Solution, build_graph, solve, with_marginals
from learned_imu.config import check_noise_density, load_config
from learned_imu.datasets.sequence import GpsFixes, ImuSequence, gap_indices
from learned_imu.errors import ConfigError, InputError
from learned_imu.evaluation.evaluate import dead_reckoning
from learned_imu.export import export_preintegration, keyframes_every, nearest_samples
from learned_imu.network.checkpoint import model_from_checkpoint
from learned_imu.network.inference import correct
from learned_imu.network.model import Correction
from learned_imu.training.experiment import load_sequences, train_run, with_epochs

if TYPE_CHECKING:
    from fusion.config import PgoConfig

log = logging.getLogger(__name__)
ScoreSpan = Literal["keyframes", "gps"]
GpsSource = Literal["auto", "simulated", "recorded"]
Keyframes = Literal["interval", "fixes"]
SCORE_SPANS, GPS_SOURCES, KEYFRAMES = (typing.get_args(t) for t in (ScoreSpan, GpsSource, Keyframes))


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

    @property
    def file_key(self) -> str:
        return self.key or f"{self.samples}_{self.covariance}"


SETTINGS = (
    PgoSetting("raw IMU + fixed cov", "raw", "fixed"),
    PgoSetting("AirIMU + fixed cov", "airimu", "fixed"),
    PgoSetting("raw IMU + learned cov", "raw", "learned"),
    PgoSetting("AirIMU + learned cov", "airimu", "learned"),
)
# GTSAM's IMUKittiExampleGPS.py, from KittiEquivBiasedImu_metadata.txt: GyroscopeSigma 1.75e-4, AccelerometerSigma
# 0.01 (continuous-time sigmas), AccelerometerBiasSigma 1.67e-4 and GyroscopeBiasSigma 2.91e-6 per sample (the
# example scales them by sqrt(samples) per interval), bias prior sigmas 0.1 (acc) and 5e-5 (gyro)
GTSAM_EXAMPLE = PgoSetting(
    "GTSAM example (raw IMU + bias states)", "raw", "fixed", (1.75e-4, 0.01), BiasStates(1.67e-4, 2.91e-6, 0.1, 5e-5),
    key="raw_gtsam_example",
)  # fmt: skip


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
    fixed_gyro_noise_density: float = 0.004
    fixed_acc_noise_density: float = 0.08
    # where ATE is scored: "keyframes" (the whole keyframe span) or "gps" (from the first to the last fused fix:
    # past the last fix the graph dead-reckons, and how far depends on where the fixes fall, not on the setting)
    score_span: ScoreSpan = "keyframes"
    # "simulated" (from the ground truth), "recorded" (the sequence's own fixes) or "auto" (simulated where there is
    # ground truth, else recorded)
    gps_source: GpsSource = "auto"
    # "interval": a keyframe every keyframe_interval_s; "fixes": one at the sample of every recorded fix (within half
    # a sample period; fixes inside a gap of the IMU are not used), so that each fused fix has its keyframe
    keyframes: Keyframes = "interval"
    gtsam_example: bool = False  # add the GTSAM_EXAMPLE row
    # with bias states (fusion.graph.BiasStates: per-sample random walk and prior sigmas): each of the four settings
    # also runs with a bias state per keyframe, as a row "<setting> + bias states"
    bias_states: BiasStates | None = None
    # (gyro rad/s/sqrt(Hz), acc m/s^2/sqrt(Hz)) sigmas, at least, of a sample that is held across a time gap of the
    # IMU (longer than MAX_GAP_STEPS median steps: KITTI's dropped OXTS packets), in every setting; null: none
    gap_noise_density: tuple[float, float] | None = None

    def __post_init__(self):
        if self.score_span not in SCORE_SPANS:
            raise ConfigError(f"options.score_span must be one of {', '.join(SCORE_SPANS)}, got {self.score_span!r}")
        if self.keyframes not in KEYFRAMES:
            raise ConfigError(f"options.keyframes must be one of {', '.join(KEYFRAMES)}, got {self.keyframes!r}")
        if not (self.gps_hz and all(math.isfinite(r) and r > 0 for r in self.gps_hz)):
            raise ConfigError(f"options.gps_hz must be a list of positive rates (Hz), got {list(self.gps_hz)!r}")
        for key in ("gps_sigma_m", "keyframe_interval_s"):
            value = getattr(self, key)
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"options.{key} must be a positive number, got {value!r}")
        if self.seeds < 1:
            raise ConfigError(f"options.seeds must be a whole number >= 1, got {self.seeds!r}")
        check_noise_density("gyro", self.fixed_gyro_noise_density, "options.fixed_gyro_noise_density")
        check_noise_density("acc", self.fixed_acc_noise_density, "options.fixed_acc_noise_density")
        if self.gap_noise_density is not None:
            check_noise_density("gyro", self.gap_noise_density[0], "options.gap_noise_density[0]")
            check_noise_density("acc", self.gap_noise_density[1], "options.gap_noise_density[1]")
        if self.gps_source not in GPS_SOURCES:
            raise ConfigError(f"options.gps_source must be one of {', '.join(GPS_SOURCES)}, got {self.gps_source!r}")

    @property
    def settings(self) -> tuple[PgoSetting, ...]:
        twins = ()
        if self.bias_states is not None:
            twins = tuple(
                dataclasses.replace(s, name=f"{s.name} + bias states", bias=self.bias_states, key=f"{s.file_key}_bias")
                for s in SETTINGS
            )
        return SETTINGS + twins + ((GTSAM_EXAMPLE,) if self.gtsam_example else ())


def write_exports(
    sequence: ImuSequence, correction: Correction, folder: Path, options: PgoOptions, settings=SETTINGS
) -> dict[str, Path]:
    """One export per setting for ``sequence`` (the model's ``correction``, (N, 3) float64 fields)."""
    if options.keyframes == "fixes":
        if sequence.gps is None:
            raise ConfigError(f"options.keyframes: 'fixes' needs recorded GPS fixes; {sequence.name} has none")
        index = np.unique(nearest_samples(sequence, sequence.gps.t)[0])
    else:
        index = keyframes_every(sequence, options.keyframe_interval_s)
    out = {}
    for setting in settings:
        gyro, acc = (None, None) if setting.samples == "raw" else (correction.gyro.numpy(), correction.acc.numpy())
        if setting.covariance == "fixed":
            fixed = (options.fixed_gyro_noise_density, options.fixed_acc_noise_density)
            gyro_sigma, acc_sigma = setting.noise_density or fixed
            covs = (gyro_sigma**2, acc_sigma**2)
        else:
            covs = (correction.gyro_cov.numpy(), correction.acc_cov.numpy())
        if options.gap_noise_density is not None:
            covs = _with_gap_noise(sequence, covs, options.gap_noise_density)
        path = folder / f"{sequence.name}__{setting.file_key}.npz"
        out[setting.name] = export_preintegration(path, sequence, index, *covs, gyro, acc)
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
        step = max(1, int(round(1.0 / (rate_hz * float(np.median(sequence.dt))))))
        index = np.arange(0, len(sequence), step)
        index = index[sequence.gt.valid[index]]
        rng = np.random.default_rng([seed, int(rate_hz * 1000)])
        noisy = sequence.gt.pos[index] + rng.normal(0.0, sigma_m, (len(index), 3))
        fuse = GpsFixes(sequence.t[index], noisy, np.full((len(index), 3), sigma_m))
        truth = GpsFixes(sequence.t, sequence.gt.pos, np.zeros((len(sequence), 3)))
        return fuse, truth
    if sequence.gps is None:
        raise InputError(f"{sequence.name}: PGO needs ground truth or GPS fixes")
    fixes = sequence.gps
    step = recorded_phases(sequence, rate_hz)
    keep = np.arange(seed % step, len(fixes.t), step)
    truth = fixes
    if sequence.gt is not None:
        valid = sequence.gt.valid
        truth = GpsFixes(sequence.t[valid], sequence.gt.pos[valid], np.zeros((int(valid.sum()), 3)))
    return fixes[keep], truth


def fixes_on_samples(sequence: ImuSequence) -> ImuSequence:
    """``sequence`` with only the recorded fixes that fall on an IMU sample (within half a sample period); the
    others (inside a gap of the IMU) are dropped with a warning."""
    if sequence.gps is None:
        raise InputError(f"{sequence.name}: no recorded GPS fixes")
    _, on_sample = nearest_samples(sequence, sequence.gps.t)
    if not on_sample.all():
        log.warning("%s: %d of %d GPS fixes lie in gaps of the IMU and are not used", sequence.name,
                    int((~on_sample).sum()), on_sample.size)  # fmt: skip
    fixes = sequence.gps
    return dataclasses.replace(sequence, gps=fixes[on_sample])


def recorded_phases(sequence: ImuSequence, rate_hz: float) -> int:
    """How many recorded fixes there are per fused fix at ``rate_hz``: the number of distinct decimations."""
    if sequence.gps is None or len(sequence.gps.t) < 2:
        raise InputError(f"{sequence.name}: PGO needs ground truth or GPS fixes")
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


def run_sequence(
    sequence: ImuSequence,
    correction: Correction,
    folder: Path,
    options: PgoOptions | None = None,
    fusion: FusionSettings | None = None,
    settings=None,
) -> tuple[list[PgoRow], dict]:
    """Every setting (default: ``options.settings``) x GPS rate x seed on one sequence; the rows, and one solution
    per setting at the first rate and seed 0 (for recordings and plots)."""
    options, fusion = options or PgoOptions(), fusion or FusionSettings()
    settings = settings or options.settings
    if options.keyframes == "fixes":
        sequence = fixes_on_samples(sequence)
    exports = write_exports(sequence, correction, folder, options, settings)
    recorded = options.gps_source == "recorded" or (options.gps_source == "auto" and sequence.gt is None)
    rows, examples = [], {}
    for setting in settings:
        export = load_export(exports[setting.name])
        for rate in options.gps_hz:
            ates = []
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
                ates.append(ate_m(solution, truth, fuse if options.score_span == "gps" else None))
                if seed == 0 and rate == options.gps_hz[0]:
                    examples[setting.name] = (solution, fuse)
            rows.append(PgoRow(setting.name, rate, sequence.name, float(np.mean(ates)), float(np.std(ates))))
            log.info("%s", asdict(rows[-1]))
    return rows, examples


@dataclass(frozen=True, eq=False)
class SequenceResult:
    """What one sequence produced: its rows, the model output, and one solution per setting (first rate, seed 0)."""

    sequence: ImuSequence
    correction: Correction
    rows: list[PgoRow]
    examples: dict


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
    run = Path(config.run)
    from fusion.recording import write_training_recording

    # resumes an interrupted run, drawing its epochs into run/training.rrd; returns at once if finished
    train_run(experiment, run, progress=progress, on_epoch=write_training_recording)
    model, _ = model_from_checkpoint(run / "best.pt")
    specs = config.sequences or experiment.data.evaluate or experiment.data.val
    results = []
    for sequence in load_sequences(specs, experiment.data.root):
        correction = correct(model, sequence, experiment.train.remove_gravity)
        rows, examples = run_sequence(sequence, correction, out / "exports", config.options, config.fusion)
        results.append(SequenceResult(sequence, correction, rows, examples))
    return results


def record(result: SequenceResult, path: str | Path) -> Path:
    """A Rerun recording of one sequence (``fusion.recording``): ground truth, GPS, fused tracks with covariance
    ellipsoids, errors against 3-sigma bounds, raw and AirIMU dead reckoning, IMU series, corrections, sigmas."""
    from fusion.recording import ImuSeries, Track, write_recording

    seq, c = result.sequence, result.correction
    fused = [Track(name, *marginal_track(solution)) for name, (solution, _) in result.examples.items()]
    times = fused[0].t
    truth, drift = None, []
    if seq.gt is not None:
        truth = Track("ground truth", seq.t, seq.gt.pos)
        drift = [
            Track("raw IMU", times, _at_times(seq, dead_reckoning(seq, seq.gyro, seq.acc), times)),
            Track("AirIMU", times, _at_times(seq, dead_reckoning(seq, c.gyro.numpy(), c.acc.numpy()), times)),
        ]
    gps = next(iter(result.examples.values()))[1]
    imu = ImuSeries(seq.t, seq.gyro, seq.acc, c.d_gyro.numpy(), c.d_acc.numpy(), c.gyro_cov.numpy(), c.acc_cov.numpy())
    return write_recording(path, fused, truth, drift, (gps.t, gps.pos), imu)


def _at_times(sequence: ImuSequence, pos: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Per-sample positions (N, 3) at ``times`` (the sample at or after each time)."""
    return pos[np.clip(np.searchsorted(sequence.t, times), 0, len(sequence) - 1)]


def marginal_track(solution) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, pos, pos_cov) of a solution's keyframes, the marginals computed once per solution."""
    if solution not in _MARGINALS:
        trajectory = with_marginals(solution)
        _MARGINALS[solution] = (trajectory.t, trajectory.pos, trajectory.pos_cov)
    return _MARGINALS[solution]


_MARGINALS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # record() and plot() share them


def paper_ate(row: PgoRow) -> float | None:
    """The paper's ATE (m) for a row's sequence, GPS rate and setting, or None where it has none."""
    from learned_imu.evaluation.paper import EUROC_PGO

    return EUROC_PGO.get(row.sequence, {}).get(row.gps_hz, {}).get(row.setting)


def write_table(rows: list[PgoRow], json_path: str | Path | None = None, csv_path: str | Path | None = None) -> None:
    """The ablation rows as JSON (keys setting, gps_hz, sequence, ate_mean_m, ate_std_m, paper_ate_m) and/or CSV,
    atomically; ``paper_ate_m`` is the AirIMU paper's published ATE for that cell (``learned_imu.evaluation.paper``),
    or null."""
    from dataclasses import asdict

    from learned_imu.io import write_csv_atomic, write_json_atomic

    records = [{**asdict(r), "paper_ate_m": paper_ate(r)} for r in rows]
    if json_path:
        write_json_atomic(json_path, records)
    if csv_path:
        write_csv_atomic(csv_path, records)
