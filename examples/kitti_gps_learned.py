"""GTSAM's ``IMUKittiExampleGPS.py`` line for line, with learned factors: the same files (``KittiEquivBiasedImu.txt``,
``KittiGps_converted.txt``, ``KittiEquivBiasedImu_metadata.txt``), the same ISAM2 loop, the same priors and the same
bias random walk; without a checkpoint its trajectory is the script's (``tests/fusion/test_examples.py`` holds the
two to 1 mm on the whole drive).

The script, step by step: a keyframe ``X(i), V(i), B(i)`` at every GPS time from fix 1 (fix 0 lies 1.9 s before the
second IMU sample); on the first, a position-only pose prior (precisions 0 on rotation, 1 on position: identity
rotation), velocity zero with sigma 1000 m/s and bias zero with sigmas 0.1 m/s^2 and 5e-5 rad/s. Between keyframes
the IMU samples with ``t_prev <= t <= t`` not yet used, each integrated over its own ``dt`` column (the time since
the previous sample), around the latest bias estimate; an ``ImuFactor`` and a ``BetweenFactorConstantBias`` whose
sigmas are ``sqrt(count) * `` the metadata's per-sample bias sigmas, where ``count`` is the number of IMU samples
integrated **since the start of the drive** (``bias_walk="cumulative"``, the script's rule). Fix ``i`` with
``i % gps_skip == 0`` becomes a pose prior with precisions 0 on rotation and 1/0.07 on position (sigma sqrt(0.07) m
per axis); ISAM2 (``relinearizeSkip`` 10) updates once the keyframe index passes ``first + 2 * gps_skip``, and every
new keyframe starts at the latest estimate.

One difference, by necessity: ISAM2 runs QR. GTSAM 4.3.0's script as shipped (CHOLESKY) stops at its first update
with ``Indeterminate linear system ... x21`` (``benchmarks/kitti_gtsam_example.py``). With every fix fused
(``gps_skip=1``) the script's first update comes 2 keyframes after the first, before the heading is observable: it
diverges (here RMSE 254 m after 50 s) and stops indeterminate, QR too (the script at x361, this mirror at x161: on a
diverging graph round-off decides where); ``wait=20`` (the first update after 20
keyframes, as at one fix in ten) is the one change that runs it, in the script (``gtsam_script(wait=20)``) and here.

``bias_walk="per_interval"``: the walk's sigma grows with the samples of the interval only (``sqrt(n_i)``), which is
what a per-sample random walk is (its standard deviation over ``n`` samples is ``sqrt(n)`` times the per-sample one);
the script's cumulative count makes the walk ``sqrt(count / n_i)`` times looser, about 20x by the end of this drive.
Kept as an option for that reason; it is not GTSAM's example.

What changes with learned factors: each interval is ``factors.learned_pim`` of the model's corrected samples with
its per-sample noise (``--checkpoint``, e.g. ``runs/kitti/best.pt`` of ``configs/kitti.yaml``); without one the raw
samples with the metadata's noise, i.e. the script itself.

    python examples/kitti_gps_learned.py [--checkpoint runs/kitti/best.pt] [--gps-skip 10] [--bias-walk cumulative]
        [--wait 20] [--against-script]
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import importlib.util
import io
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, V, X

from factors import learned_pim
from learned_imu.datasets import read_sequence
from learned_imu.datasets.kitti import GPS_FILE, IMU_FILE, read_gps

BiasWalk = Literal["cumulative", "per_interval"]
BIAS_WALKS: tuple[str, ...] = ("cumulative", "per_interval")
METADATA_FILE = "KittiEquivBiasedImu_metadata.txt"
GRAVITY = 9.8  # m/s^2, the script's PreintegrationParams.MakeSharedU(GRAVITY)
FIRST_GPS_POSE = 1  # the script's first_gps_pose
RELINEARIZE_SKIP = 10  # the script's isam_params.relinearizeSkip
# the script's priors and GPS noise, as it writes them (precisions 0: that component is free)
POSE_PRIOR_PRECISIONS = (0.0, 0.0, 0.0, 1.0, 1.0, 1.0)  # rotation (rad^-2), position (m^-2)
VEL_PRIOR_SIGMA = 1000.0  # m/s
BIAS_PRIOR_SIGMAS = (0.1, 0.1, 0.1, 5e-5, 5e-5, 5e-5)  # acc m/s^2, gyro rad/s
GPS_PRECISIONS = (0.0, 0.0, 0.0) + (1.0 / 0.07,) * 3  # position variance 0.07 m^2 per axis


@dataclass(frozen=True)
class Calibration:
    """``KittiEquivBiasedImu_metadata.txt``: continuous-time sigmas of the white noise (acc m/s^2/sqrt(Hz), gyro
    rad/s/sqrt(Hz), integration m/sqrt(Hz)) and the per-sample sigmas of the bias random walk (acc m/s^2, gyro
    rad/s)."""

    acc_sigma: float
    gyro_sigma: float
    integration_sigma: float
    acc_bias_sigma: float
    gyro_bias_sigma: float


@dataclass(frozen=True)
class Samples:
    """What each interval integrates, one row per IMU sample of the drive (``read_sequence("kitti")``'s rows):
    gyro (N, 3) rad/s, acc (N, 3) m/s^2, and their noise as continuous-time ``*_cov`` (sigma^2, (N, 3))."""

    gyro: np.ndarray
    acc: np.ndarray
    gyro_cov: np.ndarray
    acc_cov: np.ndarray


@dataclass(frozen=True, eq=False)
class KittiRun:
    """The final ISAM2 estimate at the keyframes (fix ``first`` .. the last): ``t`` (K,) s, ``pos`` (K, 3) m and
    ``rot`` (K, 3, 3) world <- IMU in the GPS file's frame, ``vel`` (K, 3) m/s, ``bias`` (K, 6) [acc m/s^2, gyro
    rad/s]; ``fused`` (K,) bool, the keyframes with a GPS prior; ``rmse_to_gps_m`` against every fix from ``first``
    on, fused or not."""

    t: np.ndarray
    pos: np.ndarray
    rot: np.ndarray
    vel: np.ndarray
    bias: np.ndarray
    fused: np.ndarray
    rmse_to_gps_m: float

    @property
    def keyframes(self) -> int:
        return len(self.t)


def read_calibration(path: Path) -> Calibration:
    """The metadata file's sigmas (columns 7-11 of its one data row; the body <- IMU pose must be identity)."""
    row = np.loadtxt(path, skiprows=1, ndmin=1)
    if np.any(row[:6] != 0):
        raise ValueError(f"{path}: body <- IMU pose {row[:6]} is not identity (the script refuses it too)")
    return Calibration(*(float(x) for x in row[6:11]))


