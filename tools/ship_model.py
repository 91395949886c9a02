"""Write a trained run's best.pt as a shipped model (``learned_imu.network.shipped``): the weights alone, in float16,
and say how much the float16 weights change the model's output on a sequence (the card records what it scores).

    python tools/ship_model.py runs/euroc/best.pt euroc --dataset euroc --path ../shared/data/euroc/MH_04_difficult
"""

from __future__ import annotations

import argparse

import torch
import yaml

from learned_imu.datasets import read_sequence
from learned_imu.network.checkpoint import load_checkpoint, save_checkpoint
from learned_imu.network.shipped import SHIPPED_DIR, slim


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("checkpoint")
    parser.add_argument("name")
    parser.add_argument("--dataset", required=True)
    parser.add_argument("--path", required=True)
    parser.add_argument("--option", action="append", default=[], help="a reader option key=value (repeatable)")
    args = parser.parse_args()
    full = load_checkpoint(args.checkpoint)
    shipped = save_checkpoint(SHIPPED_DIR / f"{args.name}.pt", slim(full, half=True))
    back = load_checkpoint(shipped)
    options = {key: yaml.safe_load(value) for key, _, value in (o.partition("=") for o in args.option)}
    sequence = read_sequence(args.dataset, args.path, **options)
    if full.kind == "correction":
        from learned_imu.network.inference import correct

        a, b = correct(full.model(args.checkpoint), sequence), correct(back.model(shipped), sequence)
        fields = {"gyro": (a.gyro, b.gyro), "acc": (a.acc, b.acc), "gyro_cov": (a.gyro_cov, b.gyro_cov)}
    else:
        from learned_imu.network.motion import predict_velocities

        rot = sequence.gt.rot  # only to compare the two files' outputs on one input (never at test time)
        a = predict_velocities(full.motion_model(args.checkpoint), sequence, rot)
        b = predict_velocities(back.motion_model(shipped), sequence, rot)
        fields = {
            "vel": (torch.as_tensor(a.vel), torch.as_tensor(b.vel)),
            "var": (torch.as_tensor(a.var), torch.as_tensor(b.var)),
        }
    for name, (x, y) in fields.items():
        difference, scale = float((x - y).abs().max()), float(x.abs().max())
        print(f"{name}: max |float32 - float16| {difference:.3g}, max |float32| {scale:.3g}")
    print(f"written {shipped} ({shipped.stat().st_size / 1e6:.2f} MB)")


if __name__ == "__main__":
    main()
