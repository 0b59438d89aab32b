"""Tests of skcath.metrics: per-run tip RMSE with equal run weights, scorers,
error distribution, binned errors and the paired comparison of two methods."""

import pickle

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose

from skcath.metrics import (
    error_cdf,
    make_run_rmse_scorer,
    mean_per_run_rmse,
    motion_time,
    motor_magnitude,
    paired_reduction,
    per_run_rmse,
    rmse_by_motor_magnitude,
    rmse_over_time,
    run_bin_rmse,
    run_rmse_scorer,
)


# ---------------------------------------------------------------------------
# hand-made data
# ---------------------------------------------------------------------------
def _frame(runs, phases):
    """Minimal recordings: only the run and phase columns are read."""
    return pd.DataFrame({"run": runs, "phase": phases})


@pytest.fixture
def two_runs():
    """Two runs with known tip errors.

    Run "b" comes first. Its motion errors are (0, 0, 2) and (2, 0, 0): RMSE 2.
    Run "a" has motion errors (3, 0, 0), (0, 4, 0) and (0, 0, 0):
    RMSE sqrt((9 + 16 + 0) / 3). Every sweep row is off by 100 mm.
    """
    X = _frame(
        ["b", "b", "b", "a", "a", "a", "a"],
        ["sweep", "motion", "motion", "sweep", "motion", "motion", "motion"],
    )
    rng = np.random.default_rng(0)
    y_true = rng.normal(0.0, 30.0, (7, 3))
    err = np.array(
        [
            [100.0, 0.0, 0.0],
            [0.0, 0.0, 2.0],
            [2.0, 0.0, 0.0],
            [0.0, -100.0, 0.0],
            [3.0, 0.0, 0.0],
            [0.0, 4.0, 0.0],
            [0.0, 0.0, 0.0],
        ]
    )
    return X, y_true, y_true + err


RMSE_A = np.sqrt(25.0 / 3.0)
RMSE_B = 2.0


def test_per_run_rmse_by_hand(two_runs):
    X, y_true, y_pred = two_runs
    rmse = per_run_rmse(y_true, y_pred, X)
    assert isinstance(rmse, pd.Series)
    assert list(rmse.index) == ["b", "a"]  # order of first appearance
    assert rmse.index.name == "run"
    assert_allclose(rmse.to_numpy(), [RMSE_B, RMSE_A], rtol=1e-12)
    assert mean_per_run_rmse(y_true, y_pred, X) == pytest.approx((RMSE_A + RMSE_B) / 2, rel=1e-12)


def test_sign_of_errors_and_symmetry(two_runs):
    X, y_true, y_pred = two_runs
    assert_allclose(per_run_rmse(y_pred, y_true, X), per_run_rmse(y_true, y_pred, X), rtol=1e-12)
    assert_allclose(per_run_rmse(y_true, y_true, X), [0.0, 0.0], atol=0)


def test_rows_of_a_run_may_be_interleaved(two_runs):
    X, y_true, y_pred = two_runs
    perm = np.array([3, 0, 4, 1, 5, 6, 2])
    rmse = per_run_rmse(y_true[perm], y_pred[perm], X.iloc[perm])
    assert list(rmse.index) == ["a", "b"]
    assert_allclose(rmse[["b", "a"]].to_numpy(), [RMSE_B, RMSE_A], rtol=1e-12)


def test_runs_have_equal_weights():
    # a long run with error 1 mm and a short run with error 3 mm: the mean
    # over runs is 2 mm, whatever their lengths
    n_long, n_short = 1000, 10
    X = _frame(["long"] * n_long + ["short"] * n_short, "motion")
    y_true = np.zeros((n_long + n_short, 3))
    y_pred = y_true.copy()
    y_pred[:n_long, 0] = 1.0
    y_pred[n_long:, 1] = -3.0
    assert_allclose(per_run_rmse(y_true, y_pred, X).to_numpy(), [1.0, 3.0], rtol=1e-12)
    assert mean_per_run_rmse(y_true, y_pred, X) == pytest.approx(2.0, rel=1e-12)
    pooled = np.sqrt((n_long * 1.0 + n_short * 9.0) / (n_long + n_short))
    assert abs(mean_per_run_rmse(y_true, y_pred, X) - pooled) > 0.5


