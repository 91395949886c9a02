"""A user's own IMU + GPS log in, a fused trajectory out: ``fuse(sequence, gps, model=None, ...)``, behind ``airimu
fuse``.

Stage by stage (independent of the PGO ablation's code; the recording and figure of ``airimu.viz.results``): the model
corrects the IMU and predicts its noise (or, without a model, the raw samples with fixed noise densities); an export
holds the keyframe preintegrations, a keyframe at the IMU sample of every fix (fixes inside a gap of the IMU are not
used), so that each fix constrains the state at its own time, and every ``keyframe_s`` between them;
``fusion.solve`` builds the graph (GPS factors, robust ones with ``graph.gps_robust``, optional bias states) and
Levenberg-Marquardt solves it. The first state is found from the
GPS track (``fusion.initial.aligned_first_state``), never from ground truth: a sequence's ground truth, if it has
one, only scores the result.

GPS files are read by ``learned_imu.datasets.gps.read_gps_csv``.

Not fused wrong in silence: given noise densities that the samples themselves contradict (``factors.noise``: a
warning naming both numbers when a sigma lies 100x under or 10x over the samples' own white noise: a variance given
for a sigma, another unit; after the solve, an IMU misfit with densities the user gave names them beside the
samples' own noise); refused: a GPS track that fits the
IMU far better read in another unit (``check_gps_units``, ``fusion.gps_units``: lat/lon in radians read as degrees,
x/y/z in km or mm; ``airimu fuse`` runs it on every GPS file).
Scoring (``write_outputs``): the fused track lives in the GPS frame, the ground truth in its own, so the ATE is
reported both after an SE(3) alignment of the ground truth to the fused track (as ``evo_ape -a``) and without one.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np

from airimu_core.errors import ConfigError, DataError, InputError
from airimu_core.motion import BodyVelocities
from airimu_core.sequence import GPS_SIGMA_UNKNOWN_M, GpsFixes, ImuSequence, read_later
from factors.noise import noise_mismatch
from fusion.config import FuseConfig, MotionSettings
from fusion.graph import Solution, Trajectory, scale_keys
from fusion.solve import solve_export
from fusion.still import StillStart, still_start
from learned_imu.datasets._tilt import GYRO_READINGS, check_gyro_unit, reading_fixes
from learned_imu.datasets.gps import gps_file_layout, read_gps_csv
from learned_imu.export import (
    check_keyframe_interval,
    fixes_on_samples,
    keyframes_every,
    merge_keyframes,
    nearest_samples,
    preintegration_export,
)
from learned_imu.network.model import Correction
from learned_imu.network.rate import check_imu_delay

UNCOVERED_WARNING_S = 30.0  # IMU time before the first or after the last fix that is worth a warning
MODEL_REFUSAL_RATIO = 3.0  # a model leaving this many times more GPS motion unexplained than the raw IMU is refused
UNIT_REFUSAL_RATIO = 2.0  # refused when another reading of the file leaves this many times less motion unexplained
# (a right file read any other way explains its track 1.04-3.6x worse, five KITTI drives x five noise draws, so no
# ratio refuses it; x/y/z in km on a straight drive read in m explains it 2.35x better: refused at 2, not at 3)
log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FusedSummary:
    """``summary.json``: the sequence, the keyframes solved, the fixes fused and the reference fixes inside the
    trajectory's span, the position RMSE at those fixes (m), and where the sequence has ground truth the ATE (m,
    RMSE over every IMU sample of ``fused_imu_rate.tum`` with valid ground truth) after a rigid SE(3) alignment of
    the ground truth to the fused track (``ate_aligned_m``; as ``evo_ape tum truth fused_imu_rate.tum -a``) and
    without one (``ate_unaligned_m``: meaningful only when the GPS frame is the ground truth's); None without."""

    sequence: str
    keyframes: int
    fused_fixes: int
    reference_fixes: int
    rmse_to_gps_m: float | None  # None without a reference fix inside the span
    ate_aligned_m: float | None
    ate_unaligned_m: float | None
    # per kind of factor ("gps", "imu", "bias", "motion", "prior"): factors, dof and chi-square per degree of freedom
    # at the solution (``fusion.consistency``; about 1 when the inputs fit their sigmas)
    normalised_residuals: dict | None = None
    # per GPS outage: start_s, duration_s (from the first sample), end_t_s (IMU clock) and the position error there
    # as a causal estimator has it (the log solved up to the outage's end: no later fix or velocity pulls it), m:
    # against the ground truth (``error_to_truth_m``, the truth aligned as for ate_aligned_m; None without) and
    # against the reference fix nearest the end within 1 s (``error_to_gps_m``; None without)
    outages: list | None = None
    motion_factors: int = 0  # learned body-frame velocity factors in the graph
    # the first state the graph started from (its prior's mean: the GPS-track alignment, or --start) against the
    # ground truth where there is one: attitude error, deg, split into roll/pitch (tilt: gravity's direction) and
    # yaw (heading); None without ground truth at the first keyframe
    initial_attitude_error_deg: dict | None = None
    # the still start the raw gyro's bias came from (fusion.still): duration_s, gyro_bias_rad_s and its sigma,
    # tilt_sigma_deg, and against the ground truth where there is one the tilt of its gravity (tilt_error_deg);
    # None without one (or with a model, which corrects the bias itself)
    still_start: dict | None = None
    # the motion factors' speed-scale states (motion.scale_sigma), one per motion.scale_interval_s from the first
    # keyframe, in time order: how much faster the estimate moves than the motion model reads; None without them
    speed_scales: list | None = None


@dataclass(frozen=True, eq=False)
class FuseRequest:
    """What ``airimu fuse`` asks for: the log (read), the output folder, the config (flags laid over the file), the
    GPS (a CSV, else the log's own fixes; ``gps_sigma_m``: a sigma for a file without sigma columns, or replacing
    the log's fixes' sigmas), every ``gps_every``-th fix fused (all score the result), the GPS clock's offset
    (subtracted from every fix time) and an optional model checkpoint. ``source`` names the log in messages."""

    sequence: ImuSequence
    source: str
    out: Path
    config: FuseConfig
    gps_file: str | None = None
    gps_sigma_m: float | None = None
    gps_every: int = 1
    gps_time_offset_s: float = 0.0
    checkpoint: str | None = None
    motion_checkpoint: str | None = None  # a motion model: learned velocity factors (FuseConfig.motion)
    start: object = None  # fuse's start: None, "ground-truth" or a gtsam.NavState at the first sample
    no_gps: bool = False  # fuse no fix (dead reckoning from start)
    outages: tuple[tuple[float, float], ...] = ()  # (start, duration) s from the first sample
    trust_model: bool = False  # fuse with the model even where its samples fit the GPS far worse than the raw ones


@dataclass(frozen=True, eq=False)
class FuseDone:
    """What ``run_fuse`` did: the summary written, the files written, the number of fixes fused."""

    summary: FusedSummary
    written: list[Path]
    fused_fixes: int


def run_fuse(request: FuseRequest) -> FuseDone:
    """``airimu fuse``: the GPS read and checked (units, clock), the model loaded, the log fused and the outputs
    written (``write_outputs``) under a writer lock on the folder (a second run into it is refused)."""
    from airimu_core.io import folder_lock

    sequence, config = request.sequence, request.config
    if request.no_gps:
        fixes = None
        sequence = dataclasses.replace(sequence, gps=None)
    elif request.gps_file:
        fixes = read_gps_csv(request.gps_file, config.gps_sigma_m)
        check_gps_units(sequence, request.gps_file, fixes, config.gps_sigma_m)
    elif sequence.gps is None:
        raise DataError(request.source, "gps", "the log has no GPS fixes; give a GPS file")
    else:
        fixes = sequence.gps if request.gps_sigma_m is None else sequence.gps.with_sigma(request.gps_sigma_m)
    if fixes is not None:
        if request.gps_time_offset_s:
            fixes = dataclasses.replace(fixes, t=fixes.t - request.gps_time_offset_s)
        check_gps_times(sequence, request.gps_file or request.source, fixes)
        check_gps_clock(sequence, request.gps_file or request.source, fixes)
    model = motion = None
    if request.checkpoint:
        from learned_imu.network.checkpoint import model_from_checkpoint

        model = model_from_checkpoint(request.checkpoint)[0]
    if request.motion_checkpoint:
        from learned_imu.network.checkpoint import motion_from_checkpoint

        motion = motion_from_checkpoint(request.motion_checkpoint)[0]
    fused = None if fixes is None else fixes[:: request.gps_every]
    with folder_lock(request.out):  # one writer per folder from here on
        start, outages = request.start, request.outages
        result = fuse(sequence, fused, model, config, motion, start, outages, request.trust_model, request.checkpoint)
        summary, written = write_outputs(result, request.out, reference=fixes)
    return FuseDone(summary, written, len(result.gps.t))


@dataclass(frozen=True, eq=False)
class Fused:
    """The result: the solution (``.trajectory`` with marginal position covariances), the model's correction of
    the IMU (raw samples with fixed noise without a model), the fixes that were fused, and the sequence."""

    solution: Solution
    correction: Correction
    gps: GpsFixes
    sequence: ImuSequence
    residuals: dict = dataclasses.field(default_factory=dict)  # fusion.consistency.residuals of the solution
    motion: BodyVelocities | None = None  # the motion model's velocities of the last pass (fused with cov_scale)
    outages: tuple[tuple[float, float], ...] = ()  # (start, duration) s from the first sample: no fix fused
    # per outage: (time s, position (3,) m) at its end as the log up to then solves (no later fix or velocity)
    outage_ends: tuple = ()
    still: StillStart | None = None  # the still start whose gyro bias was taken out (raw IMU only)


def fuse(
    sequence: ImuSequence,
    gps: GpsFixes | None = None,
    model=None,
    config: FuseConfig | None = None,
    motion_model=None,
    start=None,
    outages: tuple[tuple[float, float], ...] = (),
    trust_model: bool = False,
    model_source: str | None = None,
) -> Fused:
    """Fuse ``sequence``'s IMU with ``gps`` (default: the sequence's own fixes; none at all: dead reckoning, which
    needs ``start``); see the module docstring.

    Args:
        model: an ``AirImuNet`` (e.g. ``learned_imu.network.checkpoint.model_from_checkpoint(...)[0]``), or None
            for the raw samples with the config's noise densities.
        config: ``fusion.config.FuseConfig`` (default: ``FuseConfig()``, as ``configs/fuse.yaml``): noise without a
            model, keyframes, bias states, the graph and solver, the motion factors. Noise densities other than the
            defaults are checked against the samples' own white noise (module docstring); with a model they are
            refused (the model predicts the IMU's noise).
        motion_model: a ``MotionNet`` (``motion_from_checkpoint(...)[0]``): learned body-frame velocity factors at
            the keyframes (``config.motion``), the model reading the attitude of the previous solution.
        start: the state at the log's first IMU sample, a ``gtsam.NavState`` (pose world <- IMU, world velocity
            m/s), or ``"ground-truth"`` (the sequence's; a log that begins without truth starts at its first sample
            with it, the samples before dropped); default: aligned to the GPS track.
        outages: (start, duration) pairs, s from the log's first sample: the fixes inside are not fused.
        trust_model: fuse with ``model`` even where its corrected samples fit the GPS track far worse than the raw
            ones (``check_model_against_raw``, which names ``model_source``, e.g. the checkpoint, otherwise).
    """
    from learned_imu.network.inference import correct

    config = config or FuseConfig()
    where = sequence.source or sequence.name
    if config.imu_delay_s and sequence.imu_delay_s:
        raise InputError(
            f"fuse: {where} was read with the readers' imu_delay_s ({sequence.imu_delay_s:g} s) and the fuse config "
            f"gives imu_delay_s ({config.imu_delay_s:g} s): they would add up; give one of them"
        )
    t0 = float(sequence.t[0])  # outages count from the log's first sample, wherever the run starts
    sequence = _from_first_truth(sequence, start, where)
    if config.imu_gaps == "interpolate":
        bridged = sequence.bridge_gaps()
        if bridged is not sequence:
            log.info("%s: the IMU's gaps filled with %d samples (imu_gaps)", where, len(bridged.t) - len(sequence.t))
            sequence = bridged
    fixes = gps if gps is not None else sequence.gps
    if model is not None and not config.noise_is_default:
        raise InputError(
            "fuse: the config's noise densities apply without a model only (the model predicts the IMU's noise)"
        )
    initial_state = _start_state(sequence, start)
    if fixes is not None and len(fixes.t):
        fixes = _outside_outages(fixes, t0, outages)
    if fixes is None or len(fixes.t) == 0:
        fixes = None
        if initial_state is None:
            raise DataError(where, "gps", "no GPS fix to fuse: give the start state (--start) to dead-reckon")
        if motion_model is None:
            log.warning("%s: no GPS and no motion model: the result is integrated IMU, which drifts fast", where)
        if sequence.gt is None:  # nothing else checks the gyro's unit here (the readers do, for files)
            check_gyro_unit(sequence.t, sequence.gyro, sequence.acc, where)
    else:
        sequence = dataclasses.replace(sequence, gps=fixes)
        sequence = fixes_on_samples(sequence)  # a keyframe at every fix: only fixes on an IMU sample
        fixes = sequence.gps
        _check_coverage(sequence, fixes, where, need=1 if initial_state is not None else 2)
        check_imu_units(sequence, fixes, where)
    for network in (model, motion_model):
        check_imu_delay(network, sequence, where)
    still = None
    if model is not None:
        correction = correct(model, sequence)
        if fixes is not None and not trust_model:
            check_model_against_raw(sequence, correction, fixes, model_source or "the model")
    else:
        import torch

        if not config.noise_is_default:
            _check_noise(sequence, config.noise_density)
        gyro, acc = torch.as_tensor(sequence.gyro), torch.as_tensor(sequence.acc)
        zero = torch.zeros_like(gyro)
        d_gyro = zero
        start_velocity = None if initial_state is None else np.asarray(initial_state.velocity())
        if config.still_start:
            still = still_start(sequence.t, sequence.gyro, sequence.acc, fixes, start_velocity)
        if still is not None:  # the raw gyro's bias, measured before the platform moved, taken out
            d_gyro = zero - torch.as_tensor(still.gyro_bias)
            log.info(
                "%s: still for the first %.1f s: gyro bias %s rad/s (sigma %s) taken out",
                where,
                still.duration_s,
                np.array2string(still.gyro_bias, precision=5),
                np.array2string(still.gyro_bias_sigma, precision=1),
            )
        gyro_cov, acc_cov = (torch.full_like(gyro, s**2) for s in config.noise_density)
        correction = Correction(gyro + d_gyro, acc, d_gyro, zero, gyro_cov, acc_cov)
    if config.imu_delay_s:  # the preintegration's samples on the GPS's clock; the networks read them as recorded
        log.info("%s: the IMU's samples integrated %.1f ms earlier (imu_delay_s)", where, 1e3 * config.imu_delay_s)
        correction = _delay_removed(correction, sequence.t, config.imu_delay_s)
    result = _solve(sequence, fixes, correction, config, motion_model, initial_state, still=still)
    result = dataclasses.replace(result, still=still)
    if model is None and not config.noise_is_default:
        _blame_given_noise(sequence, config.noise_density, result.residuals)
    ends = []
    for begin, duration in outages:  # what a causal estimator believes when the outage ends: the log up to then
        end = min(t0 + begin + duration, float(sequence.t[-1]))
        head = sequence.until(end)
        cut = len(head.t)
        part = Correction(*(getattr(correction, f.name)[:cut] for f in dataclasses.fields(Correction)))
        early = None if fixes is None else fixes[fixes.t < end]  # the fix that ends it not yet
        solved = _solve(
            head,
            early if early is not None and len(early.t) else None,
            part,
            config,
            motion_model,
            initial_state,
            end_keyframe=True,
            still=still if still is not None and still.samples <= cut else None,  # (its span within the head)
        )
        ends.append((float(head.t[-1]), solved.solution.trajectory.pos[-1]))
    return dataclasses.replace(result, outages=tuple(outages), outage_ends=tuple(ends))


def _solve(sequence, fixes, correction, config, motion_model, initial_state, end_keyframe=False, still=None) -> Fused:
    """Keyframes, the export and the graph solved; with a motion model ``config.motion.passes`` more solves, each
    with the model's velocities on the previous solution's attitude. ``end_keyframe``: a keyframe at the last
    sample too (the state there is what the caller wants). ``still``: the log's still start, for an aligned first
    state (``fusion.graph.build_graph``)."""
    index = _keyframes(sequence, fixes, config, motion_model is not None, initial_state is not None)
    if end_keyframe:  # the last keyframe moves there if it is one sample short (an interval needs two samples)
        last = len(sequence.t) - 1
        index = np.unique(np.append(index[index < last - 1], last))
    blind = dataclasses.replace(sequence, gt=None)  # the first state from the GPS track or start, not ground truth
    export = preintegration_export(blind, index, correction=correction)
    solution, found = solve_export(export, fixes, config, initial_state, still=still)
    fused = fixes if fixes is not None else GpsFixes.none()
    result = Fused(solution, correction, fused, sequence, found)

    def solve_with(last: Fused, motion: BodyVelocities) -> Fused:  # the graph with these factors, from ``last``
        solved, checks = solve_export(
            export, fixes, config, initial_state, motion, guess=last.solution.values, still=still
        )
        return Fused(solved, correction, fused, sequence, checks, motion)

    passes = config.motion.passes if motion_model is not None else 0
    for k in range(passes):  # each pass on the last attitude; the speed envelope checked in the last
        check = partial(solve_with, result) if k == passes - 1 else None
        result = solve_with(result, motion_on(result, motion_model, config.motion, check))
    return result


def _delay_removed(correction: Correction, t: np.ndarray, delay_s: float) -> Correction:
    """``correction`` with its corrected gyro and acc read ``delay_s`` later (``read_later``): what the
    preintegration integrates for an IMU that late (``FuseConfig.imu_delay_s``). The networks (the AirIMU model, the
    motion model) read the samples as recorded, the timing they were trained on."""
    import torch

    def later(x: torch.Tensor) -> torch.Tensor:
        return torch.as_tensor(read_later(t, x.detach().cpu().numpy(), delay_s), dtype=x.dtype)

    return dataclasses.replace(correction, gyro=later(correction.gyro), acc=later(correction.acc))


def _from_first_truth(sequence: ImuSequence, start, where: str) -> ImuSequence:
    """``sequence`` from its first sample with ground truth when the run starts at the truth (``start`` is
    ``"ground-truth"``) and the log begins without it (a gap at the start, or samples restamped by the readers'
    ``imu_delay_s`` before the truth begins); otherwise ``sequence`` itself."""
    gt = sequence.gt
    if not isinstance(start, str) or start != "ground-truth" or gt is None or gt.valid[0] or not gt.valid.any():
        return sequence
    first = int(np.argmax(gt.valid))
    log.warning(
        "%s: no ground truth for the first %.2f s (%d samples): the run starts at the first sample with it, t = %.3f s",
        where,
        sequence.t[first] - sequence.t[0],
        first,
        sequence.t[first],
    )
    return sequence.between(float(sequence.t[first]), float(sequence.t[-1]))


def _start_state(sequence: ImuSequence, start):
    """``fuse``'s ``start`` as a ``gtsam.NavState`` at the first sample, or None."""
    if start is None:
        return None
    import gtsam

    if isinstance(start, str):
        if start != "ground-truth":
            raise InputError(f"fuse: start must be a gtsam.NavState or 'ground-truth', got {start!r}")
        gt = sequence.gt
        if gt is None or not gt.valid[0]:
            why = "the log has none" if gt is None else "no sample of the log has it"
            raise DataError(sequence.source or sequence.name, "ground truth", f"--start ground-truth: {why}")
        return gtsam.NavState(gtsam.Rot3(gt.rot[0]), gt.pos[0], gt.vel[0])
    if not isinstance(start, gtsam.NavState):
        raise InputError(f"fuse: start must be a gtsam.NavState or 'ground-truth', got {type(start).__name__}")
    return start


def _outside_outages(fixes: GpsFixes, t0: float, outages) -> GpsFixes:
    """The fixes outside every outage (start, duration), s from ``t0``."""
    keep = np.ones(len(fixes.t), dtype=bool)
    for begin, duration in outages:
        if not (np.isfinite(begin) and np.isfinite(duration) and duration > 0 and begin >= 0):
            raise InputError(f"GPS outage {begin}:{duration}: needs a start >= 0 s and a duration > 0 s")
        keep &= ~((fixes.t >= t0 + begin) & (fixes.t < t0 + begin + duration))
    return fixes[keep]


def _check_coverage(sequence: ImuSequence, fixes: GpsFixes, where, need: int) -> None:
    """``need`` fixes at least inside the IMU's span; a warning when the IMU runs long before or after them."""
    inside = (fixes.t >= sequence.t[0]) & (fixes.t <= sequence.t[-1])
    if inside.sum() < need:
        raise DataError(where, "gps", f"fewer than {need} fix(es) lie within the IMU's time span")
    before, after = fixes.t[inside][0] - sequence.t[0], sequence.t[-1] - fixes.t[inside][-1]
    if max(before, after) > UNCOVERED_WARNING_S:
        log.warning(
            "%s: the IMU runs %.0f s before the first GPS fix and %.0f s after the last: keyframes there are "
            "dead reckoning (a GPS file of a shorter stretch, or in another time base?)",
            where,
            before,
            after,
        )


def _keyframes(sequence: ImuSequence, fixes, config: FuseConfig, motion: bool, from_start: bool) -> np.ndarray:
    """Keyframe sample indices: one at the sample of every fix (each fix constrains the state at its own time), plus
    every ``keyframe_s`` and, with a motion model, every ``motion.keyframe_s`` between them (``merge_keyframes``),
    plus the first sample when the start state is given there."""
    grid = []
    if config.keyframe_s is not None:
        check_keyframe_interval(sequence, config.keyframe_s, f"{config.keyframe_s:g}s")
        grid.append(keyframes_every(sequence, config.keyframe_s))
    if motion and config.motion.keyframe_s is not None:
        check_keyframe_interval(sequence, config.motion.keyframe_s, f"motion.keyframe_s {config.motion.keyframe_s:g}s")
        grid.append(keyframes_every(sequence, config.motion.keyframe_s))
    if fixes is None and not grid:
        raise ConfigError("fuse: without GPS fixes set keyframe_s (--keyframes) or, with --motion, motion.keyframe_s")
    required = [nearest_samples(sequence, fixes.t)[0]] if fixes is not None else []
    if from_start:
        required.append(np.zeros(1, dtype=int))
    none = np.zeros(0, dtype=int)
    return merge_keyframes(np.concatenate(required or [none]), np.concatenate(grid or [none]))


def _blame_given_noise(sequence: ImuSequence, noise_density: tuple[float, float], residuals: dict) -> None:
    """After the solve: when the IMU factors' chi-square per degree of freedom is above ``consistency.HIGH`` with
    noise densities the user gave, a warning naming them beside the samples' own white noise (a sigma below it makes
    the graph trust the IMU more than its samples allow: a variance given as a sigma, a datasheet value on a
    vibrating platform, or a bias the graph does not model)."""
    from factors.noise import white_noise_density
    from fusion.consistency import HIGH

    imu = residuals.get("imu")
    if imu is None or not imu.per_dof > HIGH:
        return
    measured = [white_noise_density(x, sequence.dt) for x in (sequence.gyro, sequence.acc)]
    pairs = ", ".join(
        f"{name} {given:.3g} (the samples' own white noise {'?' if m is None else f'{m:.2g}'})"
        for name, given, m in zip(("gyro_noise_density", "acc_noise_density"), noise_density, measured, strict=True)
    )
    log.warning(
        "%s: the IMU factors do not fit their sigmas (chi-square per degree of freedom %.3g) with the densities given: "
        "%s (--gyro-noise-density, --acc-noise-density). Below the samples' own noise, the graph trusts the IMU "
        "more than it can: a variance given as a sigma, or a datasheet value on a vibrating platform? Without bias "
        "states, larger densities also absorb the bias.",
        sequence.source or sequence.name,
        imu.per_dof,
        pairs,
    )


def _check_noise(sequence: ImuSequence, noise_density: tuple[float, float]) -> None:
    """Warn, naming both numbers, about given densities that the samples contradict (``factors.noise``)."""
    for sensor, given, samples in zip(("gyro", "acc"), noise_density, (sequence.gyro, sequence.acc), strict=True):
        message = noise_mismatch(sensor, given, samples, sequence.dt)
        if message:
            log.warning("%s: %s", sequence.source or sequence.name, message)


def check_gps_units(
    sequence: ImuSequence, path: str | Path, fixes: GpsFixes, sigma_m: float = GPS_SIGMA_UNKNOWN_M
) -> None:
    """Refuse a GPS file whose track the IMU explains far worse as read than in another unit: the file re-read
    with lat/lon in radians (lat/lon files), or x/y/z scaled as km, cm or mm (x/y/z files); a ``DataError`` naming
    the columns and the likely unit (the best reading) when another reading leaves ``UNIT_REFUSAL_RATIO`` times less
    motion unexplained
    (``fusion.gps_units.track_misfit``). Measured on 2011_10_03_drive_0027 (fixes from its ground truth, 0.3 m
    noise): as read 0.64 m/s, lat/lon written in radians 2.94 m/s, x/y/z written in km 2.99 m/s, lat and lon
    swapped 2.96 m/s, x and y swapped 2.54 m/s (a mirror image); GTSAM's own KittiGps_converted.txt 0.30 m/s
    (tests/fusion/test_fuse_mistakes.py)."""
    from fusion.gps_units import track_misfit

    as_read = track_misfit(sequence, fixes)
    if as_read is None:
        return
    if gps_file_layout(path) == "lat/lon":
        alternatives = {
            "lat/lon in radians": lambda: read_gps_csv(path, sigma_m, angle_unit="rad"),
            "lat and lon swapped": lambda: read_gps_csv(path, sigma_m, swap=True),
        }
        columns = "lat/lon"
    else:
        scaled = lambda f: lambda: GpsFixes(fixes.t, fixes.pos[0] + f * (fixes.pos - fixes.pos[0]), fixes.sigma)  # noqa: E731
        # x and y swapped: a mirror image, which no rotation of the world frame explains (north-east-down read as
        # east-north-up also flips z: a rotation, whose gravity the misfit sees)
        mirrored = lambda: GpsFixes(fixes.t, fixes.pos[:, [1, 0, 2]], fixes.sigma)  # noqa: E731
        alternatives = {
            "x/y/z in km": scaled(1000.0),
            "x/y/z in cm": scaled(0.01),
            "x/y/z in mm": scaled(0.001),
            "x and y swapped": mirrored,
        }
        columns = "x/y/z"
    misfits = {}
    for unit, reading in alternatives.items():
        try:
            other = track_misfit(sequence, reading())
        except (DataError, ValueError):  # not even readable so (e.g. radians beyond +-pi/2)
            continue
        if other is not None:
            misfits[unit] = other
    if misfits:
        unit = min(misfits, key=misfits.get)  # the reading that explains the track best, not the first that beats it
        other = misfits[unit]
        if other * UNIT_REFUSAL_RATIO < as_read:
            raise DataError(
                path,
                columns,
                f"the IMU explains this GPS track far worse as read ({as_read:.3g} m/s of its velocity changes "
                f"unexplained) than with {unit} ({other:.3g} m/s): {unit}? The {columns} columns are read as "
                + ("degrees" if columns == "lat/lon" else "m"),
            )
    if columns == "lat/lon":  # altitude above the local level, not the tangent plane of the first fix
        level = fixes.pos[:, 2] + np.sum((fixes.pos[:, :2] - fixes.pos[0, :2]) ** 2, axis=1) / (2 * EARTH_RADIUS_M)
        fixes = GpsFixes(fixes.t, np.c_[fixes.pos[:, :2], level], fixes.sigma)
    check_gps_altitude(sequence, path, fixes, "alt" if columns == "lat/lon" else "z")


EARTH_RADIUS_M = 6.371e6  # the lat/lon track's curvature taken out before its climb is read
ALTITUDE_UNITS = {"feet": 1.0 / 0.3048, "km": 1e-3, "cm": 100.0, "mm": 1000.0}  # the unit -> its count per metre


def check_gps_altitude(sequence: ImuSequence, path: str | Path, fixes: GpsFixes, column: str) -> None:
    """Refuse a GPS file whose altitude alone is in another unit than metres (feet, km), found by the IMU of a
    ground vehicle: the track's climb against the IMU's tilt (``fusion.gps_units.vertical_scale``), only where
    that regression decides (a road that climbs and falls; silent on flat drives and on drones) and its scale is
    ``UNIT_REFUSAL_RATIO`` or more from 1; a ``DataError`` naming the column, the likely unit and the fix.
    Measured on KITTI drives with 0.5 m GPS noise (BENCHMARKS.md, Hostile inputs)."""
    from fusion.gps_units import vertical_scale

    found = vertical_scale(sequence, fixes)
    if found is None or not found.decided or 1.0 / UNIT_REFUSAL_RATIO < found.scale < UNIT_REFUSAL_RATIO:
        return
    unit = min(ALTITUDE_UNITS, key=lambda u: abs(np.log(found.scale / ALTITUDE_UNITS[u])))
    likely = abs(np.log(found.scale / ALTITUDE_UNITS[unit])) < np.log(1.5)
    raise DataError(
        path,
        column,
        f"the track climbs and falls {found.scale:.3g} +- {found.sigma:.2g} times as steeply as the IMU tilts "
        f"(a vehicle that travels along its own axis, {found.rows} fixes, R^2 {found.r2:.2f}): "
        + (
            f"altitude in {unit}? Convert the {column} column to m (x {1.0 / ALTITUDE_UNITS[unit]:.6g})"
            if likely
            else f"the {column} column is off by that factor; it is read as m"
        ),
    )


GYRO_CHECK_MAX_SPACING_S = 2.0  # check_imu_units needs fixes at least this often (median spacing)


def check_imu_units(sequence: ImuSequence, fixes: GpsFixes, where: object) -> None:
    """Refuse an IMU log whose gyro, read in another unit (``GYRO_READINGS``), lets the IMU explain the GPS track
    ``UNIT_REFUSAL_RATIO`` times better than as read (``fusion.gps_units.track_misfit``: the gyro's rotations
    carry the accelerometer into the world frame, so a gyro 57x off turns the IMU's motion away from the track's).
    The physical check that needs no ground truth and no rotation large enough for the reader's magnitude check (a
    car's gyro in deg/s reads as plausible rad/s); a ``DataError`` naming the file, the gyro and the fix. Only with
    fixes at least every ``GYRO_CHECK_MAX_SPACING_S`` (sparser fixes make stretches over which a raw gyro's bias
    turns the track by tens of degrees). Readings that fit alike (deg/s and mrad/s: both little rotation) are
    named together."""
    from fusion.gps_units import track_misfit

    _check_gyro_heading(sequence, fixes, where)
    inside = fixes.t[(fixes.t >= sequence.t[0]) & (fixes.t <= sequence.t[-1])]
    if len(inside) < 3 or float(np.median(np.diff(inside))) > GYRO_CHECK_MAX_SPACING_S:
        return
    # the gyro's median taken out first: a raw gyro's bias turns a stretch of the track by degrees (EuRoC's raw IMU
    # as read: 4.1-4.8 m/s against 1.3-1.6 with no rotation at all; without the median 1.0-1.7)
    steady = dataclasses.replace(sequence, gyro=sequence.gyro - np.median(sequence.gyro, axis=0))
    as_read = track_misfit(steady, fixes)
    if as_read is None:
        return
    misfits = {}
    for unit, (factor, _) in GYRO_READINGS.items():
        other = track_misfit(dataclasses.replace(steady, gyro=steady.gyro * factor), fixes)
        if other is not None:
            misfits[unit] = other
    if not misfits:
        return
    best = min(misfits.values())
    if best * UNIT_REFUSAL_RATIO >= as_read:
        return
    alike = [unit for unit, misfit in sorted(misfits.items(), key=lambda item: item[1]) if misfit < 1.5 * best]
    raise DataError(
        where,
        "gyro",
        f"the IMU explains the GPS track far worse with the gyro as read ({as_read:.3g} m/s of its velocity "
        f"changes unexplained) than as {' or '.join(alike)} ({best:.3g} m/s): gyro {' or '.join(alike)}? "
        + reading_fixes(alike),
    )


def _check_gyro_heading(sequence: ImuSequence, fixes: GpsFixes, where: object) -> None:
    """The car's test of ``check_imu_units``: the track's turns against the gyro's (``fusion.gps_units.heading_scale``;
    a vehicle that heads where it goes), refused where that regression decides and its slope is negative (the
    gyro's sign flipped) or ``UNIT_REFUSAL_RATIO`` or more from 1, naming the closest of ``GYRO_READINGS``. Finds a
    rad/s gyro shrunk 57x on mostly straight drives where the track misfit does not (KITTI 2011_10_03_drive_0047,
    1-Hz fixes with 0.5 m noise: slope 56.6 +- 7.1 against 0.988 +- 0.12 as recorded)."""
    from fusion.gps_units import heading_scale

    found = heading_scale(sequence, fixes)
    if found is None or not found.decided or 1.0 / UNIT_REFUSAL_RATIO < found.scale < UNIT_REFUSAL_RATIO:
        return
    said = (
        f"the GPS track turns {found.scale:.3g} +- {found.sigma:.2g} times as far as the gyro says (a vehicle that "
        f"heads where it goes, {found.rows} turns, R^2 {found.r2:.2f}): "
    )
    if found.scale < 0:
        raise DataError(
            where,
            "gyro",
            said + "the gyro's sign is flipped? (rates about the up axis must be positive "
            "turning left, counter-clockwise seen from above)",
        )
    unit = min(GYRO_READINGS, key=lambda u: abs(np.log(found.scale / GYRO_READINGS[u][0])))
    if abs(np.log(found.scale / GYRO_READINGS[unit][0])) < np.log(1.5):
        raise DataError(where, "gyro", said + f"gyro {unit}? {reading_fixes([unit])}")
    raise DataError(where, "gyro", said + "the gyro is off by that factor; it is read as rad/s")


def check_model_against_raw(sequence: ImuSequence, out: Correction, fixes: GpsFixes, checkpoint) -> None:
    """Refuse a model whose corrected samples ``out`` leave ``MODEL_REFUSAL_RATIO`` times more of the GPS track's
    motion unexplained than the raw samples do (``fusion.gps_units.track_misfit``, m/s): a model of another IMU, a
    broken checkpoint, or one trained on data whose frames or units differ; ``airimu fuse --trust-model`` fuses it
    anyway. A model that corrects anything fits at least as well as the raw samples."""
    from fusion.gps_units import track_misfit

    raw = track_misfit(sequence, fixes)
    if raw is None:
        return
    corrected = dataclasses.replace(sequence, gyro=out.gyro.double().numpy(), acc=out.acc.double().numpy())
    with_model = track_misfit(corrected, fixes)
    if with_model is not None and with_model > MODEL_REFUSAL_RATIO * raw:
        raise DataError(
            checkpoint,
            "model",
            f"its corrected samples explain the GPS track of {sequence.source or sequence.name} far worse than the "
            f"raw samples do ({with_model:.3g} m/s of its velocity changes unexplained against {raw:.3g}): a model "
            "of another IMU, platform or unit? Fuse without --checkpoint, or pass --trust-model to use it anyway",
        )


TIME_UNITS = {"ms": 1e-3, "us": 1e-6, "ns": 1e-9}  # GPS times in these, read as s


def check_gps_times(sequence: ImuSequence, source: object, fixes: GpsFixes) -> None:
    """Refuse GPS times that miss the IMU's span, naming the GPS file (not the IMU's) and, when the times in ms, us
    or ns would fall inside it, that unit; else both spans (another time base: GPS week seconds against the IMU's
    boot time, say) and the flag that shifts them."""
    t0, t1 = float(sequence.t[0]), float(sequence.t[-1])
    if int(((fixes.t >= t0) & (fixes.t <= t1)).sum()) >= 2:
        return
    spacing = float(np.median(np.diff(fixes.t))) if len(fixes.t) > 1 else np.nan
    for unit, scale in TIME_UNITS.items():
        inside = (fixes.t * scale >= t0) & (fixes.t * scale <= t1)
        rate_ok = 0.01 <= spacing * scale <= 100.0  # read so, the fixes come at 0.01-100 Hz, as GPS does
        if rate_ok and inside.sum() >= max(2, 0.5 * len(fixes.t)):
            raise DataError(
                source,
                "t",
                f"the fix times ({fixes.t[0]:.6g} to {fixes.t[-1]:.6g}) miss the IMU's ({t0:.6g} to {t1:.6g} s) but "
                f"fall inside it read as {unit}: convert the GPS times to seconds",
            )
    raise DataError(
        source,
        "t",
        f"fewer than 2 fixes lie within the IMU's time span: the fixes span {fixes.t[0]:.6g} to {fixes.t[-1]:.6g} "
        f"s, the IMU {t0:.6g} to {t1:.6g} s. Another time base (GPS time against the IMU's clock)? --gps-time-offset "
        f"subtracts a constant from every fix time ({fixes.t[0] - t0:.10g} aligns the first fix with the IMU's start)",
    )


def check_gps_clock(sequence: ImuSequence, source: object, fixes: GpsFixes) -> float | None:
    """Warn when the GPS track fits the IMU's motion far better shifted in time (``fusion.gps_units.clock_offset``:
    the best shift within +-60 s explains it ``CLOCK_RATIO`` times better than as read, and is at least
    ``CLOCK_MIN_S``): a clock offset between the GPS and the IMU, which the fusion would otherwise take for motion.
    Returns the estimated offset (s the fixes are late; ``--gps-time-offset`` subtracts it), or None when there is
    none. GTSAM's own GPS file against the raw KITTI drive's IMU fits best 0.1 s later (misfit 0.77 against 1.58
    m/s as read): below the floor, not warned about."""
    from fusion.gps_units import CLOCK_MIN_S, CLOCK_RATIO, clock_offset

    offset, at_offset, as_read = clock_offset(sequence, fixes)
    if not np.isfinite(offset) or abs(offset) < CLOCK_MIN_S or as_read < CLOCK_RATIO * at_offset:
        return None
    side = "late" if offset > 0 else "early"
    log.warning(
        "%s: the GPS fixes look %.2f s %s against the IMU's clock: shifted by that the IMU explains their track's "
        "motion to %.3g m/s, as read to %.3g m/s. A clock offset between GPS and IMU? Pass --gps-time-offset %.2f "
        "(subtracted from every fix time) if so.",
        source,
        abs(offset),
        side,
        at_offset,
        as_read,
        offset,
    )
    return offset


def write_outputs(result: Fused, folder: Path, reference: GpsFixes | None = None) -> tuple[FusedSummary, list[Path]]:
    """Write, each atomically: ``fused.tum`` (the keyframe states; TUM, quaternion x y z w, world <- IMU, for
    evo), ``fused_imu_rate.tum`` (every IMU sample, ``imu_rate_trajectory``), ``marginals.npz`` (``t`` (K,),
    ``pos`` (K, 3) m, ``pos_cov`` (K, 3, 3) m^2, world frame), ``fused.rrd``, ``fused.png`` and ``summary.json``
    (``FusedSummary``: RMSE against the ``reference`` fixes, default the fused ones; the ATE against the ground truth
    where the sequence has one). Returns the summary and the paths."""
    from airimu.viz.figures import plot
    from airimu.viz.results import SequenceResult, marginal_track, record
    from airimu_core.io import atomic_file, output_folder, write_json_atomic
    from learned_imu.evaluation.metrics import ate_m, umeyama_alignment

    folder = output_folder(folder)
    # summary.json is written last and marks a complete folder: a previous run's goes first, so that a rerun
    # killed half-way never leaves a folder that looks complete with some files of each run
    (folder / "summary.json").unlink(missing_ok=True)
    trajectory = result.solution.trajectory
    _, _, pos_cov = marginal_track(result.solution)  # computed once, for the recording and the PNG too
    pos_cov = np.full((len(trajectory.t), 3, 3), np.nan) if pos_cov is None else pos_cov
    dense = imu_rate_trajectory(result)
    written = [trajectory.write_tum(folder / "fused.tum"), dense.write_tum(folder / "fused_imu_rate.tum")]
    with atomic_file(folder / "marginals.npz", "wb") as f:
        np.savez(f, t=trajectory.t, pos=trajectory.pos, pos_cov=pos_cov)
    written.append(folder / "marginals.npz")
    t0 = float(result.sequence.t[0])
    spans = [(t0 + begin, t0 + begin + duration) for begin, duration in result.outages]
    view = SequenceResult(result.sequence, result.correction, [], {"fused": (result.solution, result.gps)}, spans)
    written += [record(view, folder / "fused.rrd"), plot(view, folder / "fused.png")]
    reference = reference if reference is not None else result.gps
    inside = (reference.t >= trajectory.t[0]) & (reference.t <= trajectory.t[-1])
    rmse = None
    if inside.any():
        err = trajectory.position_at(reference.t[inside]) - reference.pos[inside]
        rmse = float(np.sqrt(np.mean(np.sum(err**2, axis=1))))
    aligned = unaligned = truth_in_fused = None
    gt = result.sequence.gt
    if gt is not None:
        sample = np.searchsorted(result.sequence.t, dense.t)
        keep = gt.valid[sample]
        if keep.sum() >= 3:
            aligned = ate_m(gt.pos[sample[keep]], dense.pos[keep], align=True)  # the truth into the fused frame
            unaligned = ate_m(gt.pos[sample[keep]], dense.pos[keep], align=False)
            rot, trans = umeyama_alignment(gt.pos[sample[keep]], dense.pos[keep])
            truth_in_fused = (dense.t[keep], gt.pos[sample[keep]] @ rot.T + trans)
    normalised = {kind: r.to_json_dict() for kind, r in result.residuals.items()}
    summary = FusedSummary(
        result.sequence.name,
        len(trajectory.t),
        len(result.gps.t),
        int(inside.sum()),
        rmse,
        aligned,
        unaligned,
        normalised,
        [
            _outage_errors(begin, duration, end, truth_in_fused, reference)
            for (begin, duration), end in zip(result.outages, result.outage_ends, strict=True)
        ],
        result.residuals["motion"].factors if "motion" in result.residuals else 0,
        initial_attitude_error(result),
        still_summary(result),
        speed_scales(result.solution.values),
    )
    written.append(write_json_atomic(folder / "summary.json", dataclasses.asdict(summary)))
    return summary, written


def speed_scales(values) -> list | None:
    """``FusedSummary.speed_scales``: the values of the speed-scale states ``S(0)``, ``S(1)``, ... in ``values``, or
    None when there are none."""
    return [float(values.atVector(key)[0]) for key in scale_keys(values)] or None


def still_summary(result: Fused) -> dict | None:
    """``FusedSummary.still_start``: the still start and, with ground truth, the tilt of its gravity, deg."""
    still = result.still
    if still is None:
        return None
    out = still.to_json_dict()
    gt = result.sequence.gt
    if gt is not None and gt.valid[0]:
        cos = float(np.clip(np.dot(still.up, gt.rot[0][2]), -1.0, 1.0))
        out["tilt_error_deg"] = float(np.degrees(np.arccos(cos)))
    return out


def initial_attitude_error(result: Fused) -> dict | None:
    """``FusedSummary.initial_attitude_error_deg``: the first keyframe's prior mean (what the graph started from)
    against the ground truth there, as tilt (the angle between the two up axes) and heading (yaw about world z)."""
    import gtsam

    gt = result.sequence.gt
    trajectory = result.solution.trajectory
    if gt is None:
        return None
    sample = int(np.searchsorted(result.sequence.t, trajectory.t[0]))
    if sample >= len(result.sequence.t) or not gt.valid[sample]:
        return None
    graph = result.solution.graph
    prior = None
    for i in range(graph.size()):
        factor = graph.at(i)
        if isinstance(factor, gtsam.PriorFactorPose3) and factor.keys()[0] == gtsam.symbol_shorthand.X(0):
            prior = factor.prior().rotation().matrix()
    if prior is None:
        return None
    truth = gt.rot[sample]
    tilt = float(np.degrees(np.arccos(np.clip(prior[2] @ truth[2], -1.0, 1.0))))  # world z in the body frame
    yaw = np.degrees(np.arctan2(prior[1, 0], prior[0, 0]) - np.arctan2(truth[1, 0], truth[0, 0]))
    return {"tilt": tilt, "yaw": float((yaw + 180.0) % 360.0 - 180.0)}


def _outage_errors(begin: float, duration: float, end, truth, reference: GpsFixes) -> dict:
    """``FusedSummary.outages``' entry of one outage (its docstring); ``end``: (time, position) from
    ``Fused.outage_ends``."""
    end_t, pos = end
    to_truth = to_gps = None
    if truth is not None:
        k = int(np.argmin(np.abs(truth[0] - end_t)))
        to_truth = float(np.linalg.norm(pos - truth[1][k])) if abs(truth[0][k] - end_t) < 0.05 else None
    if len(reference.t):
        k = int(np.argmin(np.abs(reference.t - end_t)))
        to_gps = float(np.linalg.norm(pos - reference.pos[k])) if abs(reference.t[k] - end_t) <= 1.0 else None
    return {
        "start_s": begin,
        "duration_s": duration,
        "end_t_s": end_t,
        "error_to_truth_m": to_truth,
        "error_to_gps_m": to_gps,
    }


def motion_on(result: Fused, motion_model, settings: MotionSettings, solve_with=None) -> BodyVelocities:
    """The motion model's velocities over ``result``'s sequence, reading ``result``'s attitude at every sample
    (``imu_rate_trajectory``'s, held before the first keyframe and after the last: the estimate, never ground truth),
    every variance times ``settings.cov_scale``.

    The speed envelope (``settings.speed_envelope``, for a model whose checkpoint records its training speed), with
    ``solve_with`` (velocities -> ``Fused``: the same graph solved with them): the graph is solved once with every
    output's along-track axis left to the IMU (``BodyVelocities.along_track_free``: the speed then comes from the IMU
    and the GPS, not from the model), and wherever that solution is faster than the model's training speeds the
    along-track axis stays free (logged)."""
    from learned_imu.network.motion import predict_velocities

    dense = imu_rate_trajectory(result)
    at = np.clip(np.searchsorted(dense.t, result.sequence.t), 0, len(dense.t) - 1)
    velocities = predict_velocities(motion_model, result.sequence, dense.rot[at]).scaled(settings.cov_scale)
    limit = settings.speed_limit_m_s(motion_model)
    if limit is None or solve_with is None:
        return velocities
    checked = imu_rate_trajectory(solve_with(velocities.along_track_free(body_velocity(dense, velocities.t))))
    velocities, beyond = velocities.outside_envelope(body_velocity(checked, velocities.t), limit)
    if beyond.any():
        log.warning(
            "%s: the estimate is faster than the motion model's training speeds (%.1f m/s) at %d of %d outputs "
            "(%.0f %%): their along-track velocity is left to the IMU (motion.speed_envelope)",
            result.sequence.name,
            limit,
            int(beyond.sum()),
            len(beyond),
            100.0 * beyond.mean(),
        )
    return velocities


def body_velocity(dense: Trajectory, t: np.ndarray) -> np.ndarray:
    """(M, 3) the body-frame velocity ``R^T v`` (m/s) of an ``imu_rate_trajectory`` at times ``t`` (M,) s: its
    sample at or after each time (held outside its span)."""
    k = np.clip(np.searchsorted(dense.t, t), 0, len(dense.t) - 1)
    return np.einsum("mji,mj->mi", dense.rot[k], dense.vel[k])


def imu_rate_trajectory(result: Fused) -> Trajectory:
    """The fused trajectory at every IMU sample from the first keyframe to the last: each keyframe's estimated state
    carried forward by the (corrected) IMU samples, less the keyframe's estimated bias where the graph has bias
    states, up to the next keyframe, where the next estimated state takes over. ``pos_cov`` is None."""
    import torch
    from gtsam.symbol_shorthand import B

    from learned_imu.geometry.preintegration import preintegrate

    seq, traj, values = result.sequence, result.solution.trajectory, result.solution.values
    index = nearest_samples(seq, traj.t)[0]
    gravity = np.asarray(seq.gravity, dtype=float)
    gyro, acc = result.correction.gyro.double(), result.correction.acc.double()
    t, rot, pos, vel = [traj.t[:1]], [traj.rot[:1]], [traj.pos[:1]], [traj.vel[:1]]
    for k in range(len(index) - 1):
        a, b = int(index[k]), int(index[k + 1])
        if b <= a:
            continue
        bias = values.atConstantBias(B(k)) if values.exists(B(k)) else None
        g, f = gyro[a:b], acc[a:b]
        if bias is not None:
            g, f = g - torch.tensor(bias.gyroscope()), f - torch.tensor(bias.accelerometer())
        deltas = preintegrate(g, f, torch.as_tensor(seq.dt[a:b]))
        d_rot, d_vel, d_pos = (x.numpy() for x in (deltas.rot, deltas.vel, deltas.pos))
        elapsed = deltas.dt.numpy()[:, None]
        r0, v0, p0 = traj.rot[k], traj.vel[k], traj.pos[k]
        n = b - a - 1  # the samples strictly between the two keyframes; the next keyframe's own state follows
        t.append(seq.t[a + 1 : b])
        rot.append((r0 @ d_rot)[:n])
        vel.append((v0 + gravity * elapsed + d_vel @ r0.T)[:n])
        pos.append((p0 + v0 * elapsed + 0.5 * gravity * elapsed**2 + d_pos @ r0.T)[:n])
        t.append(traj.t[k + 1 : k + 2])
        rot.append(traj.rot[k + 1 : k + 2])
        vel.append(traj.vel[k + 1 : k + 2])
        pos.append(traj.pos[k + 1 : k + 2])
    return Trajectory(*(np.concatenate(x) for x in (t, rot, pos, vel)))
