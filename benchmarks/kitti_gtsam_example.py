"""GTSAM's ``IMUKittiExampleGPS.py`` as shipped against the learned model, in the script's own loop
(``examples/kitti_gps_learned.py``, which equals the script to 1e-10 m without a model), on the drive it ships
(KITTI raw 2011_10_03_drive_0027) with one fix in ten fused (the script's ``gps_skip = 10``) and with every 1 Hz fix.

    python benchmarks/kitti_gtsam_example.py --checkpoint runs/kitti/best.pt [--data ../shared/data] [--json out.json]

Rows: GTSAM's installed script itself (its source, QR: with its CHOLESKY it stops at its first update, x21); the
mirror on the raw IMU; the mirror with the model (corrected samples, learned noise); and the variants of
``VARIANTS`` that take the model apart (learned noise only, the correction without its mean, bias states that take
the constant, the learned noise calibrated over the GPS interval on the validation drives). At 1 Hz the script's
first update after 2 keyframes diverges, so every 1 Hz row waits 20 keyframes, as at one fix in ten.

Scores: RMSE (m) of the keyframe positions against every GPS fix from fix 1 on (fused or not, the script's own
comparison), and ATE (m, RMSE, no alignment) against the OXTS ground truth of ``kitti_raw/2011_10_03_drive_0027.csv``
at every raw sample between the first and the last fused fix, the keyframe trajectory interpolated (cubic Hermite
on positions and velocities) and mapped from the GPS file's frame into the ground truth's ENU frame by the per-axis
scale and offset that ``read_kitti_raw(gps_file=...)`` fits. Also printed: what the model does on this drive (the
mean of its correction, here and on the training drives) and how calibrated its covariance is over 1 s and 10 s
(NSE on this drive and on the validation drives, and the validation drives' maximum-likelihood noise scales).

Which learned row to report is chosen without this drive: every candidate of ``CANDIDATES`` runs the same loop on
each validation drive of the KITTI config (its IMU written in GTSAM's file format, its GPS file the OXTS solution's
positions at 1 Hz, as GTSAM's file holds the OXTS positions of its drive), scored by ATE against the OXTS ground
truth; at each rate the candidate with the lowest mean ATE over the validation drives is the learned row.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import json
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fusion.graph import Trajectory
from learned_imu.datasets import read_sequence

DRIVE = "kitti_raw/2011_10_03_drive_0027.csv"
REPAIR = {"on_backward": "drop", "on_duplicate": "drop", "on_gap": "keep"}
RATES = ((10, None), (1, 20))  # (gps_skip, keyframes before the first ISAM2 update; None: the script's 2 * gps_skip)
HORIZONS = {10: 1000, 1: 100}  # gps_skip -> samples of the windows whose calibration matters (the GPS interval)
LOOSE_GYRO_PRIOR = 1e-3  # rad/s: a first-bias prior that lets the bias states take a constant of the correction
EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "kitti_gps_learned.py"


def load_example():
    spec = importlib.util.spec_from_file_location("kitti_gps_learned", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


class GroundTruth:
    """The OXTS ground truth of the drive and the map from the GPS file's frame into its ENU frame."""

    def __init__(self, data: Path):
        self.truth = read_sequence("kitti_raw", data / DRIVE, **REPAIR)
        gps_file = "../kitti_gtsam/KittiGps_converted.txt"
        as_is = read_sequence("kitti_raw", data / DRIVE, **REPAIR, gps_file=gps_file, gps_frame="as_is").gps
        fitted = read_sequence("kitti_raw", data / DRIVE, **REPAIR, gps_file=gps_file).gps
        self.scale = np.array([np.polyfit(as_is.pos[:, a], fitted.pos[:, a], 1) for a in range(3)])  # (3, 2)

    def ate_m(self, run) -> float:
        """ATE of a ``KittiRun`` (module docstring)."""
        traj = Trajectory(run.t, run.rot, run.pos * self.scale[:, 0] + self.scale[:, 1], run.vel * self.scale[:, 0])
        fused = run.t[run.fused]
        inside = (self.truth.t >= fused[0]) & (self.truth.t <= fused[-1])
        err = traj.position_at(self.truth.t[inside]) - self.truth.gt.pos[inside]
        return float(np.sqrt(np.mean(np.sum(err**2, axis=1))))


@dataclass(frozen=True)
class Inputs:
    """What the variants are made of, per sample of GTSAM's IMU file: the raw samples with the script's noise, the
    model's samples and noise, the model's mean correction on the training drives ((6,) gyro rad/s, acc m/s^2) and
    the validation drives' maximum-likelihood (gyro, acc) noise scales per gps_skip (variance factors)."""

    raw: object
    model: object
    train_mean: np.ndarray
    val_scales: dict