def test_nan_targets_are_left_out(two_runs):
    X, y_true, y_pred = two_runs
    y_true = y_true.copy()
    y_pred = y_pred.copy()
    # a dropout on a motion row of "a" with a huge error: left out
    X = pd.concat([X, _frame(["a"], ["motion"])], ignore_index=True)
    y_true = np.vstack([y_true, [np.nan, 1.0, 2.0]])  # one NaN coordinate is enough
    y_pred = np.vstack([y_pred, [500.0, 500.0, 500.0]])
    assert_allclose(per_run_rmse(y_true, y_pred, X).to_numpy(), [RMSE_B, RMSE_A], rtol=1e-12)

    # a run whose motion rows are all dropouts has no RMSE and is left out of the mean
    y_true[[1, 2]] = np.nan
    rmse = per_run_rmse(y_true, y_pred, X)
    assert np.isnan(rmse["b"]) and rmse["a"] == pytest.approx(RMSE_A, rel=1e-12)
    assert mean_per_run_rmse(y_true, y_pred, X) == pytest.approx(RMSE_A, rel=1e-12)

    y_true[:] = np.nan
    with pytest.raises(ValueError, match="no run has a scored row"):
        mean_per_run_rmse(y_true, y_pred, X)


def test_phase_selection(two_runs):
    X, y_true, y_pred = two_runs
    assert_allclose(per_run_rmse(y_true, y_pred, X, phase="motion"), [RMSE_B, RMSE_A], rtol=1e-12)
    assert_allclose(per_run_rmse(y_true, y_pred, X, phase="sweep"), [100.0, 100.0], rtol=1e-12)
    all_rows = [np.sqrt((100.0**2 + 4 + 4) / 3), np.sqrt((100.0**2 + 9 + 16) / 4)]
    assert_allclose(per_run_rmse(y_true, y_pred, X, phase=None), all_rows, rtol=1e-12)
    assert mean_per_run_rmse(y_true, y_pred, X, phase=None) == pytest.approx(np.mean(all_rows))

    # phase=None needs no phase column; a phase selection does
    X_no_phase = X.drop(columns="phase")
    assert_allclose(per_run_rmse(y_true, y_pred, X_no_phase, phase=None), all_rows, rtol=1e-12)
    with pytest.raises(ValueError, match="phase"):
        per_run_rmse(y_true, y_pred, X_no_phase)


def test_categorical_ids_and_dataframe_targets(two_runs):
    X, y_true, y_pred = two_runs
    Xc = X.astype({"run": pd.CategoricalDtype(["z", "a", "b"]), "phase": "category"})
    yt = pd.DataFrame(y_true, columns=["p_x", "p_y", "p_z"], index=np.arange(7) + 50)
    rmse = per_run_rmse(yt, y_pred, Xc)
    assert list(rmse.index) == ["b", "a"]  # unused categories do not appear
    assert_allclose(rmse.to_numpy(), [RMSE_B, RMSE_A], rtol=1e-12)


def test_target_frames_are_matched_by_name(two_runs):
    X, y_true, y_pred = two_runs
    names = ["p_z", "p_x", "p_y"]
    yt = pd.DataFrame(y_true[:, [2, 0, 1]], columns=names)
    yp = pd.DataFrame(y_pred[:, [2, 0, 1]], columns=names)
    assert_allclose(per_run_rmse(yt, yp, X), [RMSE_B, RMSE_A], rtol=1e-12)
    with pytest.raises(ValueError, match=r"y_pred is a DataFrame with the columns \['x', 'y', 'z'\]"):
        per_run_rmse(y_true, pd.DataFrame(y_pred, columns=["x", "y", "z"]), X)


def test_no_scored_row_names_the_cut_run_fix(two_runs):
    X, y_true, y_pred = two_runs
    sweep = (X["phase"] == "sweep").to_numpy()
    with pytest.raises(ValueError, match=r"no run has a scored row .*cut a run.*GroupKFold"):
        mean_per_run_rmse(y_true[sweep], y_pred[sweep], X[sweep])


def test_inputs_are_not_modified(two_runs):
    X, y_true, y_pred = two_runs
    y_true[5] = np.nan
    copies = X.copy(), y_true.copy(), y_pred.copy()
    per_run_rmse(y_true, y_pred, X)
    assert X.equals(copies[0])
    np.testing.assert_array_equal(y_true, copies[1])
    np.testing.assert_array_equal(y_pred, copies[2])


# ---------------------------------------------------------------------------
# errors
# ---------------------------------------------------------------------------
def test_shape_mismatch_is_named(two_runs):
    X, y_true, y_pred = two_runs
    with pytest.raises(ValueError, match=r"y_pred.*\(7, 3\).*\(6, 3\)"):
        per_run_rmse(y_true, y_pred[:-1], X)
    with pytest.raises(ValueError, match=r"y_pred.*\(7, 3\)"):
        per_run_rmse(y_true, y_pred[:, :2], X)
    with pytest.raises(ValueError, match=r"y has 6 rows.*7"):
        per_run_rmse(y_true[:-1], y_pred, X)
    with pytest.raises(ValueError, match=r"shape \(n_rows, 3\)"):
        per_run_rmse(y_true[:, 0], y_pred, X)


