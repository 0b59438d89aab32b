"""Tests of skcath.model_selection.BlockKFold: blocked K-fold inside runs.

The expected fold of every row is derived here with integer arithmetic from
the ``run`` and ``phase`` columns, independently of the splitter, on
recordings whose runs are interleaved row by row.
"""

import pickle

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_array_equal
from sklearn.base import clone
from sklearn.dummy import DummyRegressor
from sklearn.model_selection import cross_val_score
from test_model_selection import _recordings

from skcath.model_selection import BlockKFold

LAYOUT = {"C2": ["S00", "S05"], "C1": ["S03", "S01"]}


@pytest.fixture(scope="module")
def data():
    """Eight runs of 2 sweep and 13 motion rows, rows of a catheter's runs interleaved."""
    return _recordings(layout=LAYOUT, n_repeats=2, n_sweep=2, n_motion=13, seed=3)


def _expected_folds(X, n_splits, n_blocks, group_column="run"):
    """Fold of every row, from the motion rows of each group in row order (-1: none)."""
    fold = np.full(len(X), -1)
    motion = (X["phase"] == "motion").to_numpy()
    groups = X[group_column].to_numpy()
    for g in pd.unique(groups):
        rows = np.flatnonzero((groups == g) & motion)
        n = rows.size
        sizes = [n // n_blocks + (1 if b < n % n_blocks else 0) for b in range(n_blocks)]
        start = 0
        for b, size in enumerate(sizes):
            fold[rows[start:start + size]] = b % n_splits
            start += size
    return fold


def _check_partition(folds, n_rows, tested):
    """Positions, no overlap between test sets, every tested row once, train = complement."""
    seen = np.zeros(n_rows, dtype=int)
    for train, test in folds:
        assert train.dtype.kind == "i" and test.dtype.kind == "i"
        assert np.all(np.diff(train) > 0) and np.all(np.diff(test) > 0)
        assert_array_equal(np.sort(np.concatenate([train, test])), np.arange(n_rows))
        seen[test] += 1
    assert_array_equal(seen, tested.astype(int))


@pytest.mark.parametrize("n_splits, n_blocks", [(2, 6), (3, 4), (2, 13)])
def test_folds_are_interleaved_blocks_of_each_run(data, n_splits, n_blocks):
    X, _ = data
    cv = BlockKFold(n_splits, n_blocks=n_blocks)
    folds = list(cv.split(X))
    assert cv.get_n_splits(X) == len(folds) == n_splits
    motion = (X["phase"] == "motion").to_numpy()
    _check_partition(folds, len(X), motion)  # sweep rows are never tested
    expected = _expected_folds(X, n_splits, n_blocks)
    run = X["run"].to_numpy()
    for k, (_, test) in enumerate(folds):
        assert_array_equal(test, np.flatnonzero(expected == k))
        assert set(run[test]) == set(run)  # every fold tests every run
        for r in np.unique(run):
            # within the run's motion rows, the fold's rows are whole blocks
            in_run = np.flatnonzero((run == r) & motion)
            tested = np.isin(in_run, test)
            n_pieces = int(tested[0]) + int(np.count_nonzero(np.diff(tested.astype(int)) == 1))
            assert n_pieces == len(range(k, n_blocks, n_splits))


def test_block_lengths_differ_by_at_most_one():
    X = np.zeros((23, 2))
    folds = list(BlockKFold(2, n_blocks=4).split(X))
    # no run or phase: the 23 rows are one run, cut 6, 6, 6, 5
    assert_array_equal(folds[0][1], np.r_[0:6, 12:18])
    assert_array_equal(folds[1][1], np.r_[6:12, 18:23])
    _check_partition(folds, 23, np.ones(23, dtype=bool))


def test_groups_are_respected(data):
    X, y = data
    # groups given: each catheter is one series, cut over all its runs' motion rows
    folds = list(BlockKFold(2, n_blocks=6).split(X, y, groups=X["catheter"]))
    expected = _expected_folds(X, 2, 6, group_column="catheter")
    for k, (_, test) in enumerate(folds):
        assert_array_equal(test, np.flatnonzero(expected == k))
    # groups of an array without columns: the blocks of one group never hold another's rows
    groups = np.repeat(["a", "b", "c"], [9, 12, 5])
    Xa = np.zeros((26, 1))
    for _, test in BlockKFold(2, n_blocks=4).split(Xa, groups=groups):
        for g in "abc":
            # every group is tested by every fold, in 2 blocks of its own
            rows = np.flatnonzero(groups == g)
            assert np.isin(rows, test).sum() in (rows.size // 2, rows.size - rows.size // 2)
    # a DataFrame without a run column is one run
    one = X.drop(columns="run").reset_index(drop=True)
    expected = _expected_folds(one.assign(run="all"), 2, 6)
    for k, (_, test) in enumerate(BlockKFold(2, n_blocks=6).split(one)):
        assert_array_equal(test, np.flatnonzero(expected == k))


def test_input_is_not_modified(data):
    X, y = data
    before, groups = X.copy(), X["catheter"].copy()
    list(BlockKFold(2, n_blocks=4).split(X, y, groups=groups))
    pd.testing.assert_frame_equal(X, before)
    pd.testing.assert_series_equal(groups, before["catheter"])


def test_repr_clone_pickle():
    cv = BlockKFold(3, n_blocks=9)
    assert repr(cv) == "BlockKFold(n_blocks=9, n_splits=3)"
    assert clone(cv).get_params() == {"n_splits": 3, "n_blocks": 9}
    assert pickle.loads(pickle.dumps(cv)).get_params() == cv.get_params()
    assert cv.set_params(n_blocks=12).n_blocks == 12
    with pytest.raises(ValueError, match="Invalid parameter 'blocks' for BlockKFold"):
        cv.set_params(blocks=3)


def test_with_cross_val_score(data):
    X, y = data
    cv = BlockKFold(2, n_blocks=4)
    scores = cross_val_score(DummyRegressor(), X, y, cv=cv)
    assert scores.shape == (2,) and np.isfinite(scores).all()
    # the same folds given as a list of (train, test)
    assert_array_equal(scores, cross_val_score(DummyRegressor(), X, y, cv=list(cv.split(X))))
    # without the run and phase columns, all rows are one run and all are tested
    other = cross_val_score(DummyRegressor(), X[["q1", "q2"]], y, cv=cv)
    assert not np.array_equal(scores, other)


@pytest.mark.parametrize(
    "params, match",
    [
        ({"n_splits": 1}, r"The 'n_splits' parameter of BlockKFold must be an int in the range"),
        ({"n_splits": 2.0}, r"The 'n_splits' parameter of BlockKFold must be an int"),
        ({"n_blocks": 1}, r"The 'n_blocks' parameter of BlockKFold must be an int in the range"),
        ({"n_blocks": "20"}, r"The 'n_blocks' parameter of BlockKFold must be an int"),
        ({"n_splits": 5, "n_blocks": 4}, r"n_blocks=4 must be at least n_splits=5"),
    ],
)
def test_bad_parameters_are_named(data, params, match):
    X, _ = data
    cv = BlockKFold(**params)
    with pytest.raises(ValueError, match=match):
        cv.get_n_splits()
    with pytest.raises(ValueError, match=match):
        next(cv.split(X))


def test_bad_rows_are_named(data):
    X, _ = data
    cv = BlockKFold(2, n_blocks=14)
    with pytest.raises(ValueError, match=r"Run \(group\) 'C2-S00-R0' has 13 row\(s\) to test, "
                       r"fewer than n_blocks=14"):
        next(cv.split(X))
    with pytest.raises(ValueError, match=r"groups must hold one label per row of X \(40 rows\); "
                       r"got shape \(39,\)"):
        next(BlockKFold().split(np.zeros((40, 1)), groups=np.zeros(39)))
    groups = np.array(["a"] * 40, dtype=object)
    groups[7] = None
    with pytest.raises(ValueError, match=r"groups has 1 missing label\(s\) \(NaN/None\), first "
                       r"at row position 7"):
        next(BlockKFold().split(np.zeros((40, 1)), groups=groups))
    with pytest.raises(ValueError, match=r"BlockKFold found no row to test: X has no 'phase' == "
                       r"'motion' row"):
        next(cv.split(X.assign(phase="sweep")))
    with pytest.raises(ValueError, match=r"BlockKFold.split needs X"):
        next(cv.split(None))


def test_run_without_motion_rows_is_not_tested(data):
    X, _ = data
    only_sweep = X["run"] == "C1-S01-R1"
    Xs = X.assign(phase=X["phase"].where(~only_sweep, "sweep"))
    for train, test in BlockKFold(2, n_blocks=4).split(Xs):
        assert not only_sweep.to_numpy()[test].any()
        assert only_sweep.to_numpy()[train].sum() == only_sweep.sum()