@dataclass(frozen=True)
class Variant:
    """One row: its samples at a given gps_skip, and the mirror's other arguments."""

    name: str
    samples: Callable[[Inputs, int], object]
    bias_prior_sigmas: tuple[float, ...] | None = None


def _with(example, base, gyro=None, acc=None, gyro_cov=None, acc_cov=None):
    pick = lambda new, old: old if new is None else new  # noqa: E731
    return example.Samples(
        pick(gyro, base.gyro), pick(acc, base.acc), pick(gyro_cov, base.gyro_cov), pick(acc_cov, base.acc_cov)
    )


def variants(example) -> list[Variant]:
    """The rows after the script's: the mirror raw, the model, and what takes the model apart."""
    ex = example

    def minus_mean(i: Inputs, mean: np.ndarray):
        return _with(ex, i.model, i.model.gyro - mean[:3], i.model.acc - mean[3:])

    def drive_mean(i: Inputs) -> np.ndarray:
        return np.concatenate([(i.model.gyro - i.raw.gyro).mean(0), (i.model.acc - i.raw.acc).mean(0)])

    def scaled(base, i: Inputs, skip: int):
        gyro_scale, acc_scale = i.val_scales[skip]
        return _with(ex, base, gyro_cov=i.model.gyro_cov * gyro_scale, acc_cov=i.model.acc_cov * acc_scale)

    loose = (ex.BIAS_PRIOR_SIGMAS[0],) * 3 + (LOOSE_GYRO_PRIOR,) * 3
    return [
        Variant("mirror, raw IMU (the script's settings)", lambda i, s: i.raw),
        Variant("mirror + KITTI model (corrections, learned noise)", lambda i, s: i.model),
        Variant(
            "model's corrections, the script's noise",
            lambda i, s: _with(ex, i.model, gyro_cov=i.raw.gyro_cov, acc_cov=i.raw.acc_cov),
        ),
        Variant("raw IMU + learned noise", lambda i, s: _with(ex, i.model, i.raw.gyro, i.raw.acc)),
        Variant("model, correction minus its mean on this drive", lambda i, s: minus_mean(i, drive_mean(i))),
        Variant("model, correction minus the training drives' mean", lambda i, s: minus_mean(i, i.train_mean)),
        Variant(
            f"model, gyro bias prior {LOOSE_GYRO_PRIOR:g} rad/s (bias states take the constant)",
            lambda i, s: i.model,
            loose,
        ),
        Variant("model, learned noise x validation scales at the GPS interval", lambda i, s: scaled(i.model, i, s)),
        Variant("raw IMU + learned noise x validation scales at the GPS interval", lambda i, s: scaled(i.raw, i, s)),
        Variant(
            "raw IMU + learned gyro noise x validation scale, the script's acc noise (chosen on this drive)",
            lambda i, s: _with(ex, scaled(i.raw, i, s), acc_cov=i.raw.acc_cov),
        ),
    ]


# the rows that may stand for the learned model (names of ``variants``); the validation drives choose among them,
# and score the script's own settings beside them (REFERENCE, not a candidate)
REFERENCE = "mirror, raw IMU (the script's settings)"
DIVERGED_M = 100.0  # a validation run this far off its drive's truth diverged (few fixes on a short drive): failed
CANDIDATES = (
    "mirror + KITTI model (corrections, learned noise)",
    "model's corrections, the script's noise",
    "raw IMU + learned noise",
    "model, learned noise x validation scales at the GPS interval",
    "raw IMU + learned noise x validation scales at the GPS interval",
    "raw IMU + learned gyro noise x validation scale, the script's acc noise (chosen on this drive)",
)


def write_gtsam_files(drive, folder: Path, metadata: Path) -> None:
    """``drive`` (a ``kitti_raw`` sequence) as GTSAM's example files: the IMU file (its ``dt`` column the time since
    the previous sample; rows interpolated linearly inside the drive's time gaps, as GTSAM's file has them) and a GPS
    file of the OXTS positions every 1 s."""
    folder.mkdir(parents=True, exist_ok=True)
    step = float(np.median(np.diff(drive.t)))
    t = [drive.t[:1]]
    for a, b in zip(drive.t[:-1], drive.t[1:], strict=True):
        inside = np.arange(1, int(round((b - a) / step))) * step + a if b - a > 1.5 * step else np.zeros(0)
        t += [inside, np.array([b])]
    t = np.concatenate(t)
    samples = [np.column_stack([np.interp(t, drive.t, x[:, i]) for i in range(3)]) for x in (drive.acc, drive.gyro)]
    imu = np.column_stack([t, np.diff(t, prepend=t[0]), *samples])
    np.savetxt(
        folder / "KittiEquivBiasedImu.txt",
        imu,
        header="Time dt accelX accelY accelZ omegaX omegaY omegaZ",
        comments="",
        fmt="%.12f",
    )
    fixes = np.flatnonzero(np.diff(np.floor(drive.t - drive.t[0]), prepend=-1) > 0)  # the first sample of each second
    fixes = fixes[drive.gt.valid[fixes]]
    gps = np.column_stack([drive.t[fixes], drive.gt.pos[fixes]])
    np.savetxt(folder / "KittiGps_converted.txt", gps, header="Time,X,Y,Z", comments="", delimiter=",", fmt="%.12f")
    (folder / metadata.name).write_bytes(metadata.read_bytes())


