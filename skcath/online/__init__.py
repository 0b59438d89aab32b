"""Streaming estimation and export: a fitted pipeline one motor sample at a time.

:class:`OnlineEstimator` calibrates on one run's sweep and then estimates the
tip from one motor sample per call, one step function on the step path
(compiled by numba where it is installed, else run with numpy);
:func:`export` writes a started estimator's whole step (or a pipeline's
residual network alone) as ONNX or TorchScript;
:class:`ShaftChangeDetector` raises an alarm when the shaft configuration has
changed since the sweep, from the motor angles and torques alone, and
:class:`MotorRecalibration` renews the backbone's calibration from a re-sweep
of the motors alone.
"""

from ._change import ShaftChangeDetector
from ._estimator import OnlineEstimator, calibrate_sweep
from ._export import export, export_io
from ._export_step import step_state
from ._recalibration import MotorRecalibration

__all__ = [
    "MotorRecalibration",
    "OnlineEstimator",
    "ShaftChangeDetector",
    "calibrate_sweep",
    "export",
    "export_io",
    "step_state",
]
