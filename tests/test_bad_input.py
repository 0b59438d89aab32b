"""Catalogue of bad inputs: each is rejected with a clear message or masked as documented.

Every case starts from a small valid recording, breaks it in one way and
checks where it is caught (``check_recordings``, a backbone calibrating on the
sweep, ``read_recording`` or ``tip_in_base_frame``), that the message names
the column or run and says what was expected, and that the input is left
unchanged. The table of these cases is in ``docs/bad_input.rst``.
"""

import copy
import json
import logging
import os
import pickle
import re
import warnings
import zipfile
from decimal import Decimal

import joblib
import numpy as np
import pandas as pd
import pytest
import torch
from sklearn.exceptions import NotFittedError
from sklearn.frozen import FrozenEstimator
from sklearn.model_selection import KFold, cross_val_score, cross_validate
from sklearn.pipeline import Pipeline

from skcath import persist
from skcath._validation import check_recordings
from skcath.backbones import PDLBackbone
from skcath.datasets import make_benchmark
from skcath.exceptions import (
    FileSuffixWarning,
    GroupsNotUsedWarning,
    PipelineChangedWarning,
    TruncatedFileWarning,
)
from skcath.frames import tip_in_base_frame
from skcath.io import read_recording, read_recordings, read_streams
from skcath.model_selection import BlockKFold, LeaveOneSettingOut
from skcath.online import MotorRecalibration, OnlineEstimator, ShaftChangeDetector
from skcath.residuals import GRUResidual, NoResidual
from skcath.sweep import find_rays
from test_sweep_end import _export as _rig_export
from test_validation import make_recordings

REFERENCE = ["ref_x", "ref_y", "ref_z"]
TARGET = ["p_x", "p_y", "p_z"]


# ---------------------------------------------------------------------------
# valid starting points
# ---------------------------------------------------------------------------
def tiny_recordings(n_runs=2, n_sweep=4, n_motion=5, seed=0):
    """Small valid recordings: runs ``r0, r1, ...`` one after another, labels from 100."""
    return make_recordings(n_runs=n_runs, n_sweep=n_sweep, n_motion=n_motion, seed=seed)


@pytest.fixture(scope="module")
def bench():
    """Two simulated runs (one catheter) with full 8-ray sweeps, rows relabelled 0..n-1."""
    data = make_benchmark(n_catheters=1, n_runs=1, random_state=0)
    runs = data.X["run"].unique()[:2]
    keep = data.X["run"].isin(runs).to_numpy()
    X = data.X[keep].reset_index(drop=True)
    X["run"] = X["run"].astype(str)
    return X, np.asarray(data.y)[keep]


@pytest.fixture(scope="module")
def tiny():
    return tiny_recordings()


# ---------------------------------------------------------------------------
# breakers: each takes copies (X, y) and returns the broken (X, y)
# ---------------------------------------------------------------------------
def _rows(X, run, phase=None):
    """Row labels of ``run`` (optionally only of ``phase``)."""
    mask = X["run"] == run
    if phase is not None:
        mask &= X["phase"] == phase
    return X.index[mask]


def _first_run(X):
    return X["run"].iloc[0]


def _set(column, value, run="r1", step=2):
    def breaker(X, y):
        if value is not None and not isinstance(value, float):
            X[column] = X[column].astype(object)
        X.loc[_rows(X, run)[step], column] = value
        return X, y

    return breaker


def _drop_column(column):
    return lambda X, y: (X.drop(columns=column), y)


def _swap_times(X, y):
    rows = _rows(X, "r0")
    X.loc[[rows[1], rows[2]], "t"] = X.loc[[rows[2], rows[1]], "t"].to_numpy()
    return X, y


def _repeat_time(X, y):
    rows = _rows(X, "r1")
    X.loc[rows[5], "t"] = X.loc[rows[4], "t"]
    return X, y


def _reuse_run_id(column):
    def breaker(X, y):
        X[column] = X[column].astype(object)
        X.loc[_rows(X, "r1")[-1], column] = f"{column[0]}-other"
        return X, y

    return breaker


def _sweep_after_motion(X, y):
    X.loc[_rows(X, "r0")[-1], "phase"] = "sweep"
    return X, y


def _phase_label(label):
    def breaker(X, y):
        X["phase"] = X["phase"].astype(object)
        X.loc[_rows(X, "r0")[0], "phase"] = label
        return X, y

    return breaker


def _no_sweep_rows(X, y):
    X.loc[_rows(X, "r1"), "phase"] = "motion"
    X.loc[_rows(X, "r1"), REFERENCE] = np.nan
    return X, y


def _as_dtype(column, dtype):
    def breaker(X, y):
        if dtype == "bool":
            X[column] = X[column] > 0
        elif dtype == "datetime":
            X[column] = pd.Timestamp("2026-01-01") + pd.to_timedelta(X[column], unit="s")
        elif dtype == "complex":
            X[column] = X[column].astype(complex)
        return X, y

    return breaker


def _unhashable_run_ids(X, y):
    X["run"] = [[run] for run in X["run"]]
    return X, y


def _duplicate_column(X, y):
    return pd.concat([X, X[["q1"]]], axis=1), y


def _y_rows(n):
    return lambda X, y: (X, y[:n])


def _y_value(value, row=3, col=1):
    def breaker(X, y):
        if isinstance(value, str):
            y = y.astype(object)
        y[row, col] = value
        return X, y

    return breaker


# breakers on the simulated runs (the backbone calibrates on their sweeps)
def _one_run(X, y, n_rows=None):
    rows = np.flatnonzero((X["run"] == _first_run(X)).to_numpy())[:n_rows]
    return X.iloc[rows].reset_index(drop=True), y[rows]


def _drop_one_ray(X, y):
    run = _first_run(X)
    sweep = ((X["run"] == run) & (X["phase"] == "sweep")).to_numpy()
    rays = find_rays(X.loc[sweep, ["q1", "q2"]].to_numpy())
    labels = np.full(len(X), -2)
    labels[sweep] = rays.labels
    keep = labels != labels[sweep][rays.labels >= 0][0]
    return X[keep].reset_index(drop=True), y[keep]


def _stuck_q2(X, y):
    X.loc[_rows(X, _first_run(X), "sweep"), "q2"] = 0.0
    return X, y


def _radians(X, y):
    X[["q1", "q2"]] = np.deg2rad(X[["q1", "q2"]])
    return X, y


def _metres(X, y):
    X[REFERENCE] = X[REFERENCE] / 1000.0
    return X, y / 1000.0


def _drop_most_references(X, y):
    rows = _rows(X, _first_run(X), "sweep")
    X.loc[rows[: int(0.9 * len(rows))], REFERENCE] = np.nan
    return X, y


# ---------------------------------------------------------------------------
# where the case is caught
# ---------------------------------------------------------------------------
def _check(X, y):
    check_recordings(X, y)


def _backbone(X, y):
    PDLBackbone().fit(X).predict(X)


def _standard_file(X, y):
    """The frame and its target as one file with the standard column names."""
    frame = X.copy()
    frame[TARGET] = y
    return frame


CATCHERS = {"check": _check, "backbone": _backbone}

