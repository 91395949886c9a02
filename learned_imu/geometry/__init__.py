"""Geometry and preintegration: SO(3) maps (``so3``), the differentiable preintegrator with covariance and bias
Jacobian (``preintegration``: Forster et al.'s model by a parallel scan), and a plain sample loop to check it
against (``preintegration_reference``)."""
