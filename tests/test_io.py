"""Tests of skcath.io.read_recording on synthetic files and on the TEE-probe recordings."""

import dataclasses
import inspect
import os
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose
from scipy.spatial.transform import Rotation

from skcath._format import REQUIRED_COLUMNS, SENSOR_POSE_COLUMNS
from skcath._validation import check_recordings
from skcath.exceptions import TruncatedFileWarning
from skcath.frames import quaternion_to_rotation
from skcath.io import read_recording, read_recordings
from skcath.io._options import OPTION_NAMES, ReadingOptions

N = 12


# ---------------------------------------------------------------------------
# synthetic recordings
# ---------------------------------------------------------------------------
def _poses(n=N, seed=0):
    """World-frame sensor poses and the base-frame tip they encode."""
    rng = np.random.default_rng(seed)
    r_wb = Rotation.random(n, random_state=rng)
    p_wb = rng.uniform(-200.0, 200.0, size=(n, 3))
    angle = np.linspace(0.0, 1.0, n)
    p_b = np.column_stack([80.0 * np.cos(angle), 80.0 * np.sin(angle), rng.normal(0, 1, n)])
    p_wt = p_wb + r_wb.apply(p_b)
    q_wt = Rotation.random(n, random_state=rng).as_quat()
    return {"p_wt": p_wt, "p_wb": p_wb, "q_wb": r_wb.as_quat(), "q_wt": q_wt, "p_b": p_b}


def _standard_frame(poses, n=N):
    """A file in the skcath names: long format plus sensor poses (wxyz by name)."""
    frame = pd.DataFrame(
        {
            "catheter": "cathA",
            "setting": "s1",
            "run": "r1",
            "t": np.arange(n) * 0.05,
            "phase": ["sweep"] * 5 + ["motion"] * (n - 5),
            "q1": np.linspace(-30, 30, n),
            "q2": np.linspace(10, -10, n),
            "tau1": np.linspace(0, 1, n),
            "tau2": np.linspace(1, 0, n),
        }
    )
    for sensor, p_key, q_key in (("tip", "p_wt", "q_wt"), ("base", "p_wb", "q_wb")):
        for j, name in enumerate(SENSOR_POSE_COLUMNS[f"{sensor}_position"]):
            frame[name] = poses[p_key][:, j]
        for name in SENSOR_POSE_COLUMNS[f"{sensor}_orientation"]:
            frame[name] = poses[q_key][:, "xyzw".index(name[-1])]
    return frame


def _rig_frame(poses, n=N):
    """A one-motor rig export: other names, xyzw quaternion columns, no time, no q2."""
    frame = pd.DataFrame({"enc": np.arange(n) * 100.0, "cur": np.linspace(-5, 5, n)})
    for j in range(4):
        frame[f"tq{j}"] = poses["q_wt"][:, j]
        frame[f"bq{j}"] = poses["q_wb"][:, j]
    for j, axis in enumerate("xyz"):
        frame[f"t{axis}"] = poses["p_wt"][:, j]
        frame[f"b{axis}"] = poses["p_wb"][:, j]
    return frame


RIG_COLUMNS = {
    "q1": "enc",
    "tau1": "cur",
    "tip_position": ["tx", "ty", "tz"],
    "base_position": ["bx", "by", "bz"],
    "tip_orientation": ["tq0", "tq1", "tq2", "tq3"],
    "base_orientation": ["bq0", "bq1", "bq2", "bq3"],
}
RIG_KWARGS = {
    "columns": RIG_COLUMNS,
    "quat_order": "xyzw",
    "constants": {"q2": 0.0, "tau2": 0.0},
    "catheter": "rig",
    "setting": "default",
    "rate_hz": 20.0,
    "n_sweep": 4,
}


def _write(frame, path):
    if path.suffix == ".parquet":
        pytest.importorskip("pyarrow")
        frame.to_parquet(path)
    else:
        frame.to_csv(path, index=False)
    return path


@pytest.fixture
def poses():
    return _poses()


# ---------------------------------------------------------------------------
# reading
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("suffix", [".csv", ".parquet", ".csv.gz"])
def test_standard_names_round_trip(tmp_path, poses, suffix):
    path = _write(_standard_frame(poses), tmp_path / f"rec{suffix}")
    X, y = read_recording(path)
    assert list(X.columns) == list(REQUIRED_COLUMNS)
    assert isinstance(X.index, pd.RangeIndex)
    assert len(X) == N
    assert y.shape == (N, 3)
    assert_allclose(y, poses["p_b"], atol=1e-9)
    for column in ("t", "q1", "q2", "tau1", "tau2", "ref_x", "ref_y", "ref_z"):
        assert X[column].dtype == np.float64
    sweep = (X["phase"] == "sweep").to_numpy()
    assert sweep.sum() == 5
    assert_allclose(X.loc[sweep, ["ref_x", "ref_y", "ref_z"]].to_numpy(), y[sweep])
    assert X.loc[~sweep, ["ref_x", "ref_y", "ref_z"]].isna().all().all()
    assert set(X["catheter"]) == {"cathA"}
    assert set(X["run"]) == {"r1"}


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_rig_export_with_groups_rate_constants_and_n_sweep(tmp_path, poses, suffix):
    path = _write(_rig_frame(poses), tmp_path / f"acq7{suffix}")
    X, y = read_recording(path, **RIG_KWARGS)
    assert_allclose(y, poses["p_b"], atol=1e-9)
    assert_allclose(X["t"], np.arange(N) / 20.0)
    assert_allclose(X["q1"], np.arange(N) * 100.0)
    assert (X["q2"] == 0.0).all() and (X["tau2"] == 0.0).all()
    assert list(X["phase"]) == ["sweep"] * 4 + ["motion"] * (N - 4)
    assert set(X["run"]) == {"acq7"}  # one file = one run, named after the file
    assert set(X["catheter"]) == {"rig"}