def test_non_finite_values_are_named(two_runs):
    X, y_true, y_pred = two_runs
    bad = y_pred.copy()
    bad[4, 1] = np.nan
    with pytest.raises(ValueError, match="y_pred contains NaN"):
        per_run_rmse(y_true, bad, X)
    bad[4, 1] = np.inf
    with pytest.raises(ValueError, match="y_pred"):
        per_run_rmse(y_true, bad, X)
    bad = y_true.copy()
    bad[2, 0] = -np.inf
    with pytest.raises(ValueError, match="infinite"):
        per_run_rmse(bad, y_pred, X)


def test_missing_run_column_is_named(two_runs):
    X, y_true, y_pred = two_runs
    with pytest.raises(ValueError, match="'run' column"):
        per_run_rmse(y_true, y_pred, X.drop(columns="run"))
    with pytest.raises(ValueError, match="DataFrame"):
        per_run_rmse(y_true, y_pred, X.to_numpy())


@pytest.mark.parametrize("phase", ["Motion", "all", "", 1])
def test_bad_phase_is_named(two_runs, phase):
    X, y_true, y_pred = two_runs
    with pytest.raises(ValueError, match="phase must be one of"):
        per_run_rmse(y_true, y_pred, X, phase=phase)
    with pytest.raises(ValueError, match="phase must be one of"):
        mean_per_run_rmse(y_true, y_pred, X, phase=phase)
    with pytest.raises(ValueError, match="phase must be one of"):
        make_run_rmse_scorer(phase=phase)


# ---------------------------------------------------------------------------
# scorers
# ---------------------------------------------------------------------------
class _Fixed:
    """Estimator stand-in whose predict returns fixed positions."""

    def __init__(self, pred):
        self.pred = pred

    def predict(self, X):
        return self.pred[: len(X)]


def test_scorer_is_negated_metric(two_runs):
    X, y_true, y_pred = two_runs
    score = run_rmse_scorer(_Fixed(y_pred), X, y_true)
    assert score == pytest.approx(-(RMSE_A + RMSE_B) / 2, rel=1e-12)
    # greater is better: a closer prediction scores higher
    closer = y_true + 0.5 * (y_pred - y_true)
    assert run_rmse_scorer(_Fixed(closer), X, y_true) > score
    assert run_rmse_scorer(_Fixed(y_true), X, y_true) == 0.0


def test_scorer_phases(two_runs):
    X, y_true, y_pred = two_runs
    est = _Fixed(y_pred)
    assert make_run_rmse_scorer()(est, X, y_true) == run_rmse_scorer(est, X, y_true)
    assert make_run_rmse_scorer(phase="sweep")(est, X, y_true) == pytest.approx(-100.0)
    expected = -mean_per_run_rmse(y_true, y_pred, X, phase=None)
    assert make_run_rmse_scorer(phase=None)(est, X, y_true) == pytest.approx(expected, rel=1e-12)
    assert expected < -50.0  # the sweep rows count with phase=None


def test_scorer_refuses_a_run_without_its_sweep(two_runs):
    X, y_true, y_pred = two_runs
    rows = np.array([1, 2, 3, 4, 5, 6])  # run "b" without its sweep row
    with pytest.raises(
        ValueError,
        match=r"hold 1 run\(s\) without 'sweep' rows, first 'b'.*cut a run.*"
        r"groups=X\['run'\].*KFold, the default cv",
    ):
        run_rmse_scorer(_Fixed(y_pred[rows]), X.iloc[rows], y_true[rows])
    # a plain metric on motion rows stays possible
    motion = (X["phase"] == "motion").to_numpy()
    assert mean_per_run_rmse(y_true[motion], y_pred[motion], X[motion]) == pytest.approx(
        (RMSE_A + RMSE_B) / 2, rel=1e-12
    )


@pytest.mark.parametrize("phase", ["motion", "sweep", None])
def test_scorer_pickles(two_runs, phase):
    X, y_true, y_pred = two_runs
    scorer = make_run_rmse_scorer(phase=phase)
    restored = pickle.loads(pickle.dumps(scorer))
    assert restored(_Fixed(y_pred), X, y_true) == scorer(_Fixed(y_pred), X, y_true)
    assert repr(restored) == repr(scorer)
    assert repr(phase) in repr(scorer)
    assert pickle.loads(pickle.dumps(run_rmse_scorer))(_Fixed(y_pred), X, y_true) == pytest.approx(
        -(RMSE_A + RMSE_B) / 2, rel=1e-12
    )


# ---------------------------------------------------------------------------
# error_cdf
# ---------------------------------------------------------------------------
def _with_errors(runs, phases, errors):
    """Recordings and targets whose row errors are the given 3-D offsets (mm)."""
    X = _frame(runs, phases)
    y_true = np.random.default_rng(1).normal(0.0, 20.0, (len(X), 3))
    return X, y_true, y_true + np.asarray(errors, dtype=float)


