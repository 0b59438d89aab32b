"""Read ROS 1 / ROS 2 bags into the long format, without a ROS installation.

:func:`read_rosbag` reads a ``sensor_msgs/JointState`` topic (motor angles
and efforts) and ``geometry_msgs/PoseStamped`` or
``geometry_msgs/TransformStamped`` topics (tip and base sensor poses) with the
optional package ``rosbags``, aligns them in time with
:func:`skcath.io.align_streams` and converts them like
:func:`skcath.io.read_recording`.
"""

from numbers import Real
from pathlib import Path

import numpy as np
import pandas as pd
from sklearn.utils._param_validation import Interval, validate_params

from .._format import SENSOR_POSE_COLUMNS, channel_index
from ._align import MAX_UNMATCHED, align_streams, check_alignment
from ._convert import recording_from_table
from ._errors import naming_the_file
from ._options import ReadingOptions

__all__ = ["read_rosbag"]

#: Topic keys of the config; the motors' joints are the keys ``q1 .. qN``.
_CONFIG_KEYS = ("joint_states", "tip", "base")
_POSE_TYPES = ("geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/TransformStamped")
_JOINT_TYPE = "sensor_msgs/msg/JointState"
_STAMPS = ("header", "bag")
#: ROS units (REP 103) to skcath units.
_RAD_TO_DEG = 180.0 / np.pi
_M_TO_MM = 1000.0
_NM_TO_NMM = 1000.0


def _import_rosbags():
    """Import the parts of ``rosbags`` used here, with a clear error if missing."""
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError as exc:
        raise ImportError(
            "read_rosbag needs the optional package rosbags: pip install rosbags "
            f"(or: pip install 'skcath[ros]'). ({exc})"
        ) from exc
    return AnyReader, Stores, get_typestore


def _check_config(config):
    """Validate the topic / joint mapping.

    Parameters
    ----------
    config : mapping
        See :func:`read_rosbag`.

    Returns
    -------
    config : dict
        A new dict with every key of ``_CONFIG_KEYS`` (None where not given)
        and the motor keys ``q1 .. qN`` given, in order.

    Raises
    ------
    ValueError
        On a missing required key, an unknown key or a value that is not a
        non-empty string.
    """
    if not hasattr(config, "items"):
        raise ValueError(
            f"config must be a mapping with the keys {list(_CONFIG_KEYS)}; got "
            f"{type(config).__name__}."
        )
    named = {k: channel_index(k)[1] for k in config if (channel_index(k) or ("",))[0] == "q"}
    unknown = set(config) - set(_CONFIG_KEYS) - set(named)
    motors = {k: i for k, i in named.items() if config[k] is not None}
    if unknown:
        raise ValueError(
            f"config has the unknown key(s) {sorted(unknown)}; expected keys among "
            f"{list(_CONFIG_KEYS)} and the motors' joints 'q1' .. 'qN'."
        )
    order = sorted(motors, key=motors.get)
    gap = [f"q{k}" for k in range(1, len(order) + 1) if f"q{k}" not in motors]
    if gap and order:
        raise ValueError(
            f"config names the joints of {order}, without {gap}: the motors are 'q1' .. 'qN' "
            "without a gap."
        )
    checked = {key: config.get(key) for key in (*_CONFIG_KEYS, *order)}
    for key in ("joint_states", "q1", "tip"):
        if checked.get(key) is None:
            raise ValueError(f"config needs the key {key!r} (see read_rosbag).")
    for key, value in checked.items():
        if value is not None and (not isinstance(value, str) or not value):
            raise ValueError(f"config[{key!r}] must be a non-empty string; got {value!r}.")
    topics = [(k, checked[k]) for k in ("joint_states", "tip", "base") if checked[k]]
    for i, (key, topic) in enumerate(topics):
        for other, other_topic in topics[:i]:
            if topic == other_topic:
                raise ValueError(
                    f"config names the topic {topic!r} for both {other!r} and {key!r}; "
                    "each needs its own topic."
                )
    for i, key in enumerate(order):
        for other in order[:i]:
            if checked[key] == checked[other]:
                raise ValueError(
                    f"config names the joint {checked[key]!r} for both {other!r} and {key!r}."
                )
    return checked