def test_wrong_quat_order_for_group_gives_other_positions(tmp_path, poses):
    path = _write(_rig_frame(poses), tmp_path / "rec.csv")
    _, y = read_recording(path, **{**RIG_KWARGS, "quat_order": "wxyz"})
    assert np.abs(y - poses["p_b"]).max() > 1.0


def test_component_mapping_is_by_name_whatever_the_file_order(tmp_path, poses):
    frame = _rig_frame(poses)
    # map by component name: tq0..tq3 are x, y, z, w in the file
    columns = {k: v for k, v in RIG_COLUMNS.items() if not k.endswith("orientation")}
    for sensor, prefix in (("tip", "tq"), ("base", "bq")):
        for j, c in enumerate("xyzw"):
            columns[f"{sensor}_q{c}"] = f"{prefix}{j}"
    path = _write(frame[frame.columns[::-1]], tmp_path / "rec.csv")
    for order in ("wxyz", "xyzw"):  # quat_order only matters for group mappings
        kwargs = {**RIG_KWARGS, "columns": columns, "quat_order": order}
        _, y = read_recording(path, **kwargs)
        assert_allclose(y, poses["p_b"], atol=1e-9)


def test_base_frame_target_columns(tmp_path, poses):
    frame = _standard_frame(poses).drop(columns=list(SENSOR_POSE_COLUMNS["tip_position"]))
    for j, name in enumerate(("px", "py", "pz")):
        frame[name] = poses["p_b"][:, j]
    path = _write(frame, tmp_path / "rec.csv")
    _, y = read_recording(path, columns={"p_x": "px", "p_y": "py", "p_z": "pz"})
    assert_allclose(y, poses["p_b"])


def test_scale_counts_and_metres(tmp_path, poses):
    frame = _rig_frame(poses)
    for c in ("tx", "ty", "tz", "bx", "by", "bz"):
        frame[c] = frame[c] / 1000.0  # metres in the file
    path = _write(frame, tmp_path / "rec.csv")
    scale = {"q1": 0.09, "tip_position": 1000.0, "base_position": 1000.0}
    X, y = read_recording(path, **RIG_KWARGS, scale=scale)
    assert_allclose(X["q1"], np.arange(N) * 9.0)
    assert_allclose(y, poses["p_b"], atol=1e-9)


def test_phase_for_all_rows(tmp_path, poses):
    path = _write(_rig_frame(poses), tmp_path / "rec.csv")
    kwargs = {k: v for k, v in RIG_KWARGS.items() if k != "n_sweep"}
    X, y = read_recording(path, **kwargs, phase="sweep")
    assert (X["phase"] == "sweep").all()
    assert_allclose(X[["ref_x", "ref_y", "ref_z"]].to_numpy(), y)
    X, _ = read_recording(path, **kwargs, phase="motion")
    assert (X["phase"] == "motion").all()
    assert X[["ref_x", "ref_y", "ref_z"]].isna().all().all()


def test_several_runs_in_one_file(tmp_path, poses):
    frame = _rig_frame(poses)
    frame["trial"] = [7] * 5 + [8] * (N - 5)
    path = _write(frame, tmp_path / "rec.csv")
    columns = {**RIG_COLUMNS, "run": "trial"}
    X, _ = read_recording(path, **{**RIG_KWARGS, "columns": columns, "n_sweep": 2})
    assert list(X["run"]) == [7] * 5 + [8] * (N - 5)  # ids keep their type
    assert_allclose(X["t"], np.r_[np.arange(5), np.arange(N - 5)] / 20.0)
    expected = ["sweep"] * 2 + ["motion"] * 3 + ["sweep"] * 2 + ["motion"] * (N - 7)
    assert list(X["phase"]) == expected


def test_reference_from_file_is_kept(tmp_path, poses):
    frame = _standard_frame(poses)
    # the same measurement as y on sweep rows, filtered otherwise (within the jitter)
    sweep = (frame["phase"] == "sweep").to_numpy()[:, None]
    ref = np.where(sweep, poses["p_b"] + [0.15, -0.1, 0.05], np.nan)
    for j, name in enumerate(("ref_x", "ref_y", "ref_z")):
        frame[name] = ref[:, j]
    path = _write(frame, tmp_path / "rec.csv")
    X, _ = read_recording(path)
    assert_allclose(X[["ref_x", "ref_y", "ref_z"]].to_numpy(), ref)


