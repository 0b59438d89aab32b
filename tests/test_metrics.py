"""Tests of skcath.metrics: per-run tip RMSE with equal run weights, and scorers."""

import pickle

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose

from skcath.metrics import (
    make_run_rmse_scorer,
    mean_per_run_rmse,
    per_run_rmse,
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