def _stamp(message, timestamp_ns, stamp):
    """Time of a message in integer nanoseconds: header stamp or bag receive time."""
    if stamp == "bag":
        return int(timestamp_ns)
    header = message.header.stamp
    return int(header.sec) * 1_000_000_000 + int(header.nanosec)


def _pose(message):
    """(x, y, z, qw, qx, qy, qz) of a PoseStamped or TransformStamped message."""
    if hasattr(message, "pose"):
        position, orientation = message.pose.position, message.pose.orientation
    else:
        position, orientation = message.transform.translation, message.transform.rotation
    return (
        position.x,
        position.y,
        position.z,
        orientation.w,
        orientation.x,
        orientation.y,
        orientation.z,
    )


def _joint_row(message, names, path):
    """Angles (deg) and efforts (N mm) of the configured joints of one message."""
    row = {}
    for column, joint in names.items():
        try:
            i = list(message.name).index(joint)
        except ValueError:
            raise ValueError(
                f"{path.name}: joint {joint!r} (config[{column!r}]) is not in a "
                f"JointState message; joints: {list(message.name)}."
            ) from None
        row[column] = message.position[i] * _RAD_TO_DEG
        effort = message.effort
        tau = "tau" + column[1:]
        row[tau] = effort[i] * _NM_TO_NMM if len(effort) > i else np.nan
    return row


def _read_bag(path, config, stamp):
    """Read the motor stream and the tip / base pose streams of a bag.

    Parameters
    ----------
    path : pathlib.Path
        Bag (ROS 1 ``.bag`` file, ROS 2 folder or its ``.db3`` / ``.mcap``
        file).
    config : dict
        Checked config.
    stamp : {"header", "bag"}
        Time source.

    Returns
    -------
    motors : pandas.DataFrame
        ``t`` (s from the first joint-state message), ``q1 .. qN``,
        ``tau1 .. tauN`` (torques only when every message carries efforts).
    poses : dict of str to pandas.DataFrame
        ``"tip"`` and possibly ``"base"``: ``t`` (s, same origin) and the raw
        pose columns.
    """
    AnyReader, Stores, get_typestore = _import_rosbags()
    store = Stores.ROS1_NOETIC if path.suffix == ".bag" else Stores.ROS2_HUMBLE
    joints = {c: joint for c, joint in config.items() if c not in _CONFIG_KEYS}
    sensors = {s: config[s] for s in ("tip", "base") if config[s] is not None}
    rows = {"motors": [], **{s: [] for s in sensors}}
    with AnyReader([path], default_typestore=get_typestore(store)) as reader:
        by_topic = {}
        for connection in reader.connections:
            by_topic.setdefault(connection.topic, []).append(connection)
        wanted = {config["joint_states"]: ("motors", (_JOINT_TYPE,))}
        for sensor, topic in sensors.items():
            wanted[topic] = (sensor, _POSE_TYPES)
        for topic, (role, types) in wanted.items():
            if topic not in by_topic:
                raise ValueError(
                    f"{path.name}: the bag has no topic {topic!r} (config for {role}); "
                    f"topics: {sorted(by_topic)}."
                )
            for connection in by_topic[topic]:
                if connection.msgtype not in types:
                    raise ValueError(
                        f"{path.name}: topic {topic!r} carries {connection.msgtype}; "
                        f"{role} needs {' or '.join(types)}."
                    )
        connections = [c for topic in wanted for c in by_topic[topic]]
        for connection, timestamp, raw in reader.messages(connections=connections):
            role = wanted[connection.topic][0]
            message = reader.deserialize(raw, connection.msgtype)
            t = _stamp(message, timestamp, stamp)
            if role == "motors":
                rows[role].append({"t": t, **_joint_row(message, joints, path)})
            else:
                rows[role].append((t, *_pose(message)))
    motors = pd.DataFrame(rows.pop("motors"))
    if motors.empty:
        raise ValueError(f"{path.name}: the topic {config['joint_states']!r} has no message.")
    # stamps are integer ns: subtract the origin before converting to float s
    t0 = int(motors["t"].min())
    motors["t"] = (motors["t"].to_numpy(dtype=np.int64) - t0) * 1e-9
    for tau in ("tau1", "tau2"):
        if tau in motors and motors[tau].isna().any():
            motors = motors.drop(columns=tau)  # efforts not recorded
    poses = {}
    for sensor, records in rows.items():
        if not records:
            raise ValueError(f"{path.name}: the topic {config[sensor]!r} has no message.")
        names = (
            *SENSOR_POSE_COLUMNS[f"{sensor}_position"],
            *SENSOR_POSE_COLUMNS[f"{sensor}_orientation"],
        )
        frame = pd.DataFrame(records, columns=["t", *names])
        frame["t"] = (frame["t"].to_numpy(dtype=np.int64) - t0) * 1e-9
        frame[list(SENSOR_POSE_COLUMNS[f"{sensor}_position"])] *= _M_TO_MM
        poses[sensor] = frame
    return motors, poses


