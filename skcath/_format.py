"""Names of the columns of the long recording format.

One row per time sample; the full description is in ``docs/data_format.rst``.
"""

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

#: Bending-motor angles (degrees).
MOTOR_COLUMNS = ("q1", "q2")
#: Drive torques reported by the two bending motors (drive units, N mm in the simulator).
TORQUE_COLUMNS = ("tau1", "tau2")
#: Calibration reference tip position in the bending-section base frame (mm);
#: present on sweep rows, NaN on motion rows.
REFERENCE_COLUMNS = ("ref_x", "ref_y", "ref_z")
#: Names of the three target coordinates (tip position in the base frame, mm).
TARGET_NAMES = ("p_x", "p_y", "p_z")

#: Columns every recording must have.
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
