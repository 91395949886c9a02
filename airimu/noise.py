"""``airimu noise``: an IMU's noise densities from a still recording (``learned_imu.evaluation.allan``), written as
Kalibr's ``imu.yaml`` fields and as GTSAM's continuous-time covariances, with the Allan plot.

Outputs (each written atomically, ``summary`` last): ``imu_kalibr.yaml`` (``gyroscope_noise_density`` rad/s/sqrt(Hz),
``gyroscope_random_walk`` rad/s^2/sqrt(Hz), ``accelerometer_noise_density`` m/s^2/sqrt(Hz),
``accelerometer_random_walk`` m/s^3/sqrt(Hz), ``update_rate`` Hz: the means over the three axes),
``gtsam_preintegration.yaml`` (``PreintegrationCombinedParams``' ``setGyroscopeCovariance`` etc.: sigma^2 on the
diagonal, continuous time), ``allan.json`` (per axis: N, B, K, the curve), ``allan.png``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from airimu_core.errors import DataError, InputError
from airimu_core.sequence import ImuSequence
from learned_imu.evaluation.allan import AxisNoise, allan_noise, gtsam_covariances, kalibr_yaml

SENSORS = (("gyro", "rad/s"), ("acc", "m/s^2"))


@dataclasses.dataclass(frozen=True)
class NoiseResult:
    """The fitted axes of each sensor, the stretch used (s from the first sample) and the rate."""

    gyro: list[AxisNoise]
    acc: list[AxisNoise]
    start_s: float
    end_s: float
    rate_hz: float

    def kalibr(self) -> dict:
        return kalibr_yaml(self.gyro, self.acc, self.rate_hz)


def still_noise(sequence: ImuSequence, start_s: float = 0.0, end_s: float | None = None) -> NoiseResult:
    """The Allan fit of ``sequence``'s samples from ``start_s`` to ``end_s`` (s from its first sample; default the
    end). The stretch must be still: a moving one is refused (its gyro then swings far beyond any noise)."""
    t = sequence.t - sequence.t[0]
    end_s = float(t[-1]) if end_s is None else float(end_s)
    keep = (t >= start_s) & (t <= end_s)
    where = sequence.source or sequence.name
    if keep.sum() < 100:
        raise InputError(f"{where}: {int(keep.sum())} samples from {start_s:g} to {end_s:g} s: need 100 at least")
    gyro, acc = sequence.gyro[keep], sequence.acc[keep]
    swing = float(np.max(np.ptp(gyro, axis=0)))
    if swing > 0.5:  # rad/s: a rotating IMU, not a parked one (MEMS noise peaks stay far below)
        raise DataError(
            where,
            "gyro",
            f"the gyro swings {swing:.3g} rad/s between {start_s:g} and {end_s:g} s: not a still stretch (give "
            "--start/--end of one, e.g. before the platform moves)",
        )
    rate = 1.0 / float(np.median(np.diff(sequence.t[keep])))
    result = NoiseResult(allan_noise(gyro, rate), allan_noise(acc, rate), float(start_s), end_s, rate)
    for sensor, _ in SENSORS:
        if any(axis.white <= 0 for axis in getattr(result, sensor)):  # the curve rises from the first tau on
            raise DataError(
                where,
                sensor,
                f"its Allan deviation from {start_s:g} to {end_s:g} s shows no white-noise slope (-1/2) at short "
                "averaging times: the platform moves in this stretch (give --start/--end of a still one)",
            )
    return result


def write_noise(result: NoiseResult, folder: Path, datasheet: dict | None = None) -> list[Path]:
    """The files of the module docstring in ``folder``; ``datasheet``: Kalibr keys -> values in SI, shown beside."""
    import yaml

    from airimu_core.io import atomic_file, output_folder, write_json_atomic

    folder = output_folder(folder)
    kalibr = result.kalibr()
    written = []
    for name, content in (("imu_kalibr.yaml", kalibr), ("gtsam_preintegration.yaml", gtsam_covariances(kalibr))):
        with atomic_file(folder / name, "w") as f:
            yaml.safe_dump(content, f, sort_keys=False)
        written.append(folder / name)
    written.append(_plot(result, folder / "allan.png"))
    axes = {
        sensor: [
            {
                "white": a.white,
                "bias_instability": a.bias_instability,
                "bias_tau_s": a.bias_tau,
                "random_walk": a.random_walk,
                "tau_s": a.tau.tolist(),
                "adev": a.adev.tolist(),
            }
            for a in getattr(result, sensor)
        ]
        for sensor, _ in SENSORS
    }
    summary = {
        "start_s": result.start_s,
        "end_s": result.end_s,
        "rate_hz": result.rate_hz,
        "kalibr": kalibr,
        "datasheet": datasheet or {},
        "axes": axes,
    }
    written.append(write_json_atomic(folder / "allan.json", summary))
    return written


def _plot(result: NoiseResult, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from airimu_core.io import atomic_file

    fig, panels = plt.subplots(1, 2, figsize=(11, 4.5))
    for panel, (sensor, unit) in zip(panels, SENSORS, strict=True):
        for axis, (noise, colour) in enumerate(zip(getattr(result, sensor), ("C0", "C1", "C2"), strict=True)):
            panel.loglog(noise.tau, noise.adev, color=colour, label=f"{'xyz'[axis]}")
            panel.loglog(noise.tau, noise.white / np.sqrt(noise.tau), color=colour, ls=":", lw=1)
            if noise.random_walk is not None:
                panel.loglog(noise.tau, noise.random_walk * np.sqrt(noise.tau / 3.0), color=colour, ls="--", lw=1)
        panel.set_xlabel("averaging time tau (s)")
        panel.set_ylabel(f"Allan deviation ({unit})")
        panel.set_title(f"{sensor}: dotted white noise N / sqrt(tau), dashed random walk K sqrt(tau / 3)", fontsize=8)
        panel.grid(True, which="both", alpha=0.3)
        panel.legend()
    fig.tight_layout()
    with atomic_file(path, "wb") as f:
        fig.savefig(f, format="png", dpi=110)
    plt.close(fig)
    return path