def imu_params(calibration: Calibration) -> gtsam.PreintegrationParams:
    """The script's ``getImuParams``: z-up gravity 9.8, its white-noise and integration covariances, no Coriolis."""
    params = gtsam.PreintegrationParams.MakeSharedU(GRAVITY)
    params.setAccelerometerCovariance(np.eye(3) * calibration.acc_sigma**2)
    params.setIntegrationCovariance(np.eye(3) * calibration.integration_sigma**2)
    params.setGyroscopeCovariance(np.eye(3) * calibration.gyro_sigma**2)
    params.setOmegaCoriolis(np.zeros(3))
    return params


def intervals(imu_t: np.ndarray, fix_t: np.ndarray, first: int = FIRST_GPS_POSE) -> list[slice]:
    """The samples the script integrates between fix ``i - 1`` and fix ``i`` (for i = first + 1, ...): those with
    ``fix_t[i - 1] <= t <= fix_t[i]`` not taken by an earlier interval (its ``while j ...`` loop)."""
    out, used = [], 0
    for i in range(first + 1, len(fix_t)):
        start = max(used, int(np.searchsorted(imu_t, fix_t[i - 1], side="left")))
        stop = max(start, int(np.searchsorted(imu_t, fix_t[i], side="right")))
        out.append(slice(start, stop))
        used = max(used, stop)
    return out


