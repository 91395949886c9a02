"""learned_imu: AirIMU in torch -- readers, simulator, model, differentiable preintegration, training, export.

``from learned_imu import preintegrate`` loads torch; importing a subpackage that does not need it (the readers'
numpy parts) does not."""

__all__ = ["NavState", "Preintegrated", "predict", "preintegrate"]


def __getattr__(name: str):
    if name in __all__:
        from learned_imu.geometry import preintegration

        return getattr(preintegration, name)
    raise AttributeError(f"module 'learned_imu' has no attribute {name!r}")