REJECTED = [
    # --- columns and dtypes (check_recordings) ---
    pytest.param("tiny", _drop_column("q1"), "check", ValueError,
                 r"missing the column\(s\) \['q1'\]", id="missing-column"),
    pytest.param("tiny", _duplicate_column, "check", ValueError,
                 r"column\(s\) \['q1'\] more than once", id="duplicated-column"),
    pytest.param("tiny", _as_dtype("q1", "bool"), "check", ValueError,
                 r"Column 'q1' must hold real numbers .*got dtype bool", id="bool-dtype"),
    pytest.param("tiny", _as_dtype("t", "datetime"), "check", ValueError,
                 r"Column 't' must hold real numbers .*datetime", id="datetime-time"),
    pytest.param("tiny", _as_dtype("tau2", "complex"), "check", ValueError,
                 r"Column 'tau2' must hold real numbers .*complex", id="complex-dtype"),
    pytest.param("tiny", _set("q1", "12,5"), "check", ValueError,
                 r"Column 'q1' must be numeric.*first '12,5' at run 'r1'",
                 id="string-not-a-number"),
    pytest.param("tiny", _unhashable_run_ids, "check", ValueError,
                 r"Column 'run' must hold hashable ids", id="unhashable-run-ids"),
    pytest.param("tiny", _set("run", None), "check", ValueError,
                 r"Column 'run' contains 1 missing id", id="missing-run-id"),
    # --- values ---
    pytest.param("tiny", _set("q2", np.nan), "check", ValueError,
                 r"Column 'q2' contains 1 non-finite value\(s\) \(every value must be "
                 r"finite\); first NaN at run 'r1'", id="nan-motor"),
    pytest.param("tiny", _set("tau1", np.inf), "check", ValueError,
                 r"Column 'tau1' contains 1 non-finite .*first inf at run 'r1'",
                 id="inf-torque"),
    pytest.param("tiny", _set("ref_x", -np.inf, step=1), "check", ValueError,
                 r"Column 'ref_x' .*NaN \(tracker dropout\) is allowed but \+-inf is not"
                 r".*run 'r1'", id="inf-reference"),
    pytest.param("tiny", _set("q1", 1e300), "check", ValueError,
                 r"Column 'q1' contains 1 value\(s\) larger than 1e\+12 .*run 'r1'"
                 r".*degrees, s, mm", id="huge-motor-angle"),
    pytest.param("tiny", _set("t", -3.0e38, step=0), "check", ValueError,
                 r"Column 't' contains 1 value\(s\) larger than 1e\+12 .*run 'r1'",
                 id="fill-value-time"),
    # --- time axis ---
    pytest.param("tiny", _swap_times, "check", ValueError,
                 r"Column 't' must be strictly increasing within each run.*run 'r0'",
                 id="non-monotonic-time"),
    pytest.param("tiny", _repeat_time, "check", ValueError,
                 r"Column 't' must be strictly increasing within each run.*run 'r1' "
                 r"goes from t=0\.54 s .* to t=0\.54 s", id="duplicated-timestamp"),
    # --- ids and phases ---
    pytest.param("tiny", _reuse_run_id("catheter"), "check", ValueError,
                 r"Run id 'r1' is used for several catheters .*exactly one catheter",
                 id="run-id-reused-across-catheters"),
    pytest.param("tiny", _reuse_run_id("setting"), "check", ValueError,
                 r"Run id 'r1' is used for several settings", id="run-id-reused-across-settings"),
    pytest.param("tiny", lambda X, y: (X.iloc[:0], y[:0]), "check", ValueError,
                 r"empty DataFrame \(0 rows\)", id="empty-recording"),
    pytest.param("tiny", _no_sweep_rows, "check", ValueError,
                 r"Run\(s\) 'r1' have no 'sweep' rows", id="run-without-sweep"),
    pytest.param("tiny", _sweep_after_motion, "check", ValueError,
                 r"In run 'r0' a 'sweep' row .* follows a 'motion' row", id="sweep-after-motion"),
    pytest.param("tiny", _phase_label("calibration"), "check", ValueError,
                 r"Column 'phase' must contain only \['sweep', 'motion'\]; found invalid "
                 r"value\(s\) 'calibration'", id="unknown-phase-label"),
    pytest.param("tiny", _phase_label("Sweep"), "check", ValueError,
                 r"Column 'phase' must contain only .*'Sweep'", id="capitalised-phase-label"),
    pytest.param("tiny", _phase_label(None), "check", ValueError,
                 r"Column 'phase' must contain only .*\(1 missing\)", id="missing-phase-label"),
    # --- target ---
    pytest.param("tiny", _y_rows(5), "check", ValueError,
                 r"y has 5 rows but the recordings X have 18", id="mismatched-y-length"),
    pytest.param("tiny", lambda X, y: (X, y[:, :2]), "check", ValueError,
                 r"y must have shape \(n_rows, 3\) .*got shape \(18, 2\)", id="y-two-columns"),
    pytest.param("tiny", _y_value(np.inf), "check", ValueError,
                 r"y contains 1 infinite value\(s\); first in column 'p_y'", id="inf-target"),
    pytest.param("tiny", _y_value(1e30), "check", ValueError,
                 r"y contains 1 value\(s\) larger than 1e\+12 .*'p_y'", id="huge-target"),
    pytest.param("tiny", _y_value("n/a"), "check", ValueError,
                 r"y column 1 \('p_y'\) must be numeric \(mm\); value 'n/a'",
                 id="string-in-target"),
    # --- sweep content (caught when a backbone calibrates each run) ---
    pytest.param("bench", _drop_one_ray, "backbone", ValueError,
                 r"Rays missing in the sweep of run '\S+': found 7 .*expected n_rays=8",
                 id="missing-sweep-ray"),
    pytest.param("bench", _stuck_q2, "backbone", ValueError,
                 r"Motor column 'q2' does not move during the sweep of run '\S+'",
                 id="stuck-motor"),
    pytest.param("bench", _radians, "backbone", ValueError,
                 r"motors do not move during the sweep of run '\S+'.*in degrees.*radians",
                 id="motor-angles-in-radians"),
    pytest.param("bench", _metres, "backbone", ValueError,
                 r"reference tip positions in run '\S+' do not move.*must be in mm; "
                 r"if they are in metres", id="reference-in-metres"),
    pytest.param("bench", lambda X, y: _one_run(X, y, 1), "backbone", ValueError,
                 r"sweep of run '\S+' has 1 samples; expected at least 80",
                 id="single-sample-run"),
    pytest.param("bench", _drop_most_references, "backbone", ValueError,
                 r"Too few finite reference tip positions in run '\S+'.*ref_x, ref_y, ref_z",
                 id="tracker-dropout-on-most-of-sweep"),
]


def _copy(value):
    return value.copy(deep=True) if isinstance(value, pd.DataFrame) else copy.deepcopy(value)


def _assert_unchanged(before, after):
    if isinstance(before, pd.DataFrame):
        pd.testing.assert_frame_equal(after, before)
    else:
        np.testing.assert_array_equal(np.asarray(after), np.asarray(before))


@pytest.mark.parametrize("source, breaker, where, error, match", REJECTED)
def test_bad_input_is_rejected(request, source, breaker, where, error, match):
    X, y = request.getfixturevalue(source)
    X_bad, y_bad = breaker(X.copy(deep=True), y.copy())
    X_before, y_before = _copy(X_bad), _copy(y_bad)
    with pytest.raises(error, match=match):
        CATCHERS[where](X_bad, y_bad)
    _assert_unchanged(X_before, X_bad)
    _assert_unchanged(y_before, y_bad)


@pytest.mark.parametrize(
    "X",
    [
        pytest.param(np.zeros((3, 12)), id="ndarray-instead-of-frame"),
        pytest.param({"run": ["r0"], "t": [0.0]}, id="dict-instead-of-frame"),
    ],
)
def test_not_a_frame_is_a_type_error(X):
    before = copy.deepcopy(X)
    with pytest.raises(TypeError, match=r"expects the long recording format: a pandas DataFrame"):
        check_recordings(X)
    if isinstance(X, dict):
        assert X == before
    else:
        np.testing.assert_array_equal(X, before)


# ---------------------------------------------------------------------------
# readers
# ---------------------------------------------------------------------------
READER_REJECTED = [
    pytest.param(lambda F: F.drop(columns="q2"), r"file has no 'q2' column; map it with "
                 r"columns=\{'q2': \.\.\.\} or set it with constants", id="reader-missing-column"),
    pytest.param(lambda F: F.assign(q1=F["q1"].astype(object).where(F.index != 3, "abc")),
                 r"column 'q1' must hold numbers; 1 value\(s\) are not numeric, first 'abc'",
                 id="reader-string-not-a-number"),
    pytest.param(lambda F: F.assign(t=F["t"].where(F.index != 5, F["t"][4])),
                 r"recording read is not valid: Column 't' must be strictly increasing.*"
                 r"run 'r0'", id="reader-duplicated-timestamp"),
    pytest.param(lambda F: F.assign(tau2=F["tau2"].where(F.index != 2, 1e20)),
                 r"recording read is not valid: Column 'tau2' contains 1 value\(s\) larger",
                 id="reader-huge-value"),
    pytest.param(lambda F: F.iloc[:0], r"file has no rows", id="reader-empty-file"),
]


@pytest.mark.parametrize("breaker, match", READER_REJECTED)
def test_bad_file_is_rejected(tmp_path, breaker, match):
    X, y = tiny_recordings(n_runs=1)
    frame = breaker(_standard_file(X, y).reset_index(drop=True))
    before = frame.copy(deep=True)
    path = tmp_path / "rec.csv"
    frame.to_csv(path, index=False)
    with pytest.raises(ValueError, match=r"rec\.csv: (the )?" + match):
        read_recording(path)
    pd.testing.assert_frame_equal(frame, before)


def test_unknown_reading_option_names_the_options():
    """A reader that passes options on to read_recording lists them all, in order."""
    X, y = tiny_recordings(n_runs=1)
    motors = X.drop(columns=REFERENCE)
    tracker = _standard_file(X, y)[["t", *TARGET]]
    before = motors.copy(deep=True), tracker.copy(deep=True)
    options = [
        "columns", "quat_order", "catheter", "setting", "run", "rate_hz",
        "constants", "scale", "phase", "n_sweep", "valid", "tip_offset", "torques",
    ]
    expected = (
        "read_streams() got the unknown keyword argument(s) ['nsweep']; the reading "
        f"options are {options}."
    )
    with pytest.raises(TypeError, match=re.escape(expected)):
        read_streams(motors, tracker, tolerance=0.01, nsweep=4)
    # the options left out take read_recording's defaults
    X_read, y_read, _ = read_streams(motors, tracker, tolerance=0.01)
    X_all, y_all, _ = read_streams(
        motors, tracker, tolerance=0.01, columns=None, quat_order="wxyz", catheter=None,
        setting=None, run=None, constants=None, scale=None, phase=None, n_sweep=None,
        valid=None, tip_offset=None,
    )
    pd.testing.assert_frame_equal(X_all, X_read)
    np.testing.assert_array_equal(y_all, y_read)
    np.testing.assert_allclose(y_read, y)
    pd.testing.assert_frame_equal(motors, before[0])
    pd.testing.assert_frame_equal(tracker, before[1])


