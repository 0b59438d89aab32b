"""Tests of skcath._validation: the shared validation path of the long format."""

import re

import numpy as np
import pandas as pd
import pytest

from skcath._format import REQUIRED_COLUMNS
from sklearn.utils._param_validation import InvalidParameterError

from skcath._medians import group_medians
from skcath._validation import (
    MAX_GAP_FRACTION,
    REFERENCE_TOLERANCE_MM,
    check_recordings,
    check_target,
    motor_columns,
)

NUMERIC = ["t", "q1", "q2", "tau1", "tau2", "ref_x", "ref_y", "ref_z"]


def make_recordings(n_runs=3, n_sweep=3, n_motion=4, seed=0, first_label=100):
    """Valid long-format recordings: runs ``r0, r1, ...`` stored one after another.

    Row labels start at ``first_label`` so that messages naming a row label can
    be told apart from row positions.
    """
    rng = np.random.default_rng(seed)
    frames = []
    for k in range(n_runs):
        n = n_sweep + n_motion
        sweep = np.arange(n) < n_sweep
        ref = rng.normal(size=(n, 3))
        ref[~sweep] = np.nan
        frames.append(
            pd.DataFrame(
                {
                    "catheter": f"c{k % 2}",
                    "setting": f"s{k}",
                    "run": f"r{k}",
                    "t": 0.5 + 0.01 * np.arange(n),
                    "phase": np.where(sweep, "sweep", "motion"),
                    "q1": rng.normal(size=n),
                    "q2": rng.normal(size=n),
                    "tau1": rng.normal(size=n),
                    "tau2": rng.normal(size=n),
                    "ref_x": ref[:, 0],
                    "ref_y": ref[:, 1],
                    "ref_z": ref[:, 2],
                }
            )
        )
    X = pd.concat(frames, ignore_index=True)
    X.index = pd.RangeIndex(first_label, first_label + len(X))
    y = rng.normal(size=(len(X), 3))
    # on sweep rows the target and the reference are the same measurement
    sweep = (X["phase"] == "sweep").to_numpy()
    y[sweep] = X.loc[sweep, ["ref_x", "ref_y", "ref_z"]].to_numpy()
    return X, y


def label_of(X, run, step):
    """Row label of the ``step``-th row of ``run``."""
    return X.index[X["run"] == run][step]


def set_value(X, run, step, column, value):
    """Return a copy of ``X`` with one cell changed (column cast to object if needed)."""
    X = X.copy()
    label = label_of(X, run, step)
    if isinstance(value, str) and X[column].dtype == np.float64:
        X[column] = X[column].astype(object)
    X.loc[label, column] = value
    return X


# ---------------------------------------------------------------------------
# valid input
# ---------------------------------------------------------------------------
def test_valid_input_returns_float64_copies():
    X, y = make_recordings()
    X_checked, y_checked = check_recordings(X, y)
    assert X_checked is not X
    assert list(X_checked.columns) == list(X.columns)
    assert X_checked.index.equals(X.index)
    for column in NUMERIC:
        assert X_checked[column].dtype == np.float64
    pd.testing.assert_frame_equal(X_checked, X)
    assert y_checked.dtype == np.float64 and y_checked.shape == (len(X), 3)
    assert not np.shares_memory(y_checked, y)
    np.testing.assert_array_equal(y_checked, y)


def test_without_y_returns_none():
    X, _ = make_recordings()
    _, y_checked = check_recordings(X)
    assert y_checked is None


def test_integer_and_numeric_string_columns_are_coerced():
    X, _ = make_recordings()
    X["q1"] = np.arange(len(X))  # int64
    X["tau2"] = X["tau2"].map(repr).astype(object)
    X["q2"] = pd.array(np.arange(len(X)), dtype="Int64")
    X_checked, _ = check_recordings(X)
    for column in ("q1", "q2", "tau2"):
        assert X_checked[column].dtype == np.float64
    np.testing.assert_allclose(X_checked["tau2"], X["tau2"].astype(float))


def test_inputs_are_not_modified():
    X, y = make_recordings()
    X["q1"] = np.arange(len(X))  # needs coercion
    X_before, y_before = X.copy(), y.copy()
    X_checked, y_checked = check_recordings(X, y)
    pd.testing.assert_frame_equal(X, X_before)
    assert X["q1"].dtype == np.int64
    np.testing.assert_array_equal(y, y_before)
    # the results are independent of the inputs
    X_checked.loc[X_checked.index[0], "q2"] = 123.0
    y_checked[0] = 7.0
    pd.testing.assert_frame_equal(X, X_before)
    np.testing.assert_array_equal(y, y_before)