def test_tracker_dropout_rows_are_nan_and_kept(tmp_path, poses):
    frame = _standard_frame(poses)
    frame.loc[2, "tip_px"] = np.nan
    frame.loc[7, ["base_qw", "base_qx", "base_qy", "base_qz"]] = np.nan
    path = _write(frame, tmp_path / "rec.csv")
    X, y = read_recording(path)
    assert len(X) == N
    assert np.isnan(y[[2, 7]]).all()
    assert np.isnan(X.loc[2, ["ref_x", "ref_y", "ref_z"]].to_numpy(dtype=float)).all()
    keep = ~np.isin(np.arange(N), [2, 7])
    assert_allclose(y[keep], poses["p_b"][keep], atol=1e-9)


@pytest.mark.parametrize(
    ("status", "valid_arg"),
    [
        ([True] * 3 + [False] + [True] * (N - 4), "status"),
        (["OK"] * 3 + ["MISSING"] + [" ok "] * (N - 4), "status"),
        ([0] * 3 + [4] + [0] * (N - 4), "status"),
        ([1] * 3 + [0] + [1] * (N - 4), ("status", [1])),
        (["good"] * 3 + ["bad"] + ["good"] * (N - 4), ("status", "good")),
    ],
)
def test_valid_column_masks_rows(tmp_path, poses, status, valid_arg):
    frame = _standard_frame(poses)
    frame["status"] = status
    # a tracker writes zeros for a missing sensor: masked rows must not raise
    frame.loc[3, ["base_qw", "base_qx", "base_qy", "base_qz"]] = 0.0
    path = _write(frame, tmp_path / "rec.csv")
    X, y = read_recording(path, valid=valid_arg)
    assert len(X) == N
    assert np.isnan(y[3]).all()
    assert np.isnan(X.loc[3, ["ref_x", "ref_y", "ref_z"]].to_numpy(dtype=float)).all()
    keep = np.arange(N) != 3
    assert_allclose(y[keep], poses["p_b"][keep], atol=1e-9)


@pytest.mark.parametrize("status", ["OK", True, 0])
def test_valid_column_with_empty_cell_is_invalid(tmp_path, poses, status):
    frame = _standard_frame(poses)
    frame["status"] = pd.Series([status] * N, dtype=object)
    frame.loc[6, "status"] = None
    path = _write(frame, tmp_path / "rec.csv")
    _, y = read_recording(path, valid="status")
    assert np.isnan(y[6]).all()
    assert np.isfinite(np.delete(y, 6, axis=0)).all()


def test_tip_offset(tmp_path, poses):
    path = _write(_standard_frame(poses), tmp_path / "rec.csv")
    offset = np.array([0.0, 0.0, 7.0])
    _, y = read_recording(path, tip_offset=offset)
    r_wb = Rotation.from_quat(poses["q_wb"])
    expected = poses["p_b"] + r_wb.inv().apply(Rotation.from_quat(poses["q_wt"]).apply(offset))
    assert_allclose(y, expected, atol=1e-9)


def test_arguments_not_modified(tmp_path, poses):
    path = _write(_rig_frame(poses), tmp_path / "rec.csv")
    columns = {k: (list(v) if isinstance(v, list) else v) for k, v in RIG_COLUMNS.items()}
    constants = {"q2": 0.0, "tau2": 0.0}
    scale = {"q1": 2.0}
    kwargs = {**RIG_KWARGS, "columns": columns, "constants": constants, "scale": scale}
    read_recording(path, **kwargs)
    assert columns == RIG_COLUMNS
    assert constants == {"q2": 0.0, "tau2": 0.0}
    assert scale == {"q1": 2.0}


# ---------------------------------------------------------------------------
# reading options
# ---------------------------------------------------------------------------
def test_reading_options_have_the_defaults_of_read_recording():
    signature = inspect.signature(read_recording).parameters
    # quat_check is a check of what was read, made after reading, not a reading option
    keyword_only = [
        p for p in signature.values()
        if p.kind is inspect.Parameter.KEYWORD_ONLY and p.name != "quat_check"
    ]
    assert OPTION_NAMES == tuple(p.name for p in keyword_only)
    defaults = ReadingOptions()
    for parameter in keyword_only:
        assert getattr(defaults, parameter.name) == (
            {} if parameter.name in ("columns", "constants", "scale") else parameter.default
        ), parameter.name


