"""Property-based fuzzing of check_recordings, read_recording and align_streams.

Small valid long-format frames are generated and then broken in one random
way (NaN / inf / huge values, a dropped column, a changed dtype, rows shuffled
within a run, a changed phase label, a repeated time stamp, a missing id).
Whatever comes in, the checks either accept it, returning the same content
(numeric channels as float64), or raise ValueError / TypeError with a message
that names a column or a run; they never raise anything else and never modify
their input.
"""

import re
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from skcath._format import REQUIRED_COLUMNS, TARGET_NAMES
from skcath._validation import NUMERIC_COLUMNS, check_recordings
from skcath.io import read_recording

FUZZ = settings(
    max_examples=60,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)

_finite = st.floats(-200.0, 200.0, allow_nan=False, allow_infinity=False, width=32)


@st.composite
def recordings(draw):
    """A small valid recording (1-3 runs) and its target ``y`` (n_rows, 3)."""
    frames = []
    for k in range(draw(st.integers(1, 3))):
        n_sweep = draw(st.integers(1, 4))
        n = n_sweep + draw(st.integers(0, 4))
        sweep = np.arange(n) < n_sweep
        steps = draw(st.lists(st.floats(0.0625, 1.0, width=32), min_size=n, max_size=n))
        channels = {
            c: draw(st.lists(_finite, min_size=n, max_size=n))
            for c in ("q1", "q2", "tau1", "tau2", "ref_x", "ref_y", "ref_z")
        }
        frame = pd.DataFrame(
            {
                "catheter": f"c{k % 2}",
                "setting": f"s{k}",
                "run": f"r{k}",
                "t": np.cumsum(steps),
                "phase": np.where(sweep, "sweep", "motion"),
                **channels,
            }
        )
        frame.loc[~sweep, ["ref_x", "ref_y", "ref_z"]] = np.nan
        frames.append(frame)
    X = pd.concat(frames, ignore_index=True)
    if draw(st.booleans()):  # interleave the runs; rows of a run stay in time order
        X = X.sort_values("t", kind="stable")
    X.index = pd.RangeIndex(1000, 1000 + len(X))
    y = np.asarray(draw(st.lists(_finite, min_size=3 * len(X), max_size=3 * len(X))))
    y = y.reshape(-1, 3)
    # on sweep rows the target and the reference are the same measurement
    sweep = (X["phase"] == "sweep").to_numpy()
    y[sweep] = X.loc[sweep, ["ref_x", "ref_y", "ref_z"]].to_numpy()
    return X, y


MUTATIONS = (
    "none",
    "value",
    "drop_column",
    "dtype",
    "shuffle_run",
    "phase_label",
    "repeat_time",
    "missing_id",
)


@st.composite
def mutated(draw):
    """A recording from :func:`recordings` broken in one way, and the mutation's name."""
    X, y = draw(recordings())
    kind = draw(st.sampled_from(MUTATIONS))
    row = draw(st.integers(0, len(X) - 1))
    if kind == "value":
        column = draw(st.sampled_from(NUMERIC_COLUMNS))
        value = draw(st.sampled_from([np.nan, np.inf, -np.inf, 1e300, -3e38]))
        X.iloc[row, X.columns.get_loc(column)] = value
    elif kind == "drop_column":
        X = X.drop(columns=draw(st.sampled_from(REQUIRED_COLUMNS)))
    elif kind == "dtype":
        column = draw(st.sampled_from(REQUIRED_COLUMNS))
        new = draw(st.sampled_from(["str", "object", "bool", "int", "category"]))
        if new == "str":
            X[column] = X[column].astype(str)
        elif new == "object":
            X[column] = X[column].astype(object)
        elif new == "bool":
            X[column] = X[column].notna()
        elif new == "int":
            values = pd.to_numeric(X[column], errors="coerce")
            X[column] = pd.array(np.round(values), dtype="Int64") if values.notna().all() else (
                X[column].astype(str)
            )
        else:
            X[column] = X[column].astype("category")
    elif kind == "shuffle_run":
        run = X["run"].iloc[row]
        positions = np.flatnonzero((X["run"] == run).to_numpy())
        shuffled = draw(st.permutations(list(positions)))
        order = np.arange(len(X))
        order[positions] = shuffled
        X = X.iloc[order]
    elif kind == "phase_label":
        label = draw(st.sampled_from(["sweep", "motion", "Sweep", "calib", "", None]))
        X["phase"] = X["phase"].astype(object)
        X.iloc[row, X.columns.get_loc("phase")] = label
    elif kind == "repeat_time" and row > 0:
        X.iloc[row, X.columns.get_loc("t")] = X["t"].iloc[row - 1]
    elif kind == "missing_id":
        column = draw(st.sampled_from(["catheter", "setting", "run"]))
        X[column] = X[column].astype(object)
        X.iloc[row, X.columns.get_loc(column)] = None
    return X, y, kind


