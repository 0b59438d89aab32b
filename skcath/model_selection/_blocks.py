"""Blocked K-fold inside runs: interleaved contiguous blocks of the motion rows.

When there are too few runs to hold one out (a single training recording,
for example), a model can still be compared with itself on parts of a run it
did not learn from. :class:`BlockKFold` cuts the ``"motion"`` rows of every
run into contiguous blocks of (nearly) equal length and deals the blocks out
to the folds in turn, so that every fold tests all stretches of the run and
neighbouring samples are held out together.
"""

import numbers

import numpy as np
import pandas as pd
from sklearn.utils._param_validation import Interval, validate_parameter_constraints
from sklearn.utils.validation import _num_samples

from .._format import MOTION, PHASE, RUN
from ._split import _ParamSplitter

__all__ = ["BlockKFold"]


def _group_codes(groups, n_samples):
    """Integer codes of ``groups`` (order of first appearance) and their labels.

    Raises
    ------
    ValueError
        If ``groups`` does not have one label per row, or has a missing label.
    """
    labels = np.asarray(groups, dtype=object)
    if labels.ndim != 1 or labels.shape[0] != n_samples:
        raise ValueError(
            f"groups must hold one label per row of X ({n_samples} rows); got "
            f"shape {labels.shape}."
        )
    codes, uniques = pd.factorize(labels, sort=False)
    missing = np.flatnonzero(codes < 0)
    if missing.size:
        raise ValueError(
            f"groups has {missing.size} missing label(s) (NaN/None), first at row "
            f"position {int(missing[0])}; every row needs a group (a run id)."
        )
    return np.asarray(codes, dtype=np.intp), np.asarray(uniques, dtype=object)


def block_test_folds(testable, codes, n_splits, n_blocks):
    """Fold of every row: the blocks of each group dealt out to the folds in turn.

    Parameters
    ----------
    testable : ndarray of bool, shape (n_samples,)
        Rows that may be held out; the others are in no test set.
    codes : ndarray of int, shape (n_samples,)
        Group code of every row (``0 .. n_groups - 1``).
    n_splits : int
        Number of folds.
    n_blocks : int
        Number of contiguous blocks of each group's testable rows.

    Returns
    -------
    test_fold : ndarray of int, shape (n_samples,)
        Fold ``0 .. n_splits - 1`` that tests the row, ``-1`` for rows that no
        fold tests.
    """
    test_fold = np.full(codes.shape[0], -1, dtype=np.intp)
    for group in range(int(codes.max(initial=-1)) + 1):
        rows = np.flatnonzero(testable & (codes == group))
        for b, block in enumerate(np.array_split(rows, n_blocks)):
            test_fold[block] = b % n_splits
    return test_fold