def test_reading_options_are_frozen_copies():
    columns = {"tip_position": ["tx", "ty", "tz"], "q1": "enc"}
    scale = {"tip_position": 1000.0}
    options = ReadingOptions(columns=columns, scale=scale, valid=("flag", 1), tip_offset=[0, 0, 5])
    columns["q2"] = "other"
    scale["q1"] = 2.0
    assert dict(options.columns) == {"tip_px": "tx", "tip_py": "ty", "tip_pz": "tz", "q1": "enc"}
    assert dict(options.scale) == {"tip_px": 1000.0, "tip_py": 1000.0, "tip_pz": 1000.0}
    assert (options.valid_column, options.valid_values) == ("flag", [1])
    assert options.tip_offset == (0.0, 0.0, 5.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        options.n_sweep = 3
    with pytest.raises(TypeError):
        options.columns["q2"] = "other"
    # the normalised options are valid options that give the same options again
    fields = {f.name: getattr(options, f.name) for f in dataclasses.fields(options)}
    assert ReadingOptions(**fields) == options


def test_reading_options_from_kwargs():
    options = ReadingOptions.from_kwargs({"n_sweep": 4, "catheter": "A"}, "reader")
    assert (options.n_sweep, options.catheter, options.phase, options.require_sweep) == (
        4, "A", None, True
    )
    assert not ReadingOptions(n_sweep=0).require_sweep
    assert not ReadingOptions(phase="motion").require_sweep
    with pytest.raises(TypeError, match=r"reader\(\) got the unknown keyword argument\(s\) \['x'\]"):
        ReadingOptions.from_kwargs({"x": 1}, "reader")


def test_options_are_checked_before_the_file_is_read(tmp_path):
    missing = tmp_path / "missing.csv"  # never read: the options fail first
    with pytest.raises(ValueError, match="tip_offset must be three finite numbers"):
        read_recording(missing, tip_offset=[0.0, 0.0])
    with pytest.raises(ValueError, match="n_sweep must be a non-negative integer"):
        read_recording(missing, n_sweep=-1)


# ---------------------------------------------------------------------------
# errors
# ---------------------------------------------------------------------------
@pytest.fixture
def rig_csv(tmp_path, poses):
    return _write(_rig_frame(poses), tmp_path / "rig.csv")


@pytest.fixture
def standard_csv(tmp_path, poses):
    return _write(_standard_frame(poses), tmp_path / "std.csv")


_DROP = object()  # marks a keyword of RIG_KWARGS to leave out


def _rig_error(path, match, **changes):
    kwargs = {**RIG_KWARGS, **changes}
    kwargs = {k: v for k, v in kwargs.items() if v is not _DROP}
    with pytest.raises(ValueError, match=match):
        read_recording(path, **kwargs)



def test_unsupported_suffix(tmp_path):
    path = tmp_path / "rec.xlsx"
    path.write_text("x")
    with pytest.raises(ValueError, match=r"path.*CSV.*Parquet.*rec\.xlsx"):
        read_recording(path)


def test_missing_pyarrow_message(tmp_path, monkeypatch):
    path = tmp_path / "rec.parquet"
    path.write_bytes(b"")

    def no_engine(*args, **kwargs):
        raise ImportError("Unable to find a usable engine")

    monkeypatch.setattr(pd, "read_parquet", no_engine)
    with pytest.raises(ImportError, match="pip install pyarrow"):
        read_recording(path)


def test_empty_file(tmp_path, poses):
    path = _write(_standard_frame(poses).iloc[:0], tmp_path / "rec.csv")
    with pytest.raises(ValueError, match="no rows"):
        read_recording(path)


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"columns": {**RIG_COLUMNS, "q1": "encoder"}}, r"'q1'.*'encoder'.*does not have"),
        ({"columns": {**RIG_COLUMNS, "speed": "enc"}}, r"unknown key 'speed'"),
        ({"columns": {**RIG_COLUMNS, "q1": 3}}, r"columns\['q1'\].*file column name"),
        (
            {"columns": {**RIG_COLUMNS, "tip_orientation": ["tq0", "tq1", "tq2"]}},
            r"columns\['tip_orientation'\] must be 4 file column names in the order 'xyzw'",
        ),
        (
            {"columns": {**RIG_COLUMNS, "tip_position": "tx"}},
            r"columns\['tip_position'\] must be 3 file column names",
        ),
        ({"columns": {**RIG_COLUMNS, "tip_px": "tx"}}, r"group 'tip_position'.*'tip_px'"),
        ({"columns": ["q1"]}, r"columns must be a mapping"),
        ({"constants": {"tau2": 0.0}}, r"no 'q2' column.*constants"),
        ({"constants": {"q2": 0.0, "tau2": 0.0, "q1": 1.0}}, r"constants sets 'q1'.*'enc'"),
        ({"constants": {"q2": np.nan, "tau2": 0.0}}, r"constants\['q2'\] must be a finite"),
        ({"constants": {"q2": "0", "tau2": 0.0}}, r"constants\['q2'\]"),
        ({"constants": {"t": 0.0}}, r"constants has the key 't'"),
        ({"scale": {"q2": 2.0}}, r"scale.*'q2'.*not read from the file"),
        ({"scale": {"q1": 0.0}}, r"scale\['q1'\] must be a finite nonzero"),
        ({"scale": {"tip_qw": 2.0}}, r"scale has the key 'tip_qw'"),
        ({"rate_hz": _DROP}, r"no time column 't'.*rate_hz"),
        ({"rate_hz": -1.0}, r"rate_hz must be a positive"),
        ({"n_sweep": _DROP}, r"no 'phase' column.*n_sweep"),
        ({"n_sweep": 3, "phase": "sweep"}, r"either phase.*or n_sweep"),
        ({"n_sweep": 2.5}, r"n_sweep must be a non-negative integer"),
        ({"n_sweep": N + 1}, r"n_sweep=13.*only 12 samples"),
        ({"phase": "calibration", "n_sweep": _DROP}, r"phase must be one of"),
        ({"catheter": _DROP}, r"no 'catheter' column.*catheter="),
        ({"setting": 1.5}, r"setting must be a string or an integer"),
        ({"quat_order": "zyxw"}, r"quat_order must be one of"),
        ({"valid": "quality"}, r"status column 'quality'"),
        ({"valid": ("quality", [])}, r"valid must be a file column name"),
        ({"tip_offset": [0, 0]}, r"tip_offset must be three finite numbers"),
    ],
)
def test_argument_and_mapping_errors(rig_csv, changes, match):
    _rig_error(rig_csv, match, **changes)