def test_reader_keeps_tracker_dropouts_as_nan(tmp_path):
    """Documented masking: a dropped tracker sample keeps its row with a NaN target."""
    X, y = tiny_recordings(n_runs=1)
    y[[2, 6]] = np.nan
    frame = _standard_file(X, y).reset_index(drop=True)
    frame.to_csv(tmp_path / "rec.csv", index=False)
    X_read, y_read = read_recording(tmp_path / "rec.csv")
    assert len(X_read) == len(X)
    np.testing.assert_array_equal(np.isnan(y_read).all(axis=1), np.isnan(y).all(axis=1))
    np.testing.assert_allclose(y_read[~np.isnan(y).any(axis=1)], y[~np.isnan(y).any(axis=1)])


# ---------------------------------------------------------------------------
# readers: orientation order, cut and foreign CSV files, unreadable files,
# missing columns, clock units of two streams
# ---------------------------------------------------------------------------
def _scalar_last_pose_file(X, y, seed=0):
    """The recording as a tracker export: sensor poses under other names, quaternions x, y, z, w."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    r_wb = Rotation.random(len(y), random_state=rng)
    p_wb = rng.uniform(-100.0, 100.0, size=(len(y), 3))
    frame = X.drop(columns=REFERENCE).reset_index(drop=True)
    for j, axis in enumerate("xyz"):
        frame[f"tip_{axis}"] = p_wb[:, j] + r_wb.apply(y)[:, j]
        frame[f"base_{axis}"] = p_wb[:, j]
    for j, axis in enumerate("xyzw"):
        frame[f"base_r{axis}"] = r_wb.as_quat()[:, j]
    columns = {
        "tip_position": ["tip_x", "tip_y", "tip_z"],
        "base_position": ["base_x", "base_y", "base_z"],
        "base_orientation": ["base_rx", "base_ry", "base_rz", "base_rw"],
    }
    return frame, columns


def test_orientation_group_without_quat_order_is_refused(tmp_path):
    """A mapped orientation group names no component order: quat_order is required."""
    X, y = tiny_recordings(n_runs=1)
    frame, columns = _scalar_last_pose_file(X, y)
    frame.to_csv(tmp_path / "export.csv", index=False)
    match = (
        r"columns\['base_orientation'\] maps the base orientation to the file "
        r"columns \['base_rx', 'base_ry', 'base_rz', 'base_rw'\], but quat_order is not given"
        r".*quat_order='wxyz' .*scalar first.*quat_order='xyzw' .*scalar last"
    )
    with pytest.raises(ValueError, match=match):
        read_recording(tmp_path / "export.csv", columns=columns)
    _, y_read = read_recording(tmp_path / "export.csv", columns=columns, quat_order="xyzw")
    np.testing.assert_allclose(y_read, y, atol=1e-9)
    # the skcath names are scalar first by name and need no quat_order
    standard = _standard_file(X, y).reset_index(drop=True)
    standard.to_csv(tmp_path / "standard.csv", index=False)
    np.testing.assert_allclose(read_recording(tmp_path / "standard.csv")[1], y)


@pytest.mark.parametrize(
    "dropped, match",
    [
        pytest.param(["catheter"], r"file has no 'catheter' column", id="no-catheter"),
        pytest.param(["t"], r"file has no time column 't'", id="no-time"),
        pytest.param(["phase"], r"file has no 'phase' column", id="no-phase"),
        pytest.param(["tau2"], r"file has no 'tau2' column", id="no-torque"),
        pytest.param(["p_z"], r"no target found.*missing: \['p_z'\]", id="no-target"),
        pytest.param(["ref_y"], r"reference column\(s\) \['ref_x', 'ref_z'\] but not", id="part-ref"),
    ],
)
def test_reader_missing_column_lists_the_file_columns(tmp_path, dropped, match):
    """A column the reader misses is named together with the columns the file has."""
    X, y = tiny_recordings(n_runs=1)
    frame = _standard_file(X, y).reset_index(drop=True).drop(columns=dropped)
    frame.to_csv(tmp_path / "rec.csv", index=False)
    found = re.escape(f"file columns: {list(frame.columns)}.")
    with pytest.raises(ValueError, match=rf"rec\.csv: .*{match}.*{found}$"):
        read_recording(tmp_path / "rec.csv")


def _recording_csv(path, **to_csv):
    """Write a one-run recording in the skcath names; return the frame written."""
    X, y = tiny_recordings(n_runs=1)
    frame = _standard_file(X, y).reset_index(drop=True)
    frame.to_csv(path, index=False, **to_csv)
    return frame


def _cut_in_last_number(text):
    return text.rstrip("\n")[:-3]  # a number cut short, no line break


def _cut_in_last_line(text):
    body = text.rstrip("\n")
    return body[: body.rfind("\n") + 40]  # the line stops after a few fields


def _cut_with_line_break(text):
    return _cut_in_last_line(text) + "\n"  # fewer fields than the header, then a break


@pytest.mark.parametrize("cut", [_cut_in_last_number, _cut_in_last_line, _cut_with_line_break])
@pytest.mark.parametrize("suffix", [".csv", ".csv.gz"])
def test_cut_last_line_is_dropped_with_a_warning(tmp_path, cut, suffix):
    """A recording interrupted while written: its last line is dropped, with a warning naming the file."""
    import gzip

    frame = _recording_csv(tmp_path / "full.csv")
    text = cut((tmp_path / "full.csv").read_text())
    path = tmp_path / f"cut{suffix}"
    path.write_bytes(gzip.compress(text.encode()) if suffix == ".csv.gz" else text.encode())
    with pytest.warns(TruncatedFileWarning, match=rf"cut\.csv(\.gz)?: the last line .*dropped"):
        X_read, y_read = read_recording(path)
    expected, y_expected = read_recording(tmp_path / "full.csv")
    pd.testing.assert_frame_equal(X_read, expected.iloc[:-1])
    np.testing.assert_array_equal(y_read, y_expected[:-1])
    assert len(X_read) == len(frame) - 1


@pytest.mark.parametrize(
    "sep, decimal", [(";", ","), (";", "."), ("\t", ",")], ids=["semicolon-comma", "semicolon-point", "tab-comma"]
)
def test_european_csv_is_read_like_the_standard_one(tmp_path, sep, decimal):
    """The delimiter and the decimal mark are found in the file."""
    _recording_csv(tmp_path / "standard.csv")
    _recording_csv(tmp_path / "lab.csv", sep=sep, decimal=decimal)
    X_std, y_std = read_recording(tmp_path / "standard.csv")
    X_lab, y_lab = read_recording(tmp_path / "lab.csv")
    pd.testing.assert_frame_equal(X_lab, X_std)
    np.testing.assert_array_equal(y_lab, y_std)


def test_decimal_commas_in_a_comma_file_are_refused(tmp_path):
    """Decimal commas split the numbers of a ','-delimited file: said as such, not as a missing column."""
    _recording_csv(tmp_path / "lab.csv", sep=";", decimal=",")
    path = tmp_path / "mixed.csv"
    path.write_text((tmp_path / "lab.csv").read_text().replace(";", ","))
    match = (
        r"mixed\.csv: line 2 has \d+ fields but the header has 15 \(delimiter ','\).*"
        r"decimal commas \(12,5\).*';' as the delimiter, or with decimal points"
    )
    with pytest.raises(ValueError, match=match):
        read_recording(path)


def _write_bytes(data):
    def write(path):
        path.write_bytes(data)
    return write


def _gzip_cut(path):
    import gzip

    X, y = tiny_recordings(n_runs=1, seed=1)
    text = _standard_file(X, y).assign(run="cut").to_csv(index=False)
    data = gzip.compress(text.encode())
    path.write_bytes(data[: len(data) // 2])


def _ros_bag(kind):
    """A ROS bag broken in one way; skipped without rosbags."""

    def write(path):
        pytest.importorskip("rosbags")
        from test_readers import _write_bag

        ros1 = kind.startswith("bag")
        _write_bag(path, ros1=ros1)
        if kind == "bag-random":
            path.write_bytes(np.random.default_rng(0).bytes(600))
        elif kind == "bag-cut":
            path.write_bytes(path.read_bytes()[:300])
        elif kind == "db3-random":
            (path / f"{path.name}.db3").write_bytes(np.random.default_rng(0).bytes(3000))
        elif kind == "yaml-broken":
            (path / "metadata.yaml").write_text("rosbag2_bagfile_information: [unclosed\n : :")

    return write


def _read_bag(path):
    from test_readers import CONFIG

    from skcath.io import read_rosbag

    read_rosbag(path, CONFIG, tolerance=0.005, catheter="A", setting="s", n_sweep=5)


def _read_as_streams(path):
    X, y = tiny_recordings(n_runs=1)
    read_streams(path, _standard_file(X, y)[["t", *TARGET]], tolerance=0.01)


def _read_folder(path):
    _recording_csv(path.with_name("a_good.csv"))
    read_recordings(path.parent, n_sweep=None, progress=False)


def _read_ndi(path):
    from skcath.io import read_ndi_csv

    read_ndi_csv(path, tip="0A")


UNREADABLE = [
    pytest.param("rec.csv.gz", _gzip_cut, read_recording, r"ends early.*EOFError", id="cut-csv-gz"),
    pytest.param("rec.csv.gz", _write_bytes(b"plain text, not gzip"), read_recording,
                 r"not compressed as its suffix says.*BadGzipFile", id="not-gzip"),
    pytest.param("rec.csv", _write_bytes(bytes(range(128, 256)) * 8), read_recording,
                 r"not UTF-8 text.*UnicodeDecodeError", id="binary-csv"),
    pytest.param("rec.csv", _write_bytes(b"\x00" * 64), read_recording, r"NUL bytes",
                 id="nul-bytes-csv"),
    pytest.param("rec.csv", _write_bytes(b""), read_recording, r"the file is empty",
                 id="zero-byte-csv"),
    pytest.param("rec.parquet", _write_bytes(b"PAR1 not really"), read_recording,
                 r"cannot be read as Parquet.*ArrowInvalid", id="broken-parquet"),
    pytest.param("rec.csv", _write_bytes(bytes(range(128, 256))), _read_as_streams,
                 r"not UTF-8 text", id="binary-motor-log"),
    pytest.param("z_broken.csv.gz", _gzip_cut, _read_folder, r"ends early", id="folder-with-cut-gz"),
    pytest.param("aurora.csv", _write_bytes(bytes(range(128, 256))), _read_ndi,
                 r"not UTF-8 text", id="binary-ndi-export"),
    pytest.param("session.bag", _ros_bag("bag-random"), _read_bag,
                 r"cannot be read as a ROS bag: .*UnicodeDecodeError", id="random-bag"),
    pytest.param("session.bag", _ros_bag("bag-cut"), _read_bag,
                 r"cannot be read as a ROS bag: .*AnyReaderError", id="cut-bag"),
    pytest.param("session", _ros_bag("db3-random"), _read_bag,
                 r"cannot be read as a ROS bag: .*not a database", id="broken-db3"),
    pytest.param("session", _ros_bag("yaml-broken"), _read_bag,
                 r"cannot be read as a ROS bag: .*YAML", id="broken-metadata-yaml"),
]


@pytest.mark.parametrize("name, write, read, match", UNREADABLE)
def test_unreadable_file_error_names_the_file(tmp_path, name, write, read, match):
    """Whatever the parser finds, the reader's error is a ValueError that starts with the file name."""
    path = tmp_path / name
    write(path)
    with pytest.raises(ValueError, match=re.escape(f"{name}: ") + r"(.|\n)*" + match) as info:
        read(path)
    assert str(info.value).startswith(f"{name}: ")


