"""Steering the tip: motor commands from a fitted tip model, compensating its hysteresis.

:class:`FeedforwardController` inverts the model's own streaming step (the
backbone, the residual and the hysteresis in front of the backbone: the
play or the Prandtl-Ishlinskii model) for the command whose predicted tip
is the target; :class:`FeedbackController`
closes the loop on the streamed estimate (or on the tracker) by resolved
rate on the model's Jacobian. Both start on the run's sweep and return one
motor command per sample, within the motor and rate limits given; a target
out of reach is steered to the nearest reachable tip with an
:class:`UnreachableTargetWarning`. See ``docs/steering.rst``.
"""

from ._controllers import FeedbackController, FeedforwardController
from ._limits import MotorLimits, UnreachableTargetWarning

__all__ = [
    "FeedbackController",
    "FeedforwardController",
    "MotorLimits",
    "UnreachableTargetWarning",
]