def test_non_numeric_values_name_file_and_skcath_column(tmp_path, poses):
    frame = _rig_frame(poses)
    frame["enc"] = frame["enc"].astype(object)
    frame.loc[5, "enc"] = "n/a?"
    path = _write(frame, tmp_path / "rec.csv")
    _rig_error(path, r"file column 'enc' \(skcath column 'q1'\).*'n/a\?'.*row 5")


def test_non_numeric_pose_value(tmp_path, poses):
    frame = _rig_frame(poses)
    frame["bq2"] = frame["bq2"].astype(object)
    frame.loc[1, "bq2"] = "MISSING"
    path = _write(frame, tmp_path / "rec.csv")
    _rig_error(path, r"file column 'bq2' \(skcath column 'base_qz'\)")


def test_zero_quaternion_names_column_and_row(tmp_path, poses):
    frame = _standard_frame(poses)
    frame.loc[4, ["base_qw", "base_qx", "base_qy", "base_qz"]] = 0.0
    path = _write(frame, tmp_path / "rec.csv")
    with pytest.raises(ValueError, match=r"rec\.csv.*base_orientation.*row 4"):
        read_recording(path)


def test_no_target_columns(tmp_path, poses):
    frame = _rig_frame(poses).drop(columns=["bq3"])
    path = _write(frame, tmp_path / "rec.csv")
    columns = {k: v for k, v in RIG_COLUMNS.items() if k != "base_orientation"}
    _rig_error(
        path,
        r"no target found.*sensor-pose columns \(missing: \['base_qw'.*'p_x', 'p_y', 'p_z'",
        columns=columns,
    )


def test_tip_offset_needs_tip_orientation(tmp_path, poses):
    columns = {k: v for k, v in RIG_COLUMNS.items() if k != "tip_orientation"}
    path = _write(_rig_frame(poses), tmp_path / "rec.csv")
    _rig_error(path, r"tip_offset needs the sensor-pose columns.*tip_qx", columns=columns,
               tip_offset=[0, 0, 5])


def test_bad_phase_values(tmp_path, poses):
    frame = _standard_frame(poses)
    frame.loc[8, "phase"] = "free"
    path = _write(frame, tmp_path / "rec.csv")
    with pytest.raises(ValueError, match=r"column 'phase'.*'free'.*row 8"):
        read_recording(path)


def test_phase_given_twice(standard_csv):
    with pytest.raises(ValueError, match=r"n_sweep was given.*'phase'"):
        read_recording(standard_csv, n_sweep=3)


def test_id_given_twice(standard_csv):
    with pytest.raises(ValueError, match=r"run='x' was given.*'run'"):
        read_recording(standard_csv, run="x")


def test_time_given_twice(standard_csv):
    with pytest.raises(ValueError, match=r"rate_hz was given.*'t'"):
        read_recording(standard_csv, rate_hz=10.0)


def test_partial_reference_columns(tmp_path, poses):
    frame = _standard_frame(poses)
    frame["ref_x"] = 1.0
    path = _write(frame, tmp_path / "rec.csv")
    with pytest.raises(ValueError, match=r"\['ref_x'\] but not \['ref_y', 'ref_z'\]"):
        read_recording(path)


def test_empty_id_cell(tmp_path, poses):
    frame = _standard_frame(poses)
    frame.loc[3, "catheter"] = None
    path = _write(frame, tmp_path / "rec.csv")
    with pytest.raises(ValueError, match=r"column 'catheter' has 1 empty cell.*row 3"):
        read_recording(path)


def test_invalid_recording_is_rejected(tmp_path, poses):
    frame = _standard_frame(poses)
    frame.loc[6, "t"] = frame.loc[5, "t"]  # time not strictly increasing
    path = _write(frame, tmp_path / "rec.csv")
    with pytest.raises(ValueError, match=r"rec\.csv.*not valid.*'t'.*strictly increasing"):
        read_recording(path)


# ---------------------------------------------------------------------------
# real recordings: TEE probe with two bending motors (one moves per file)
# ---------------------------------------------------------------------------
def _tee_dir():
    shared = os.environ.get("SKCATH_SHARED")
    base = Path(shared) if shared else Path(__file__).resolve().parents[2] / "shared"
    return base / "data" / "tee-probe"


TEE_FILES = [f"motor{m}_current60_acq{a}.csv" for m in (1, 2) for a in (1, 2, 3)]
TEE_RATE_HZ = 10.0  # the files have no time stamps and the rate is unknown


def _tee_columns(motor, orientation_order="xyzw"):
    """Column map of the TEE files; the moving motor is q1 (motor1) or q2 (motor2)."""
    columns = {f"q{motor}": "motor_position", f"tau{motor}": "current"}
    for sensor in ("tip", "base"):
        columns[f"{sensor}_position"] = [f"{sensor}_position_{a}" for a in "xyz"]
        columns[f"{sensor}_orientation"] = [f"{sensor}_orientation_{a}" for a in orientation_order]
    return columns