def walk_counts(take: list[slice], rule: BiasWalk) -> np.ndarray:
    """The sample count that scales each interval's bias walk: since the start (``"cumulative"``, the script's
    ``included_imu_measurement_count``) or within the interval (``"per_interval"``)."""
    n = np.array([s.stop - s.start for s in take])
    if rule == "cumulative":
        return np.cumsum(n)
    if rule == "per_interval":
        return n
    raise ValueError(f"bias_walk must be one of {', '.join(BIAS_WALKS)}, got {rule!r}")


def raw_samples(seq, calibration: Calibration) -> Samples:
    """The raw samples with the metadata's constant noise (the script's own)."""
    return Samples(
        seq.gyro,
        seq.acc,
        np.full_like(seq.gyro, calibration.gyro_sigma**2),
        np.full_like(seq.acc, calibration.acc_sigma**2),
    )


def model_samples(seq, checkpoint: str | Path) -> Samples:
    """The model's corrected samples and learned noise (torch is imported here only)."""
    from learned_imu.network.inference import correct_from_checkpoint

    out = correct_from_checkpoint(checkpoint, seq)
    return Samples(*(np.asarray(x.numpy(), dtype=float) for x in (out.gyro, out.acc, out.gyro_cov, out.acc_cov)))


def run(
    data: str | Path | None = None,
    checkpoint: str | Path | None = None,
    gps_skip: int = 10,
    bias_walk: BiasWalk = "cumulative",
    seconds: float | None = None,
    samples: Samples | None = None,
    bias_prior_sigmas: tuple[float, ...] = BIAS_PRIOR_SIGMAS,
    factorization: str = "QR",
    wait: int | None = None,
) -> KittiRun:
    """The script's loop on the files in ``data`` (None: those gtsam installs). ``samples`` (rows of
    ``read_sequence("kitti", data)``) replaces what ``checkpoint`` or the raw IMU would give; ``seconds`` stops
    after the first seconds of GPS; ``bias_prior_sigmas`` replaces the script's prior on the first bias; ``wait``:
    keyframes after the first before the first ISAM2 update (None: the script's ``2 * gps_skip``)."""
    seq = read_sequence("kitti", data)  # the IMU file without its first row (never integrated: before fix 1)
    root = Path(data) if data is not None else Path(gtsam.findExampleDataFile(IMU_FILE)).parent
    calibration = read_calibration(root / METADATA_FILE)
    fixes = read_gps(root / GPS_FILE, 1.0)  # every fix of the file, fix 0 included: the script's numbering
    if samples is None:
        samples = model_samples(seq, checkpoint) if checkpoint else raw_samples(seq, calibration)
    end = len(fixes.t) if seconds is None else int(np.searchsorted(fixes.t, fixes.t[FIRST_GPS_POSE] + seconds))
    dt = np.diff(seq.t, prepend=np.nan)  # the file's dt column: time since the previous sample (row 0: unused)
    take = intervals(seq.t, fixes.t[:end])
    walk_n = walk_counts(take, bias_walk)
    params = imu_params(calibration)
    walk_sigma = np.array([calibration.acc_bias_sigma] * 3 + [calibration.gyro_bias_sigma] * 3)

    isam_params = gtsam.ISAM2Params()
    isam_params.setFactorization(factorization)
    isam_params.relinearizeSkip = RELINEARIZE_SKIP
    isam = gtsam.ISAM2(isam_params)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    gps_noise = gtsam.noiseModel.Diagonal.Precisions(np.array(GPS_PRECISIONS))
    first = FIRST_GPS_POSE
    pose, vel, bias = gtsam.Pose3(gtsam.Rot3(), fixes.pos[first]), np.zeros(3), gtsam.imuBias.ConstantBias()
    # the first keyframe: position prior only, a loose velocity prior, a bias prior
    values.insert(X(first), pose)
    values.insert(V(first), vel)
    values.insert(B(first), bias)
    graph.addPriorPose3(X(first), pose, gtsam.noiseModel.Diagonal.Precisions(np.array(POSE_PRIOR_PRECISIONS)))
    graph.addPriorVector(V(first), vel, gtsam.noiseModel.Diagonal.Sigmas(np.full(3, VEL_PRIOR_SIGMA)))
    graph.addPriorConstantBias(B(first), bias, gtsam.noiseModel.Diagonal.Sigmas(np.array(bias_prior_sigmas)))
    fused = [False]
    for i, cut, n in zip(range(first + 1, end), take, walk_n, strict=True):
        # the interval preintegrated around the latest bias estimate, and its IMU factor
        pim = learned_pim(
            samples.gyro[cut],
            samples.acc[cut],
            dt[cut],
            samples.gyro_cov[cut],
            samples.acc_cov[cut],
            bias=bias,
            params=params,
        )
        graph.push_back(gtsam.ImuFactor(X(i - 1), V(i - 1), X(i), V(i), B(i - 1), pim))
        # the bias random walk
        walk = gtsam.noiseModel.Diagonal.Sigmas(np.sqrt(n) * walk_sigma)
        graph.push_back(gtsam.BetweenFactorConstantBias(B(i - 1), B(i), gtsam.imuBias.ConstantBias(), walk))
        # every gps_skip-th fix a position prior; new states start at the latest estimate
        fused.append(i % gps_skip == 0)
        if fused[-1]:
            fix = gtsam.Pose3(pose.rotation(), fixes.pos[i])
            graph.addPriorPose3(X(i), fix, gps_noise)
            values.insert(X(i), fix)
        else:
            values.insert(X(i), pose)
        values.insert(V(i), vel)
        values.insert(B(i), bias)
        # ISAM2 once 2 * gps_skip fixes are in, so that the heading is observable
        if i > first + (2 * gps_skip if wait is None else wait):
            isam.update(graph, values)
            graph.resize(0)
            values.clear()
            estimate = isam.calculateEstimate()
            pose, vel, bias = estimate.atPose3(X(i)), estimate.atVector(V(i)), estimate.atConstantBias(B(i))
    estimate = isam.calculateEstimate()
    keys = range(first, end)
    poses = [estimate.atPose3(X(k)) for k in keys]
    pos = np.array([p.translation() for p in poses])
    return KittiRun(
        t=fixes.t[first:end],
        pos=pos,
        rot=np.array([p.rotation().matrix() for p in poses]),
        vel=np.array([estimate.atVector(V(k)) for k in keys]),
        bias=np.array([estimate.atConstantBias(B(k)).vector() for k in keys]),
        fused=np.array(fused),
        rmse_to_gps_m=float(np.sqrt(np.mean(np.sum((pos - fixes.pos[first:end]) ** 2, axis=1)))),
    )


