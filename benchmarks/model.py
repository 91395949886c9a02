"""AirImuNet size and speed: streaming inference samples/s and one full training step, ours against the same step
with pypose's ``IMUPreintegrator`` (the integrator the official AirIMU code trains with) in place of ours.

    python benchmarks/model.py [--samples 100000] [--window 1000] [--batch 16] [--repeats 7]

Inference: ``correct_sequence`` over a random sequence in chunks of 4096 (batch 1, no ground truth).
Training step (both sides, one run): the network on a batch of windows, preintegration of the corrected samples with
the learned noise, the state loss on every 50th sample and the covariance NLL, backward, Adam step.
- ours: ``learned_imu.training.train.window_loss`` exactly as training runs it (deltas and covariance at every
supervised
  sample, float32);
- pypose: the same network, errors and losses, with ``pp.module.IMUPreintegrator(gravity=0, prop_cov=True,
  reset=True)`` integrating the window (deltas after every sample; its covariance after the last sample only,
  reordered to GTSAM's [rotation, position, velocity], so the NLL sees one covariance per window: the official
  code's loss). pypose's side therefore propagates less covariance than ours.
Median of ``--repeats`` steps after one warm-up; the ratio is pypose's time over ours.
"""

from __future__ import annotations

import argparse
import functools
import statistics
import time

import pypose as pp
import torch

from learned_imu.datasets.simulator import simulate
from learned_imu.geometry.preintegration import Preintegrated
from learned_imu.network.model import AirImuNet, correct_sequence
from learned_imu.training.losses import LossWeights, covariance_nll, delta_errors, state_loss
from learned_imu.training.train import window_loss
from learned_imu.training.windows import Windows, make_windows

PYPOSE_TO_GTSAM = [0, 1, 2, 6, 7, 8, 3, 4, 5]  # pypose's covariance is [rot, vel, pos]; GTSAM's [rot, pos, vel]


def pypose_window_loss(model, windows: Windows, weights: LossWeights, integrator) -> torch.Tensor:
    """``window_loss`` with pypose's integrator in place of ``learned_imu.preintegrate`` (see the module doc)."""
    out = model(windows.gyro, windows.acc)
    batch = windows.gyro.shape[0]
    init = {"pos": torch.zeros(batch, 1, 3), "rot": pp.identity_SO3(batch, 1), "vel": torch.zeros(batch, 1, 3)}
    dt = windows.dt[..., None]
    state = integrator(
        dt, out.gyro, out.acc, gyro_cov=out.gyro_cov / dt, acc_cov=out.acc_cov / dt, init_state=init
    )  # pypose takes per-sample variances (density / dt)
    at = windows.at
    pre = Preintegrated(
        rot=state["rot"].matrix()[:, at], vel=state["vel"][:, at], pos=state["pos"][:, at], dt=windows.dt[:, at]
    )
    errors = delta_errors(pre, windows.start, windows.targets, windows.gravity)
    cov = state["cov"].reshape(batch, 9, 9)[:, PYPOSE_TO_GTSAM][:, :, PYPOSE_TO_GTSAM]
    nll = covariance_nll(errors[:, -1].detach(), cov)  # detached, as ours (loss.covariance_trains_corrections off)
    return state_loss(errors, weights) + weights.covariance * nll


def time_steps(loss_fn, model, repeats: int) -> float:
    """Median seconds of one forward + backward + Adam step (after one warm-up step)."""
    optimiser = torch.optim.Adam(model.parameters(), lr=1e-3)
    steps = []
    for _ in range(repeats + 1):
        start = time.perf_counter()
        loss = loss_fn()
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        steps.append(time.perf_counter() - start)
    return statistics.median(steps[1:])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--samples", type=int, default=100_000)
    parser.add_argument("--window", type=int, default=1000)
    parser.add_argument("--batch", type=int, default=16)
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    torch.manual_seed(0)
    gyro, acc = torch.randn(args.samples, 3), torch.randn(args.samples, 3)
    seq = simulate("drone", duration_s=args.batch * args.window / 200.0 + 1.0, seed=0)
    windows = make_windows(seq, length=args.window, every=50)
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads; pypose {pp.__version__}")
    for use_gru in (True, False):
        model = AirImuNet(use_gru=use_gru)
        n_params = sum(p.numel() for p in model.parameters())
        model.eval()
        correct_sequence(model, gyro[:9000], acc[:9000])
        start = time.perf_counter()
        correct_sequence(model, gyro, acc, chunk=4096)
        inference = args.samples / (time.perf_counter() - start)
        model.train()
        weights = LossWeights()
        integrator = pp.module.IMUPreintegrator(gravity=0.0, prop_cov=True, reset=True)
        ours = time_steps(functools.partial(window_loss, model, windows, weights), model, args.repeats)
        theirs = time_steps(
            functools.partial(pypose_window_loss, model, windows, weights, integrator), model, args.repeats
        )
        print(
            f"use_gru={use_gru}: {n_params:,} parameters; inference {inference:,.0f} samples/s "
            f"({inference / 200:,.0f}x real time at 200 Hz)\n"
            f"  training step, {len(windows)} windows of {args.window} samples: ours {ours * 1e3:.0f} ms "
            f"({len(windows) / ours:.1f} windows/s), with pypose's integrator {theirs * 1e3:.0f} ms: "
            f"{theirs / ours:.2f}x ours"
        )


if __name__ == "__main__":
    main()
