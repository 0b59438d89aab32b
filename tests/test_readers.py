"""Tests of the readers of skcath.io: NDI exports, two streams, ROS bags, many files."""

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose, assert_array_equal
from scipy.spatial.transform import Rotation
from sklearn.utils._param_validation import InvalidParameterError

from skcath import check_recordings
from skcath._format import REQUIRED_COLUMNS
from skcath.frames import tip_in_base_frame
from skcath.io import (
    AlignmentReport,
    align_streams,
    read_ndi_csv,
    read_recording,
    read_recordings,
    read_rosbag,
    read_streams,
)


# ---------------------------------------------------------------------------
# synthetic streams
# ---------------------------------------------------------------------------
def _motor_stream(n=60, rate=100.0):
    """A motor log at ``rate`` Hz on its own clock."""
    t = np.arange(n) / rate
    return pd.DataFrame(
        {
            "t": t,
            "q1": 30.0 * np.sin(t),
            "q2": 20.0 * np.cos(t),
            "tau1": np.linspace(0.0, 5.0, n),
            "tau2": np.linspace(5.0, 0.0, n),
        }
    )


def _tracker_poses(n, seed=0):
    """Tip/base poses in the tracker frame (wxyz) and the tip in the base frame."""
    rng = np.random.default_rng(seed)
    r_wb = Rotation.random(n, random_state=rng)
    p_wb = rng.uniform(-100.0, 100.0, size=(n, 3))
    p_b = np.column_stack([np.linspace(50, 60, n), rng.normal(0, 5, n), np.full(n, 70.0)])
    p_wt = p_wb + r_wb.apply(p_b)
    q_wb = r_wb.as_quat(scalar_first=True)
    q_wt = Rotation.random(n, random_state=rng).as_quat(scalar_first=True)
    return p_wt, q_wt, p_wb, q_wb, p_b


def _tracker_stream(t, seed=0):
    """A tracker stream in the raw pose columns of skcath, and the true tip."""
    p_wt, q_wt, p_wb, q_wb, p_b = _tracker_poses(len(t), seed)
    data = {"t": t}
    for prefix, p, q in (("tip", p_wt, q_wt), ("base", p_wb, q_wb)):
        for j, c in enumerate("xyz"):
            data[f"{prefix}_p{c}"] = p[:, j]
        for j, c in enumerate("wxyz"):
            data[f"{prefix}_q{c}"] = q[:, j]
    return pd.DataFrame(data), p_b


def _brute_force(t_motor, t_tracker, tolerance):
    """Index of the nearest tracker sample per motor sample, -1 if none is close."""
    d = np.abs(t_motor[:, None] - t_tracker[None, :])
    best = d.argmin(axis=1)
    return np.where(d[np.arange(len(t_motor)), best] <= tolerance, best, -1)


# ---------------------------------------------------------------------------
# align_streams
# ---------------------------------------------------------------------------
def test_align_streams_matches_nearest_and_reports_dropped():
    motors = _motor_stream()
    t_tracker = 0.004 + np.arange(30) * 0.025
    t_tracker = np.delete(t_tracker, np.arange(8, 13))  # a 0.15 s dropout
    tracker, _ = _tracker_stream(t_tracker)
    motors_before, tracker_before = motors.copy(), tracker.copy()

    aligned, report = align_streams(motors, tracker, tolerance=0.006)

    expected = _brute_force(motors["t"].to_numpy(), t_tracker, 0.006)
    matched = expected >= 0
    assert_allclose(aligned.loc[matched, "tracker_time"], t_tracker[expected[matched]])
    assert aligned.loc[~matched, "tip_px"].isna().all()
    tip_px = tracker["tip_px"].to_numpy()
    assert_allclose(aligned.loc[matched, "tip_px"], tip_px[expected[matched]])
    assert_array_equal(aligned["q1"], motors["q1"])
    assert isinstance(report, AlignmentReport)
    assert report.n_motor == len(motors)
    assert report.n_tracker == len(tracker)
    assert report.n_unmatched == int((~matched).sum()) > 0
    assert report.fraction_unmatched == pytest.approx(report.n_unmatched / len(motors))
    assert report.n_tracker_unused == len(t_tracker) - len(np.unique(expected[matched]))
    pd.testing.assert_frame_equal(motors, motors_before)
    pd.testing.assert_frame_equal(tracker, tracker_before)


def test_align_streams_latency_and_start_offset():
    motors = _motor_stream()
    t_tracker = np.arange(0, 0.6, 0.02)
    tracker, _ = _tracker_stream(t_tracker + 1000.0)  # another clock origin
    tracker = tracker.rename(columns={"t": "stamp"})

    _, unaligned = align_streams(motors, tracker, tracker_on="stamp", tolerance=0.005)
    assert unaligned.n_unmatched == len(motors)

    aligned, report = align_streams(
        motors, tracker, tracker_on="stamp", tolerance=0.005, latency=1000.0
    )
    expected = _brute_force(motors["t"].to_numpy(), t_tracker, 0.005)
    assert report.offset == 1000.0
    assert report.n_unmatched == int((expected < 0).sum())
    assert_allclose(aligned["tracker_time"].dropna(), t_tracker[expected[expected >= 0]] + 1000.0)

    _, start = align_streams(motors, tracker, tracker_on="stamp", tolerance=0.005, latency="start")
    assert start.offset == pytest.approx(1000.0)
    assert start.n_unmatched == report.n_unmatched