def test_error_cdf_by_hand(two_runs):
    # motion errors: run "b" 2, 2; run "a" 3, 4, 0 (sweep rows: 100)
    X, y_true, y_pred = two_runs
    cdf = error_cdf(y_true, y_pred, X, [0.0, 2.0, 3.5, 5.0, -1.0])
    assert isinstance(cdf, pd.Series) and cdf.name == "fraction"
    assert cdf.index.name == "threshold_mm"
    assert list(cdf.index) == [0.0, 2.0, 3.5, 5.0, -1.0]  # order as given
    expected = [
        (0 / 2 + 1 / 3) / 2,  # error 0 <= 0: the threshold is inclusive
        (2 / 2 + 1 / 3) / 2,  # 2 <= 2
        (2 / 2 + 2 / 3) / 2,
        1.0,
        0.0,
    ]
    assert_allclose(cdf.to_numpy(), expected, rtol=1e-12)
    assert error_cdf(y_true, y_pred, X, 2.0).tolist() == pytest.approx([expected[1]])
    # sweep rows: 100 mm everywhere
    assert_allclose(error_cdf(y_true, y_pred, X, [99.0, 100.0 + 1e-9], phase="sweep"), [0.0, 1.0])
    # all rows: run "b" has 3, run "a" 4 scored rows
    assert error_cdf(y_true, y_pred, X, [5.0], phase=None).iloc[0] == pytest.approx((2 / 3 + 3 / 4) / 2)
    assert error_cdf(y_true, y_pred, X, [np.inf]).iloc[0] == 1.0


def test_error_cdf_weights_runs_equally():
    # 1000 samples with error 1 mm in one run, 10 with error 9 mm in another:
    # half the runs are below 5 mm, although 99 % of the samples are
    X, y_true, y_pred = _with_errors(
        ["long"] * 1000 + ["short"] * 10, "motion", [[1.0, 0, 0]] * 1000 + [[0, 9.0, 0]] * 10
    )
    assert error_cdf(y_true, y_pred, X, [5.0]).iloc[0] == pytest.approx(0.5)


def test_error_cdf_leaves_out_dropouts_and_empty_runs():
    X, y_true, y_pred = _with_errors(
        ["a", "a", "a", "b", "c"],
        "motion",
        [[1.0, 0, 0], [9.0, 0, 0], [0, 0, 1.0], [0, 7.0, 0], [0, 0, 0]],
    )
    y_true[1] = [np.nan, 0.0, 0.0]  # the 9 mm row of "a" is a dropout
    y_true[4] = np.nan  # run "c" has no scored row and does not count
    assert error_cdf(y_true, y_pred, X, [5.0]).iloc[0] == pytest.approx((1.0 + 0.0) / 2)
    y_true[:] = np.nan
    with pytest.raises(ValueError, match="no run has a scored row"):
        error_cdf(y_true, y_pred, X, [5.0])


def test_error_cdf_errors(two_runs):
    X, y_true, y_pred = two_runs
    with pytest.raises(ValueError, match=r"thresholds contains 1 NaN value\(s\); first at position 1"):
        error_cdf(y_true, y_pred, X, [1.0, np.nan])
    with pytest.raises(ValueError, match="thresholds must be 1-D"):
        error_cdf(y_true, y_pred, X, [[1.0, 2.0]])
    with pytest.raises(ValueError, match="thresholds must hold real numbers"):
        error_cdf(y_true, y_pred, X, ["a"])
    with pytest.raises(ValueError, match="phase must be one of"):
        error_cdf(y_true, y_pred, X, [1.0], phase="all")
    with pytest.raises(ValueError, match=r"y_pred.*\(7, 3\)"):
        error_cdf(y_true, y_pred[:-1], X, [1.0])


# ---------------------------------------------------------------------------
# motor_magnitude and motion_time
# ---------------------------------------------------------------------------
def test_motor_magnitude():
    X = pd.DataFrame({"q1": [3.0, -5.0, 0.0, 8.0], "q2": [4.0, 12.0, -2.0, 0.0], "run": "a"})
    before = X.copy()
    out = motor_magnitude(X)
    assert isinstance(out, np.ndarray) and out.shape == (4,)
    assert_allclose(out, [5.0, 13.0, 2.0, 8.0], rtol=1e-15)
    pd.testing.assert_frame_equal(X, before)
    # integer and string-typed numeric columns are read as numbers
    assert_allclose(motor_magnitude(X.astype({"q1": int, "q2": str})), [5.0, 13.0, 2.0, 8.0])


