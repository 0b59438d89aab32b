"""Names of the columns of the long recording format.

One row per time sample; the full description is in ``docs/data_format.rst``.
A recording has ``N >= 1`` motors: the angles ``q1 .. qN`` and, when the
drives report them, the torques ``tau1 .. tauN``; :func:`motor_names` and
:func:`torque_names` give the names for ``N``, :func:`channel_index` reads
``N`` back from a name.
"""

import re

#: Identifier columns. ``run`` is unique over the whole data set: one run id
#: belongs to exactly one catheter and one shaft setting.
CATHETER = "catheter"
SETTING = "setting"
RUN = "run"
ID_COLUMNS = (CATHETER, SETTING, RUN)

#: Time of the sample within its run, in seconds, strictly increasing.
TIME = "t"

#: Phase of the run: the initial calibration sweep, then free motion.
PHASE = "phase"
SWEEP = "sweep"
MOTION = "motion"
PHASES = (SWEEP, MOTION)

#: Prefixes of the motor-angle (degrees) and drive-torque columns: ``q1 .. qN``
#: and ``tau1 .. tauN``, numbered from 1.
MOTOR_PREFIX = "q"
TORQUE_PREFIX = "tau"
_CHANNEL = re.compile(rf"({MOTOR_PREFIX}|{TORQUE_PREFIX})([1-9][0-9]*)")


def motor_names(n_motors):
    """Names of the motor-angle columns of ``n_motors`` motors: ``("q1", ..., "qN")``."""
    return tuple(f"{MOTOR_PREFIX}{k}" for k in range(1, n_motors + 1))


def torque_names(n_motors):
    """Names of the drive-torque columns of ``n_motors`` motors: ``("tau1", ..., "tauN")``."""
    return tuple(f"{TORQUE_PREFIX}{k}" for k in range(1, n_motors + 1))


def channel_index(name):
    """``("q", k)`` or ``("tau", k)`` for the column ``qk`` or ``tauk`` (``k >= 1``), else None."""
    match = _CHANNEL.fullmatch(name) if isinstance(name, str) else None
    return None if match is None else (match.group(1), int(match.group(2)))


#: Motor angles of the default two-motor catheter (degrees): anterior-posterior
#: and left-right bending. Recordings of other instruments have ``motor_names(N)``.
MOTOR_COLUMNS = motor_names(2)
#: Drive torques of the default two-motor catheter (drive units, N mm in the
#: simulator). Optional: a recording has all of ``torque_names(N)`` or none.
TORQUE_COLUMNS = torque_names(2)
#: Calibration reference tip position in the bending-section base frame (mm);
#: present on sweep rows, NaN on motion rows.
REFERENCE_COLUMNS = ("ref_x", "ref_y", "ref_z")
#: Names of the three target coordinates (tip position in the base frame, mm).
TARGET_NAMES = ("p_x", "p_y", "p_z")

#: Columns every recording has, whatever its motors.
RECORDING_COLUMNS = (*ID_COLUMNS, TIME, PHASE, *REFERENCE_COLUMNS)

#: Columns of a recording of the default two-motor catheter with torques.
REQUIRED_COLUMNS = (
    *ID_COLUMNS,
    TIME,
    PHASE,
    *MOTOR_COLUMNS,
    *TORQUE_COLUMNS,
    *REFERENCE_COLUMNS,
)

#: Raw EM sensor streams (world/tracker frame): position (mm) and unit
#: quaternion of the tip sensor and of the sensor at the base of the bending
#: section. Quaternions in these default names are scalar first (w, x, y, z).
SENSOR_POSE_COLUMNS = {
    "tip_position": ("tip_px", "tip_py", "tip_pz"),
    "tip_orientation": ("tip_qw", "tip_qx", "tip_qy", "tip_qz"),
    "base_position": ("base_px", "base_py", "base_pz"),
    "base_orientation": ("base_qw", "base_qx", "base_qy", "base_qz"),
}

#: Component orders accepted for quaternion columns: scalar first (``"wxyz"``,
#: as NDI Aurora exports write them) or scalar last (``"xyzw"``, SciPy, ROS).
QUAT_ORDERS = ("wxyz", "xyzw")