def test_align_streams_sorts_only_when_asked():
    motors = _motor_stream(n=20)
    tracker, _ = _tracker_stream(np.arange(10) * 0.02)
    shuffled = motors.iloc[::-1]
    with pytest.raises(ValueError, match=r"motors\['t'\] is not increasing.*sort=True"):
        align_streams(shuffled, tracker, tolerance=0.01)
    aligned, _ = align_streams(shuffled, tracker, tolerance=0.01, sort=True)
    reference, _ = align_streams(motors, tracker, tolerance=0.01)
    pd.testing.assert_frame_equal(aligned, reference)
    assert shuffled["t"].iloc[0] == motors["t"].iloc[-1]  # input untouched


@pytest.mark.parametrize(
    "change, kwargs, match",
    [
        (lambda m, t: (m.drop(columns="t"), t), {}, r"motors has no time column 't'"),
        (lambda m, t: (m, t.assign(t=0.0)), {}, r"tracker\['t'\] has duplicated timestamps"),
        (lambda m, t: (m.assign(t=np.nan), t), {}, r"motors\['t'\] must be finite"),
        (lambda m, t: (m.assign(t="a"), t), {}, r"must hold numbers"),
        (lambda m, t: (m, t), {"tolerance": 0.0}, r"tolerance must be a positive"),
        (lambda m, t: (m, t), {"tolerance": -1.0}, r"tolerance must be a positive"),
        (lambda m, t: (m, t), {"direction": "closest"}, r"direction must be one of"),
        (lambda m, t: (m, t), {"latency": "auto"}, r"latency must be a finite number"),
        (lambda m, t: (m, t.assign(q1=1.0)), {}, r"share the column\(s\) \['q1'\]"),
    ],
)
def test_align_streams_errors(change, kwargs, match):
    motors, tracker = change(_motor_stream(n=10), _tracker_stream(np.arange(5) * 0.02)[0])
    kwargs = {"tolerance": 0.01, **kwargs}
    with pytest.raises(ValueError, match=match):
        align_streams(motors, tracker, **kwargs)


@pytest.mark.parametrize(
    "kwargs", [{"sort": "yes"}, {"on": 0}, {"tracker_on": ["t"]}]
)
def test_align_streams_rejects_bad_arguments_by_name(kwargs):
    motors, tracker = _motor_stream(n=10), _tracker_stream(np.arange(5) * 0.02)[0]
    (name,) = kwargs
    with pytest.raises(InvalidParameterError, match=rf"'{name}' parameter of align_streams"):
        align_streams(motors, tracker, tolerance=0.01, **kwargs)


def test_read_streams_gives_long_format_with_dropouts(tmp_path):
    motors = _motor_stream(n=40)
    t_tracker = np.arange(0, 0.4, 0.02)
    tracker, p_b = _tracker_stream(t_tracker)
    tracker = tracker.drop(index=[5, 6]).reset_index(drop=True)
    motors.to_csv(tmp_path / "session.csv", index=False)

    X, y, report = read_streams(
        tmp_path / "session.csv", tracker, tolerance=0.005,
        catheter="A", setting="s", n_sweep=10,
    )
    assert list(X.columns) == list(REQUIRED_COLUMNS)
    assert (X["run"] == "session").all()
    expected = _brute_force(motors["t"].to_numpy(), np.delete(t_tracker, [5, 6]), 0.005)
    matched = expected >= 0
    assert report.n_unmatched == int((~matched).sum()) > 0
    assert np.isnan(y[~matched]).all()
    assert_allclose(y[matched], np.delete(p_b, [5, 6], axis=0)[expected[matched]], atol=1e-9)
    assert (X["phase"].iloc[:10] == "sweep").all()
    with pytest.raises(TypeError, match=r"read_streams\(\) got the unknown keyword"):
        read_streams(motors, tracker, tolerance=0.005, cathether="A")
    with pytest.raises(ValueError, match="rate_hz is not accepted"):
        read_streams(motors, tracker, tolerance=0.005, rate_hz=100.0)


# ---------------------------------------------------------------------------
# NDI exports
# ---------------------------------------------------------------------------
def _fmt(values):
    return ",".join(f"{v:.10g}" for v in values)


def _ndi_wide(path, t, quat_order="wxyz"):
    """An NDI Track-like export: two tools side by side, with markers and dropouts."""
    p_wt, q_wt, p_wb, q_wb, p_b = _tracker_poses(len(t))
    order = ["wxyz".index(c) for c in quat_order]
    lines = [
        "#Tools,Frame#,Port,Face #,State,Q0,Qx,Qy,Qz,Tx,Ty,Tz,Error,#Markers,State,Tx,Ty,Tz,"
        "Port,Face #,State,Q0,Qx,Qy,Qz,Tx,Ty,Tz,Error,#Markers,Timestamp"
    ]
    for i, ti in enumerate(t):
        tip = f"0A,0,OK,{_fmt(q_wt[i, order])},{_fmt(p_wt[i])},0.1"
        if i == 3:
            tip = "0A,0,Missing,,,,,,,,"
        if i == 5:
            tip = "0A,0,Out of Volume," + ",".join(["Missing"] * 8)
        base = f"0B,0,OK,{_fmt(q_wb[i, order])},{_fmt(p_wb[i])},0.1"
        if i == 7:
            base = "0B,0,Disabled,,,,,,,,"
        lines.append(f"2,{100 + i},{tip},1,OK,1,2,3,{base},0,{ti:.6f}")
    path.write_text("\n".join(lines) + "\n")
    return p_wt, q_wt, p_b