def test_motor_magnitude_errors():
    X = pd.DataFrame({"q1": [3.0, 1.0], "q2": [4.0, np.nan], "run": "a"})
    with pytest.raises(ValueError, match=r"'q2' contains 1 non-finite"):
        motor_magnitude(X)
    with pytest.raises(ValueError, match=r"missing the column\(s\) \['q1'\]"):
        motor_magnitude(X.drop(columns="q1"))
    with pytest.raises(TypeError, match="DataFrame"):
        motor_magnitude(X.to_numpy())


def test_motion_time_interleaved_runs():
    X = pd.DataFrame(
        {
            "run": ["a", "b", "a", "b", "a", "b", "a"],
            "t": [10.0, 0.0, 10.5, 0.2, 11.0, 0.3, 14.0],
            "phase": ["sweep", "sweep", "motion", "motion", "motion", "motion", "motion"],
        }
    )
    before = X.copy()
    out = motion_time(X)
    assert_allclose(out, [np.nan, np.nan, 0.0, 0.0, 0.5, 0.1, 3.5], rtol=1e-12)
    pd.testing.assert_frame_equal(X, before)
    # a run without motion rows is NaN throughout
    assert np.isnan(motion_time(X.iloc[[0, 1, 2]])[[0, 1]]).all()


def test_motion_time_errors():
    X = pd.DataFrame({"run": ["a", "a"], "t": [0.0, 1.0], "phase": ["sweep", "motion"]})
    with pytest.raises(ValueError, match=r"missing the column\(s\) \['t'\]"):
        motion_time(X.drop(columns="t"))
    with pytest.raises(ValueError, match=r"'phase' must contain only"):
        motion_time(X.assign(phase=["sweep", "free"]))
    with pytest.raises(ValueError, match=r"'t' contains 1 non-finite"):
        motion_time(X.assign(t=[0.0, np.inf]))


# ---------------------------------------------------------------------------
# run_bin_rmse and its shortcuts
# ---------------------------------------------------------------------------
def test_run_bin_rmse_by_hand():
    # run "a": errors 3, 4 in bin [0, 10), 1 in [10, 20); run "b": 2 in [10, 20)
    X, y_true, y_pred = _with_errors(
        ["a", "b", "a", "a", "a"],
        ["motion"] * 5,
        [[3.0, 0, 0], [0, 2.0, 0], [0, 0, 4.0], [1.0, 0, 0], [50.0, 0, 0]],
    )
    values = [0.0, 10.0, 9.999, 10.0, 30.0]  # 30 is outside the bins
    table = run_bin_rmse(y_true, y_pred, X, values, [0.0, 10.0, 20.0])
    assert list(table.columns) == ["run", "bin_left", "bin_right", "n_samples", "rmse_mm"]
    assert table["run"].tolist() == ["a", "a", "b"]
    assert table["bin_left"].tolist() == [0.0, 10.0, 10.0]
    assert table["bin_right"].tolist() == [10.0, 20.0, 20.0]
    assert table["n_samples"].tolist() == [2, 1, 1]
    assert_allclose(table["rmse_mm"], [np.sqrt(12.5), 1.0, 2.0], rtol=1e-12)


def test_run_bin_rmse_edges_are_left_closed():
    X, y_true, y_pred = _with_errors(["a"] * 5, "motion", [[1.0, 0, 0]] * 5)
    values = np.array([-0.1, 0.0, 5.0, 10.0, np.nan])
    table = run_bin_rmse(y_true, y_pred, X, values, [0.0, 5.0, 10.0])
    # -0.1 is below the first edge, 10 equals the last (open) edge, NaN is dropped
    assert table["bin_left"].tolist() == [0.0, 5.0]
    assert table["n_samples"].tolist() == [1, 1]
    table = run_bin_rmse(y_true, y_pred, X, values, [-1.0, 5.0, 10.0 + 1e-9])
    assert table["n_samples"].tolist() == [2, 2]


def test_run_bin_rmse_dropouts_phase_and_empty_bins():
    X, y_true, y_pred = _with_errors(
        ["a", "a", "a", "b"],
        ["sweep", "motion", "motion", "motion"],
        [[7.0, 0, 0], [2.0, 0, 0], [6.0, 0, 0], [3.0, 0, 0]],
    )
    y_true[2] = np.nan
    values = [1.0, 1.0, 1.0, 25.0]
    table = run_bin_rmse(y_true, y_pred, X, values, [0, 10, 20, 30])
    # the empty bin [10, 20) has no row; the dropout and the sweep row are not scored
    assert list(zip(table["run"], table["bin_left"], table["n_samples"])) == [("a", 0.0, 1), ("b", 20.0, 1)]
    assert_allclose(table["rmse_mm"], [2.0, 3.0])
    table = run_bin_rmse(y_true, y_pred, X, values, [0, 10, 20, 30], phase="sweep")
    assert_allclose(table["rmse_mm"], [7.0], rtol=1e-12)
    table = run_bin_rmse(y_true, y_pred, X, values, [0, 10, 20, 30], phase=None)
    assert_allclose(table["rmse_mm"], [np.sqrt((49 + 4) / 2), 3.0])
    # no scored row at all: an empty table with the same columns
    empty = run_bin_rmse(y_true, y_pred, X, values, [100, 200])
    assert empty.empty and list(empty.columns) == ["run", "bin_left", "bin_right", "n_samples", "rmse_mm"]