def _clock_streams(tracker_factor=1.0, shift=0.0):
    """A motor log at 100 Hz (s) and a tracker log at 40 Hz, its clock scaled and shifted."""
    X, y = tiny_recordings(n_runs=1, n_sweep=200, n_motion=400)
    motors = X.drop(columns=REFERENCE).reset_index(drop=True).assign(t=np.arange(len(X)) / 100.0)
    tracker = pd.DataFrame(y[::5], columns=TARGET).assign(t=(np.arange(len(y[::5])) / 20.0 + shift))
    return motors, tracker.assign(t=tracker["t"] * tracker_factor)


MISALIGNED = [
    pytest.param(
        {"tracker_factor": 1000.0},
        r"the two clocks count in different units: the motor clock spans 5\.99 \(0 to 5\.99\) "
        r"and the tracker clock 5950 \(0 to 5950\).*tracker counts in ms and the motors in s\. "
        r"Pass tracker_time_scale=0\.001",
        {"tracker_time_scale": 1e-3},
        id="tracker-clock-in-ms",
    ),
    pytest.param(
        {"shift": 60.0},
        r"aligned streams: 600 of the 600 motor samples \(100\.0 %\) found no tracker sample "
        r"within tolerance=0\.006, more than max_unmatched=0\.9.*from 0 to 5\.99.*from 60 to "
        r"65\.95.*latency='start'",
        {"latency": "start"},
        id="streams-not-overlapping",
    ),
]


@pytest.mark.parametrize("streams, match, fix", MISALIGNED)
def test_misaligned_streams_are_refused(streams, match, fix):
    """Clocks in other units, or streams that do not meet: refused, with the fix to pass."""
    motors, tracker = _clock_streams(**streams)
    with pytest.raises(ValueError, match=match):
        read_streams(motors, tracker, tolerance=0.006)
    # the fix named aligns them as well as streams on one clock in seconds
    _, y, report = read_streams(motors, tracker, tolerance=0.006, **fix)
    _, y_same, report_same = read_streams(*_clock_streams(), tolerance=0.006)
    np.testing.assert_array_equal(y, y_same)
    assert report.n_unmatched == report_same.n_unmatched < 0.9 * len(motors)


# ---------------------------------------------------------------------------
# quaternions (tip_in_base_frame)
# ---------------------------------------------------------------------------
def _poses(n=6, seed=0):
    rng = np.random.default_rng(seed)
    quats = rng.normal(size=(n, 4))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    return rng.normal(size=(n, 3)) * 50, rng.normal(size=(n, 3)) * 50, quats


def test_non_unit_quaternion_is_normalised():
    """Documented masking: quaternions are normalised, so their scale does not matter."""
    tip, base, quats = _poses()
    scaled = quats * np.array([[3.0], [0.2], [1.0], [7.5], [1.0], [0.01]])
    before = scaled.copy()
    np.testing.assert_allclose(
        tip_in_base_frame(tip, base, scaled), tip_in_base_frame(tip, base, quats), atol=1e-9
    )
    np.testing.assert_array_equal(scaled, before)


def test_zero_quaternion_is_rejected():
    tip, base, quats = _poses()
    quats[4] = 0.0
    before = quats.copy()
    with pytest.raises(
        ValueError, match=r"base_orientation has a zero-norm quaternion at row 4.*Mark missing"
    ):
        tip_in_base_frame(tip, base, quats)
    np.testing.assert_array_equal(quats, before)


# ---------------------------------------------------------------------------
# documented masking and conversions of check_recordings
# ---------------------------------------------------------------------------
def _dropouts(X, y):
    X.loc[_rows(X, "r0", "sweep")[1], REFERENCE] = np.nan
    y[[0, 7]] = np.nan
    return X, y


def _string_numbers(X, y):
    X["q1"] = [f"{v:.17g}" for v in X["q1"]]
    return X, y


def _nullable_ints(X, y):
    X["tau1"] = pd.array(np.round(X["tau1"] * 10).astype(int), dtype="Int64")
    return X, y


def _interleaved(X, y):
    order = np.argsort(np.concatenate([np.arange(9), np.arange(9) + 0.5]), kind="stable")
    return X.iloc[order], y[order]


MASKED = [
    pytest.param(_dropouts, id="dropped-tracker-samples-kept-as-nan"),
    pytest.param(_string_numbers, id="string-numbers-converted"),
    pytest.param(_nullable_ints, id="nullable-integers-converted"),
    pytest.param(_interleaved, id="interleaved-runs-kept-in-row-order"),
    pytest.param(lambda X, y: (X.assign(extra=list("abcdefghijklmnopqr")), y),
                 id="extra-column-passed-through"),
]


@pytest.mark.parametrize("breaker", MASKED)
def test_documented_masking(tiny, breaker):
    X, y = tiny
    X_in, y_in = breaker(X.copy(deep=True), y.copy())
    X_before, y_before = X_in.copy(deep=True), y_in.copy()
    X_out, y_out = check_recordings(X_in, y_in)
    pd.testing.assert_frame_equal(X_in, X_before)
    np.testing.assert_array_equal(y_in, y_before)
    # same rows, labels and columns in the same order; numeric channels float64
    pd.testing.assert_index_equal(X_out.index, X_in.index)
    assert list(X_out.columns) == list(X_in.columns)
    for column in ["t", "q1", "q2", "tau1", "tau2", *REFERENCE]:
        assert X_out[column].dtype == np.float64
        np.testing.assert_array_equal(
            X_out[column].to_numpy(), pd.to_numeric(X_in[column]).to_numpy(dtype=float)
        )
    np.testing.assert_array_equal(y_out, y_in)  # NaN rows kept in place


def test_backbone_calibrates_through_scattered_dropouts(bench):
    """A third of the sweep references missing: calibration still works on the rest."""
    X, _ = bench
    X = X.copy(deep=True)
    rows = _rows(X, _first_run(X), "sweep")
    X.loc[rows[::3], REFERENCE] = np.nan
    before = X.copy(deep=True)
    full = PDLBackbone().fit(bench[0]).predict(bench[0])
    masked = PDLBackbone().fit(X).predict(X)
    pd.testing.assert_frame_equal(X, before)
    assert np.isfinite(masked).all()
    assert np.median(np.linalg.norm(masked - full, axis=1)) < 1.0


# ---------------------------------------------------------------------------
# files skcath reads back: saved estimators (skcath.persist), the benchmark cache
# ---------------------------------------------------------------------------
def _members(path):
    with zipfile.ZipFile(path) as zf:
        return {name: zf.read(name) for name in zf.namelist()}


def _write_members(path, members):
    """Write the archive again, uncompressed, without the members set to None."""
    with zipfile.ZipFile(path, "w") as zf:
        for name, content in members.items():
            if content is not None:
                zf.writestr(name, content)


def _edit_header(edit):
    def breaker(path):
        members = _members(path)
        header = json.loads(members["skcath.json"])
        edit(header)
        _write_members(path, {**members, "skcath.json": json.dumps(header).encode()})

    return breaker