def test_read_ndi_csv_wide_layout(tmp_path):
    t = np.arange(10) * 0.025
    p_wt, q_wt, p_b = _ndi_wide(tmp_path / "aurora.csv", t)
    stream = read_ndi_csv(tmp_path / "aurora.csv", tip="0a", base="0B")

    assert list(stream.columns[:2]) == ["frame", "t"]
    assert_array_equal(stream["frame"], 100 + np.arange(10))
    assert_allclose(stream["t"], t, atol=1e-6)
    tracked = np.ones(10, dtype=bool)
    tracked[[3, 5]] = False
    assert stream.loc[~tracked, "tip_px":"tip_qz"].isna().all().all()
    assert_allclose(stream.loc[tracked, ["tip_px", "tip_py", "tip_pz"]], p_wt[tracked], rtol=1e-9)
    quat = ["tip_qw", "tip_qx", "tip_qy", "tip_qz"]
    assert_allclose(stream.loc[tracked, quat], q_wt[tracked], rtol=1e-9)
    assert stream.loc[7, "base_px":"base_qz"].isna().all()
    y = tip_in_base_frame(
        stream[["tip_px", "tip_py", "tip_pz"]].to_numpy(),
        stream[["base_px", "base_py", "base_pz"]].to_numpy(),
        stream[["base_qw", "base_qx", "base_qy", "base_qz"]].to_numpy(),
    )
    ok = tracked & (np.arange(10) != 7)
    assert_allclose(y[ok], p_b[ok], atol=1e-6)
    assert np.isnan(y[~ok]).all()


def test_read_ndi_csv_quat_order_is_explicit(tmp_path):
    t = np.arange(6) * 0.025
    _, q_wt, _ = _ndi_wide(tmp_path / "xyzw.csv", t, quat_order="xyzw")
    read_xyzw = read_ndi_csv(tmp_path / "xyzw.csv", tip="0A", quat_order="xyzw")
    read_wxyz = read_ndi_csv(tmp_path / "xyzw.csv", tip="0A")
    ok = ~read_xyzw["tip_qw"].isna().to_numpy()
    cols = ["tip_qw", "tip_qx", "tip_qy", "tip_qz"]
    assert_allclose(read_xyzw.loc[ok, cols], q_wt[ok], rtol=1e-9)
    assert not np.allclose(read_wxyz.loc[ok, cols], q_wt[ok])
    assert "base_px" not in read_xyzw.columns


def test_read_ndi_csv_long_layout(tmp_path):
    # one row per tool per frame; frame 2 has no row for the tip at all
    text = (
        "Frame,Tool Handle,Status,Q0,Qx,Qy,Qz,Tx,Ty,Tz,Error\n"
        "1,10,OK,1,0,0,0,1,2,3,0.1\n"
        "1,11,OK,1,0,0,0,0,0,0,0.1\n"
        "2,11,OK,1,0,0,0,0,0,0,0.1\n"
        "3,10,Missing,,,,,,,,\n"
        "3,11,OK,0,1,0,0,5,5,5,0.1\n"
        "4,11,OK,1,0,0,0,0,0,0,0.1\n"
        "4,10,OK,1,0,0,0,4,5,6,0.1\n"
    )
    (tmp_path / "long.csv").write_text(text)
    stream = read_ndi_csv(tmp_path / "long.csv", tip=10, base="11")
    assert_array_equal(stream["frame"], [1, 2, 3, 4])
    assert "t" not in stream.columns
    assert_allclose(stream["tip_px"], [1.0, np.nan, np.nan, 4.0])
    assert_allclose(stream["tip_pz"], [3.0, np.nan, np.nan, 6.0])
    assert_allclose(stream["base_qx"], [0.0, 0.0, 1.0, 0.0])