def test_run_bin_rmse_integer_runs_and_nullable_values():
    X, y_true, y_pred = _with_errors([7, 7, 3], "motion", [[1.0, 0, 0], [5.0, 0, 0], [0, 2.0, 0]])
    values = pd.Series([1.0, None, 4.0], dtype="Float64")  # <NA> is not scored
    table = run_bin_rmse(y_true, y_pred, X, values, [0.0, 5.0])
    assert table["run"].tolist() == [7, 3]
    assert table["run"].dtype.kind == "i"
    assert_allclose(table["rmse_mm"], [1.0, 2.0])
    with pytest.raises(ValueError, match="values must hold real numbers; got dtype bool"):
        run_bin_rmse(y_true, y_pred, X, [True, False, True], [0.0, 5.0])


def test_run_bin_rmse_errors(two_runs):
    X, y_true, y_pred = two_runs
    values = np.zeros(7)
    with pytest.raises(ValueError, match="bins must be strictly increasing; edge 2"):
        run_bin_rmse(y_true, y_pred, X, values, [0, 1, 1])
    with pytest.raises(ValueError, match="at least 2 edges"):
        run_bin_rmse(y_true, y_pred, X, values, [0])
    with pytest.raises(ValueError, match="bins contains 1 NaN"):
        run_bin_rmse(y_true, y_pred, X, values, [0, np.nan])
    with pytest.raises(ValueError, match=r"values must have one entry per row of X \(7\); got 6"):
        run_bin_rmse(y_true, y_pred, X, values[:-1], [0, 1])
    with pytest.raises(ValueError, match="phase must be one of"):
        run_bin_rmse(y_true, y_pred, X, values, [0, 1], phase="Motion")


def _motor_recordings():
    """Two runs with known motor angles, times and errors."""
    X = pd.DataFrame(
        {
            "run": ["a", "a", "a", "a", "b", "b", "b"],
            "t": [0.0, 1.0, 2.0, 13.0, 5.0, 6.0, 26.0],
            "phase": ["sweep", "motion", "motion", "motion", "sweep", "motion", "motion"],
            "q1": [50.0, 3.0, 6.0, 0.0, 0.0, 20.0, 0.0],
            "q2": [0.0, 4.0, 8.0, 12.0, 0.0, 0.0, 0.0],
        }
    )
    y_true = np.zeros((7, 3))
    y_pred = np.zeros((7, 3))
    y_pred[:, 0] = [9.0, 1.0, 3.0, 2.0, 9.0, 4.0, 6.0]
    return X, y_true, y_pred


def test_rmse_by_motor_magnitude():
    X, y_true, y_pred = _motor_recordings()
    # motion magnitudes: a: 5, 10, 12; b: 20, 0. Largest over all rows (sweep 50)
    table = rmse_by_motor_magnitude(y_true, y_pred, X)
    assert list(zip(table["run"], table["bin_left"], table["bin_right"])) == [
        ("a", 0.0, 10.0),
        ("a", 10.0, 20.0),
        ("b", 0.0, 10.0),
        ("b", 20.0, 30.0),  # a magnitude equal to an edge opens the next bin
    ]
    assert_allclose(table["rmse_mm"], [1.0, np.sqrt((9 + 4) / 2), 6.0, 4.0])
    expected = run_bin_rmse(y_true, y_pred, X, motor_magnitude(X), np.arange(0.0, 51.0, 5.0))
    pd.testing.assert_frame_equal(rmse_by_motor_magnitude(y_true, y_pred, X, width=5.0), expected)
    # sweep rows when asked: the 50-deg sweep row lands in the last bin [50, 60)
    sweep = rmse_by_motor_magnitude(y_true, y_pred, X, phase="sweep")
    assert sweep["bin_left"].tolist() == [50.0, 0.0] and sweep["bin_right"].tolist() == [60.0, 10.0]


