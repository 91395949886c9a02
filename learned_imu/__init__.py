"""learned_imu: AirIMU in torch -- readers, simulator, model, differentiable preintegration, training, export."""

from learned_imu.geometry.preintegration import NavState, Preintegrated, predict, preintegrate

__all__ = ["NavState", "Preintegrated", "predict", "preintegrate"]