def test_read_ndi_csv_errors(tmp_path):
    t = np.arange(4) * 0.025
    _ndi_wide(tmp_path / "a.csv", t)
    match = r"tip='0C' is not a tool of this file; tools present: \['0A', '0B'\]"
    with pytest.raises(ValueError, match=match):
        read_ndi_csv(tmp_path / "a.csv", tip="0C")
    with pytest.raises(ValueError, match="same tool"):
        read_ndi_csv(tmp_path / "a.csv", tip="0A", base="0a")
    with pytest.raises(ValueError, match="quat_order"):
        read_ndi_csv(tmp_path / "a.csv", tip="0A", quat_order="wzyx")
    (tmp_path / "b.csv").write_text("Frame,x,y,z\n1,2,3,4\n")
    with pytest.raises(ValueError, match="no quaternion columns"):
        read_ndi_csv(tmp_path / "b.csv", tip=1)
    header = "Frame,Port,State,Q0,Qx,Qy,Qz,Tx,Ty,Tz\n"
    (tmp_path / "c.csv").write_text(header + "1,0A,OK,1,0,0,0,abc,0,0\n")
    with pytest.raises(ValueError, match=r"column 'Tx' .* must hold numbers; got 'abc'"):
        read_ndi_csv(tmp_path / "c.csv", tip="0A")
    (tmp_path / "d.csv").write_text(
        "Frame,Port,State,Q0,Qx,Qy,Qz,Tx,Ty,Tz\n1,0A,OK,1,0,0,0,0,0,0\n1,0A,OK,1,0,0,0,0,0,0\n"
        "1,0B,OK,1,0,0,0,0,0,0\n"
    )
    with pytest.raises(ValueError, match="more than once in one frame"):
        read_ndi_csv(tmp_path / "d.csv", tip="0A")


def test_ndi_stream_with_motor_log(tmp_path):
    t = np.arange(10) * 0.025
    _, _, p_b = _ndi_wide(tmp_path / "aurora.csv", t)
    tracker = read_ndi_csv(tmp_path / "aurora.csv", tip="0A", base="0B")
    X, y, report = read_streams(
        _motor_stream(n=25), tracker, tolerance=0.006,
        catheter="A", setting="s", run=1, n_sweep=5,
    )
    assert len(X) == 25
    expected = _brute_force(np.arange(25) / 100.0, t, 0.006)
    ok = (expected >= 0) & ~np.isin(expected, [3, 5, 7])
    assert_allclose(y[ok], p_b[expected[ok]], atol=1e-6)
    assert np.isnan(y[~ok]).all()
    assert report.n_unmatched == int((expected < 0).sum())


# ---------------------------------------------------------------------------
# read_recordings
# ---------------------------------------------------------------------------
def _recording_file(path, n=12, seed=0):
    """A small file in the skcath names (ids come from elsewhere)."""
    rng = np.random.default_rng(seed)
    frame = pd.DataFrame(
        {
            "t": np.arange(n) * 0.05,
            "q1": rng.uniform(-30, 30, n),
            "q2": rng.uniform(-30, 30, n),
            "tau1": rng.uniform(0, 1, n),
            "tau2": rng.uniform(0, 1, n),
            "p_x": rng.normal(0, 10, n),
            "p_y": rng.normal(0, 10, n),
            "p_z": rng.normal(80, 1, n),
        }
    )
    frame.to_csv(path, index=False)
    return frame


PATTERN = r"(?P<catheter>[^_]+)_(?P<setting>[^_]+)_run(?P<run>\d+)"


def test_read_recordings_from_file_names(tmp_path):
    names = ["A_slow_run1.csv", "A_slow_run2.csv", "B_fast_run3.csv"]
    frames = [_recording_file(tmp_path / name, seed=i) for i, name in enumerate(names)]
    (tmp_path / "notes.txt").write_text("not a recording")

    X, y = read_recordings(tmp_path, pattern=PATTERN, n_sweep=4, progress=False)
    assert len(X) == 36 and y.shape == (36, 3)
    assert list(X.columns) == list(REQUIRED_COLUMNS)
    runs = X[["catheter", "setting", "run"]].drop_duplicates().values.tolist()
    assert runs == [["A", "slow", "1"], ["A", "slow", "2"], ["B", "fast", "3"]]
    check_recordings(X, y)  # the joined table is valid recordings
    assert_allclose(y, np.concatenate([f[["p_x", "p_y", "p_z"]].to_numpy() for f in frames]))
    for name in names:  # same as reading the files one by one
        cat, setting, run = name[:-4].replace("run", "").split("_")
        Xi, yi = read_recording(tmp_path / name, catheter=cat, setting=setting, run=run, n_sweep=4)
        mask = (X["catheter"] == cat) & (X["setting"] == setting) & (X["run"] == run)
        assert_allclose(y[mask.to_numpy()], yi)
        assert_allclose(X.loc[mask, "q1"], Xi["q1"])

    X_glob, _ = read_recordings(
        str(tmp_path / "A_*.csv"), pattern=PATTERN, n_sweep=4, progress=False
    )
    assert len(X_glob) == 24


def test_read_recordings_manifest(tmp_path):
    (tmp_path / "data").mkdir()
    _recording_file(tmp_path / "data" / "first.csv")
    _recording_file(tmp_path / "data" / "second.csv", n=15, seed=1)
    manifest = pd.DataFrame(
        {
            "path": ["data/first.csv", "data/second.csv"],
            "catheter": ["A", "A"],
            "setting": ["s1", "s2"],
            "run": [1, 2],
            "n_sweep": [4, 6],
        }
    )
    manifest.to_csv(tmp_path / "manifest.csv", index=False)
    manifest_before = manifest.copy()
    X, y = read_recordings(manifest=tmp_path / "manifest.csv", progress=False)
    assert len(X) == 27
    assert X.groupby("setting")["phase"].apply(lambda p: (p == "sweep").sum()).to_dict() == {
        "s1": 4,
        "s2": 6,
    }
    pd.testing.assert_frame_equal(manifest, manifest_before)

    with pytest.raises(ValueError, match=r"manifest has the unknown column\(s\) \['speed'\]"):
        read_recordings(manifest=manifest.assign(speed=1.0, path="x"), progress=False)

    manifest.loc[1, "path"] = "data/missing.csv"
    manifest.to_csv(tmp_path / "bad.csv", index=False)
    match = r"bad.csv: row 1 lists 'data/missing.csv', which does not exist"
    with pytest.raises(ValueError, match=match):
        read_recordings(manifest=tmp_path / "bad.csv", progress=False)