@validate_params(
    {
        "path": "no_validation",
        "config": "no_validation",
        "max_unmatched": [Interval(Real, 0, 1, closed="both")],
    },
    prefer_skip_nested_validation=True,
)
def read_rosbag(
    path,
    config,
    *,
    tolerance,
    latency=0.0,
    direction="nearest",
    stamp="header",
    max_unmatched=MAX_UNMATCHED,
    **read_kwargs,
):
    """Read a ROS 1 or ROS 2 bag into the long format.

    Needs the optional package ``rosbags`` (no ROS installation).

    Parameters
    ----------
    path : str or path-like
        A ROS 1 ``.bag`` file, or a ROS 2 bag (its folder, or the ``.db3`` /
        ``.mcap`` file in it). Message definitions missing from the bag are
        taken from the ROS 1 Noetic (``.bag``) or ROS 2 Humble type store.
    config : mapping
        Which topic and joint is what:

        - ``"joint_states"``: topic of ``sensor_msgs/JointState`` messages;
        - ``"q1"`` (and ``"q2"`` .. ``"qN"``, optional, without a gap): joint
          names of the motors in those messages, for the columns ``q1 .. qN``
          and ``tau1 .. tauN``;
        - ``"tip"`` (and ``"base"``, optional): topics of
          ``geometry_msgs/PoseStamped`` or ``geometry_msgs/TransformStamped``
          messages with the tip and base sensor poses in the tracker frame.

        Without ``"base"``, the tip topic must already be in the base frame;
        say so with ``columns={"p_x": "tip_px", "p_y": "tip_py", "p_z":
        "tip_pz"}``.
    tolerance : float
        Largest time difference (s) between a joint-state message and the
        pose message attached to it; see :func:`skcath.io.align_streams`.
        The base pose is attached to the tip pose with the same tolerance.
    latency : float or "start", default=0.0
        Offset of the pose clock (s); see :func:`skcath.io.align_streams`.
    direction : {"nearest", "backward", "forward"}, default="nearest"
        See :func:`skcath.io.align_streams`.
    stamp : {"header", "bag"}, default="header"
        Time of a message: its header stamp, or the time the bag recorded
        it.
    max_unmatched : float in [0, 1], default=0.9
        Largest fraction of the joint-state messages allowed to find no
        pose message within ``tolerance``; see
        :func:`skcath.io.read_streams`.
    **read_kwargs
        Options of :func:`skcath.io.read_recording` (``catheter``,
        ``setting``, ``run``, ``n_sweep``, ``phase``, ``constants``,
        ``scale``, ``columns``, ``tip_offset``). ``run`` defaults to the bag
        name without suffix.

    Returns
    -------
    X : pandas.DataFrame
        Long format, one row per joint-state message; ``t`` in seconds from
        the first joint-state message.
    y : ndarray of shape (n_rows, 3)
        Tip in the base frame (mm); NaN where no pose message was within the
        tolerance.
    report : AlignmentReport
        Alignment of the joint states with the tip (and base) poses.

    Raises
    ------
    ImportError
        If ``rosbags`` is not installed.
    sklearn.utils._param_validation.InvalidParameterError
        If ``max_unmatched`` is not a number in [0, 1].
    ValueError
        On a bad ``config`` (unknown key, missing topic or joint, wrong
        message type); a bag that cannot be read (damaged or cut short, a
        damaged ``metadata.yaml`` or database; the message names the bag and
        what ``rosbags`` found); more than ``max_unmatched`` of the
        joint-state messages without a pose message; and as
        :func:`skcath.io.read_recording`.

    Notes
    -----
    Units follow ROS (REP 103) and are converted to skcath units: joint
    positions in rad become motor angles in degrees, efforts in N m become
    torques in N mm (x 1000), pose positions in m become mm. Use ``scale``
    for other units (its factor multiplies the converted values). Torque
    columns are read only when every joint-state message carries efforts;
    otherwise give them with ``constants``.

    The quaternions are read from the messages' fields by name (``w``,
    ``x``, ``y``, ``z``), so their order is never declared; and a bag is
    one run, which cannot tell two orders apart. The data check of the
    quaternion order of :func:`skcath.io.read_recording` and
    :func:`skcath.io.read_streams` (``quat_check``) therefore has nothing
    to check here.

    Examples
    --------
    ::

        X, y, report = read_rosbag(
            "session.bag",
            {"joint_states": "/motors/joint_states", "q1": "m1", "q2": "m2",
             "tip": "/aurora/tip", "base": "/aurora/base"},
            tolerance=0.02, catheter="A", setting="default", n_sweep=200,
        )
    """
    path = Path(path)
    config = _check_config(config)
    if stamp not in _STAMPS:
        raise ValueError(f"stamp must be one of {list(_STAMPS)}; got {stamp!r}.")
    if "rate_hz" in read_kwargs:
        raise ValueError("read_rosbag takes the time from the bag; rate_hz is not accepted.")
    options = ReadingOptions.from_kwargs(read_kwargs, "read_rosbag")
    if not path.exists():
        raise ValueError(f"no such bag {str(path)!r}.")
    bag = path.parent if path.suffix in (".db3", ".mcap") else path
    with naming_the_file(bag, "a ROS bag"):
        motors, poses = _read_bag(bag, config, stamp)

    tracker = poses["tip"]
    try:
        if "base" in poses:
            tracker, _ = align_streams(
                tracker, poses["base"], tolerance=tolerance, direction=direction, sort=True
            )
            tracker = tracker.drop(columns="tracker_time")
        aligned, report = align_streams(
            motors,
            tracker,
            tolerance=tolerance,
            latency=latency,
            direction=direction,
            sort=True,
        )
    except ValueError as exc:
        raise ValueError(
            f"{bag.name}: cannot align the joint states ({config['joint_states']!r}) "
            f"and the poses ({config['tip']!r}"
            + (f", {config['base']!r}" if config["base"] else "")
            + f"): {exc}"
        ) from None
    check_alignment(
        report, motors["t"], tracker["t"], label=bag.name, max_unmatched=max_unmatched,
        check_units=False,  # both clocks are converted from ns here
    )
    stem = bag.name[: -len(".bag")] if bag.suffix == ".bag" else bag.name
    X, y = recording_from_table(aligned, bag.name, stem, options)
    return X, y, report
