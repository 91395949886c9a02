"""How much of KITTI's 1-s rotation error is the OXTS rate channels' ~40 ms lag behind the attitude
(../shared/data/kitti_raw/README.md, Conventions 5): the raw ROE with the gyro advanced by 0, 2, 4 and 5 samples.

    python benchmarks/kitti_lag.py

A causal model (the network sees samples up to the one it corrects) cannot advance its input; a model with a few
samples of look-ahead could.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from learned_imu.config import load_config
from learned_imu.evaluation.evaluate import evaluate
from learned_imu.training.experiment import load_sequences

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "kitti.yaml"


def main() -> None:
    config = load_config(CONFIG)
    for seq in load_sequences(config.data.evaluate, config.data.root):
        out = []
        for lag in (0, 2, 4, 5):
            gyro = np.concatenate([seq.gyro[lag:], np.repeat(seq.gyro[-1:], lag, 0)]) if lag else seq.gyro
            out.append(evaluate(seq, 1.0, "s", gyro, seq.acc).roe_deg)
        print(
            f"{seq.name}: ROE 1 s (deg) with the gyro advanced by 0 / 2 / 4 / 5 samples: "
            + " / ".join(f"{x:.4f}" for x in out)
        )


if __name__ == "__main__":
    main()