def test_read_recordings_errors(tmp_path):
    with pytest.raises(ValueError, match="has no CSV or Parquet file"):
        read_recordings(tmp_path, progress=False)
    with pytest.raises(ValueError, match="no CSV or Parquet file matches"):
        read_recordings(str(tmp_path / "*.csv"), progress=False)
    _recording_file(tmp_path / "A_slow_run1.csv")
    _recording_file(tmp_path / "A-slow-2.csv")
    with pytest.raises(ValueError, match=r"file name 'A-slow-2.csv' does not match pattern"):
        read_recordings(tmp_path, pattern=PATTERN, n_sweep=4, progress=False)
    with pytest.raises(ValueError, match=r"unknown group\(s\) \['speed'\]"):
        read_recordings(tmp_path, pattern=r"(?P<speed>.*)", progress=False)
    with pytest.raises(ValueError, match=r"a run id must be unique across all files"):
        read_recordings(tmp_path, catheter="A", setting="s", run=1, n_sweep=4, progress=False)
    with pytest.raises(ValueError, match=r"\['catheter'\] given both"):
        read_recordings(
            tmp_path, pattern=r"(?P<catheter>A)[-_].*", catheter="B", n_sweep=4, progress=False
        )
    with pytest.raises(ValueError, match="either source"):
        read_recordings(progress=False)
    with pytest.raises(TypeError, match=r"unknown keyword argument\(s\) \['nsweep'\]"):
        read_recordings(tmp_path, nsweep=4, progress=False)


def test_read_recordings_progress_must_be_a_bool(tmp_path):
    with pytest.raises(InvalidParameterError, match="'progress' parameter of read_recordings"):
        read_recordings(tmp_path, progress="no")


def test_folder_lists_the_files_read_recording_accepts(tmp_path):
    from skcath.io._many import _files_of

    for name in ("a.csv", "B.CSV.GZ", "c.parquet", ".csv", "notes.txt", "d.csv.tar"):
        (tmp_path / name).write_text("")
    (tmp_path / "e.csv").mkdir()  # a folder, whatever its name
    expected = ["B.CSV.GZ", "a.csv", "c.parquet"]
    assert [p.name for p in _files_of(tmp_path)] == expected
    assert [p.name for p in _files_of(str(tmp_path / "*"))] == expected


# ---------------------------------------------------------------------------
# ROS bags
# ---------------------------------------------------------------------------
def _write_bag(path, ros1, n_joint=30, n_pose=12, with_effort=True):
    """Write a small bag: joint states at 100 Hz, tip/base poses at 40 Hz (m, rad, N m)."""
    rosbag1 = pytest.importorskip("rosbags.rosbag1")
    rosbag2 = pytest.importorskip("rosbags.rosbag2")
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    T = store.types
    Time = T["builtin_interfaces/msg/Time"]

    def header(t_ns):
        stamp = Time(sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000)
        if ros1:
            return T["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id="")
        return T["std_msgs/msg/Header"](stamp=stamp, frame_id="")

    serialize = store.serialize_ros1 if ros1 else store.serialize_cdr
    t0 = 1_700_000_000 * 10**9  # ns
    t_joint = t0 + np.arange(n_joint) * 10_000_000
    t_pose = t0 + 2_000_000 + np.arange(n_pose) * 25_000_000
    p_wt, q_wt, p_wb, q_wb, p_b = _tracker_poses(n_pose)
    angles = np.deg2rad(np.linspace(-20, 20, n_joint))
    efforts = np.linspace(0.0, 0.004, n_joint)  # N m

    writer = rosbag1.Writer(path) if ros1 else rosbag2.Writer(path, version=9)
    with writer:
        js, tip, base = (
            writer.add_connection(topic, msgtype, typestore=store)
            for topic, msgtype in (
                ("/motors/joint_states", "sensor_msgs/msg/JointState"),
                ("/aurora/tip", "geometry_msgs/msg/PoseStamped"),
                ("/aurora/base", "geometry_msgs/msg/TransformStamped"),
            )
        )
        messages = []
        for i, t in enumerate(t_joint.tolist()):
            msg = T["sensor_msgs/msg/JointState"](
                header=header(t),
                name=["other", "m1", "m2"],
                position=np.array([9.0, angles[i], -angles[i]]),
                velocity=np.array([], dtype=np.float64),
                effort=(
                    np.array([0.0, efforts[i], 2 * efforts[i]])
                    if with_effort
                    else np.array([], dtype=np.float64)
                ),
            )
            messages.append((t, js, msg, "sensor_msgs/msg/JointState"))
        for i, t in enumerate(t_pose.tolist()):
            pose = T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](*(p_wt[i] / 1000.0)),
                orientation=T["geometry_msgs/msg/Quaternion"](
                    x=q_wt[i, 1], y=q_wt[i, 2], z=q_wt[i, 3], w=q_wt[i, 0]
                ),
            )
            msg = T["geometry_msgs/msg/PoseStamped"](header=header(t), pose=pose)
            messages.append((t, tip, msg, "geometry_msgs/msg/PoseStamped"))
            transform = T["geometry_msgs/msg/Transform"](
                translation=T["geometry_msgs/msg/Vector3"](*(p_wb[i] / 1000.0)),
                rotation=T["geometry_msgs/msg/Quaternion"](
                    x=q_wb[i, 1], y=q_wb[i, 2], z=q_wb[i, 3], w=q_wb[i, 0]
                ),
            )
            msg = T["geometry_msgs/msg/TransformStamped"](
                header=header(t), child_frame_id="base", transform=transform
            )
            messages.append((t, base, msg, "geometry_msgs/msg/TransformStamped"))
        for t, connection, msg, msgtype in sorted(messages, key=lambda m: m[0]):
            writer.write(connection, t, serialize(msg, msgtype))
    if not with_effort:
        return (t_joint - t0) * 1e-9, (t_pose - t0) * 1e-9, p_wt
    return (t_joint - t0) * 1e-9, (t_pose - t0) * 1e-9, angles, efforts, p_b