def _replace_member(name, content):
    def breaker(path):
        _write_members(path, {**_members(path), name: content})

    return breaker


def _corrupt_payload(path):
    """Flip one byte of the stored payload: its CRC no longer matches."""
    _write_members(path, _members(path))
    data = bytearray(path.read_bytes())
    data[data.rfind(b"NoResidual")] ^= 0xFF
    path.write_bytes(bytes(data))


SAVED_FILE_DAMAGED = [
    pytest.param(_replace_member("skcath.json", b'{"file_format": 1, "format": '),
                 r"its skcath\.json is not valid JSON", id="saved-file-header-not-json"),
    pytest.param(_replace_member("skcath.json", b"[1, 2]"),
                 r"its skcath\.json holds a list, not a JSON object",
                 id="saved-file-header-not-an-object"),
    pytest.param(_edit_header(lambda h: h.pop("versions")),
                 r"its skcath\.json has no \['versions'\]", id="saved-file-header-missing-key"),
    pytest.param(_edit_header(lambda h: h["versions"].update(skcath=1)),
                 r"'versions' of its skcath\.json is \{.*\}, not an object with the skcath "
                 r"version as a string", id="saved-file-version-not-a-string"),
    pytest.param(_edit_header(lambda h: h["versions"].update(skcath="abc")),
                 r"cannot parse the skcath version 'abc'", id="saved-file-version-unparsable"),
    pytest.param(_edit_header(lambda h: h.update(estimator=None)),
                 r"'estimator' of its skcath\.json is None, not a class name",
                 id="saved-file-estimator-not-a-string"),
    pytest.param(_replace_member("estimator.skops", None), r"it has no estimator\.skops",
                 id="saved-file-without-payload"),
    pytest.param(_corrupt_payload, r"its member estimator\.skops cannot be read \(Bad CRC-32",
                 id="saved-file-corrupt-payload"),
]


@pytest.mark.parametrize("breaker, match", SAVED_FILE_DAMAGED)
def test_damaged_saved_file_is_a_value_error(tmp_path, breaker, match):
    path = tmp_path / "saved.skcath"
    persist.save(NoResidual(), path)
    breaker(path)
    before = path.read_bytes()
    with pytest.raises(ValueError, match=r"saved\.skcath' cannot be loaded: " + match) as info:
        persist.load(path)
    assert "damaged or was not written by skcath.persist.save" in str(info.value)
    assert path.read_bytes() == before


@pytest.mark.parametrize("name", ["model.joblib", "model.pkl", "model"])
def test_saved_file_with_another_suffix_warns(tmp_path, name):
    with pytest.warns(FileSuffixWarning, match=re.escape(f"{name}' does not end in '.skcath'")
                      + r".*joblib\.load, pickle\.load and skops\.io\.load cannot.*"
                      + re.escape("Name the file 'model.skcath'")):
        persist.save(NoResidual(), tmp_path / name)
    assert isinstance(persist.load(tmp_path / name), NoResidual)  # written all the same


class _Payload:
    """An object whose unpickling creates the folder ``marker``: code from a file."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return os.mkdir, (self.marker,)


def test_planted_pickle_in_benchmark_cache_never_runs(tmp_path, caplog):
    home = tmp_path / "cache"
    fresh = make_benchmark(n_catheters=1, n_runs=1, data_home=home)
    (path,) = home.glob("benchmark-play-*")
    marker = tmp_path / "payload-ran"
    stem = path.with_suffix("")
    # at the path of the pickled caches of earlier versions, and at today's path
    joblib.dump(_Payload(marker), stem.with_suffix(".joblib"))
    with open(stem.with_suffix(".npz"), "wb") as file:
        np.savez(file, __meta__=np.array([_Payload(marker)], dtype=object))
    with caplog.at_level(logging.WARNING, logger="skcath"):
        data = make_benchmark(n_catheters=1, n_runs=1, data_home=home)
    assert not marker.exists()
    assert any("ignoring unreadable cache file" in r.getMessage() and stem.name in r.getMessage()
               for r in caplog.records)
    pd.testing.assert_frame_equal(data.X, fresh.X)
    np.testing.assert_array_equal(data.y, fresh.y)


def test_residual_pipeline_from_others_loads_without_pickle(bench, tmp_path):
    pytest.importorskip("skops")
    X, y = bench
    pipe = Pipeline([("backbone", PDLBackbone()), ("residual", GRUResidual(
        max_epochs=1, module__hidden_size=8, window_step_s=20.0, random_state=0, n_threads=1))])
    expected = pipe.fit(X, y).predict(X)
    path = tmp_path / "from_others.skcath"
    persist.save(pipe, path)  # pickle-free by default
    # skcath's own classes are trusted by default: nothing left for the user to trust
    assert persist.get_untrusted_types(path) == []
    np.testing.assert_array_equal(persist.load(path).predict(X), expected)
# targets, references and cross-validation
# ---------------------------------------------------------------------------
def test_target_frame_columns_are_matched_by_name(bench):
    """A DataFrame y with its columns in another order: matched by name, same score."""
    X, y = bench
    y_frame = pd.DataFrame(y, columns=TARGET)[["p_z", "p_y", "p_x"]]
    before = y_frame.copy()
    _, y_checked = check_recordings(X, y_frame)
    np.testing.assert_array_equal(y_checked, y)
    model = PDLBackbone().fit(X)
    assert model.score(X, y_frame) == pytest.approx(model.score(X, y), rel=1e-12)
    pd.testing.assert_frame_equal(y_frame, before)


def test_target_frame_with_other_names_is_rejected(tiny):
    """Column names other than p_x, p_y, p_z are listed and refused."""
    X, y = tiny
    y_frame = pd.DataFrame(y, columns=["x", "y", "z"])
    with pytest.raises(ValueError, match=r"y is a DataFrame with the columns \['x', 'y', 'z'\]; "
                       r"its columns must be the target names \['p_x', 'p_y', 'p_z'\]"):
        check_recordings(X, y_frame)


@pytest.mark.parametrize(
    "breaker, match",
    [
        pytest.param(lambda y: y / 1000.0, r"y is 0\.001 times as far", id="y-in-metres-ref-in-mm"),
        pytest.param(lambda y: np.roll(y, 1500, axis=0), r"y shifted against the rows of X",
                     id="y-shifted-by-rows"),
    ],
)
def test_target_far_from_reference_is_rejected(bench, breaker, match):
    """y and ref_* hold the same measurement on sweep rows: units or a row shift are caught."""
    X, y = bench
    y_bad = breaker(y.copy())
    before = y_bad.copy()
    with pytest.raises(ValueError, match=r"disagree on the 'sweep' rows of run '\S+': their median "
                       r"distance is [\d.]+ mm .*above the 1 mm allowed.*" + match):
        check_recordings(X, y_bad)
    np.testing.assert_array_equal(y_bad, before)


def _failure_messages(caught):
    return [str(w.message) for w in caught if "fail" in str(w.message)]


def test_kfold_that_cuts_runs_names_the_fix(bench):
    """Every failed fold of the default cv (KFold) says that it cut a run, and the fix."""
    X, y = bench
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scores = cross_val_score(Pipeline([("backbone", PDLBackbone())]), X, y)
    assert np.isnan(scores).all()
    messages = _failure_messages(caught)
    assert len(messages) == len(scores)
    for message in messages:
        assert "it cut a run" in message and "groups=X['run']" in message, message


def test_shuffled_kfold_that_cuts_runs_is_an_error(bench):
    """A shuffled KFold leaves runs with missing motion rows: every fit fails."""
    X, y = bench
    with pytest.raises(ValueError, match=r"All the 5 fits failed(.|\n)*'motion' rows of run "
                       r"'\S+' miss samples(.|\n)*it cut a run"):
        cross_validate(Pipeline([("backbone", PDLBackbone())]), X, y,
                       cv=KFold(5, shuffle=True, random_state=0))


def test_groups_given_to_a_package_splitter_warn(bench):
    """The package splitters fold by the columns of X and say that groups is not used."""
    X, _ = bench
    with pytest.warns(GroupsNotUsedWarning, match=r"does not use: it groups the rows by the "
                      r"'catheter' and 'setting' columns of X"):
        list(LeaveOneSettingOut().split(X, groups=X["run"]))


# ---------------------------------------------------------------------------
# residual learners and the streaming estimator: sample weights, a refit
# pipeline, step inputs, pretrained networks, methods not offered, devices
# ---------------------------------------------------------------------------
def _tiny_gru(**params):
    return GRUResidual(**{"max_epochs": 1, "module__hidden_size": 8, "window_step_s": 20.0,
                          "random_state": 0, "n_threads": 1, **params})


def _fit_is_refused(X, y, match, **params):
    """A tiny GRU's ``fit`` raises ValueError matching ``match`` and leaves ``X`` as it was."""
    before = X.copy()
    with pytest.raises(ValueError, match=match):
        _tiny_gru(**params).fit(X, y)
    pd.testing.assert_frame_equal(X, before)


@pytest.fixture(scope="module")
def nominal(bench):
    """The bench runs with the PDL backbone's nominal tip appended, and y."""
    X, y = bench
    return PDLBackbone().fit(X).transform(X), y