@pytest.mark.parametrize("copy", [True, False])
def test_copy_false_still_leaves_input_untouched(copy):
    X, _ = make_recordings()
    X_before = X.copy()
    X_checked, _ = check_recordings(X, copy=copy)
    X_checked.loc[X_checked.index[0], "q1"] = 99.0
    pd.testing.assert_frame_equal(X, X_before)


def test_y_dataframe_is_not_modified_and_converted():
    X, y = make_recordings()
    y_frame = pd.DataFrame(y, columns=["p_x", "p_y", "p_z"])
    y_frame.iloc[3] = np.nan
    before = y_frame.copy()
    _, y_checked = check_recordings(X, y_frame)
    pd.testing.assert_frame_equal(y_frame, before)
    assert isinstance(y_checked, np.ndarray) and y_checked.dtype == np.float64
    assert np.isnan(y_checked[3]).all()


def test_interleaved_runs_are_accepted_and_keep_row_order():
    X, y = make_recordings(n_runs=3)
    # round-robin interleaving keeps the time order within each run
    step = X.groupby("run").cumcount()
    order = np.lexsort((X["run"].to_numpy(), step.to_numpy()))
    X_mixed, y_mixed = X.iloc[order], y[order]
    X_checked, y_checked = check_recordings(X_mixed, y_mixed)
    assert X_checked.index.equals(X_mixed.index)
    np.testing.assert_array_equal(y_checked, y_mixed)


def test_nan_reference_is_a_dropout_and_allowed():
    X, y = make_recordings()
    X = set_value(X, "r1", 0, "ref_y", np.nan)
    y[4] = np.nan
    _, y_checked = check_recordings(X, y)
    assert np.isnan(y_checked[4]).all()


def test_require_sweep_false_allows_motion_only_runs():
    X, _ = make_recordings()
    X = X[~((X["run"] == "r2") & (X["phase"] == "sweep"))]
    X_checked, _ = check_recordings(X, require_sweep=False)
    pd.testing.assert_frame_equal(X_checked, X)  # every row kept, r2 without a sweep
    # the same runs are refused when a sweep is required, naming the run
    with pytest.raises(ValueError, match="r2"):
        check_recordings(X)


def test_columns_subset_skips_unlisted_channels():
    X, _ = make_recordings()
    X = X.drop(columns=["tau1", "tau2"]).assign(tau1="not checked")
    columns = [c for c in REQUIRED_COLUMNS if c not in ("tau1", "tau2")]
    X_checked, _ = check_recordings(X, columns=columns)
    assert X_checked["tau1"].iloc[0] == "not checked"


# ---------------------------------------------------------------------------
# X errors
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("bad", [np.zeros((3, 12)), [[1, 2]], pd.Series([1.0])])
def test_non_dataframe_is_rejected(bad):
    with pytest.raises(TypeError, match=r"DataFrame.*docs/data_format\.rst"):
        check_recordings(bad)


def test_empty_frame_is_rejected():
    X, _ = make_recordings()
    with pytest.raises(ValueError, match="empty"):
        check_recordings(X.iloc[:0])


def test_missing_columns_are_all_listed():
    X, _ = make_recordings()
    with pytest.raises(ValueError, match=r"\['q2', 'ref_z'\].*Expected columns"):
        check_recordings(X.drop(columns=["q2", "ref_z"]))


def test_duplicated_required_column_is_rejected():
    X, _ = make_recordings()
    X = pd.concat([X, X[["q1"]]], axis=1)
    with pytest.raises(ValueError, match=r"\['q1'\] more than once"):
        check_recordings(X)


@pytest.mark.parametrize("column", ["q1", "t", "ref_x"])
def test_non_numeric_value_names_column_run_and_row(column):
    X, _ = make_recordings()
    X = set_value(X, "r1", 2, column, "abc")
    label = label_of(X, "r1", 2)
    with pytest.raises(
        ValueError, match=rf"'{column}' must be numeric.*'abc'.*run 'r1', row label {label}"
    ):
        check_recordings(X)