CONFIG = {
    "joint_states": "/motors/joint_states",
    "q1": "m1",
    "q2": "m2",
    "tip": "/aurora/tip",
    "base": "/aurora/base",
}


@pytest.mark.parametrize("ros1", [False, True], ids=["ros2", "ros1"])
def test_read_rosbag(tmp_path, ros1):
    path = tmp_path / ("session.bag" if ros1 else "session")
    t_joint, t_pose, angles, efforts, p_b = _write_bag(path, ros1)
    X, y, report = read_rosbag(
        path, CONFIG, tolerance=0.005, catheter="A", setting="s", n_sweep=5
    )
    assert len(X) == len(t_joint)
    assert (X["run"] == "session").all()
    assert_allclose(X["t"], t_joint, atol=1e-6)
    assert_allclose(X["q1"], np.rad2deg(angles), atol=1e-9)
    assert_allclose(X["q2"], -np.rad2deg(angles), atol=1e-9)
    assert_allclose(X["tau1"], efforts * 1000.0, atol=1e-9)
    assert_allclose(X["tau2"], 2 * efforts * 1000.0, atol=1e-9)
    expected = _brute_force(t_joint, t_pose, 0.005)
    matched = expected >= 0
    assert report.n_unmatched == int((~matched).sum()) > 0
    assert_allclose(y[matched], p_b[expected[matched]], atol=1e-6)
    assert np.isnan(y[~matched]).all()
    # the bag's receive times equal the header stamps here
    X_bag, y_bag, _ = read_rosbag(
        path, CONFIG, tolerance=0.005, stamp="bag", catheter="A", setting="s", n_sweep=5
    )
    pd.testing.assert_frame_equal(X_bag, X)
    assert_allclose(y_bag, y)


def test_read_rosbag_tip_only_without_efforts(tmp_path):
    path = tmp_path / "tip_only"
    t_joint, t_pose, p_wt = _write_bag(path, ros1=False, with_effort=False)
    config = {k: v for k, v in CONFIG.items() if k != "base"}
    with pytest.raises(ValueError, match=r"no 'tau1' column.*constants"):
        read_rosbag(path, config, tolerance=0.005, catheter="A", setting="s", n_sweep=5)
    X, y, _ = read_rosbag(
        path, config, tolerance=0.005, catheter="A", setting="s", n_sweep=5,
        constants={"tau1": 0.0, "tau2": 0.0},
        columns={"p_x": "tip_px", "p_y": "tip_py", "p_z": "tip_pz"},
    )
    assert (X["tau1"] == 0.0).all()
    expected = _brute_force(t_joint, t_pose, 0.005)
    matched = expected >= 0
    assert_allclose(y[matched], p_wt[expected[matched]], rtol=1e-9)  # m -> mm


def test_read_rosbag_of_one_and_three_motors(tmp_path):
    """The config's joints q1 .. qN give the columns q1 .. qN and tau1 .. tauN, in that order."""
    path = tmp_path / "bag"
    t_joint, _, angles, efforts, _ = _write_bag(path, ros1=False)
    kwargs = {"tolerance": 0.005, "catheter": "A", "setting": "s", "n_sweep": 5}
    three = {**CONFIG, "q2": "other", "q3": "m2"}
    X, _, _ = read_rosbag(path, three, **kwargs)
    assert [c for c in X.columns if c[0] in "qt" and c != "t"] == [
        "q1", "q2", "q3", "tau1", "tau2", "tau3"
    ]
    assert_allclose(X["q1"], np.rad2deg(angles), atol=1e-9)
    assert_allclose(X["q2"], np.rad2deg(9.0), atol=1e-9)
    assert_allclose(X["q3"], -np.rad2deg(angles), atol=1e-9)
    assert_allclose(X["tau3"], 2 * efforts * 1000.0, atol=1e-9)
    one = {k: v for k, v in CONFIG.items() if k != "q2"}
    X1, _, _ = read_rosbag(path, one, **kwargs)
    assert "q2" not in X1.columns and "tau2" not in X1.columns
    assert_allclose(X1["q1"], np.rad2deg(angles), atol=1e-9)
    assert len(X1) == len(X) == len(t_joint)