@pytest.fixture(scope="module")
def streaming(bench, nominal):
    """A fitted PDL + tiny GRU pipeline, and the sweep and first motion samples of a run."""
    X, y = bench
    pipe = Pipeline([("backbone", PDLBackbone().fit(X)), ("residual", _tiny_gru())])
    pipe.named_steps["residual"].fit(*nominal)
    rows = X[X["run"] == X["run"].iloc[-1]]
    motion = (rows["phase"] == "motion").to_numpy()
    return pipe, rows[~motion], rows.loc[motion, ["q1", "q2", "tau1", "tau2"]].to_numpy()[:40]


def test_zero_weighted_run_is_left_out_of_training(nominal):
    """sample_weight reaches the loss: a run of weight 0 gives the model fitted without it."""
    Xb, y = nominal
    left_out = (Xb["run"] == Xb["run"].iloc[0]).to_numpy()
    weight = np.where(left_out, 0.0, 1.0)
    before = weight.copy()
    zeroed = _tiny_gru().fit(Xb, y, sample_weight=weight)
    without = _tiny_gru().fit(Xb[~left_out], y[~left_out], sample_weight=weight[~left_out])
    np.testing.assert_array_equal(zeroed.predict(Xb), without.predict(Xb))
    np.testing.assert_array_equal(weight, before)


def test_refit_pipeline_does_not_change_a_started_estimator(nominal, streaming):
    """Refit in place after start: the estimator and its pickle keep start's step, and warn."""
    pipe, sweep, samples = streaming
    pipe = copy.deepcopy(pipe)
    est = OnlineEstimator(pipe, engine="numpy").start(sweep)
    expected = np.array([est.step(*s) for s in samples])
    pipe.named_steps["residual"].set_params(random_state=1).fit(*nominal)
    with pytest.warns(PipelineChangedWarning, match=r"was unpickled, but its pipeline has been "
                      r"refit or its parameters set since start\(\)(.|\n)*start\(sweep\) again"):
        pickled = pickle.loads(pickle.dumps(est))
    for started in (est, pickled):
        with pytest.warns(PipelineChangedWarning, match="was reset, but its pipeline"):
            started.reset()
        np.testing.assert_array_equal(np.array([started.step(*s) for s in samples]), expected)


@pytest.fixture(scope="module")
def steppers(streaming):
    """A started OnlineEstimator (backbone alone) and a started ShaftChangeDetector."""
    pipe, sweep, _ = streaming
    online = OnlineEstimator(Pipeline([("backbone", pipe.named_steps["backbone"])]),
                             engine="numpy")
    return online.start(sweep), ShaftChangeDetector().start(sweep)


@pytest.mark.parametrize(
    "value",
    ["1.0", b"1.0", Decimal("1.0"), True, np.bool_(True), 1 + 0j, np.complex128(1.0)],
    ids=["str", "bytes", "decimal", "bool", "numpy-bool", "complex", "numpy-complex"],
)
def test_streaming_steps_take_real_numbers_only(steppers, value):
    """OnlineEstimator.step and ShaftChangeDetector.step refuse the same values, alike."""
    messages = []
    for stepper in steppers:
        with pytest.raises(TypeError, match=r"step takes four numbers, q1, q2 \(deg\), tau1, "
                           r"tau2: tau1 must be a real number \(int, float or a numpy real "
                           r"scalar\), not ") as info:
            stepper.step(0.0, 0.0, value, 0.0)
        assert stepper.n_steps_ == 0
        messages.append(str(info.value))
    assert messages[0] == messages[1]


def test_pretrained_of_another_size_names_the_sizes(nominal, streaming):
    """Fine-tuning a network of another size names the module__* argument and both sizes."""
    pretrained = FrozenEstimator(streaming[0].named_steps["residual"])
    with pytest.raises(ValueError, match=r"pretrained has another network than this "
                       r"GRUResidual: module__hidden_size=16 here, 8 in pretrained\. Give "
                       r"this estimator the module and module__\* parameters"):
        _tiny_gru(module__hidden_size=16, pretrained=pretrained).fit(*nominal)


def test_predict_proba_and_forward_say_what_to_use(nominal, streaming):
    """A regressor has no predict_proba; forward on recordings names predict instead."""
    Xb, _ = nominal
    residual = streaming[0].named_steps["residual"]
    assert not hasattr(residual, "predict_proba")
    with pytest.raises(AttributeError, match=r"GRUResidual has no predict_proba: it is a "
                       r"regressor of tip positions\. Use predict"):
        residual.predict_proba(Xb)
    with pytest.raises(TypeError, match=r"the network's methods \(forward, forward_iter, "
                       r"infer\) take the input those prepare from recordings, not DataFrame\. "
                       r"Use GRUResidual\.predict for tip positions"):
        residual.forward(Xb)


def test_unavailable_device_is_refused_before_training(nominal):
    """device='cuda' without a GPU: a ValueError naming the devices there are, up front."""
    device = f"cuda:{torch.cuda.device_count()}" if torch.cuda.is_available() else "cuda"
    with pytest.raises(ValueError, match=rf"GRUResidual has device='{device}', but torch "
                       r"cannot compute there on this machine; the devices available are "
                       r"\['cpu'"):
        _tiny_gru(device=device).fit(*nominal)


# ---------------------------------------------------------------------------
# shaft recovery: a re-sweep without the tracker (OnlineEstimator.resweep),
# and a re-sweep asked of a benchmark without a shaft change
# ---------------------------------------------------------------------------
def test_resweep_after_a_refit_is_refused(nominal, streaming):
    """resweep reads the pipeline's encoder: after a refit it refuses and names start(sweep)."""
    pipe, sweep, _ = streaming
    pipe = copy.deepcopy(pipe)
    est = OnlineEstimator(pipe, engine="numpy").start(sweep)
    context = est.context_.copy()
    pipe.named_steps["residual"].set_params(random_state=1).fit(*nominal)
    with pytest.raises(ValueError, match=r"resweep encodes the new sweep with the pipeline's "
                       r"residual learner and keeps the calibration taken at start\(\), but the "
                       r"pipeline has been refit or its parameters set since start\(\)\. Call "
                       r"start\(sweep\) with a tracked sweep"):
        est.resweep(sweep.drop(columns=REFERENCE))
    np.testing.assert_array_equal(est.context_, context)


def test_resweep_of_another_layout_names_the_rays(streaming):
    """A re-sweep that is not a sweep of the backbone's rays: the error of find_rays, nothing changed."""
    pipe, sweep, _ = streaming
    est = OnlineEstimator(pipe, engine="numpy").start(sweep)
    context = est.context_.copy()
    rays = find_rays(sweep[["q1", "q2"]].to_numpy())
    four = sweep[(rays.labels % 2 == 0) | rays.neutral].drop(columns=REFERENCE)
    with pytest.raises(ValueError, match=r"Rays missing in the sweep of run .*: found 4 distinct "
                       r"ray\(s\) .* expected n_rays=8"):
        est.resweep(four)
    np.testing.assert_array_equal(est.context_, context)
    assert est.run_ == str(sweep["run"].iloc[0])


def test_resweep_without_a_shaft_change_is_refused(tmp_path):
    """resweep=True of the simulator needs a shaft change to sweep again after."""
    with pytest.raises(ValueError, match=r"resweep=True sweeps again after the shaft change; "
                       r"it needs shaft_change=True"):
        make_benchmark(n_catheters=1, n_runs=1, resweep=True, data_home=tmp_path)
    assert not list(tmp_path.iterdir())


def test_resweep_at_another_rate_is_refused(tmp_path):
    """The simulated re-sweep after a shaft change exists at the protocol's 10 Hz only."""
    with pytest.raises(ValueError, match=r"re-sweep after the shaft change \(resweep=True\) is "
                       r"simulated at rate_hz=10 only; got rate_hz=40"):
        make_benchmark(n_catheters=1, n_runs=1, shaft_change=True, resweep=True, rate_hz=40,
                       data_home=tmp_path)
    assert not list(tmp_path.iterdir())


def test_resweep_with_other_channels_is_refused(streaming):
    """A re-sweep without the torques the start sweep had: both channel lists, nothing changed."""
    pipe, sweep, _ = streaming
    est = OnlineEstimator(pipe, engine="numpy").start(sweep)
    context = est.context_.copy()
    with pytest.raises(ValueError, match=r"missing the column\(s\) \['tau1', 'tau2'\]"):
        est.resweep(sweep.drop(columns=["tau1", "tau2", *REFERENCE]))
    with pytest.raises(ValueError, match=r"the re-sweep has the channels q1, q2, q3, tau1, tau2, "
                       r"tau3, but the sweep given to start\(\) had q1, q2, tau1, tau2"):
        est.resweep(sweep.drop(columns=REFERENCE).assign(q3=0.0, tau3=0.0))
    np.testing.assert_array_equal(est.context_, context)


# ---------------------------------------------------------------------------
# shaft recovery: the calibration renewed from the motors (MotorRecalibration,
# OnlineEstimator.resweep(recalibration=...))
# ---------------------------------------------------------------------------
def _sweeps(X):
    return X[(X["phase"] == "sweep").to_numpy()]


def test_recalibration_with_one_catheter_needs_an_alpha(bench):
    """alpha="auto" holds out one catheter at a time: one catheter is refused, naming alpha."""
    X, _ = bench
    with pytest.raises(ValueError, match=r'alpha="auto" holds out one catheter at a time and needs '
                       r"at least two groups; got 1\. Give alpha as a number"):
        MotorRecalibration().fit(_sweeps(X))


