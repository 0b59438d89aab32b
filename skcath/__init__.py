"""skcath: catheter tip-position estimation with scikit-learn estimators.

A geometric backbone calibrated on each recording's initial sweep predicts a
nominal tip position from the bending-motor angles; a learned residual
corrects it from motor history. See ``docs/`` for the data format and the method.
"""

from ._format import (
    ID_COLUMNS,
    MOTOR_COLUMNS,
    REFERENCE_COLUMNS,
    REQUIRED_COLUMNS,
    TARGET_NAMES,
    TORQUE_COLUMNS,
)

from ._validation import check_recordings, motor_columns
from ._version import __version__

__all__ = [
    "ID_COLUMNS",
    "MOTOR_COLUMNS",
    "REFERENCE_COLUMNS",
    "REQUIRED_COLUMNS",
    "TARGET_NAMES",
    "TORQUE_COLUMNS",
    "__version__",
    "check_recordings",
    "motor_columns",
]
