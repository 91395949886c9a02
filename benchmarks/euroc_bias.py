"""Why a learned EuRoC model is (or is not) better than a constant bias on flights it has not seen.

    python benchmarks/euroc_bias.py [--checkpoint runs/ablate-euroc/airimu_seed0/best.pt] [--data ../shared/data]

Prints, from the real data alone:
- each flight's own constant gyro bias (the mean of raw minus ground-truth-implied samples, ``average_bias`` on that
  flight), and its spread over the paper's six training flights (the day-to-day drift a model must cope with);
- the ROE over 1 s of each test flight corrected by: its own constant bias (an oracle no deployed model has), the
  average bias of the training flights in the same room (an environment oracle), and the average over all six
  training flights (the Average Bias baseline).
With ``--checkpoint``: the model's mean gyro correction per flight and its variation in time, and the ROE of the
model, of the model's own mean used as a constant, and of the flight's own constant plus the model's time-varying
part (does what the network adds beyond a constant help?), and of the running mean of the model's correction (at
each sample, the mean of its correction so far: causal, so a deployed model could use it); and whether the
correction is a constant: the std over 1-s means of the model's correction beside the std over 1-s means of the
flight's own gyro error (raw minus ground-truth-implied, ``imu_from_ground_truth``) after removing its constant.
``--flights`` scores other flights than the three test flights (e.g. the ones a leave-flights-out run held out).
``--observer KP,KI`` adds a model-free, causal estimate of the bias from the IMU alone: a Mahony filter (tilt from
the accelerometer's gravity, gyro bias by its integral term, starting from the six-flight average) for each gain
pair, so the part of a day's bias that gravity makes observable (the two horizontal axes) is measured without
learning; the gains are to be chosen on the training flights (their mean ROE is printed first).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from learned_imu.datasets import read_sequence
from learned_imu.evaluation.baselines import average_bias, imu_from_ground_truth
from learned_imu.evaluation.evaluate import evaluate

TRAIN = ("MH_01_easy", "MH_03_medium", "MH_05_difficult", "V1_02_medium", "V2_01_easy", "V2_03_difficult")
TEST = ("MH_04_difficult", "V1_03_difficult", "V2_02_medium")
ROOM = {
    "MH": ("MH_01_easy", "MH_03_medium", "MH_05_difficult"),
    "V1": ("V1_02_medium",),
    "V2": ("V2_01_easy", "V2_03_difficult"),
}


def roe(sequence, gyro) -> float:
    return evaluate(sequence, 1.0, "s", gyro, sequence.acc).roe_deg


def second_means_std(sequence, x: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray:
    """(3,) std over the flight's whole seconds of the per-second means of x (N, 3), samples where ``valid``."""
    second = np.floor(sequence.t[: len(x)] - sequence.t[0]).astype(int)
    keep = np.ones(len(x), dtype=bool) if valid is None else valid
    means = [x[keep & (second == k)].mean(axis=0) for k in np.unique(second[keep])]
    return np.std(means, axis=0)


def own_residual_std(sequence) -> np.ndarray:
    """(3,) ``second_means_std`` of the flight's own gyro error minus its constant, rad/s."""
    gyro_gt, _, ok = imu_from_ground_truth(sequence)
    error = sequence.gyro[:-1] - gyro_gt
    return second_means_std(sequence, error - error[ok].mean(axis=0), ok)


