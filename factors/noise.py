"""An IMU's white noise measured on its own samples, to catch a noise setting in the wrong unit.

``white_noise_density(samples, dt)``: the continuous-time sigma (``*_noise_density``: rad/s/sqrt(Hz) or
m/s^2/sqrt(Hz)) of the white noise in ``samples``, from their second differences ``x[i+1] - 2 x[i] + x[i-1]``
(variance 6 sigma_d^2 for white noise of per-sample sigma sigma_d = density / sqrt(dt); motion slower than the
sample rate cancels in them): 1.4826 x their median absolute deviation / sqrt(6), times sqrt(dt), the median over
the three axes. Motion and vibration faster than the sample rate count as noise, which is what a graph must assume
for them. Measured on the shared data (commit of this module): EuRoC MH flights 0.6-4.3e-3 (gyro) and 0.02-0.09
(acc) by axis, against the ADIS16448's datasheet 1.7e-4 / 2.0e-3 (rotor vibration) and VINS-Mono's setting 0.004 /
0.08; KITTI raw drives 4-16e-5 and 0.7-3.5e-3 (GTSAM's KITTI example: 1.75e-4 / 0.01); BROAD 1.5-4.2e-4 and
2.8-4.8e-3.

``noise_mismatch``: a message naming both numbers when a given sigma lies more than ``BELOW`` (100x) under the
measured one (a variance given for a sigma: the square of any IMU's sigma is orders of magnitude below it; a
datasheet value on a vibrating platform lies 3-50x under, EuRoC's ADIS16448 datasheet values 1.7e-4 / 2.0e-3 against
the MH flights' 0.6-4.3e-3 / 0.02-0.09, and is no mistake: not warned about before the solve; whether the graph can
trust the IMU that much is the chi-square check's to say, after it, and ``airimu fuse`` names the given densities
there) or more than ``ABOVE`` (10x) over it (another unit, a sigma given for a
variance; or a deliberately conservative setting: without bias states, the density has to absorb the bias, and on
GTSAM's KITTI drive 0.004 / 0.08, 49x / 25x above, fuse to 0.60 m where 1.75e-4 / 0.01 fuse to 25.9 m and
1.6e-5 / 6.4e-3 to 411 m, ``airimu fuse --dataset kitti --gps-every 10 --keyframes 1s``). Callers warn with it.
"""

from __future__ import annotations

import numpy as np

BELOW, ABOVE = 100.0, 10.0  # how far under / over the log's own white noise a given sigma may lie unremarked
MIN_SAMPLES = 50  # fewer second differences than this measure too little to judge a setting by
UNITS = {"gyro": "rad/s/sqrt(Hz)", "acc": "m/s^2/sqrt(Hz)"}


def white_noise_density(samples, dt) -> float | None:
    """The white-noise sigma of (N, 3) ``samples`` taken every ``dt`` s (a float or (N,): its median is used), in
    the samples' unit times sqrt(s) (module docstring); None for fewer than ``MIN_SAMPLES`` samples or a log whose
    second differences are all zero (quantised, or repeated samples)."""
    x = np.asarray(samples, dtype=float)
    if x.ndim != 2 or x.shape[0] < MIN_SAMPLES + 2:
        return None
    step = float(np.median(np.asarray(dt, dtype=float)))
    second = x[2:] - 2.0 * x[1:-1] + x[:-2]
    second = second[np.all(np.isfinite(second), axis=1)]
    if second.shape[0] < MIN_SAMPLES or not step > 0:
        return None
    mad = np.median(np.abs(second - np.median(second, axis=0)), axis=0)
    sigma = float(np.median(1.4826 * mad / np.sqrt(6.0) * np.sqrt(step)))
    return sigma if sigma > 0 else None


def noise_mismatch(sensor: str, given: float, samples, dt, below: float = BELOW, above: float = ABOVE) -> str | None:
    """A message naming both numbers when ``given`` (a ``*_noise_density`` sigma of the ``sensor``, "gyro" or
    "acc") lies more than ``below`` times under or ``above`` times over what ``samples`` show
    (``white_noise_density``); None when it does not, or when the samples measure nothing."""
    measured = white_noise_density(samples, dt)
    if measured is None or not np.isfinite(given) or given <= 0:
        return None
    ratio, unit = given / measured, UNITS[sensor]
    head = f"{'an' if sensor == 'acc' else 'a'} {sensor} noise density of {given:.3g} {unit} is"
    tail = f"the white noise of the samples themselves, {measured:.2g}"
    if ratio * below < 1.0:
        why = "far below any IMU's noise: a variance (sigma^2) given where a sigma is expected?"
        return f"{head} {1 / ratio:.1f}x below {tail}: {why}"
    if ratio > above:
        why = "another unit? (or a deliberately conservative setting, e.g. without bias states)"
        return f"{head} {ratio:.0f}x above {tail}: {why}"
    return None