def test_unconvertible_objects_are_rejected():
    X, _ = make_recordings()
    X["tau1"] = X["tau1"].astype(object)
    X.loc[label_of(X, "r0", 1), "tau1"] = [1.0, 2.0]
    with pytest.raises(ValueError, match=r"'tau1' must be numeric.*run 'r0'"):
        check_recordings(X)


@pytest.mark.parametrize("dtype", [bool, "datetime64[ns]"])
def test_non_real_dtypes_are_rejected(dtype):
    X, _ = make_recordings()
    X["q2"] = np.zeros(len(X), dtype=dtype)
    with pytest.raises(ValueError, match=r"'q2' must hold real numbers"):
        check_recordings(X)


@pytest.mark.parametrize("column", ["t", "q1", "q2", "tau1", "tau2"])
@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_non_finite_channel_names_column_run_and_row(column, value):
    X, _ = make_recordings()
    X = set_value(X, "r2", 5, column, value)
    label = label_of(X, "r2", 5)
    with pytest.raises(
        ValueError, match=rf"'{column}' contains 1 non-finite.*run 'r2', row label {label}"
    ):
        check_recordings(X)


@pytest.mark.parametrize("value", [np.inf, -np.inf])
def test_infinite_reference_is_rejected(value):
    X, _ = make_recordings()
    X = set_value(X, "r0", 1, "ref_z", value)
    with pytest.raises(ValueError, match=r"'ref_z'.*\+-inf is not.*run 'r0'"):
        check_recordings(X)


@pytest.mark.parametrize("column", ["catheter", "setting", "run"])
def test_missing_id_names_column(column):
    X, _ = make_recordings()
    X[column] = X[column].astype(object)
    X.loc[label_of(X, "r1", 3), column] = None
    with pytest.raises(ValueError, match=rf"'{column}' contains 1 missing id"):
        check_recordings(X)


def test_invalid_phase_values_are_listed():
    X, _ = make_recordings()
    X = set_value(X, "r0", 4, "phase", "calib")
    X = set_value(X, "r1", 4, "phase", "Motion")
    with pytest.raises(ValueError, match=r"'phase'.*'calib', 'Motion'"):
        check_recordings(X)


def test_missing_phase_is_rejected():
    X, _ = make_recordings()
    X = set_value(X, "r0", 4, "phase", None)
    with pytest.raises(ValueError, match=r"'phase'.*1 missing"):
        check_recordings(X)


def test_run_without_sweep_is_named():
    X, _ = make_recordings()
    X = X[~((X["run"] == "r1") & (X["phase"] == "sweep"))]
    with pytest.raises(ValueError, match=r"Run\(s\) 'r1' have no 'sweep' rows"):
        check_recordings(X)


def test_sweep_after_motion_is_rejected():
    X, _ = make_recordings(n_sweep=3, n_motion=4)
    X = set_value(X, "r2", 5, "phase", "sweep")
    label = label_of(X, "r2", 5)
    with pytest.raises(ValueError, match=rf"run 'r2' a 'sweep' row \(row label {label}\)"):
        check_recordings(X, require_sweep=False)


@pytest.mark.parametrize("delta", [0.0, -0.5])
def test_time_not_increasing_names_run_and_rows(delta):
    X, _ = make_recordings()
    previous = X.loc[label_of(X, "r1", 3), "t"]
    X = set_value(X, "r1", 4, "t", previous + delta)
    label = label_of(X, "r1", 4)
    with pytest.raises(
        ValueError,
        match=rf"strictly increasing.*run 'r1' goes from .* to .*row label {label}",
    ):
        check_recordings(X)


def test_time_restarting_in_the_next_run_is_fine():
    X, _ = make_recordings()  # every run starts at t = 0.5 s
    starts = X.groupby("run", observed=True)["t"].first()
    assert starts.nunique() == 1 and len(starts) > 1  # the clock restarts in every run
    X_checked, _ = check_recordings(X)
    pd.testing.assert_frame_equal(X_checked, X)
    # the same restart inside one run is refused: the check is per run
    restarted = set_value(X, "r1", 4, "t", starts["r1"])
    with pytest.raises(ValueError, match="strictly increasing.*run 'r1'"):
        check_recordings(restarted)


def test_time_order_is_checked_within_interleaved_runs():
    X, _ = make_recordings(n_runs=2)
    X = X.iloc[[0, 7, 1, 8, 2, 9, 3, 10, 5, 11, 4, 12, 6, 13]]  # r0 rows 4, 5 swapped
    with pytest.raises(ValueError, match=r"run 'r0' goes from"):
        check_recordings(X)