def _read_tee(name, quat_order="xyzw"):
    motor = int(name[len("motor")])
    other = 3 - motor
    # The file lists its quaternion columns as x, y, z, w. Reading them with
    # quat_order="xyzw" is the correct interpretation; "wxyz" treats x as w.
    return read_recording(
        _tee_dir() / name,
        columns=_tee_columns(motor),
        quat_order=quat_order,
        constants={f"q{other}": 0.0, f"tau{other}": 0.0},
        catheter="tee-probe",
        setting="current60",
        rate_hz=TEE_RATE_HZ,
        phase="sweep",
    )


@pytest.fixture(scope="module")
def tee():
    if not _tee_dir().is_dir():
        pytest.skip(f"TEE-probe recordings not found at {_tee_dir()}")
    return {name: _read_tee(name) for name in TEE_FILES}


def _moving_motor(X):
    return X["q1"].to_numpy() if X["q1"].abs().max() > 0 else X["q2"].to_numpy()


def test_tee_all_files_read(tee):
    assert sorted(tee) == sorted(TEE_FILES)
    for name, (X, y) in tee.items():
        raw = pd.read_csv(_tee_dir() / name, usecols=["sample"])
        assert len(X) == len(raw) > 1000
        assert list(X.columns) == list(REQUIRED_COLUMNS)
        assert np.isfinite(y).all()
        assert set(X["run"]) == {name[: -len(".csv")]}
        assert_allclose(np.diff(X["t"]), 1.0 / TEE_RATE_HZ)
    X_all = pd.concat([X for X, _ in tee.values()], ignore_index=True)
    y_all = np.vstack([y for _, y in tee.values()])
    check_recordings(X_all, y_all)  # the six runs form a valid data set


def test_tee_tip_distance_from_base(tee):
    # SOURCE.md: the tip lies about 76-88 mm from the base sensor (measured 76.4-87.9 mm)
    for _, y in tee.values():
        distance = np.linalg.norm(y, axis=1)
        assert distance.min() > 70.0
        assert distance.max() < 95.0


def test_tee_tip_moves_while_base_sensor_is_static(tee):
    for name, (_, y) in tee.items():
        raw = pd.read_csv(_tee_dir() / name)
        base = raw[[f"base_position_{a}" for a in "xyz"]].to_numpy()
        assert np.ptp(base, axis=0).max() < 1.0  # mm (measured at most 0.55 mm)
        assert np.ptp(y, axis=0).max() > 40.0  # mm (measured 54-63 mm)


def test_tee_bending_is_planar(tee):
    # One motor bends the section in one plane: the smallest singular value of the
    # centred positions is about 1 % of the largest (measured 0.007-0.015). The
    # base sensor barely rotates, so this ratio does not depend on the quaternion
    # order; test_tee_quaternion_order checks the order.
    for _, y in tee.values():
        s = np.linalg.svd(y - y.mean(axis=0), compute_uv=False)
        assert s[2] / s[0] < 0.03


def _plane_normal(points):
    return np.linalg.svd(points - points.mean(axis=0))[2][2]


def _tip_turn_axis_alignment(name, quat_order, y):
    """Mean |cos| between the tip's rotation axis (base frame) and the bending-plane normal.

    In planar bending the tip sensor turns about the normal of the bending
    plane. The turn since the first sample is computed from the tip and base
    quaternions of the file read in ``quat_order``, for samples turned by more
    than 10 degrees.
    """
    raw = pd.read_csv(_tee_dir() / name)
    # the four file columns, in file order (x, y, z, w), interpreted as quat_order,
    # exactly as read_recording does with the orientation groups of _tee_columns
    q_tip = raw[[f"tip_orientation_{c}" for c in "xyzw"]].to_numpy()
    q_base = raw[[f"base_orientation_{c}" for c in "xyzw"]].to_numpy()
    r_tip_in_base = quaternion_to_rotation(q_base, quat_order).inv() * quaternion_to_rotation(
        q_tip, quat_order
    )
    turn = (r_tip_in_base * r_tip_in_base[0].inv()).as_rotvec()
    angle = np.linalg.norm(turn, axis=1)
    bent = angle > np.deg2rad(10.0)
    axes = turn[bent] / angle[bent, None]
    return np.abs(axes @ _plane_normal(y)).mean()


def test_tee_quaternion_order(tee):
    # With the file columns read as x, y, z, w the tip turns about the normal of
    # the bending plane (measured |cos| >= 0.996 on every file); reading the same
    # columns as w, x, y, z gives no such agreement (measured 0.13-0.46).
    for name in TEE_FILES:
        _, y_right = tee[name]
        _, y_wrong = _read_tee(name, quat_order="wxyz")
        assert _tip_turn_axis_alignment(name, "xyzw", y_right) > 0.98
        assert _tip_turn_axis_alignment(name, "wxyz", y_wrong) < 0.6
        # both readings give the same distances (a rotation), but not the same points
        assert_allclose(np.linalg.norm(y_wrong, axis=1), np.linalg.norm(y_right, axis=1))
        assert np.abs(y_wrong - y_right).max() > 10.0