def gravity_observer(sequence, kp: float, ki: float, start: np.ndarray) -> np.ndarray:
    """(N, 3) causal gyro bias of a Mahony filter: tilt from the accelerometer, bias from the integral term.

    ``up`` is the world's up axis in the body frame; the error ``e = a/|a| x up`` rotates it toward the measured
    specific force (gain ``kp``, 1/s) and integrates into the bias (``ki``, 1/s^2). Yaw is not observed.
    """
    gyro, acc, dt = sequence.gyro, sequence.acc, sequence.dt
    bias, out = start.astype(float).copy(), np.empty_like(gyro)
    up = acc[0] / np.linalg.norm(acc[0])
    for i in range(len(gyro)):
        out[i] = bias
        e = np.cross(acc[i] / np.linalg.norm(acc[i]), up)
        bias -= ki * e * dt[i]
        w = (gyro[i] - bias + kp * e) * dt[i]  # up (fixed in the world) moves by -w in the body frame
        angle = np.linalg.norm(w)
        if angle > 0:
            k = -w / angle
            up = up * np.cos(angle) + np.cross(k, up) * np.sin(angle) + k * (k @ up) * (1 - np.cos(angle))
        up /= np.linalg.norm(up)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", default=str(Path(__file__).resolve().parents[2] / "shared" / "data"))
    parser.add_argument("--checkpoint", default=None)
    parser.add_argument("--flights", default=",".join(TEST), help="flights scored with --checkpoint (comma-separated)")
    parser.add_argument("--observer", action="append", default=[], help="KP,KI of a gravity-referenced bias observer")
    args = parser.parse_args()
    scored = tuple(args.flights.split(","))
    euroc = Path(args.data) / "euroc"
    flights = {name: read_sequence("euroc", euroc / name) for name in dict.fromkeys(TRAIN + TEST + scored)}
    own = {name: average_bias([seq]).gyro_rad_s for name, seq in flights.items()}
    print("constant gyro bias of each flight (mrad/s, x y z):")
    for name in TRAIN + TEST:
        print(f"  {name:16s} {np.array2string(own[name] * 1e3, precision=2)}")
    spread = np.std([own[n] for n in TRAIN], axis=0, ddof=1) * np.sqrt(1 + 1 / len(TRAIN))
    print(f"spread over the training flights, for a new flight: {np.array2string(spread * 1e3, precision=2)} mrad/s")
    everything = average_bias([flights[n] for n in TRAIN]).gyro_rad_s
    print("\nROE 1 s (deg): own constant (oracle) | same-room average | all-training average (Average Bias)")
    for name in TEST:
        seq = flights[name]
        room = average_bias([flights[n] for n in ROOM[name[:2]]]).gyro_rad_s
        print(
            f"  {name:16s} {roe(seq, seq.gyro - own[name]):.4f} | {roe(seq, seq.gyro - room):.4f} | "
            f"{roe(seq, seq.gyro - everything):.4f}"
        )
    for gains in args.observer:
        kp, ki = (float(v) for v in gains.split(","))
        scores = {n: roe(s, s.gyro - gravity_observer(s, kp, ki, everything)) for n, s in flights.items()}
        train_mean = np.mean([scores[n] for n in TRAIN])
        tests = " | ".join(f"{n} {scores[n]:.4f}" for n in TEST)
        print(f"gravity observer kp {kp:g} ki {ki:g}: training flights' mean ROE {train_mean:.4f}; {tests}")
    if args.checkpoint:
        from learned_imu.network.checkpoint import model_from_checkpoint
        from learned_imu.network.inference import correct

        model, config = model_from_checkpoint(args.checkpoint)
        gravity = config.train.remove_gravity
        print(f"\n{args.checkpoint}: mean gyro correction, its std in time (mrad/s); ROE of the model | its mean as a")
        print("constant | the flight's own constant + the model's time-varying part | the running mean of its")
        print("correction (causal); std of 1-s means of the correction | of the flight's own error minus its constant")
        for name in dict.fromkeys(TRAIN + TEST + scored):
            seq = flights[name]
            out = correct(model, seq, gravity)
            d_gyro = out.d_gyro.numpy()
            line = (
                f"  {name:16s} mean {np.array2string(-d_gyro.mean(0) * 1e3, precision=2)} "
                f"std {np.array2string(d_gyro.std(0) * 1e3, precision=2)}"
            )
            if name in scored:
                varying = d_gyro - d_gyro.mean(0)
                running = np.cumsum(d_gyro, axis=0) / np.arange(1, len(d_gyro) + 1)[:, None]
                line += (
                    f"; ROE {roe(seq, out.gyro.numpy()):.4f} | {roe(seq, seq.gyro + d_gyro.mean(0)):.4f} | "
                    f"{roe(seq, seq.gyro - own[name] + varying):.4f} | {roe(seq, seq.gyro + running):.4f}; "
                    f"1-s std {np.array2string(second_means_std(seq, d_gyro) * 1e3, precision=2)} | "
                    f"{np.array2string(own_residual_std(seq) * 1e3, precision=2)}"
                )
            print(line)


if __name__ == "__main__":
    main()