@pytest.mark.parametrize("column, noun", [("catheter", "catheters"), ("setting", "settings")])
def test_run_id_reused_across_catheters_or_settings(column, noun):
    X, _ = make_recordings()
    X = set_value(X, "r1", 6, column, "other")
    with pytest.raises(ValueError, match=rf"Run id 'r1' is used for several {noun}.*'other'"):
        check_recordings(X)


@pytest.mark.parametrize(
    "kwargs", [{"require_sweep": "yes"}, {"copy": 1}, {"columns": 3}, {"columns": None}]
)
def test_bad_options_are_rejected_by_name(kwargs):
    X, _ = make_recordings()
    (name,) = kwargs
    with pytest.raises(InvalidParameterError, match=rf"'{name}' parameter of check_recordings"):
        check_recordings(X, **kwargs)


# ---------------------------------------------------------------------------
# y errors
# ---------------------------------------------------------------------------
def test_y_length_mismatch():
    X, y = make_recordings()
    with pytest.raises(ValueError, match=rf"y has {len(X) - 1} rows but .* have {len(X)}"):
        check_recordings(X, y[:-1])


@pytest.mark.parametrize("shape", [(21,), (21, 2), (21, 3, 1)])
def test_y_wrong_shape(shape):
    X, _ = make_recordings()
    with pytest.raises(ValueError, match=r"shape \(n_rows, 3\)"):
        check_recordings(X, np.zeros(shape))


def test_y_series_and_wrong_column_count_are_rejected():
    X, y = make_recordings()
    with pytest.raises(ValueError, match="Series"):
        check_recordings(X, pd.Series(y[:, 0]))
    with pytest.raises(ValueError, match="3 columns"):
        check_recordings(X, pd.DataFrame(y[:, :2]))


def test_y_non_numeric_is_rejected():
    X, y = make_recordings()
    y_obj = y.astype(object)
    y_obj[5, 1] = "x"
    with pytest.raises(ValueError, match=r"y column 1 \('p_y'\).*'x' at row position 5"):
        check_recordings(X, y_obj)
    frame = pd.DataFrame(y_obj)
    with pytest.raises(ValueError, match=r"'p_y'"):
        check_recordings(X, frame)


def test_y_infinite_is_rejected():
    X, y = make_recordings()
    y[7, 2] = np.inf
    with pytest.raises(ValueError, match=r"infinite.*'p_z' at row position 7"):
        check_recordings(X, y)


def test_check_target_accepts_lists():
    out = check_target([[1, 2, 3], [4, 5, np.nan]], 2)
    assert out.dtype == np.float64 and np.isnan(out[1, 2])


# ---------------------------------------------------------------------------
# target columns by name
# ---------------------------------------------------------------------------
TARGET = ["p_x", "p_y", "p_z"]


@pytest.mark.parametrize("order", [[2, 1, 0], [1, 2, 0], [0, 2, 1]])
def test_y_frame_columns_are_matched_by_name(order):
    X, y = make_recordings()
    y_frame = pd.DataFrame(y[:, order], columns=[TARGET[j] for j in order])
    before = y_frame.copy()
    _, y_checked = check_recordings(X, y_frame)
    np.testing.assert_array_equal(y_checked, y)
    pd.testing.assert_frame_equal(y_frame, before)
    np.testing.assert_array_equal(check_target(y_frame, len(X)), y)


def test_y_frame_without_names_is_taken_by_position():
    X, y = make_recordings()
    _, y_checked = check_recordings(X, pd.DataFrame(y))
    np.testing.assert_array_equal(y_checked, y)


@pytest.mark.parametrize(
    "names",
    [["x", "y", "z"], ["p_x", "p_y", "p_y"], ["p_x", "p_y", "q"], [1, 2, 3], ["0", "1", "2"]],
)
def test_y_frame_with_other_names_is_rejected(names):
    X, y = make_recordings()
    y_frame = pd.DataFrame(y, columns=names)
    with pytest.raises(ValueError, match=r"y is a DataFrame with the columns .*target names "
                       r"\['p_x', 'p_y', 'p_z'\] \(in any order"):
        check_recordings(X, y_frame)


def test_y_frame_names_are_listed_when_the_count_is_wrong():
    X, y = make_recordings()
    y_frame = pd.DataFrame(np.column_stack([y, y[:, 0]]), columns=[*TARGET, "p_w"])
    with pytest.raises(ValueError, match=r"3 columns .*'p_w'"):
        check_recordings(X, y_frame)