def test_rmse_over_time():
    X, y_true, y_pred = _motor_recordings()
    # motion time: a: 0, 1, 12; b: 0, 20. The sweep rows are never scored.
    table = rmse_over_time(y_true, y_pred, X, width=10.0)
    assert list(zip(table["run"], table["bin_left"], table["n_samples"])) == [
        ("a", 0.0, 2),
        ("a", 10.0, 1),
        ("b", 0.0, 1),
        ("b", 20.0, 1),
    ]
    assert_allclose(table["rmse_mm"], [np.sqrt(5.0), 2.0, 4.0, 6.0])
    assert table["bin_right"].max() == 30.0
    assert rmse_over_time(y_true, y_pred, X, width=100).shape[0] == 2
    with pytest.raises(ValueError, match="no motion rows"):
        rmse_over_time(y_true[[0, 4]], y_pred[[0, 4]], X.iloc[[0, 4]])


@pytest.mark.parametrize("width", [0, -1.0, np.nan, np.inf, "10", True, None])
def test_bad_width_is_named(width):
    X, y_true, y_pred = _motor_recordings()
    with pytest.raises(ValueError, match="width must be a positive finite number"):
        rmse_by_motor_magnitude(y_true, y_pred, X, width=width)
    with pytest.raises(ValueError, match="width must be a positive finite number"):
        rmse_over_time(y_true, y_pred, X, width=width)


# ---------------------------------------------------------------------------
# paired_reduction
# ---------------------------------------------------------------------------
def test_paired_reduction_by_hand():
    baseline = [8.0, 6.0, 7.0, 9.0, 5.0]
    candidate = [4.0, 7.0, 4.0, 4.0, 5.0]  # one run worse, one tied
    res = paired_reduction(baseline, candidate, ["A", "A", "B", "B", "C"], random_state=0)
    assert res.reduction_mm == pytest.approx((4 - 1 + 3 + 5 + 0) / 5)
    assert res.reduction_pct == pytest.approx(100 * 2.2 / 7.0)
    assert res.fraction_improved == pytest.approx(3 / 5)
    assert (res.n_runs, res.n_clusters) == (5, 3)
    assert res.ci_low_mm <= res.reduction_mm <= res.ci_high_mm
    assert set(res) == {
        "reduction_mm", "reduction_pct", "ci_low_mm", "ci_high_mm",
        "fraction_improved", "n_runs", "n_clusters",
    }


def test_paired_reduction_bootstrap_weights_runs_equally():
    # cluster A: one run with difference 0; cluster B: three runs with difference 4.
    # Resamples: AA (p=1/4) -> 0, BB (1/4) -> 4, AB (1/2) -> 12 / 4 = 3 with equal
    # run weights (2 with equal cluster weights). The central 40 % is all 3.
    res = paired_reduction(
        [5.0, 9.0, 9.0, 9.0], [5.0, 5.0, 5.0, 5.0], ["A", "B", "B", "B"],
        confidence=0.4, random_state=0,
    )
    assert res.reduction_mm == 3.0
    assert res.ci_low_mm == 3.0 and res.ci_high_mm == 3.0
    wide = paired_reduction(
        [5.0, 9.0, 9.0, 9.0], [5.0, 5.0, 5.0, 5.0], ["A", "B", "B", "B"],
        confidence=0.99, random_state=0,
    )
    assert (wide.ci_low_mm, wide.ci_high_mm) == (0.0, 4.0)


def _simulated_runs(n_clusters, runs_per_cluster, seed):
    rng = np.random.default_rng(seed)
    clusters = np.repeat([f"C1/S{k:02d}" for k in range(n_clusters)], runs_per_cluster)
    effect = np.repeat(rng.normal(2.0, 1.0, n_clusters), runs_per_cluster)
    baseline = rng.uniform(6.0, 10.0, clusters.size)
    candidate = baseline - effect - rng.normal(0.0, 0.3, clusters.size)
    return baseline, candidate, clusters


def test_paired_reduction_interval_shrinks_with_more_clusters():
    # the same 6 clusters (3 runs each), then 25 copies of them: identical
    # spread of the cluster means, 25 times as many clusters, so the
    # interval is about 1 / sqrt(25) as wide
    baseline, candidate, clusters = _simulated_runs(6, 3, seed=0)
    few = paired_reduction(baseline, candidate, clusters, random_state=0)
    copies = np.repeat(np.arange(25), baseline.size)
    many = paired_reduction(
        np.tile(baseline, 25), np.tile(candidate, 25),
        [f"{k}-{g}" for k, g in zip(copies, np.tile(clusters, 25))], random_state=0,
    )
    assert many.reduction_mm == pytest.approx(few.reduction_mm, rel=1e-12)
    assert many.n_clusters == 150 and many.n_runs == 450
    for res in (few, many):
        assert res.ci_low_mm < res.reduction_mm < res.ci_high_mm
    ratio = (many.ci_high_mm - many.ci_low_mm) / (few.ci_high_mm - few.ci_low_mm)
    assert 0.12 < ratio < 0.3