def test_tee_hysteresis_between_loading_and_unloading(tee):
    # Each file: centre -> max -> min -> centre. Half-way between centre and max,
    # the rising branch (centre -> max) and the falling branch (max -> min) differ
    # by several mm (measured 5.2-6.4 mm for motor1, 8.6 mm for motor2), far above
    # the scatter of repeated samples (< 0.4 mm).
    for name, (X, y) in tee.items():
        motor = _moving_motor(X)
        i_max, i_min = int(np.argmax(motor)), int(np.argmin(motor))
        assert 0 < i_max < i_min < len(motor) - 1
        target = 0.5 * (motor[0] + motor[i_max])
        rising = np.flatnonzero(np.abs(motor[:i_max] - target) <= 3)
        falling = i_max + np.flatnonzero(np.abs(motor[i_max:i_min] - target) <= 3)
        assert rising.size and falling.size, name
        gap = np.linalg.norm(y[rising].mean(axis=0) - y[falling].mean(axis=0))
        assert gap > 4.0, (name, gap)
        assert y[rising].std(axis=0).max() < 1.0
        assert y[falling].std(axis=0).max() < 1.0


# ---------------------------------------------------------------------------
# CSV text: compression, dialect, cut last line, unreadable files
# ---------------------------------------------------------------------------
def _text_of(frame, **to_csv):
    return frame.to_csv(index=False, **to_csv)


def _compressed(path, text):
    """Write ``text`` to ``path``, compressed as its suffix says."""
    import bz2
    import gzip
    import lzma
    import zipfile

    data = text.encode()
    if path.name.endswith(".zip"):
        with zipfile.ZipFile(path, "w") as archive:
            archive.writestr("inner.csv", data)
        return path
    openers = {".gz": gzip.compress, ".bz2": bz2.compress, ".xz": lzma.compress}
    path.write_bytes(openers.get(path.suffix, bytes)(data))
    return path


@pytest.mark.parametrize("suffix", [".csv", ".csv.gz", ".csv.bz2", ".csv.xz", ".csv.zip"])
def test_semicolon_decimal_comma_in_every_compression(tmp_path, poses, suffix):
    frame = _standard_frame(poses)
    X_ref, y_ref = read_recording(_write(frame, tmp_path / "ref.csv"))
    path = _compressed(tmp_path / f"lab{suffix}", _text_of(frame, sep=";", decimal=","))
    X, y = read_recording(path)
    pd.testing.assert_frame_equal(X, X_ref)
    np.testing.assert_array_equal(y, y_ref)


def test_windows_line_ends_and_byte_order_mark(tmp_path, poses):
    frame = _standard_frame(poses)
    X_ref, y_ref = read_recording(_write(frame, tmp_path / "ref.csv"))
    path = tmp_path / "excel.csv"
    path.write_bytes(b"\xef\xbb\xbf" + _text_of(frame, sep=";", decimal=",", lineterminator="\r\n").encode())
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a complete file: no warning
        X, y = read_recording(path)
    pd.testing.assert_frame_equal(X, X_ref)
    np.testing.assert_array_equal(y, y_ref)