def test_read_rosbag_errors(tmp_path):
    path = tmp_path / "bag"
    _write_bag(path, ros1=False, n_joint=10, n_pose=4)
    kwargs = {"tolerance": 0.005, "catheter": "A", "setting": "s", "n_sweep": 2}
    with pytest.raises(ValueError, match=r"no topic '/tracker/tip'.*topics: \["):
        read_rosbag(path, {**CONFIG, "tip": "/tracker/tip"}, **kwargs)
    with pytest.raises(ValueError, match=r"joint 'm3' \(config\['q2'\]\) is not in a JointState"):
        read_rosbag(path, {**CONFIG, "q2": "m3"}, **kwargs)
    with pytest.raises(ValueError, match=r"carries geometry_msgs/msg/TransformStamped; motors"):
        read_rosbag(path, {**CONFIG, "joint_states": "/aurora/base", "base": None}, **kwargs)
    with pytest.raises(ValueError, match=r"topic '/aurora/tip' for both 'joint_states' and 'tip'"):
        read_rosbag(path, {**CONFIG, "joint_states": "/aurora/tip"}, **kwargs)
    with pytest.raises(ValueError, match=r"no such bag"):
        read_rosbag(tmp_path / "nothing", CONFIG, **kwargs)
    with pytest.raises(ValueError, match=r"stamp must be one of"):
        read_rosbag(path, CONFIG, stamp="receive", **kwargs)
    with pytest.raises(ValueError, match=r"unknown key\(s\) \['camera'\]"):
        read_rosbag(path, {**CONFIG, "camera": "/cam"}, **kwargs)
    with pytest.raises(ValueError, match=r"config needs the key 'tip'"):
        read_rosbag(path, {k: v for k, v in CONFIG.items() if k != "tip"}, **kwargs)
    with pytest.raises(ValueError, match=r"joints of \['q1', 'q3'\], without \['q2'\]"):
        read_rosbag(path, {**CONFIG, "q2": None, "q3": "other"}, **kwargs)
    with pytest.raises(ValueError, match=r"joint 'm1' for both 'q1' and 'q3'"):
        read_rosbag(path, {**CONFIG, "q3": "m1"}, **kwargs)


def test_read_recordings_refuses_a_run_id_in_two_files(tmp_path):
    """Run ids are unique across catheters and settings: a clash names both files."""
    _recording_file(tmp_path / "A_S01_run1.csv")
    _recording_file(tmp_path / "B_S01_run1.csv", seed=1)
    with pytest.raises(ValueError, match=r"run id '1' is in both 'A_S01_run1.csv' and 'B_S01_run1.csv'"):
        read_recordings(tmp_path, pattern=PATTERN, n_sweep=4, progress=False)
    # a run group that spans the catheter and the setting gives unique ids
    spanning = r"(?P<run>(?P<catheter>[^_]+)_(?P<setting>[^_]+)_run\d+)"
    X, y = read_recordings(tmp_path, pattern=spanning, n_sweep=4, progress=False)
    assert sorted(X["run"].astype(str).unique()) == ["A_S01_run1", "B_S01_run1"]


def test_read_recordings_manifest_with_an_empty_id_cell(tmp_path):
    """A blank cell turns an integer column into floats; whole numbers are read back as ints."""
    _recording_file(tmp_path / "first.csv")
    _recording_file(tmp_path / "second.csv", seed=1)
    (tmp_path / "manifest.csv").write_text(
        "path,catheter,setting,run,n_sweep\nfirst.csv,A,s1,7,4\nsecond.csv,A,s2,,4\n"
    )
    X, _ = read_recordings(manifest=tmp_path / "manifest.csv", progress=False)
    assert "7" in set(X["run"].astype(str))


# ---------------------------------------------------------------------------
# dialects, cut and unreadable files, clock units, unmatched samples
# ---------------------------------------------------------------------------
def test_read_ndi_csv_semicolon_decimal_comma(tmp_path):
    t = np.arange(10) * 0.025
    _ndi_wide(tmp_path / "aurora.csv", t)
    text = (tmp_path / "aurora.csv").read_text()
    (tmp_path / "lab.csv").write_text(text.replace(",", ";").replace(".", ","))
    reference = read_ndi_csv(tmp_path / "aurora.csv", tip="0A", base="0B")
    pd.testing.assert_frame_equal(read_ndi_csv(tmp_path / "lab.csv", tip="0A", base="0B"), reference)


def test_read_ndi_csv_drops_a_cut_last_line(tmp_path):
    from skcath.exceptions import TruncatedFileWarning

    t = np.arange(10) * 0.025
    _ndi_wide(tmp_path / "aurora.csv", t)
    text = (tmp_path / "aurora.csv").read_text()
    (tmp_path / "cut.csv").write_text(text[:-25])
    with pytest.warns(TruncatedFileWarning, match=r"cut\.csv: the last line does not end"):
        stream = read_ndi_csv(tmp_path / "cut.csv", tip="0A", base="0B")
    reference = read_ndi_csv(tmp_path / "aurora.csv", tip="0A", base="0B")
    pd.testing.assert_frame_equal(stream, reference.iloc[:-1])


