"""Is a model's learned covariance right over longer spans than it was calibrated on? The NSE (mean e^2 / sigma^2 of
rotation, position, velocity; 1 when right) of ``ablate-imu`` on the model's evaluation sequences, with windows of
1 / 5 / 10 s, one window every window length, each scored at its end.

    python benchmarks/covariance_horizon.py [--checkpoint euroc] [--data-root ../shared/data] [--seconds 1 5 10]

The learned noise is white per sample; an NSE that grows with the span says the corrected samples keep an error
correlated over seconds that the covariance does not carry (BENCHMARKS.md, PGO EuRoC).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
from pathlib import Path

import numpy as np

from learned_imu.evaluation.ablation import calibration
from learned_imu.network.checkpoint import model_from_checkpoint
from learned_imu.training.experiment import load_sequences

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", default="euroc", help="a shipped model's name or a best.pt")
    parser.add_argument("--data-root", default=str(DATA))
    parser.add_argument("--seconds", type=float, nargs="+", default=[1.0, 5.0, 10.0])
    args = parser.parse_args()
    logging.basicConfig(level=logging.ERROR)
    model, config = model_from_checkpoint(args.checkpoint)
    sequences = load_sequences(config.data.evaluate, args.data_root)
    for seconds in args.seconds:
        for seq in sequences:
            window = int(round(seconds / float(np.median(np.diff(seq.t)))))
            chunk = config.train.chunk and max(window, config.train.chunk)  # 0 stays 0: windows one by one
            train = dataclasses.replace(config.train, window=window, every=window, chunk=chunk)
            nse = calibration(model, seq, dataclasses.replace(config, train=train))
            row = {"sequence": seq.name, "seconds": seconds, "nse_rot_pos_vel": [round(float(x), 2) for x in nse]}
            print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