# ---------------------------------------------------------------------------
# target against the reference on sweep rows
# ---------------------------------------------------------------------------
def test_group_medians_match_pandas():
    rng = np.random.default_rng(3)
    values = rng.normal(size=200)
    codes = rng.integers(0, 6, 200)
    codes[codes == 4] = 5  # group 4 is empty
    medians = group_medians(values, codes, 7)
    expected = pd.Series(values).groupby(codes).median().reindex(range(7)).to_numpy()
    np.testing.assert_allclose(medians, expected, equal_nan=True)


def _scaled_recordings(n_sweep=8, n_motion=30):
    """Recordings whose tip positions are tens of mm away from the base, y = ref on sweep rows."""
    X, y = make_recordings(n_sweep=n_sweep, n_motion=n_motion)
    X[["ref_x", "ref_y", "ref_z"]] = 10.0 * X[["ref_x", "ref_y", "ref_z"]] + 60.0
    return X, 10.0 * y + 60.0


def test_y_in_metres_against_reference_in_mm_is_rejected():
    X, y = _scaled_recordings()
    with pytest.raises(
        ValueError,
        match=r"disagree on the 'sweep' rows of run 'r0': their median distance is \d+\.?\d* mm "
        r"over 8 rows .*y is 0\.001 times .*Runs affected: 'r0', 'r1', 'r2'",
    ):
        check_recordings(X, y / 1000.0)


def test_y_shifted_by_rows_is_rejected():
    X, y = _scaled_recordings()
    with pytest.raises(ValueError, match=r"disagree .*run 'r0'.*shifted against the rows of X"):
        check_recordings(X, np.roll(y, 5, axis=0))


@pytest.mark.parametrize("offset, accepted", [(0.8, True), (1.2, False)])
def test_reference_tolerance_is_on_the_median_distance(offset, accepted):
    assert REFERENCE_TOLERANCE_MM == 1.0
    X, y = _scaled_recordings()
    sweep = (X["phase"] == "sweep").to_numpy()
    y[sweep, 0] += offset
    y[np.flatnonzero(sweep)[0]] += 500.0  # one glitch does not move the median
    if accepted:
        check_recordings(X, y)
    else:
        with pytest.raises(ValueError, match=r"median distance is 1\.2 mm"):
            check_recordings(X, y)


def test_reference_check_skips_rows_without_both_values():
    X, y = _scaled_recordings()
    sweep = (X["phase"] == "sweep").to_numpy()
    r1 = (X["run"] == "r1").to_numpy()
    X.loc[sweep & r1, "ref_x"] = np.nan  # no reference in the sweep of r1
    y[sweep & r1] = 0.0
    others = np.flatnonzero(sweep & ~r1)
    y[others[::2], 1] = np.nan  # dropouts of y on half the sweep rows of r0 and r2
    y[others[1]] += 50.0  # one of the 4 rows left in r0 is off: the median is not
    check_recordings(X, y)
    y[others[3]] += 50.0  # two of 4: the median is
    with pytest.raises(ValueError, match=r"run 'r0'.* over 4 rows"):
        check_recordings(X, y)
    # without the reference columns among those checked, nothing is compared
    columns = [c for c in REQUIRED_COLUMNS if not c.startswith("ref_")]
    check_recordings(X, np.zeros_like(y), columns=columns)


# ---------------------------------------------------------------------------
# motion rows of a run at a constant rate
# ---------------------------------------------------------------------------
def _drop_motion_rows(X, y, every):
    """Drop every ``every``-th motion row of each run."""
    step = X.groupby("run").cumcount().to_numpy()
    drop = (X["phase"] == "motion").to_numpy() & (step % every == 0)
    return X[~drop], y[~drop]


def test_motion_rows_missing_samples_are_rejected():
    X, y = make_recordings(n_sweep=3, n_motion=60)
    X_cut, y_cut = _drop_motion_rows(X, y, every=5)  # 20 % of the rows, like a KFold(5) fold
    with pytest.raises(
        ValueError,
        match=r"The 'motion' rows of run 'r0' miss samples: \d+ of their \d+ time steps "
        r"\(\d+ %, at most 5 % allowed\).*cut a run.*GroupKFold",
    ):
        check_recordings(X_cut, y_cut)


