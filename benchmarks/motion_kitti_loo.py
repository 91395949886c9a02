"""Leave-one-sequence-out motion models for KITTI (AI-IMU's protocol): one training per sequence of AI-IMU's table.

    python benchmarks/motion_kitti_loo.py --out runs/kitti-loo [--only 04 08] [--threads 1]
    python benchmarks/motion_kitti.py --loo runs/kitti-loo --cov-scale 30 1 1 --imu-gaps interpolate
    python benchmarks/motion_kitti_loo.py --out runs/kitti-loo-delay --imu-delay 0.049   # the IMU on the truth's clock

Sequence S's model (``OUT/seqS``) is ``configs/kitti_motion_loo.yaml`` with S's whole drive taken out of the training
list and S's drive as the one to evaluate; validation as the template (three drives that are no sequence). Runs
resume (``airimu train``'s run folders); each takes 5-7 min on two CPU cores. Two of these processes, each with
``--threads 1`` and half the sequences, finish the ten in about the time of one with two threads.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from motion_kitti import SEQUENCES  # noqa: E402

from learned_imu.config import ExperimentConfig, load_config  # noqa: E402
from learned_imu.training.experiment import train_run  # noqa: E402

TEMPLATE = Path(__file__).resolve().parents[1] / "configs" / "kitti_motion_loo.yaml"


def held_out(template: ExperimentConfig, sequence: str) -> ExperimentConfig:
    """The template without ``sequence``'s drive in training, and with it alone to evaluate."""
    drive = SEQUENCES[sequence][0]
    data = template.data
    train = tuple(spec for spec in data.train if drive not in spec.path)
    evaluate = tuple(spec for spec in data.evaluate if drive in spec.path)
    if len(train) == len(data.train) or len(evaluate) != 1:
        raise SystemExit(f"{TEMPLATE}: sequence {sequence}'s drive {drive} must be in train and once in evaluate")
    data = dataclasses.replace(data, train=train, evaluate=evaluate)
    return dataclasses.replace(template, name=f"{template.name}_seq{sequence}", data=data)


def with_imu_delay(config: ExperimentConfig, delay_s: float) -> ExperimentConfig:
    """``config`` with every sequence read ``delay_s`` later (the readers' ``imu_delay_s``): trained, validated and
    scored on the IMU's samples on the ground truth's clock."""

    def delayed(specs):
        return tuple(dataclasses.replace(s, options={**s.options, "imu_delay_s": delay_s}) for s in specs)

    data = config.data
    data = dataclasses.replace(data, train=delayed(data.train), val=delayed(data.val), evaluate=delayed(data.evaluate))
    return dataclasses.replace(config, data=data)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, help="one run folder per sequence is made here (seq00, seq01, ...)")
    parser.add_argument("--only", nargs="*", choices=sorted(SEQUENCES), help="these sequences (default: all ten)")
    parser.add_argument(
        "--imu-delay",
        type=float,
        default=0.0,
        help="read every drive's IMU this much later (s; the readers' imu_delay_s): motion_kitti.py --measure-delay",
    )
    parser.add_argument("--threads", type=int, help="torch threads of this process (default: torch's)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    template = load_config(TEMPLATE)
    if args.imu_delay:
        template = with_imu_delay(template, args.imu_delay)
    for sequence in args.only or sorted(SEQUENCES):
        summary = train_run(held_out(template, sequence), Path(args.out) / f"seq{sequence}", progress=False)
        print(f"seq {sequence}: {summary}", flush=True)


if __name__ == "__main__":
    main()