def _names_column_or_run(message, columns):
    named = [c for c in (*columns, *TARGET_NAMES) if f"'{c}'" in message]
    return bool(named) or re.search(r"\b[Rr]un\b|\bRun\(s\)|^(\S+: )?y ", message) is not None


def _numeric(series):
    return pd.to_numeric(series.astype(object), errors="raise").to_numpy(dtype=np.float64)


@given(mutated())
@FUZZ
def test_check_recordings_accepts_or_names_the_problem(case):
    X, y, kind = case
    X_before, y_before = X.copy(deep=True), y.copy()
    try:
        X_out, y_out = check_recordings(X, y)
    except (ValueError, TypeError) as exc:
        assert _names_column_or_run(str(exc), REQUIRED_COLUMNS), (kind, str(exc))
    else:
        pd.testing.assert_index_equal(X_out.index, X.index)
        assert list(X_out.columns) == list(X.columns)
        for column in X.columns:
            if column in NUMERIC_COLUMNS:
                assert X_out[column].dtype == np.float64
                np.testing.assert_array_equal(X_out[column].to_numpy(), _numeric(X[column]))
            else:
                pd.testing.assert_series_equal(X_out[column], X[column])
        np.testing.assert_array_equal(y_out, y)
    pd.testing.assert_frame_equal(X, X_before)
    np.testing.assert_array_equal(y, y_before)


@pytest.fixture(scope="module")
def csv_dir():
    with tempfile.TemporaryDirectory() as folder:
        yield Path(folder)


@given(case=mutated())
@settings(FUZZ, max_examples=40)
def test_read_recording_accepts_or_names_the_problem(csv_dir, case):
    X, y, kind = case
    frame = X.reset_index(drop=True)
    frame[list(TARGET_NAMES)] = y
    before = frame.copy(deep=True)
    path = csv_dir / "fuzz.csv"
    frame.to_csv(path, index=False)
    try:
        X_read, y_read = read_recording(path)
    except (ValueError, TypeError) as exc:
        message = str(exc)
        assert message.startswith("fuzz.csv: "), message
        # a column or run, or one of the few errors about the file as a whole
        file_level = ("is empty", "has no column", "no row")
        assert _names_column_or_run(message, REQUIRED_COLUMNS) or any(
            f in message for f in file_level
        ), (kind, message)
    else:
        assert len(X_read) == len(frame)
        for column in ("t", "q1", "q2", "tau1", "tau2"):
            np.testing.assert_allclose(
                X_read[column].to_numpy(), _numeric(frame[column]), rtol=1e-12
            )
        np.testing.assert_allclose(y_read, y, rtol=1e-12)
    pd.testing.assert_frame_equal(frame, before)


# ---------------------------------------------------------------------------
# two-stream alignment
# ---------------------------------------------------------------------------
_times = st.lists(
    st.integers(0, 400), min_size=1, max_size=25, unique=True
).map(lambda v: np.sort(np.asarray(v, dtype=float)) / 8.0)  # exact binary fractions


@FUZZ
@given(motor_t=_times, tracker_t=_times, tolerance=st.sampled_from([0.06, 0.5, 2.0]),
       latency=st.sampled_from([0.0, 0.25]))
def test_fuzz_align_streams_matches_the_nearest_tracker_sample(motor_t, tracker_t, tolerance, latency):
    """Every motor sample gets the nearest shifted tracker sample within the tolerance, else NaN."""
    from skcath.io import align_streams

    motors = pd.DataFrame({"t": motor_t, "q1": np.arange(motor_t.size, dtype=float)})
    tracker = pd.DataFrame({"t": tracker_t, "tip_px": 100.0 + np.arange(tracker_t.size)})
    before = (motors.copy(deep=True), tracker.copy(deep=True))
    aligned, report = align_streams(motors, tracker, tolerance=tolerance, latency=latency)
    pd.testing.assert_frame_equal(motors, before[0])
    pd.testing.assert_frame_equal(tracker, before[1])
    assert len(aligned) == motor_t.size
    shifted = tracker_t - latency
    distance = np.abs(motor_t[:, None] - shifted[None, :])
    nearest = distance.min(axis=1)
    matched = nearest <= tolerance
    got = aligned["tip_px"].to_numpy()
    assert np.array_equal(np.isfinite(got), matched)
    # the matched sample is at the nearest distance (ties may go either way)
    picked = (got[matched] - 100.0).astype(int)
    assert np.allclose(distance[matched, picked], nearest[matched])
    assert report.n_unmatched == int((~matched).sum())
    assert report.n_motor == motor_t.size and report.n_tracker == tracker_t.size
