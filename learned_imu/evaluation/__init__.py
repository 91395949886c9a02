"""Evaluation: ``evaluate`` (integrate windows restarted from ground truth), ``metrics`` (the paper's definitions),
``baselines`` (average bias, linear calibration), ``ablation`` (the paper's IMU ablation), ``paper`` (its
published numbers)."""