def test_recalibration_groups_are_checked(bench):
    """groups= of another length, or a single run: each named."""
    X, _ = bench
    sweeps = _sweeps(X)
    with pytest.raises(ValueError, match=r"groups must have one value per row of X \(\d+\); got "
                       r"shape \(2,\)"):
        MotorRecalibration(alpha=1.0).fit(sweeps, groups=[0, 1])
    single = sweeps[(sweeps["run"] == sweeps["run"].iloc[0]).to_numpy()]
    with pytest.raises(ValueError, match=r"fit needs at least two runs of one group"):
        MotorRecalibration(alpha=1.0).fit(single)


def test_resweep_recalibration_of_another_kind_is_refused(bench, streaming):
    """recalibration= takes a fitted MotorRecalibration; the estimator is left as it was."""
    X, _ = bench
    pipe, sweep, _ = streaming
    est = OnlineEstimator(pipe, engine="numpy").start(sweep)
    params = est.backbone_params_
    with pytest.raises(TypeError, match=r"recalibration must be a fitted MotorRecalibration"):
        est.resweep(sweep.drop(columns=REFERENCE), recalibration=object())
    with pytest.raises(NotFittedError):
        est.resweep(sweep.drop(columns=REFERENCE), recalibration=MotorRecalibration())
    fitted = MotorRecalibration(alpha=1.0).fit(_sweeps(X))
    with pytest.raises(ValueError, match=r"exactly one run"):
        est.resweep(_sweeps(X).drop(columns=REFERENCE), recalibration=fitted)
    assert est.backbone_params_ is params and est.run_ == str(sweep["run"].iloc[0])


def test_resweep_recalibration_needs_torques(bench):
    """Without torques there are no torque loops to renew the calibration from: named."""
    X, _ = bench
    sweeps = _sweeps(X)
    fitted = MotorRecalibration(alpha=1.0).fit(sweeps)
    sweep = sweeps[(sweeps["run"] == sweeps["run"].iloc[0]).to_numpy()].drop(columns=["tau1", "tau2"])
    est = OnlineEstimator(Pipeline([("backbone", PDLBackbone().fit(sweep))])).start(sweep)
    with pytest.raises(ValueError, match=r"resweep\(recalibration=\.\.\.\) reads the torque loops of "
                       r"two motors, q1, q2 with tau1, tau2, on the sweep given to start\(\); this "
                       r"estimator has q1, q2\. Call start\(sweep\) with a tracked sweep"):
        est.resweep(sweep.drop(columns=REFERENCE), recalibration=fitted)


# ---------------------------------------------------------------------------
# any number of motors: gaps in the motor columns, torques of some motors,
# learners and backbones given another number of motors or no torque
# ---------------------------------------------------------------------------
def test_gap_in_the_motor_columns_is_named():
    """q1, q3 without q2: the missing column, and how motors and torques are numbered."""
    X, y = tiny_recordings()
    X = X.drop(columns="q2").assign(q3=1.0)
    with pytest.raises(ValueError, match=r"missing the column\(s\) \['q2', 'tau3'\].*A recording "
                       r"of N motors has the motor angles q1 \.\. qN without a gap and the "
                       r"torques tau1 \.\. tauN or no torque column"):
        check_recordings(X, y)


def test_torques_of_some_motors_only_are_refused():
    """q1..q3 with tau1, tau2: torques come for every motor or for none."""
    X, y = tiny_recordings()
    with pytest.raises(ValueError, match=r"missing the column\(s\) \['tau3'\]"):
        check_recordings(X.assign(q3=0.5), y)


def test_non_finite_third_motor_is_named():
    X, y = tiny_recordings()
    X = X.assign(q3=0.5, tau3=0.1)
    X.loc[X.index[6], "q3"] = np.inf
    with pytest.raises(ValueError, match=r"Column 'q3' contains 1 non-finite value\(s\)"):
        check_recordings(X, y)


def test_learner_with_torques_on_recordings_without_torques(nominal):
    """use_torque=True on a rig without torque sensing names use_torque and the columns."""
    Xb, y = nominal
    _fit_is_refused(Xb.drop(columns=["tau1", "tau2"]), y,
                    r"GRUResidual has use_torque=True and reads the drive "
                    r"torques \['tau1', 'tau2'\] of the 2 motor\(s\), but the recordings have "
                    r"no torque column\. Pass use_torque=False")


def test_learner_given_another_number_of_motors(nominal, streaming):
    """A network fitted on two motors refuses three, in predict and in the streaming start."""
    Xb, _ = nominal
    pipe, sweep, _ = streaming
    residual = pipe.named_steps["residual"]
    message = r"This GRUResidual was fitted on recordings of 2 motor\(s\) \(q1 \.\. q2\); X has 3"
    with pytest.raises(ValueError, match=message):
        residual.predict(Xb.assign(q3=0.0, tau3=0.0))
    with pytest.raises(ValueError, match=message):
        OnlineEstimator(pipe, engine="numpy").start(sweep.assign(q3=1.0, tau3=0.0))


@pytest.mark.parametrize("n_motors", [1, 3])
def test_geometric_backbone_given_another_number_of_motors(bench, n_motors):
    """PCC and PDL model two motors: the count is named, PolynomialBackbone proposed."""
    X, _ = bench
    X = X.drop(columns=["q2", "tau2"]) if n_motors == 1 else X.assign(q3=0.0, tau3=0.0)
    listed = "q1" if n_motors == 1 else "q1, q2, q3"
    with pytest.raises(ValueError, match=rf"PDLBackbone models a catheter with two bending "
                       rf"motors \(q1, q2\), but the recordings have {n_motors} motor\(s\) "
                       rf"\({listed}\)\. Use PolynomialBackbone"):
        PDLBackbone().fit(X)


def test_streaming_step_with_another_number_of_channels(steppers):
    """Five values for the four channels of the recordings: the count and the channels."""
    estimator = steppers[0]
    with pytest.raises(TypeError, match=r"step takes four numbers, q1, q2 \(deg\), tau1, tau2, "
                       r"one per channel of the recordings; got 5 value\(s\)"):
        estimator.step(0.0, 0.0, 0.0, 0.0, 0.0)
    assert estimator.n_steps_ == 0


# ---------------------------------------------------------------------------
# sample rates: training runs at two rates, a run too slow for the model, the
# times of a stream at another rate
# ---------------------------------------------------------------------------
def _run_slowed(X, factor):
    """``X`` with the times of its last run multiplied by ``factor`` (a copy), and that run."""
    run = X["run"].iloc[-1]
    slowed = X.copy()
    rows = (slowed["run"] == run).to_numpy()
    slowed.loc[rows, "t"] = slowed.loc[rows, "t"] * factor
    return slowed, run


def test_training_runs_at_two_rates_name_the_runs(nominal):
    """A network at the runs' own rate: training runs at two rates are refused by name."""
    Xb, y = nominal
    X, run = _run_slowed(Xb, 2.0)  # that run at 5 Hz
    _fit_is_refused(X, y,
                    rf"GRUResidual learns time in samples, so its "
                    rf"training runs must share one sample rate; most rows are at 10 Hz, "
                    rf"but run\(s\) '{run}' at 5 Hz differ by more than 10 % "
                    r"\(RATE_TOLERANCE\)\. Resample them to one rate first", rate_hz=None)
    # by default the network steps at 10 Hz and the 5 Hz run is resampled to it
    assert _tiny_gru().fit(X, y).rate_hz_ == pytest.approx(10.0, rel=1e-6)


def test_training_run_too_slow_for_the_network_names_rate_hz(nominal):
    """A run at a tenth of the network's default 10 Hz: refused, naming ``rate_hz=None``."""
    Xb, y = nominal
    X, run = _run_slowed(Xb, 10.0)  # that run at 1 Hz
    _fit_is_refused(X, y,
                    rf"GRUResidual\(rate_hz=10\) steps its network at 10 Hz and brings the "
                    rf"training runs to that rate: .*run\(s\) '{run}' at 1 Hz are recorded "
                    r"slower than 0\.2 times.*Pass rate_hz=None")


def test_run_too_slow_for_the_learner_is_refused(nominal, streaming):
    """A run at a tenth of the learner's rate: refused by name, not silently mis-read."""
    Xb, _ = nominal
    X, run = _run_slowed(Xb, 10.0)  # that run at 1 Hz
    residual = streaming[0].named_steps["residual"]
    with pytest.raises(ValueError, match=rf"GRUResidual was fitted at 10 Hz and steps at that "
                       rf"rate; run\(s\) '{run}' at 1 Hz are recorded slower than 0\.2 times "
                       r"that rate \(MIN_RATE_FRACTION\)"):
        residual.predict(X)