# GTSAM's script (gtsam/examples/IMUKittiExampleGPS.py as installed) and the only lines gtsam_script changes in it
SCRIPT = "gtsam.examples.IMUKittiExampleGPS"
SCRIPT_FACTORIZATION = 'isam_params.setFactorization("CHOLESKY")'
SCRIPT_GPS_SKIP = "gps_skip = 10"
SCRIPT_WAIT = "if i > (first_gps_pose + 2 * gps_skip):"


def gtsam_script(
    data: str | Path | None = None, gps_skip: int = 10, factorization: str = "QR", wait: int | None = None
) -> KittiRun:
    """GTSAM's installed ``IMUKittiExampleGPS.py`` itself: its source executed with ``factorization`` in place of its
    CHOLESKY, ``gps_skip`` in place of its 10 (and, given ``wait``, that many keyframes before its first update
    instead of ``2 * gps_skip``), its ``main()`` run on the files in ``data`` (None: gtsam's copies) with its output
    silenced; the final estimate as ``KittiRun``. Raises if the script no longer holds the lines this edits."""
    origin = importlib.util.find_spec(SCRIPT).origin
    source = Path(origin).read_text(encoding="utf-8")
    edits = [
        (SCRIPT_FACTORIZATION, f'isam_params.setFactorization("{factorization}")'),
        (SCRIPT_GPS_SKIP, f"gps_skip = {int(gps_skip)}"),
    ]
    if wait is not None:
        edits.append((SCRIPT_WAIT, f"if i > (first_gps_pose + {int(wait)}):"))
    for old, new in edits:
        if source.count(old) != 1:
            raise RuntimeError(f"{origin}: expected the line {old!r} once, found it {source.count(old)} times")
        source = source.replace(old, new)
    script = {"__name__": "IMUKittiExampleGPS", "__file__": origin}
    exec(compile(source, origin, "exec"), script)  # noqa: S102 -- gtsam's own example, as installed
    root = Path(data) if data is not None else Path(gtsam.findExampleDataFile(IMU_FILE)).parent
    script["loadKittiData"] = functools.partial(
        script["loadKittiData"], str(root / IMU_FILE), str(root / GPS_FILE), str(root / METADATA_FILE)
    )
    script["parse_args"] = lambda: argparse.Namespace(output_filename=os.devnull)
    kept = {}
    script["save_results"] = lambda isam, _, first, gps: kept.update(
        estimate=isam.calculateEstimate(), first=first, gps=gps
    )
    sys.stdout.flush()
    stdout = os.dup(1)  # the script prints every factor and pose, through Python and through GTSAM's C++ print
    try:
        with open(os.devnull, "w") as null, contextlib.redirect_stdout(io.StringIO()):
            os.dup2(null.fileno(), 1)
            script["main"]()
    finally:
        sys.stdout.flush()
        os.dup2(stdout, 1)
        os.close(stdout)
    estimate, first, gps = kept["estimate"], kept["first"], kept["gps"]
    keys = range(first, len(gps))
    poses = [estimate.atPose3(X(k)) for k in keys]
    pos = np.array([p.translation() for p in poses])
    fix = np.array([gps[k].position for k in keys])
    return KittiRun(
        t=np.array([gps[k].time for k in keys]),
        pos=pos,
        rot=np.array([p.rotation().matrix() for p in poses]),
        vel=np.array([estimate.atVector(V(k)) for k in keys]),
        bias=np.array([estimate.atConstantBias(B(k)).vector() for k in keys]),
        fused=np.array([k != first and k % gps_skip == 0 for k in keys]),
        rmse_to_gps_m=float(np.sqrt(np.mean(np.sum((pos - fix) ** 2, axis=1)))),
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", default=None, help="folder of the three files (default: gtsam's installed copies)")
    parser.add_argument("--checkpoint", default=None, help="a trained model (default: the raw IMU, the script itself)")
    parser.add_argument("--seconds", type=float, default=None, help="only the first seconds of the drive")
    parser.add_argument("--gps-skip", type=int, default=10, help="fuse fix i if i %% gps_skip == 0 (the script: 10)")
    parser.add_argument("--bias-walk", choices=BIAS_WALKS, default="cumulative", help="the script's rule: cumulative")
    parser.add_argument("--wait", type=int, default=None, help="keyframes before the first update (2 * gps_skip)")
    parser.add_argument("--against-script", action="store_true", help="also run GTSAM's installed script (QR)")
    args = parser.parse_args()
    result = run(args.data, args.checkpoint, args.gps_skip, args.bias_walk, args.seconds, wait=args.wait)
    print(f"keyframes: {result.keyframes}")
    print(f"RMSE against every GPS fix: {result.rmse_to_gps_m:.3f} m")
    if args.against_script:
        script = gtsam_script(args.data, args.gps_skip, "QR", args.wait)
        print(f"GTSAM's IMUKittiExampleGPS.py (QR): RMSE {script.rmse_to_gps_m:.3f} m")
        if script.keyframes == result.keyframes:
            print(f"largest position difference: {np.abs(script.pos - result.pos).max():.2e} m")


if __name__ == "__main__":
    main()
