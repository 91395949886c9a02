"""Preintegration with covariance, side by side: ours (parallel scan), pypose, GTSAM's C++ loop, a torch loop.

    python benchmarks/integrator.py [--repeats 7] [--json out.json]

Every peer integrates the same random float32 IMU samples (200 Hz, rates up to 3 rad/s) with covariance
propagation. Reported: the median wall time of several repeats, and ratios (peer time / our time).
"ours" is ``learned_imu.preintegrate`` (covariance by cumulative sums, O(N) work); "ours_pair_scan" is the
other O(log N)-deep route, a scan over (A, Q) pairs with O(N log N) 9x9 products (``preintegration_reference``).
- batch 1, N = 1000, forward: ours, pypose ``IMUPreintegrator(prop_cov=True)``, GTSAM
  ``PreintegratedImuMeasurements.integrateMeasurement`` called from Python per sample (float64, C++), and the
  sample-by-sample torch loop (``preintegrate_loop``, the paper's "iterative" integrator).
- batch 64, N = 1000, forward + backward through deltas and covariance: ours, pypose, the torch loop.
"ours" returns deltas and covariance after every sample; pypose returns the covariance after the last sample only,
which is what "ours_final_only" (``preintegrate(..., at=-1)``) returns too.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import gtsam
import numpy as np
import pypose as pp
import torch

from learned_imu import preintegrate
from learned_imu.geometry.preintegration_reference import preintegrate_loop, preintegrate_pair_scan

DT = 0.005  # s, 200 Hz
GYRO_DENSITY = 1.6968e-4**2  # rad^2/s (EuRoC ADIS16448 datasheet density, squared)
ACC_DENSITY = 2.0e-3**2  # m^2/s^3


def make_samples(batch: int, n: int, seed: int = 0):
    gen = torch.Generator().manual_seed(seed)
    gyro = (torch.rand(batch, n, 3, generator=gen) * 2 - 1) * 3.0
    acc = torch.randn(batch, n, 3, generator=gen) * 2.0 + torch.tensor([0.0, 0.0, 9.81])
    return gyro, acc


def median_time(fn, repeats: int, warmup: int = 2) -> float:
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def torch_function(fn, gyro, acc, backward: bool, **kwargs):
    """Time one of our torch routes: ``preintegrate`` (cumsum route), the pair scan, or the sample loop."""

    def run():
        g = gyro.clone().requires_grad_(backward)
        a = acc.clone().requires_grad_(backward)
        out = fn(g, a, DT, GYRO_DENSITY, ACC_DENSITY, **kwargs)
        if backward:
            (out.pos.sum() + out.rot.sum() + out.vel.sum() + out.cov[..., -1, :, :].sum()).backward()

    return run


def pypose_integrator(gyro, acc, backward: bool):
    integrator = pp.module.IMUPreintegrator(gravity=9.81, prop_cov=True, reset=True)
    batch, n = gyro.shape[:2]
    dt = torch.full((batch, n, 1), DT)
    gyro_cov = torch.full((batch, n, 3), GYRO_DENSITY)
    acc_cov = torch.full((batch, n, 3), ACC_DENSITY)
    init = {
        "pos": torch.zeros(batch, 1, 3),
        "rot": pp.identity_SO3(batch, 1),
        "vel": torch.zeros(batch, 1, 3),
    }

    def run():
        g = gyro.clone().requires_grad_(backward)
        a = acc.clone().requires_grad_(backward)
        out = integrator(dt, g, a, gyro_cov=gyro_cov, acc_cov=acc_cov, init_state=init)
        if backward:
            (out["pos"].sum() + out["rot"].tensor().sum() + out["vel"].sum() + out["cov"].sum()).backward()

    return run


def gtsam_loop(gyro, acc):
    params = gtsam.PreintegrationParams.MakeSharedU(9.81)
    params.setGyroscopeCovariance(np.eye(3) * GYRO_DENSITY)
    params.setAccelerometerCovariance(np.eye(3) * ACC_DENSITY)
    params.setIntegrationCovariance(np.zeros((3, 3)))
    g = gyro[0].double().numpy()
    a = acc[0].double().numpy()

    def run():
        pim = gtsam.PreintegratedImuMeasurements(params, gtsam.imuBias.ConstantBias())
        for k in range(len(g)):
            pim.integrateMeasurement(a[k], g[k], DT)
        pim.preintMeasCov()

    return run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--n", type=int, default=1000)
    parser.add_argument("--json", default=None, help="write the timings to this file")
    args = parser.parse_args()
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads; pypose {pp.__version__}; N = {args.n}")

    results = {}
    gyro1, acc1 = make_samples(1, args.n)
    single = {
        "ours": torch_function(preintegrate, gyro1, acc1, backward=False),
        "ours_final_only": torch_function(preintegrate, gyro1, acc1, backward=False, at=-1),
        "ours_pair_scan": torch_function(preintegrate_pair_scan, gyro1, acc1, backward=False),
        "pypose": pypose_integrator(gyro1, acc1, backward=False),
        "gtsam_cpp_loop": gtsam_loop(gyro1, acc1),
        "torch_loop": torch_function(preintegrate_loop, gyro1, acc1, backward=False),
    }
    gyro64, acc64 = make_samples(64, args.n)
    batched = {
        "ours": torch_function(preintegrate, gyro64, acc64, backward=True),
        "ours_final_only": torch_function(preintegrate, gyro64, acc64, backward=True, at=-1),
        "ours_pair_scan": torch_function(preintegrate_pair_scan, gyro64, acc64, backward=True),
        "pypose": pypose_integrator(gyro64, acc64, backward=True),
        "torch_loop": torch_function(preintegrate_loop, gyro64, acc64, backward=True),
    }
    for case, peers in (("batch1_forward", single), ("batch64_forward_backward", batched)):
        times = {}
        for name, fn in peers.items():
            repeats = args.repeats if name != "torch_loop" else max(3, args.repeats // 2)
            times[name] = median_time(fn, repeats, warmup=1 if name == "torch_loop" else 2)
        results[case] = times
        print(f"\n{case} (float32, with covariance), median of repeats:")
        for name, t in times.items():
            print(
                f"  {name:16s} {t * 1e3:10.2f} ms   {t / times['ours']:8.1f}x ours"
                f"   {t / times['ours_final_only']:8.1f}x ours_final_only"
            )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f, indent=2)


if __name__ == "__main__":
    main()