def corrected(example, out):
    """A model's output (``correct``) as the example's per-sample ``Samples``."""
    fields = (out.gyro, out.acc, out.gyro_cov, out.acc_cov)
    return example.Samples(*(np.asarray(x.numpy(), dtype=float) for x in fields))


def run_variant(example, folder: Path, variant: Variant, inputs: Inputs, skip: int, wait: int | None):
    """The script's loop on the files in ``folder`` with ``variant``'s samples (and first-bias prior)."""
    kwargs = {"bias_prior_sigmas": variant.bias_prior_sigmas} if variant.bias_prior_sigmas else {}
    return example.run(folder, gps_skip=skip, wait=wait, samples=variant.samples(inputs, skip), **kwargs)


def drive_ate_m(run, drive) -> float:
    """ATE of a run on a validation drive against its OXTS ground truth (the GPS file is in the truth's frame)."""
    traj = Trajectory(run.t, run.rot, run.pos, run.vel)
    fused = run.t[run.fused]
    inside = (drive.t >= fused[0]) & (drive.t <= fused[-1]) & drive.gt.valid
    err = traj.position_at(drive.t[inside]) - drive.gt.pos[inside]
    return float(np.sqrt(np.mean(np.sum(err**2, axis=1))))


def choose_on_validation(example, model, val: list, inputs: Inputs, data: Path, scratch: Path) -> dict:
    """For each rate (gps_skip): each candidate's mean ATE over the validation drives ``val`` and the one with the
    lowest."""
    from learned_imu.network.inference import correct

    metadata = data / "kitti_gtsam" / example.METADATA_FILE
    calibration = example.read_calibration(metadata)
    by_variant = {v.name: v for v in variants(example)}
    scored = (REFERENCE, *CANDIDATES)
    scores = {(name, skip): [] for name in scored for skip, _ in RATES}
    for i, drive in enumerate(val):
        folder = scratch / f"val{i}"
        write_gtsam_files(drive, folder, metadata)
        seq = read_sequence("kitti", folder)
        raw, learned = example.raw_samples(seq, calibration), corrected(example, correct(model, seq))
        here = dataclasses.replace(inputs, raw=raw, model=learned)
        for name in scored:
            for skip, wait in RATES:
                try:
                    run = run_variant(example, folder, by_variant[name], here, skip, wait)
                except RuntimeError:  # the script's loop stops (indeterminate) on some short drives
                    scores[name, skip].append(np.nan)
                else:
                    ate = drive_ate_m(run, drive)
                    scores[name, skip].append(ate if ate < DIVERGED_M else np.nan)
    out = {}
    for skip, _ in RATES:
        table = np.array([scores[name, skip] for name in scored])  # (rows, drives)
        solved = ~np.isnan(table).any(axis=0)  # drives every row solved: the means compare like with like
        means = {name: float(np.mean(row[solved])) for name, row in zip(scored, table, strict=True)}
        failed = {name: int(np.isnan(row).sum()) for name, row in zip(scored, table, strict=True)}
        fewest = min(failed[n] for n in CANDIDATES)
        chosen = min((n for n in CANDIDATES if failed[n] == fewest), key=means.get)
        out[skip] = {
            "mean_ate_m": means,
            "failed_drives": failed,
            "drives_compared": int(solved.sum()),
            "per_drive_ate_m": {n: [float(v) for v in row] for n, row in zip(scored, table, strict=True)},
            "chosen": chosen,
        }
        for name in scored:
            print(
                f"validation drives, gps_skip {skip}: {name}: mean ATE {means[name]:.3f} m over {solved.sum()} "
                f"drives ({failed[name]} of {table.shape[1]} drives stopped indeterminate or diverged)"
            )
        print(f"validation drives, gps_skip {skip}: chosen: {chosen}")
    return out