def test_motion_rows_with_few_gaps_or_thinned_evenly_are_accepted():
    assert MAX_GAP_FRACTION == 0.05
    X, y = make_recordings(n_sweep=3, n_motion=60)
    check_recordings(*_drop_motion_rows(X, y, every=30))  # 2 of 59 steps
    motion = (X["phase"] == "motion").to_numpy()
    step = X.groupby("run").cumcount().to_numpy()
    keep = ~motion | (step % 2 == 0)  # every other motion row: a constant rate
    check_recordings(X[keep], y[keep])
    sweep_thinned = motion | (step % 2 == 0)  # thinning the sweep is allowed
    check_recordings(X[sweep_thinned], y[sweep_thinned])
    # runs with fewer than 20 motion steps are not judged
    X_short, y_short = make_recordings(n_sweep=3, n_motion=12)
    check_recordings(*_drop_motion_rows(X_short, y_short, every=2))


def test_run_without_sweep_names_the_cut_run_fix():
    X, y = make_recordings()
    rows = (X["run"] == "r1").to_numpy() & (X["phase"] == "sweep").to_numpy()
    with pytest.raises(ValueError, match=r"Run\(s\) 'r1' have no 'sweep' rows.*cut a run.*"
                       r"groups=X\['run'\].*LeaveOneSettingOut"):
        check_recordings(X[~rows], y[~rows])


# ---------------------------------------------------------------------------
# any number of motors, torques optional
# ---------------------------------------------------------------------------
def _motors(X, n_motors, torques=True):
    """``X`` of ``make_recordings`` with ``n_motors`` motors (q3, tau3 drawn at random)."""
    rng = np.random.default_rng(5)
    X = X.drop(columns=["q2", "tau2"]) if n_motors == 1 else X.copy()
    for k in range(3, n_motors + 1):
        X[f"q{k}"] = rng.normal(size=len(X))
        X[f"tau{k}"] = rng.normal(size=len(X))
    if not torques:
        X = X.drop(columns=[c for c in X.columns if c.startswith("tau")])
    return X


@pytest.mark.parametrize("n_motors", [1, 2, 3, 4])
@pytest.mark.parametrize("torques", [True, False])
def test_motor_columns_reads_the_motors_and_torques(n_motors, torques):
    X = _motors(make_recordings()[0], n_motors, torques)
    motors, torque_columns = motor_columns(X)
    assert motors == tuple(f"q{k}" for k in range(1, n_motors + 1))
    assert torque_columns == (tuple(f"tau{k}" for k in range(1, n_motors + 1)) if torques else ())
    # the columns alone decide: an empty frame and column order do not matter
    assert motor_columns(X.iloc[:0, ::-1]) == (motors, torque_columns)


@pytest.mark.parametrize("n_motors", [1, 3])
@pytest.mark.parametrize("torques", [True, False])
def test_recordings_of_any_number_of_motors_are_checked(n_motors, torques):
    X, y = make_recordings()
    X = _motors(X, n_motors, torques)
    X_checked, _ = check_recordings(X, y)
    pd.testing.assert_frame_equal(X_checked, X)
    # every motor and torque column is a numeric channel that must be finite
    last = f"tau{n_motors}" if torques else f"q{n_motors}"
    X_bad = X.copy()
    X_bad.loc[X.index[5], last] = np.nan
    with pytest.raises(ValueError, match=rf"Column '{last}' contains 1 non-finite value"):
        check_recordings(X_bad, y)
    X_text = X.astype({last: object})
    X_text.loc[X.index[2], last] = "1.5"
    assert check_recordings(X_text)[0][last].dtype == np.float64


@pytest.mark.parametrize(
    "drop, add, missing",
    [
        (["q2"], {}, "['q2']"),
        (["tau1"], {}, "['tau1']"),
        ([], {"q4": 0.0}, "['q3', 'tau3', 'tau4']"),
        ([], {"q3": 0.0}, "['tau3']"),
    ],
    ids=["motor-gap", "torque-gap", "motor-beyond-a-gap", "torques-of-some-motors"],
)
def test_channel_gaps_are_named(drop, add, missing):
    X, _ = make_recordings()
    X = X.drop(columns=drop).assign(**add)
    expected = re.escape(f"missing the column(s) {missing}") + r".*without a gap"
    with pytest.raises(ValueError, match=expected):
        motor_columns(X)
    with pytest.raises(ValueError, match=expected):
        check_recordings(X)
