"""The gyro's unit from gravity and turns (``learned_imu.datasets._tilt``, issue 37) on every shared recording: each
read right (the control), its gyro x 180/pi (a deg/s file read as rad/s), x 1000 (mrad/s) and x pi/180 (a rad/s file
converted as if deg/s); per log the outcome of ``check_gyro_unit``, the gravity spread as read (m/s^2), and the turn
fit's windows and median speed as read (m/s), then the counts.

    python benchmarks/gyro_tilt.py [--json F]

Outcomes: "accepted" (a control that passes), "false refusal" (a control refused), "refused, right" (the message
names the unit of the mistake), "wrong cause", "undecided" (the log has fewer than three 10-s stretches without a
gap and fewer than ``TURN_MIN_WINDOWS`` turn windows: not checked), "missed" (checked, nothing said).
"""

from __future__ import annotations

import argparse
import json
import logging
from collections import Counter
from pathlib import Path

import numpy as np

from airimu_core.errors import DataError
from learned_imu.datasets import read_sequence
from learned_imu.datasets._tilt import TILT_SHORT, TURN_MIN_WINDOWS, check_gyro_unit, gravity_spread, turn_speeds

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
MISTAKES = {"as read": (1.0, None), "deg/s": (180.0 / np.pi, "deg/s"), "mrad/s": (1000.0, "mrad/s")}
MISTAKES["rad/s as deg/s"] = (np.pi / 180.0, "converted as if deg/s")


def logs():
    """(dataset, path, reader options) of every shared recording with its full IMU."""
    out = [
        ("euroc", p, {"on_gap": "keep"})
        for p in sorted((DATA / "euroc").iterdir())
        if (p / "mav0/imu0/data.csv").exists()
    ]
    kitti = {"on_backward": "drop", "on_duplicate": "drop", "on_gap": "keep"}
    out += [("kitti_raw", p, kitti) for p in sorted((DATA / "kitti_raw").glob("*.csv"))]
    out += [("broad", p, {}) for p in sorted((DATA / "broad").glob("*.mat"))]
    out += [("tumvi", p, {}) for p in sorted((DATA / "tumvi").glob("dataset-*"))]
    return out


def outcome(seq, factor: float, cause: str | None) -> tuple[str, float | None, list]:
    gyro = seq.gyro * factor
    fit = gravity_spread(seq.t, gyro, seq.acc) or gravity_spread(seq.t, gyro, seq.acc, *TILT_SHORT)
    spread = None if fit is None else fit.spread
    speeds = turn_speeds(seq.t, gyro, seq.acc)
    turns = [len(speeds), round(float(np.median(speeds)), 1) if len(speeds) else None]
    try:
        check_gyro_unit(seq.t, gyro, seq.acc, seq.source)
    except DataError as error:
        if cause is None:
            return "false refusal", spread, turns
        return ("refused, right" if cause in str(error).split("gyro in ")[-1] else "wrong cause"), spread, turns
    if fit is None and len(speeds) < TURN_MIN_WINDOWS:
        return "undecided", None, turns
    return ("accepted" if cause is None else "missed"), spread, turns


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", help="write the rows here")
    args = parser.parse_args()
    logging.basicConfig(level=logging.ERROR)
    rows, counts = [], Counter()
    for dataset, path, options in logs():
        seq = read_sequence(dataset, path, **options)
        row = {"log": path.name, "dataset": dataset}
        for mistake, (factor, cause) in MISTAKES.items():
            said, spread, turns = outcome(seq, factor, cause)
            row[mistake] = [said, None if spread is None else round(spread, 2), *turns]
            counts[(dataset, mistake, said)] += 1
        rows.append(row)
        print(json.dumps(row), flush=True)
    print("| dataset | reading | " + " | ".join(sorted({k[2] for k in counts})) + " |")
    for dataset in dict.fromkeys(k[0] for k in counts):
        for mistake in MISTAKES:
            cells = [str(counts[(dataset, mistake, said)]) for said in sorted({k[2] for k in counts})]
            print(f"| {dataset} | {mistake} | " + " | ".join(cells) + " |")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