def test_stream_at_another_rate_needs_increasing_times(streaming):
    """A stream whose sweep is at 40 Hz steps at the model's ticks: each sample needs its time."""
    pipe, sweep, samples = streaming
    est = OnlineEstimator(pipe, engine="numpy").start(sweep.assign(t=sweep["t"] / 4.0))
    assert est.resampled_
    with pytest.raises(ValueError, match=r"This stream is stepped at the model's rate of 10 Hz "
                       r"\(its sweep, or an earlier sample, is at another rate or uneven\), so "
                       r"every sample needs its time: pass step\(\.\.\., t=seconds\)"):
        est.step(*samples[0])
    t = float(sweep["t"].iloc[-1]) / 4.0 + 0.025
    est.step(*samples[0], t=t)
    at = re.escape(repr(t))
    with pytest.raises(ValueError, match=rf"step got t={at} s; the times of a stream must be "
                       rf"finite and increase, and the previous sample was at t={at} s"):
        est.step(*samples[1], t=t)
    assert est.n_steps_ == 1


# ---------------------------------------------------------------------------
# blocked K-fold inside runs (BlockKFold): fewer blocks than folds, a run
# shorter than its blocks, groups of another length
# ---------------------------------------------------------------------------
def test_block_kfold_with_fewer_blocks_than_folds(bench):
    """Every fold must test a block of every run: n_blocks below n_splits is refused."""
    X, _ = bench
    with pytest.raises(ValueError, match=r"n_blocks=3 must be at least n_splits=4"):
        next(BlockKFold(4, n_blocks=3).split(X))


def test_block_kfold_run_shorter_than_its_blocks(bench):
    """A run with fewer motion rows than n_blocks is named, with its count."""
    X, _ = bench
    run = X["run"].iloc[0]
    n_motion = int(((X["run"] == run) & (X["phase"] == "motion")).sum())
    with pytest.raises(ValueError, match=rf"Run \(group\) '{run}' has {n_motion} row\(s\) to "
                       rf"test, fewer than n_blocks={n_motion + 1}: lower n_blocks"):
        next(BlockKFold(2, n_blocks=n_motion + 1).split(X))


def test_block_kfold_groups_of_another_length(bench):
    """groups must label every row of X: a groups of the wrong length is refused."""
    X, _ = bench
    with pytest.raises(ValueError, match=rf"groups must hold one label per row of X "
                       rf"\({len(X)} rows\); got shape \({len(X) - 1},\)"):
        next(BlockKFold().split(X, groups=X["run"].iloc[1:]))


# rigs without a sweep phase: a residual learner whose parameters read the sweep
# ---------------------------------------------------------------------------
@pytest.mark.parametrize(
    "params, reading",
    [({}, r"GRUResidual\(frame='sweep', use_context=True\)"),
     ({"frame": "base"}, r"GRUResidual\(use_context=True\)"),
     ({"use_context": False}, r"GRUResidual\(frame='sweep'\)")],
    ids=["default", "context", "sweep-frame"],
)
def test_learner_reading_the_sweep_given_runs_without_one(nominal, params, reading):
    """Runs all motion: the runs, the parameters that read the sweep, and the ones that do not."""
    Xb, y = nominal
    motion = (Xb["phase"] == "motion").to_numpy()
    X, y = Xb[motion].reset_index(drop=True), y[motion]
    before = X.copy()
    runs = ", ".join(repr(run) for run in X["run"].unique())
    with pytest.raises(ValueError, match=rf"Run\(s\) {runs} have no 'sweep' rows; {reading} "
                       r"reads the calibration sweep at the start of every run .*For "
                       r"recordings without a sweep phase \(every row 'motion'\), pass "
                       r"frame='base' and use_context=False\."):
        _tiny_gru(**params).fit(X, y)
    pd.testing.assert_frame_equal(X, before)
    _tiny_gru(use_context=False, frame="base").fit(X, y)  # reads no sweep: taken


# ---------------------------------------------------------------------------
# the simulated instruments: the number of motors of the simulator
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("n_motors", [0, 4, 2.0, True, "3"])
def test_simulator_refuses_another_number_of_motors(n_motors):
    """The simulator has instruments of one, two and three motors; the parameter is named."""
    from skcath.datasets import benchmark_catheter, simulate_run

    for func, kwargs in ((make_benchmark, {"cache": False}), (simulate_run, {}),
                         (benchmark_catheter, {"number": 1})):
        with pytest.raises(ValueError, match=rf"The 'n_motors' parameter of {func.__name__} "
                           r"must be an int among \{1, 2, 3\}\. Got .* instead"):
            func(n_motors=n_motors, **kwargs)


def test_simulator_refuses_a_unit_of_another_number_of_motors():
    """A given three-motor unit and the default two motors: both numbers and the fix."""
    from skcath.datasets import benchmark_catheter, simulate_run

    unit = benchmark_catheter(1, n_motors=3)
    before = unit.to_dict()
    with pytest.raises(ValueError, match=r"catheter 'C1' has 3 motor\(s\), but n_motors=2; "
                       r"pass n_motors=3 or a unit of 2"):
        simulate_run(catheter=unit)
    with pytest.raises(ValueError, match=r"catheters: unit 'C1' has 3 motor\(s\), but "
                       r"n_motors=1; pass n_motors=3 or units of 1"):
        make_benchmark(catheters=[unit], n_motors=1, cache=False)
    assert joblib.hash(unit.to_dict()) == joblib.hash(before)


def test_simulator_resweep_of_other_numbers_of_motors_is_refused():
    """The re-sweep after a shaft change is simulated for two motors only, and says so."""
    with pytest.raises(ValueError, match=r"resweep=True is simulated for two motors only; "
                       r"got n_motors=3"):
        make_benchmark(n_motors=3, shaft_change=True, resweep=True, cache=False)


# ---------------------------------------------------------------------------
# where the sweep ends: n_sweep="auto" on a start that is not a sweep, a wrong
# n_sweep given for one run of several
# ---------------------------------------------------------------------------
def _rig_folder(bench, folder, breaker=None):
    """The bench runs as a rig exports them (no phase column), ``breaker`` applied to the second.

    Returns the paths, one file ``run0.csv``, ``run1.csv`` ... per run, and
    the true sweep length of each run.
    """
    X, y = bench
    paths, n_sweeps = [], []
    for k, run in enumerate(pd.unique(X["run"])):
        rows = (X["run"] == run).to_numpy()
        run_X, run_y = X[rows], y[rows]
        if k == 1 and breaker is not None:
            run_X, run_y = breaker(run_X, run_y)
        paths.append(_rig_export(run_X, run_y, folder / f"run{k}.csv"))
        n_sweeps.append(int((run_X["phase"] == "sweep").sum()))
    return paths, n_sweeps


def _in_radians(X, y):
    return X.assign(q1=np.deg2rad(X["q1"]), q2=np.deg2rad(X["q2"])), y


def _motion_first(X, y):
    """The motion rows first, then the sweep: the run starts with no sweep."""
    order = np.argsort((X["phase"] == "sweep").to_numpy(), kind="stable")
    return X.iloc[order].assign(t=X["t"].to_numpy()), y[order]


@pytest.mark.parametrize(
    "breaker, match",
    [
        pytest.param(_in_radians, r"The motors do not move at the start of run 'run1': the "
                     r"largest motor-input magnitude \|q - q_neutral\| is [\d.]+ deg; expected a "
                     r"sweep whose rays reach at least min_amplitude_deg=5 deg\. Motor angles "
                     r"must be in degrees; .*numpy\.rad2deg", id="auto-in-radians"),
        pytest.param(_motion_first, r"The start of run 'run1' is not a calibration sweep: the "
                     r"excursion of samples \d+-\d+ \(t = [\d.]+-[\d.]+ s\), which",
                     id="auto-motion-before-sweep"),
    ],
)
def test_auto_sweep_end_on_a_start_that_is_not_a_sweep(bench, tmp_path, breaker, match):
    """n_sweep="auto" in a folder of runs: the file whose start is not a sweep is named."""
    paths, n_sweeps = _rig_folder(bench, tmp_path, breaker)
    with pytest.raises(ValueError, match=r"run1\.csv: n_sweep='auto': " + match):
        read_recordings(tmp_path, n_sweep="auto", catheter="A", setting="s", progress=False)
    # the other run alone is read: its start is a sweep
    X, _ = read_recording(paths[0], n_sweep="auto", catheter="A", setting="s")
    assert (X["phase"] == "sweep").sum() == n_sweeps[0]


def test_wrong_n_sweep_of_one_run_names_it_and_the_end_found(bench, tmp_path):
    """A manifest of two runs, one with a too short n_sweep: the backbone names that run's."""
    paths, n_sweeps = _rig_folder(bench, tmp_path)
    short = n_sweeps[1] - 600
    manifest = tmp_path / "manifest.csv"
    pd.DataFrame({"path": [p.name for p in paths], "n_sweep": ["auto", str(short)]}).to_csv(
        manifest, index=False)
    X, y = read_recordings(manifest=manifest, catheter="A", setting="s", progress=False)
    before = X.copy()
    with pytest.raises(ValueError, match=rf"The run was read with n_sweep={short} \(its first "
                       rf"{short} samples are the sweep\), but from the motor angles its sweep of "
                       rf"8 rays ends after {n_sweeps[1]} samples \(t = [\d.]+ s; "
                       rf"skcath\.sweep\.find_sweep_end\): read it with n_sweep={n_sweeps[1]}, "
                       r"or with n_sweep='auto'") as info:
        PDLBackbone().fit(X, y).predict(X)
    assert "'run1'" in str(info.value) and "KFold" not in str(info.value)
    pd.testing.assert_frame_equal(X, before)