def test_paired_reduction_is_reproducible():
    # its speed (at most 1 s for these 204 runs) is measured by
    # benchmarks/bench_functions.py, not here: the test machines are noisy
    baseline, candidate, clusters = _simulated_runs(68, 3, seed=1)  # 204 runs
    first = paired_reduction(baseline, candidate, clusters, n_bootstrap=2000, random_state=42)
    again = paired_reduction(baseline, candidate, clusters, n_bootstrap=2000, random_state=42)
    assert dict(first) == dict(again)
    other = paired_reduction(baseline, candidate, clusters, n_bootstrap=2000, random_state=43)
    assert (other.ci_low_mm, other.ci_high_mm) != (first.ci_low_mm, first.ci_high_mm)
    assert other.reduction_mm == first.reduction_mm
    rs = np.random.RandomState(5)
    assert paired_reduction(baseline, candidate, clusters, random_state=rs).n_runs == 204


def test_paired_reduction_aligns_series():
    baseline, candidate, clusters = _simulated_runs(10, 2, seed=2)
    runs = [f"r{k}" for k in range(20)]
    reference = paired_reduction(baseline, candidate, clusters, random_state=0)
    perm = np.random.default_rng(0).permutation(20)
    b = pd.Series(baseline, index=runs)
    c = pd.Series(candidate, index=runs).iloc[perm]
    g = pd.Series(clusters, index=runs).iloc[perm[::-1]]
    before = b.copy(), c.copy(), g.copy()
    res = paired_reduction(b, c, g, random_state=0)
    assert dict(res) == pytest.approx(dict(reference))
    pd.testing.assert_series_equal(b, before[0])
    pd.testing.assert_series_equal(c, before[1])
    pd.testing.assert_series_equal(g, before[2])
    # positional matching when only one of them is a Series
    res = paired_reduction(b, candidate, clusters, random_state=0)
    assert dict(res) == pytest.approx(dict(reference))


def test_paired_reduction_leaves_out_nan_runs():
    baseline = pd.Series([8.0, np.nan, 7.0, 9.0, 6.0], index=list("abcde"))
    candidate = pd.Series([4.0, 3.0, 4.0, 4.0, np.nan], index=list("abcde"))
    clusters = ["A", "A", "B", "B", "C"]
    res = paired_reduction(baseline, candidate, clusters, random_state=0)
    assert res.n_runs == 3 and res.n_clusters == 2  # cluster C lost its only run
    assert res.reduction_mm == pytest.approx((4 + 3 + 5) / 3)
    assert res.reduction_pct == pytest.approx(100 * 4.0 / 8.0)


def test_paired_reduction_errors():
    b, c, g = [8.0, 6.0, 7.0], [4.0, 3.0, 4.0], ["A", "A", "B"]
    with pytest.raises(ValueError, match=r"lengths 3, 2 and 3"):
        paired_reduction(b, c[:2], g)
    with pytest.raises(ValueError, match=r"lengths 3, 3 and 2"):
        paired_reduction(b, c, g[:2])
    with pytest.raises(ValueError, match="at least 2 clusters"):
        paired_reduction(b, c, ["A", "A", "A"])
    with pytest.raises(ValueError, match=r"clusters contains 1 missing label"):
        paired_reduction(b, c, ["A", None, "B"])
    with pytest.raises(ValueError, match=r"candidate contains 1 \+-inf"):
        paired_reduction(b, [4.0, np.inf, 4.0], g)
    with pytest.raises(ValueError, match="baseline must hold real numbers"):
        paired_reduction(["x", "y", "z"], c, g)
    with pytest.raises(TypeError, match="baseline must be 1-D"):
        paired_reduction(pd.DataFrame({"a": b}), c, g)
    for bad in (0, -5, 2.5, True):
        with pytest.raises(ValueError, match="n_bootstrap must be a positive integer"):
            paired_reduction(b, c, g, n_bootstrap=bad)
    for bad in (0.0, 1.0, 95, "0.95"):
        with pytest.raises(ValueError, match="confidence must be a number strictly between 0 and 1"):
            paired_reduction(b, c, g, confidence=bad)
    # Series with different runs, or duplicated runs
    sb = pd.Series(b, index=["r1", "r2", "r3"])
    with pytest.raises(ValueError, match=r"different index labels.*1 label\(s\) only in candidate"):
        paired_reduction(sb, pd.Series(c, index=["r1", "r2", "r4"]), g)
    with pytest.raises(ValueError, match=r"clusters and the per-run errors are Series with different"):
        paired_reduction(sb, c, pd.Series(g, index=["r1", "r2", "r9"]))
    with pytest.raises(ValueError, match="duplicated index label"):
        paired_reduction(pd.Series(b, index=["r1", "r1", "r3"]), c, g)