class BlockKFold(_ParamSplitter):
    """K folds of interleaved contiguous blocks of the motion rows of every run.

    The ``"motion"`` rows of each run (each group) are cut, in row order, into
    ``n_blocks`` contiguous blocks of (nearly) equal length; block ``b`` is
    tested by fold ``b % n_splits``. Every motion row is tested by exactly one
    fold, every fold tests every run, and a block never spans two runs. The
    training set of a fold is all other rows: the other folds' blocks and the
    ``"sweep"`` rows, which no fold tests.

    Parameters
    ----------
    n_splits : int, default=2
        Number of folds, at least 2.
    n_blocks : int, default=20
        Number of blocks per run, at least ``n_splits``; each fold tests
        ``n_blocks / n_splits`` of them (a multiple of ``n_splits`` gives
        every fold the same number).

    See Also
    --------
    SettingGroupKFold : Hold out whole settings, when there are several.
    sklearn.model_selection.TimeSeriesSplit : Test only after the training rows.

    Notes
    -----
    The rows of ``X`` are read as follows. The groups are ``groups`` when
    given, else the ``run`` column of ``X`` when ``X`` is a DataFrame with
    one, else all rows form one run. Only the rows whose ``phase`` is
    ``"motion"`` are tested when ``X`` has a ``phase`` column, else all rows.
    A run without such rows is tested by no fold; a run with fewer of them
    than ``n_blocks`` is an error.

    The training rows of a fold are not a run's time series: they have holes
    where the test blocks are. A sequence model (the residual learners of
    :mod:`skcath.residuals`) is fitted on the whole ``X`` with the targets of
    the test rows set to NaN, which the backbones and learners skip as they
    skip tracker dropouts, and scored on the test rows.

    Examples
    --------
    >>> import numpy as np
    >>> import pandas as pd
    >>> from skcath.model_selection import BlockKFold
    >>> X = pd.DataFrame({"run": ["r1"] * 7 + ["r2"] * 4,
    ...                   "phase": ["sweep"] * 3 + ["motion"] * 4 + ["motion"] * 4})
    >>> cv = BlockKFold(n_splits=2, n_blocks=2)
    >>> cv.get_n_splits(X)
    2
    >>> for train, test in cv.split(X):
    ...     print(train.tolist(), test.tolist())
    [0, 1, 2, 5, 6, 9, 10] [3, 4, 7, 8]
    [0, 1, 2, 3, 4, 7, 8] [5, 6, 9, 10]
    """

    _parameter_constraints: dict = {
        "n_splits": [Interval(numbers.Integral, 2, None, closed="left")],
        "n_blocks": [Interval(numbers.Integral, 2, None, closed="left")],
    }

    def __init__(self, n_splits=2, *, n_blocks=20):
        self.n_splits = n_splits
        self.n_blocks = n_blocks

    def _check_params(self):
        validate_parameter_constraints(
            self._parameter_constraints, self.get_params(), caller_name=type(self).__name__
        )
        if self.n_blocks < self.n_splits:
            raise ValueError(
                f"n_blocks={self.n_blocks!r} must be at least n_splits={self.n_splits!r}: "
                "every fold tests at least one block of every run."
            )

    def _test_folds(self, X, groups):
        """Fold of every row (see :func:`block_test_folds`), with the checks on ``X``."""
        self._check_params()
        if X is None:
            raise ValueError(
                f"{type(self).__name__}.split needs X (the recordings, or any array "
                "with one row per sample) to know the folds; got None."
            )
        n_samples = _num_samples(X)
        is_frame = isinstance(X, pd.DataFrame)
        if groups is None and is_frame and RUN in X.columns:
            groups = X[RUN]
        if groups is None:
            codes, labels = np.zeros(n_samples, dtype=np.intp), np.array(["X"], dtype=object)
        else:
            codes, labels = _group_codes(groups, n_samples)
        if is_frame and PHASE in X.columns:
            testable = (X[PHASE] == MOTION).to_numpy(dtype=bool)
        else:
            testable = np.ones(n_samples, dtype=bool)
        counts = np.bincount(codes[testable], minlength=len(labels))
        short = np.flatnonzero((counts > 0) & (counts < self.n_blocks))
        if short.size:
            g = int(short[0])
            raise ValueError(
                f"Run (group) {labels[g]!r} has {int(counts[g])} row(s) to test, fewer "
                f"than n_blocks={self.n_blocks}: lower n_blocks, or leave the run out of X."
            )
        if not counts.any():
            raise ValueError(
                f"{type(self).__name__} found no row to test: X has no "
                f"{PHASE!r} == {MOTION!r} row (or no row at all)."
            )
        return block_test_folds(testable, codes, int(self.n_splits), int(self.n_blocks))

    def split(self, X, y=None, groups=None):
        """Generate the row positions of the training and test set of every fold.

        Parameters
        ----------
        X : pandas.DataFrame or array-like of shape (n_samples, n_features)
            Recordings in the long format (``docs/data_format.rst``), of
            which the ``run`` and ``phase`` columns are read when present; or
            any array with one row per sample.
        y : object, default=None
            Ignored, present for API compatibility.
        groups : array-like of shape (n_samples,), default=None
            Run of every row: each run is cut into its own blocks. None reads
            the ``run`` column of ``X`` (all rows one run without it).

        Yields
        ------
        train : ndarray of int
            Row positions (for ``X.iloc``, increasing) of every row the fold
            does not test, sweep rows included.
        test : ndarray of int
            Row positions (increasing) of the fold's blocks.
        """
        test_fold = self._test_folds(X, groups)
        for k in range(int(self.n_splits)):
            yield np.flatnonzero(test_fold != k), np.flatnonzero(test_fold == k)

    def get_n_splits(self, X=None, y=None, groups=None):
        """Number of folds, ``n_splits``.

        Parameters
        ----------
        X, y, groups : object, default=None
            Ignored, present for API compatibility.

        Returns
        -------
        n_splits : int
        """
        self._check_params()
        return int(self.n_splits)
