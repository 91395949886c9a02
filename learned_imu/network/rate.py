"""A model refuses data sampled off its training rate: its convolutions see time in samples, not seconds.

``check_times_rate(model, t, where)``: the model's ``trained_on`` record (``learned_imu.network.checkpoint``, None for a
model built in code) against the median rate of sample times ``t`` (s); the correction and the motion model alike.
"""

from __future__ import annotations

import numpy as np

from airimu_core.errors import InputError

MAX_RATE_MISMATCH = 0.1  # relative difference of sample rates a model is applied across


def check_times_rate(model, t: np.ndarray, where: str) -> None:
    """An ``InputError`` naming ``where`` (a file, or a stream's method) and both rates when the median rate of
    sample times ``t`` (s) is more than ``MAX_RATE_MISMATCH`` off ``model.trained_on.rate_hz`` (an ``AirImuNet`` or a
    ``MotionNet``; nothing to check without the record)."""
    trained = getattr(model, "trained_on", None)  # a TrainedOn record (learned_imu.network.checkpoint) or None
    if trained is None or len(t) < 2:
        return
    rate = 1.0 / float(np.median(np.diff(t)))
    if abs(rate / trained.rate_hz - 1.0) > MAX_RATE_MISMATCH:
        raise InputError(
            f"{where}: IMU sampled at {rate:.1f} Hz, but the model was trained at {trained.rate_hz:.1f} Hz "
            f"({', '.join(trained.datasets)}): resample the IMU to that rate or train a model on data at this rate"
        )
