"""A model refuses data sampled off its training rate: its convolutions see time in samples, not seconds.

``check_times_rate(model, t, where)``: the model's ``trained_on`` record (``learned_imu.network.checkpoint``, None for a
model built in code) against the median rate of sample times ``t`` (s); the correction and the motion model alike.
``check_imu_delay(model, sequence, where)``: a warning when a log is read with another IMU delay than the model's
training data was (the readers' ``imu_delay_s``).
"""

from __future__ import annotations

import logging

import numpy as np

from airimu_core.errors import InputError

log = logging.getLogger(__name__)
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


# a log read with an IMU delay this far (s) from its model's training delay is warned about (check_imu_delay)
IMU_DELAY_TOLERANCE_S = 0.005


def check_imu_delay(model, sequence, where: str) -> None:
    """A warning naming ``where`` and both delays when ``sequence`` was read with another IMU delay
    (``ImuSequence.imu_delay_s``, the readers' ``imu_delay_s``) than ``model``'s training sequences
    (``model.trained_on.imu_delay_s``): the network then sees its samples shifted against the timing it learned."""
    trained = getattr(getattr(model, "trained_on", None), "imu_delay_s", None)
    if trained is None or abs(sequence.imu_delay_s - trained) <= IMU_DELAY_TOLERANCE_S:
        return
    log.warning(
        "%s: read with imu_delay_s %.3f s, but the %s was trained on samples read with imu_delay_s %.3f s: give the "
        "reader option imu_delay_s=%g (--reader-option) to read the log as it was trained",
        where,
        sequence.imu_delay_s,
        type(model).__name__,
        trained,
        trained,
    )
