"""Hostile inputs on real logs (issue 37): each physical check fed the mistake it is for, at several magnitudes, on
several KITTI raw drives, and the right input as a control; every outcome classified as refused with the right cause,
warned with the right cause, accepted and right (the controls), a wrong-cause message, or quiet and wrong.

    python benchmarks/hostile_inputs.py --drive 2011_10_03_drive_0047 --drive 2011_09_30_drive_0033 \\
        --drive 2011_10_03_drive_0027

GPS: the drive's ground truth at 1 Hz with 0.5 m noise (as a user's CSV would carry it), run through the checks that
``airimu fuse`` runs on a GPS file before fusing (``check_gps_units``, the altitude alone in feet or km included,
``check_gps_times``, ``check_gps_clock``, ``read_gps_csv``'s sigma check); models: ``check_model_against_raw`` with an
untrained AirIMU network whose gyro output is offset; the gyro's unit and sign: ``check_imu_units`` (the track's
turns against the gyro's, and the track explained by the gyro as read and in other units; no ground truth); and
without GPS ``check_gyro_unit`` (the gyro's rotations against the gravity the accelerometer sees, and a car's turns
against its centripetal force, as the readers and ``fuse()`` run it on a log without ground truth;
``benchmarks/gyro_tilt.py`` runs it on every shared log).
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
from collections import Counter
from pathlib import Path

import numpy as np

from airimu.fuse import check_gps_clock, check_gps_times, check_gps_units, check_imu_units, check_model_against_raw
from airimu_core.errors import AirImuError
from airimu_core.sequence import GpsFixes
from learned_imu.datasets._assemble import ReadChecks
from learned_imu.datasets._tilt import check_gyro_unit
from learned_imu.datasets.gps import read_gps_csv
from learned_imu.datasets.kitti_raw import read_kitti_raw

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "kitti_raw"
OUTCOMES = ("refused, right cause", "warned, right cause", "accepted, right", "wrong cause", "quiet and wrong")


class Captured(logging.Handler):
    def __init__(self):
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record):
        self.messages.append(record.getMessage())


def classify(run, cause: str | None) -> tuple[str, str]:
    """Run ``run`` (no argument); ``cause``: a phrase the right message holds, None for a control (right input)."""
    handler = Captured()
    logging.getLogger().addHandler(handler)
    try:
        run()
        error = None
    except AirImuError as caught:
        error = str(caught)
    finally:
        logging.getLogger().removeHandler(handler)
    said = error or " | ".join(handler.messages)
    if cause is None:
        return ("accepted, right" if not said else "wrong cause"), said
    if not said:
        return "quiet and wrong", said
    if cause not in said:
        return "wrong cause", said
    return ("refused, right cause" if error else "warned, right cause"), said


def gps_file(folder: Path, name: str, t, pos, sigma=None) -> Path:
    path = folder / f"{name}.csv"
    columns, header = [t, *pos.T], "t,x,y,z"
    if sigma is not None:
        columns.append(np.full(len(t), sigma))
        header += ",sigma"
    np.savetxt(path, np.column_stack(columns), delimiter=",", header=header, comments="", fmt="%.9f")
    return path


def cases(sequence, folder: Path):
    """(check, magnitude, runner, right cause or None) for one drive."""
    index = np.arange(0, len(sequence.t), 100)
    index = index[sequence.gt.valid[index]]
    t = sequence.t[index]
    pos = sequence.gt.pos[index] + np.random.default_rng(0).normal(0.0, 0.5, (len(index), 3))
    out = []
    right = gps_file(folder, "m", t, pos)

    def units(path):
        return lambda: check_gps_units(sequence, path, read_gps_csv(path, 0.5), 0.5)

    out.append(("GPS x/y/z unit", "m (control)", units(right), None))
    for unit, scale in (("km", 1e-3), ("cm", 1e2), ("mm", 1e3)):
        out.append(("GPS x/y/z unit", unit, units(gps_file(folder, unit, t, pos * scale)), f"x/y/z in {unit}?"))
    for unit, factor in (("feet", 1.0 / 0.3048), ("km", 1e-3)):  # the altitude alone (its m control: above)
        path = gps_file(folder, f"alt_{unit}", t, pos * np.array([1.0, 1.0, factor]))
        out.append(("GPS altitude unit", unit, units(path), f"altitude in {unit}?"))
    fixes = GpsFixes(t, pos, np.full((len(t), 3), 0.5))
    out.append(("GPS time unit", "s (control)", lambda: check_gps_times(sequence, "gps.csv", fixes), None))
    for unit, scale in (("ms", 1e3), ("us", 1e6), ("ns", 1e9)):
        scaled = GpsFixes(t * scale, pos, fixes.sigma)
        out.append(("GPS time unit", unit, lambda s=scaled: check_gps_times(sequence, "gps.csv", s), f"read as {unit}"))
    out.append(("GPS clock offset", "0 s (control)", lambda: check_gps_clock(sequence, "gps.csv", fixes), None))
    for late in (1.0, 2.0, 7.0, -30.0):
        shifted = GpsFixes(t + late, pos, fixes.sigma)
        side = "late" if late > 0 else "early"
        out.append(
            ("GPS clock offset", f"{late:+g} s", lambda s=shifted: check_gps_clock(sequence, "gps.csv", s), side)
        )
    out.append(("GPS sigma column", "m (control)", lambda: read_gps_csv(gps_file(folder, "s", t, pos, 0.5)), None))
    for unit, value in (("cm", 50.0), ("mm", 500.0)):
        path = gps_file(folder, f"s{unit}", t, pos, value)
        out.append(("GPS sigma column", unit, lambda p=path: read_gps_csv(p), "in cm or mm"))
    out += model_cases(sequence, fixes)
    blind = dataclasses.replace(sequence, gt=None, gps=None)  # the gyro check needs no ground truth
    for label, scale, cause in (
        ("rad/s (control)", 1.0, None),
        ("deg/s", 180.0 / np.pi, "deg/s"),
        ("mrad/s", 1000.0, "mrad/s"),
        ("rad/s read as deg/s", np.pi / 180.0, "converted as if deg/s"),
        ("sign flipped", -1.0, "sign is flipped"),
    ):
        wrong = dataclasses.replace(blind, gyro=blind.gyro * scale)
        out.append(("gyro unit (GPS track)", label, lambda w=wrong: check_imu_units(w, fixes, "imu.csv"), cause))
        if scale > 0:  # without GPS: the gyro's rotations against gravity (what a reader or fuse() runs then)
            out.append(
                (
                    "gyro unit (gravity and turns, no GPS)",
                    label,
                    lambda w=wrong: check_gyro_unit(w.t, w.gyro, w.acc, "imu.csv"),
                    cause,
                )
            )
    return out


def model_cases(sequence, fixes):
    import torch

    from learned_imu.network.inference import correct
    from learned_imu.network.model import AirImuNet

    out = []
    for offset_rad_s in (0.0, 0.052, 0.17):
        torch.manual_seed(0)
        model = AirImuNet().eval()
        with torch.no_grad():  # the decoder's output is scaled by pi / 180: 3.0 -> 0.052 rad/s
            model.gyro_decoder[2].bias.fill_(offset_rad_s / (np.pi / 180.0))
        label = "untrained (control)" if offset_rad_s == 0 else f"gyro +{offset_rad_s:g} rad/s"
        cause = None if offset_rad_s == 0 else "far worse than the raw samples"
        corrected = correct(model, sequence)
        run = lambda c=corrected: check_model_against_raw(sequence, c, fixes, "m.pt")  # noqa: E731
        out.append(("model vs raw IMU", label, run, cause))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--drive", action="append", default=None)
    parser.add_argument("--work", default="/tmp/airimu-hostile")
    args = parser.parse_args()
    drives = args.drive or ["2011_10_03_drive_0047", "2011_09_30_drive_0033", "2011_10_03_drive_0027"]
    folder = Path(args.work)
    folder.mkdir(parents=True, exist_ok=True)
    counts: dict[str, Counter] = {}
    print("| drive | check | input | outcome | message |")
    print("|---|---|---|---|---|")
    for drive in drives:
        checks = ReadChecks(on_duplicate="drop", on_gap="keep")
        sequence = read_kitti_raw(DATA / f"{drive}.csv", on_backward="drop", checks=checks)
        for check, magnitude, run, cause in cases(sequence, folder):
            outcome, said = classify(run, cause)
            counts.setdefault(check, Counter())[outcome] += 1
            print(f"| {drive} | {check} | {magnitude} | {outcome} | {said[:90]} |", flush=True)
    print()
    print("| check | " + " | ".join(OUTCOMES) + " |")
    print("|---" * (len(OUTCOMES) + 1) + "|")
    total = Counter()
    for check, counter in counts.items():
        total.update(counter)
        print(f"| {check} | " + " | ".join(str(counter[o]) for o in OUTCOMES) + " |")
    print("| all | " + " | ".join(str(total[o]) for o in OUTCOMES) + " |")


if __name__ == "__main__":
    main()