def test_read_ndi_csv_file_errors_name_the_file(tmp_path):
    (tmp_path / "empty.csv").write_bytes(b"")
    with pytest.raises(ValueError, match=r"^empty\.csv: the file is empty"):
        read_ndi_csv(tmp_path / "empty.csv", tip="0A")
    (tmp_path / "long.csv").write_text("Tool,Q0,Qx,Qy,Qz,Tx,Ty,Tz\n1,1,0,0,0,1,2,3\n2,1,0,0,0,1,2,3\n")
    with pytest.raises(ValueError, match=r"neither a frame number nor a timestamp.*Header: \["):
        read_ndi_csv(tmp_path / "long.csv", tip=1)


def test_align_streams_tracker_time_scale():
    motors = _motor_stream()
    t_tracker = np.arange(0, 0.6, 0.02)
    tracker, _ = _tracker_stream(t_tracker)
    reference, expected = align_streams(motors, tracker, tolerance=0.005)
    in_ms = tracker.assign(t=(t_tracker + 2.0) * 1000.0)  # other origin, ms
    aligned, report = align_streams(
        motors, in_ms, tolerance=0.005, tracker_time_scale=1e-3, latency="start"
    )
    assert report.offset == pytest.approx(2.0)  # in the motor's unit
    assert report.n_unmatched == expected.n_unmatched
    assert_allclose(aligned["tip_px"], reference["tip_px"])
    assert_allclose(aligned["tracker_time"], (reference["tracker_time"] + 2.0) * 1000.0)
    for bad in (0.0, -1.0, np.inf, "ms"):
        with pytest.raises(ValueError, match="tracker_time_scale must be a positive finite"):
            align_streams(motors, tracker, tolerance=0.005, tracker_time_scale=bad)


def test_unit_power_of_two_clocks():
    from skcath.io._align import _unit_power

    assert _unit_power(6.0, 6.0) == 0
    assert _unit_power(6.0, 200.0) == 0  # a factor 33: no unit
    assert _unit_power(6.0, 6000.0) == 3
    assert _unit_power(6.0, 15000.0) == 3  # within a factor 3 of 1000
    assert _unit_power(6.0, 30000.0) == 0
    assert _unit_power(6000.0, 6.0) == -3
    assert _unit_power(6.0, 6e6) == 6 and _unit_power(6.0, 6e9) == 9
    assert _unit_power(0.0, 5.0) == 0


def test_read_streams_unit_check_is_skipped_for_a_given_scale():
    motors = _motor_stream(n=40)
    tracker, _ = _tracker_stream(np.arange(0, 0.4, 0.02) * 1000.0)  # looks like ms
    kwargs = {"tolerance": 0.005, "catheter": "A", "setting": "s", "n_sweep": 10}
    with pytest.raises(ValueError, match="count in different units"):
        read_streams(motors, tracker, **kwargs)
    # stating one unit skips the unit check; the alignment itself is then refused
    with pytest.raises(ValueError, match=r"found no tracker sample.*max_unmatched=0\.9"):
        read_streams(motors, tracker, tracker_time_scale=1.0, **kwargs)
    _, y, report = read_streams(motors, tracker, tracker_time_scale=1.0, max_unmatched=1.0, **kwargs)
    assert report.fraction_unmatched > 0.9


@pytest.mark.parametrize("bad", [-0.1, 1.5, np.nan, "all"])
def test_max_unmatched_must_be_a_fraction(bad):
    motors, tracker = _motor_stream(n=10), _tracker_stream(np.arange(5) * 0.02)[0]
    with pytest.raises(InvalidParameterError, match="'max_unmatched' parameter of read_streams"):
        read_streams(motors, tracker, tolerance=0.01, max_unmatched=bad)


def test_read_rosbag_refuses_mostly_unmatched_messages(tmp_path):
    path = tmp_path / "bag"
    _write_bag(path, ros1=False)
    kwargs = {"tolerance": 0.005, "catheter": "A", "setting": "s", "n_sweep": 5}
    with pytest.raises(ValueError, match=r"^bag: \d+ of the 30 motor samples .*max_unmatched=0\.1"):
        read_rosbag(path, CONFIG, max_unmatched=0.1, **kwargs)
    with pytest.raises(ValueError, match=r"^bag: 30 of the 30 motor samples \(100\.0 %\)"):
        read_rosbag(path, CONFIG, latency=5.0, **kwargs)
    with pytest.raises(InvalidParameterError, match="'max_unmatched' parameter of read_rosbag"):
        read_rosbag(path, CONFIG, max_unmatched=2, **kwargs)


def test_unreadable_manifest_names_the_file(tmp_path):
    (tmp_path / "manifest.csv").write_bytes(bytes(range(128, 256)))
    with pytest.raises(ValueError, match=r"^manifest\.csv: cannot be read as a CSV manifest"):
        read_recordings(manifest=tmp_path / "manifest.csv", progress=False)