def test_trailing_blank_lines_are_not_a_cut_line(tmp_path, poses):
    path = tmp_path / "rec.csv"
    path.write_text(_text_of(_standard_frame(poses)) + "\n \n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        X, _ = read_recording(path)
    assert len(X) == N


def test_last_line_without_line_break_is_dropped_even_if_complete(tmp_path, poses):
    """Documented: a missing final line break is the sign of a cut file; the line is not read."""
    path = tmp_path / "handmade.csv"
    path.write_text(_text_of(_standard_frame(poses)).rstrip("\n"))
    with pytest.warns(TruncatedFileWarning, match=r"handmade\.csv: the last line does not end"):
        X, _ = read_recording(path)
    assert len(X) == N - 1


def test_header_without_line_break_is_a_file_without_rows(tmp_path, poses):
    path = tmp_path / "rec.csv"
    path.write_text(_text_of(_standard_frame(poses).iloc[:0]).rstrip("\n"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match=r"rec\.csv: the file has no rows"):
            read_recording(path)


def test_mixed_decimal_marks_are_refused(tmp_path, poses):
    text = _text_of(_standard_frame(poses), sep=";", decimal=",")
    lines = text.split("\n")
    lines[3] = lines[3].replace(",", ".")
    path = tmp_path / "mixed.csv"
    path.write_text("\n".join(lines))
    with pytest.raises(ValueError, match=r"mixed\.csv: .*decimal commas \(e\.g\. '.*'\) and with "
                                         r"decimal points \(e\.g\. '.*'\)"):
        read_recording(path)


def test_wider_line_in_semicolon_file_is_refused(tmp_path, poses):
    lines = _text_of(_standard_frame(poses), sep=";").split("\n")
    lines[4] += ";7"
    path = tmp_path / "wide.csv"
    path.write_text("\n".join(lines))
    with pytest.raises(ValueError, match=r"wide\.csv: line 5 has \d+ fields but the header has "
                                         r"\d+ \(delimiter ';'\); every line needs one field per "
                                         r"column\.$"):
        read_recording(path)


def test_zip_archive_must_hold_one_file(tmp_path, poses):
    import zipfile

    path = tmp_path / "two.csv.zip"
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("a.csv", _text_of(_standard_frame(poses)))
        archive.writestr("b.csv", _text_of(_standard_frame(poses)))
    with pytest.raises(ValueError, match=r"two\.csv\.zip: the zip archive holds 2 files"):
        read_recording(path)


def test_parser_errors_are_chained_and_name_the_file(tmp_path, poses):
    import gzip

    data = gzip.compress(_text_of(_standard_frame(poses)).encode())
    path = tmp_path / "rec.csv.gz"
    path.write_bytes(data[:-20])
    with pytest.raises(ValueError, match=r"^rec\.csv\.gz: cannot be read as CSV: ") as info:
        read_recording(path)
    assert isinstance(info.value.__cause__, EOFError)


def test_errors_that_name_the_file_pass_unchanged(tmp_path):
    from skcath.io._errors import naming_the_file

    path = tmp_path / "rec.csv"
    own = ValueError("rec.csv: a message of the reader")
    for exc in (own, FileNotFoundError(2, "No such file", str(path)), ImportError("pip install x")):
        with pytest.raises(type(exc)) as info:
            with naming_the_file(path, "CSV"):
                raise exc
        assert info.value is exc
    with pytest.raises(ValueError, match=r"^rec\.csv: cannot be read as CSV: \(KeyError: 'x'\)$"):
        with naming_the_file(path, "CSV"):
            raise KeyError("x")


def test_missing_file_is_a_file_not_found_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="nothing.csv"):
        read_recording(tmp_path / "nothing.csv")


# ---------------------------------------------------------------------------
# any number of motors, torques optional
# ---------------------------------------------------------------------------
def test_one_motor_rig_is_read_as_one_motor(tmp_path, poses):
    """Without constants, a file with q1, tau1 alone is a recording of one motor."""
    path = _write(_rig_frame(poses), tmp_path / "rig.csv")
    kwargs = {k: v for k, v in RIG_KWARGS.items() if k != "constants"}
    X, y = read_recording(path, **kwargs)
    assert list(X.columns) == [
        "catheter", "setting", "run", "t", "phase", "q1", "tau1", "ref_x", "ref_y", "ref_z"
    ]
    assert_allclose(X["q1"], np.arange(N) * 100.0)
    assert_allclose(y, poses["p_b"], atol=1e-9)
    # the same file read as two motors, as before, differs only by the constant motor
    X2, y2 = read_recording(path, **RIG_KWARGS)
    pd.testing.assert_frame_equal(X2.drop(columns=["q2", "tau2"]), X)
    assert_allclose(y2, y)


def test_three_motors_by_name_and_by_map(tmp_path, poses):
    frame = _standard_frame(poses).assign(q3=np.linspace(5, -5, N), tau3=np.linspace(2, 3, N))
    X, _ = read_recording(_write(frame, tmp_path / "rec.csv"))
    assert list(X.columns[5:11]) == ["q1", "q2", "q3", "tau1", "tau2", "tau3"]
    assert_allclose(X["q3"], frame["q3"])
    # a third motor under another name, mapped, and scaled
    other = frame.rename(columns={"q3": "motor_c"})
    X_map, _ = read_recording(
        _write(other, tmp_path / "other.csv"), columns={"q3": "motor_c"}, scale={"q3": 2.0}
    )
    assert_allclose(X_map["q3"], 2.0 * frame["q3"])


def test_rig_without_torque_sensing_reads_no_torque(tmp_path, poses):
    frame = _standard_frame(poses).drop(columns=["tau1", "tau2"])
    path = _write(frame, tmp_path / "rec.csv")
    with pytest.raises(ValueError, match=r"no 'tau1' column.*or pass torques=False"):
        read_recording(path)
    X, y = read_recording(path, torques=False)
    assert list(X.columns) == [
        "catheter", "setting", "run", "t", "phase", "q1", "q2", "ref_x", "ref_y", "ref_z"
    ]
    assert_allclose(y, poses["p_b"], atol=1e-9)
    # torque columns in the file are not read with torques=False
    X_with, _ = read_recording(_write(_standard_frame(poses), tmp_path / "t.csv"), torques=False)
    pd.testing.assert_frame_equal(X_with, X)


@pytest.mark.parametrize(
    "options, match",
    [
        ({"torques": "no"}, r"torques must be True .* or False"),
        ({"torques": False, "columns": {"tau1": "cur"}}, r"torques=False reads no torque, but "
         r"columns names \['tau1'\]"),
        ({"torques": False, "constants": {"tau2": 0.0}}, r"but constants names \['tau2'\]"),
        ({"columns": {"q7x": "enc"}}, r"unknown key 'q7x'"),
        ({"constants": {"tau0": 0.0}}, r"constants has the key 'tau0'"),
    ],
)
def test_bad_motor_options_are_refused(options, match):
    with pytest.raises(ValueError, match=match):
        ReadingOptions(**options)


def test_read_recordings_refuses_files_of_other_motors(tmp_path, poses):
    _write(_standard_frame(poses).assign(run="a"), tmp_path / "a.csv")
    _write(_standard_frame(poses).assign(run="b", q3=1.0, tau3=0.0), tmp_path / "b.csv")
    with pytest.raises(ValueError, match=r"b\.csv has the channels \['q1', 'q2', 'q3', 'tau1', "
                       r"'tau2', 'tau3'\] but a\.csv has \['q1', 'q2', 'tau1', 'tau2'\]"):
        read_recordings(tmp_path, progress=False)
