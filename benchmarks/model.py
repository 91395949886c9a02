"""AirImuNet size and speed: streaming inference samples/s and training windows/s on this CPU.

    python benchmarks/model.py [--samples 100000] [--window 1000] [--batch 16]

Inference: ``correct_sequence`` over a random sequence in chunks of 4096 (batch 1, no ground truth).
Training: ``window_loss`` forward + backward + Adam step on a batch of windows (covariance included).
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch

from learned_imu.losses import LossWeights
from learned_imu.model import AirImuNet, correct_sequence
from learned_imu.simulator import simulate
from learned_imu.train import window_loss
from learned_imu.windows import make_windows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--samples", type=int, default=100_000)
    parser.add_argument("--window", type=int, default=1000)
    parser.add_argument("--batch", type=int, default=16)
    args = parser.parse_args()
    torch.manual_seed(0)
    gyro, acc = torch.randn(args.samples, 3), torch.randn(args.samples, 3)
    seq = simulate("drone", duration_s=args.batch * args.window / 200.0 + 1.0, seed=0)
    windows = make_windows(seq, length=args.window, every=50)
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads")
    for use_gru in (True, False):
        model = AirImuNet(use_gru=use_gru)
        n_params = sum(p.numel() for p in model.parameters())
        model.eval()
        correct_sequence(model, gyro[:9000], acc[:9000])
        start = time.perf_counter()
        correct_sequence(model, gyro, acc, chunk=4096)
        inference = args.samples / (time.perf_counter() - start)
        model.train()
        optimiser = torch.optim.Adam(model.parameters(), lr=1e-3)
        steps = []
        for _ in range(4):
            start = time.perf_counter()
            loss = window_loss(model, windows, LossWeights())
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            steps.append(time.perf_counter() - start)
        train_rate = len(windows) / statistics.median(steps[1:])
        print(
            f"use_gru={use_gru}: {n_params:,} parameters; inference {inference:,.0f} samples/s "
            f"({inference / 200:,.0f}x real time at 200 Hz); training {train_rate:.1f} windows/s "
            f"({len(windows)} windows of {args.window} samples per step)"
        )


if __name__ == "__main__":
    main()
