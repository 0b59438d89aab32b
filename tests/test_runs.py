"""Tests of skcath._runs: the rows of every run, and runs as arrays.

The padded converters are tested through their public home in
``test_sequences.py``.
"""

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from skcath._runs import group_positions, run_codes, run_differences, run_positions, run_steps
from test_validation import make_recordings


# ---------------------------------------------------------------------------
# rows of every run
# ---------------------------------------------------------------------------
def test_run_codes_follow_first_appearance():
    X, _ = make_recordings(n_runs=3, n_sweep=1, n_motion=1)
    X = X.iloc[[2, 0, 4, 3, 1, 5]]  # r1, r0, r2, r1, r0, r2
    codes, runs = run_codes(X)
    assert list(runs) == ["r1", "r0", "r2"]
    np.testing.assert_array_equal(codes, [0, 1, 2, 0, 1, 2])


def test_run_codes_rejects_missing_run():
    X, _ = make_recordings()
    with pytest.raises(ValueError, match=r"\['run'\]"):
        run_codes(X.drop(columns="run"))


def test_group_positions_is_stable():
    codes = np.array([1, 0, 1, 2, 0, 1])
    order, bounds = group_positions(codes, 4)
    np.testing.assert_array_equal(order, [1, 4, 0, 2, 5, 3])
    np.testing.assert_array_equal(bounds, [0, 2, 5, 6, 6])


def test_group_positions_rejects_bad_codes():
    with pytest.raises(ValueError, match="non-negative"):
        group_positions(np.array([0, -1]))
    with pytest.raises(ValueError, match="integer"):
        group_positions(np.array([0.0, 1.0]))


def test_run_positions_with_row_mask():
    X, _ = make_recordings(n_runs=2, n_sweep=2, n_motion=2)
    X = X.iloc[[0, 4, 1, 5, 2, 6, 3, 7]]
    positions = run_positions(X)
    np.testing.assert_array_equal(positions[0], [0, 2, 4, 6])
    np.testing.assert_array_equal(positions[1], [1, 3, 5, 7])
    motion = run_positions(X, rows=(X["phase"] == "motion").to_numpy())
    np.testing.assert_array_equal(motion[0], [4, 6])
    np.testing.assert_array_equal(motion[1], [5, 7])
    nothing = run_positions(X, rows=np.zeros(len(X), dtype=bool))
    assert [p.size for p in nothing] == [0, 0]


def test_run_steps_count_rows_within_each_run():
    # rows of runs 0 and 1 interleaved, run 2 has no row, run 3 one row
    codes = np.array([0, 1, 0, 1, 0, 3, 1])
    assert_array_equal(run_steps(codes, 4), [0, 0, 1, 1, 2, 0, 2])
    assert run_steps(codes).dtype == np.intp
    assert run_steps(np.zeros(0, dtype=np.intp)).shape == (0,)
    with pytest.raises(ValueError, match="non-negative"):
        run_steps(np.array([0, -1]))


def test_run_steps_agree_with_run_positions():
    X, _ = make_recordings(n_runs=3, n_sweep=2, n_motion=3)
    X = X.iloc[np.random.default_rng(0).permutation(len(X))]
    codes, _ = run_codes(X)
    steps = run_steps(codes)
    for positions in run_positions(X):
        assert_array_equal(steps[positions], np.arange(positions.size))


def test_run_differences_with_interleaved_runs():
    # rows of runs 0 and 1 interleaved, run 2 has no row, run 3 one row
    codes = np.array([0, 1, 0, 1, 0, 3, 1])
    q = np.array([[0, 10], [5, 50], [1, 12], [7, 49], [4, 11], [9, 9], [6, 40]], dtype=float)
    dq = run_differences(q, codes, 4)
    expected = np.array([[0, 0], [0, 0], [1, 2], [2, -1], [3, -1], [0, 0], [-1, -9]], dtype=float)
    assert_array_equal(dq, expected)
    # the same rows stored run after run give the same differences
    order = np.argsort(codes, kind="stable")
    assert_array_equal(run_differences(q[order], codes[order], 4), expected[order])