def model_inputs(example, model, config, val: list, data: Path, seq, raw) -> tuple[Inputs, dict]:
    """The model's samples on GTSAM's file, its mean correction on the training drives, its calibration (NSE over
    1 s and 10 s on this drive and the validation drives ``val``) and the validation drives' ML noise scales."""
    from learned_imu.network.inference import correct
    from learned_imu.training.experiment import build_windows, load_sequences
    from learned_imu.training.train import noise_residuals

    out = correct(model, seq)
    samples = corrected(example, out)
    sums, count = np.zeros(6), 0
    for train in load_sequences(config.data.train, config.data.root):
        c = correct(model, train)
        sums += np.concatenate([c.d_gyro.numpy().sum(0), c.d_acc.numpy().sum(0)])
        count += len(train)
    drive = read_sequence("kitti_raw", data / DRIVE, **REPAIR)
    report = {
        "correction_mean_this_drive": np.concatenate([out.d_gyro.numpy().mean(0), out.d_acc.numpy().mean(0)]),
        "correction_mean_training_drives": sums / count,
    }
    scales = {}
    for skip, length in HORIZONS.items():
        windows = dataclasses.replace(config, train=dataclasses.replace(config.train, window=length, every=length))
        on_val = noise_residuals(model, build_windows(val, windows, length))
        scales[skip] = on_val.best_scales()
        report[f"nse_{length / 100:g}s_val"] = on_val.nse()
        report[f"nse_{length / 100:g}s_this_drive"] = noise_residuals(
            model, build_windows([drive], windows, length)
        ).nse()
        report[f"val_scales_{length / 100:g}s"] = np.array(scales[skip])
    return Inputs(raw, samples, sums / count, scales), report


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(Path(__file__).resolve().parents[2] / "shared" / "data"))
    parser.add_argument("--checkpoint", default="runs/kitti/best.pt", help="the KITTI model (configs/kitti.yaml)")
    parser.add_argument("--config", default="configs/kitti.yaml", help="its experiment (training, validation drives)")
    parser.add_argument("--json", default=None, help="write the rows to this JSON file")
    args = parser.parse_args()
    data = Path(args.data)
    example, truth = load_example(), GroundTruth(data)
    files = data / "kitti_gtsam"
    rows = []

    def add(name: str, skip: int, run) -> None:
        rows.append({"row": name, "gps_skip": skip, "rmse_to_gps_m": run.rmse_to_gps_m, "ate_m": truth.ate_m(run)})
        print(
            f"{name} [gps_skip {skip}]: RMSE {rows[-1]['rmse_to_gps_m']:.3f} m, ATE {rows[-1]['ate_m']:.3f} m",
            flush=True,
        )

    for skip, factorization in ((10, "CHOLESKY"), (1, "QR")):  # as shipped: the two that stop
        try:
            solved = example.gtsam_script(files, skip, factorization)
        except RuntimeError as error:
            print(f"GTSAM's script, {factorization}, gps_skip {skip}: {' '.join(str(error).split()[:12])}")
        else:
            print(f"GTSAM's script, {factorization}, gps_skip {skip}: solved, RMSE {solved.rmse_to_gps_m:.3f} m")
    for skip, wait in RATES:
        add("GTSAM's IMUKittiExampleGPS.py, QR", skip, example.gtsam_script(files, skip, "QR", wait))
    import tempfile

    from learned_imu.config import load_config
    from learned_imu.network.checkpoint import model_from_checkpoint
    from learned_imu.training.experiment import load_sequences

    seq = read_sequence("kitti", files)
    raw = example.raw_samples(seq, example.read_calibration(files / example.METADATA_FILE))
    model, config = model_from_checkpoint(args.checkpoint)[0], load_config(args.config, data_root=data)
    val = load_sequences(config.data.val, config.data.root)
    inputs, report = model_inputs(example, model, config, val, data, seq, raw)
    for key, value in report.items():
        print(f"{key}: {np.array2string(np.asarray(value), precision=5)}")
    with tempfile.TemporaryDirectory() as scratch:
        choice = choose_on_validation(example, model, val, inputs, data, Path(scratch))
    for variant in variants(example):
        for skip, wait in RATES:
            start = time.perf_counter()
            add(variant.name, skip, run_variant(example, files, variant, inputs, skip, wait))
            rows[-1]["seconds"] = time.perf_counter() - start
            rows[-1]["chosen_on_validation"] = variant.name == choice[skip]["chosen"]
    if args.json:
        extra = {k: np.asarray(v).tolist() for k, v in report.items()}
        validation = {str(skip): value for skip, value in choice.items()}
        Path(args.json).write_text(json.dumps({"rows": rows, "model": extra, "validation": validation}, indent=1))
    for skip, value in choice.items():
        chosen = next(r for r in rows if r["gps_skip"] == skip and r["row"] == value["chosen"])
        script = next(r for r in rows if r["gps_skip"] == skip and r["row"].startswith("GTSAM's"))
        print(
            f"gps_skip {skip}: the row the validation drives chose, {chosen['row']}: RMSE "
            f"{chosen['rmse_to_gps_m']:.3f} / ATE {chosen['ate_m']:.3f} m against GTSAM's script "
            f"{script['rmse_to_gps_m']:.3f} / {script['ate_m']:.3f} m"
        )


if __name__ == "__main__":
    main()
