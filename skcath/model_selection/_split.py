"""Cross-validation splitters that hold out shaft settings or catheters.

The splitters read the ``catheter`` and ``setting`` columns of the recordings
(long format, ``docs/data_format.rst``) and yield integer row positions, so
they plug into the ``cv=`` argument of :func:`sklearn.model_selection.cross_validate`,
:func:`~sklearn.model_selection.cross_val_score` and
:class:`~sklearn.model_selection.GridSearchCV`. A run belongs to exactly one
catheter and one setting, so all its rows (sweep and motion) always land on
the same side of a split.

Unlike the group splitters of scikit-learn, the training set of a fold is not
the complement of its test set: a setting is held out *within* its catheter
(the other catheters never enter the fold), and excluded settings stay in
training without ever being tested.
"""

import inspect
import numbers
import warnings

import numpy as np
import pandas as pd
from sklearn.model_selection import BaseCrossValidator
from sklearn.utils import check_random_state

from .._format import CATHETER, RUN, SETTING
from .._validation import factorize_ids
from ..exceptions import GroupsNotUsedWarning

__all__ = ["LeaveOneCatheterOut", "LeaveOneSettingOut", "SettingGroupKFold", "exclusion_set"]

_DOCS = "docs/data_format.rst"


# ---------------------------------------------------------------------------
# reading the recordings
# ---------------------------------------------------------------------------
def exclusion_set(exclude_settings):
    """Setting labels to exclude, as a set of strings.

    Parameters
    ----------
    exclude_settings : str, iterable of labels or None
        The ``exclude_settings`` of a splitter: one setting, several, or
        none. Labels are compared as strings.

    Returns
    -------
    labels : frozenset of str

    Raises
    ------
    TypeError
        If ``exclude_settings`` is neither None, a string nor an iterable.
    """
    if exclude_settings is None:
        return frozenset()
    if isinstance(exclude_settings, str):
        return frozenset([exclude_settings])
    if isinstance(exclude_settings, (pd.Series, pd.Index, np.ndarray)):
        exclude_settings = list(np.asarray(exclude_settings, dtype=object).ravel())
    try:
        labels = list(exclude_settings)
    except TypeError:
        raise TypeError(
            "exclude_settings must be None or an iterable of setting labels "
            f"(e.g. ['S00']); got {type(exclude_settings).__qualname__} "
            f"{exclude_settings!r}."
        ) from None
    return frozenset(str(label) for label in labels)


class _Layout:
    """Catheter and (catheter, setting) pair of every row of the recordings.

    Attributes
    ----------
    catheter : ndarray of shape (n_rows,)
        Catheter code of every row, in order of first appearance.
    pair : ndarray of shape (n_rows,)
        Code of the (catheter, setting) pair of every row, in order of first
        appearance; within a catheter, settings are in order of first
        appearance.
    pair_catheter : ndarray of shape (n_pairs,)
        Catheter code of every pair.
    pair_setting : ndarray of shape (n_pairs,), dtype object
        Setting label of every pair, as a string.
    catheters : ndarray of shape (n_catheters,), dtype object
        Catheter ids.
    """

    def __init__(self, X, caller):
        if not isinstance(X, pd.DataFrame):
            if X is None:
                raise ValueError(
                    f"{caller} needs the recordings X (a pandas DataFrame with the "
                    f"columns {CATHETER!r} and {SETTING!r}) to know the folds; got None."
                )
            raise TypeError(
                f"{caller} expects X as a pandas DataFrame in the long recording "
                f"format with the columns {CATHETER!r} and {SETTING!r} (see {_DOCS}); "
                f"got {type(X).__module__}.{type(X).__qualname__}."
            )
        missing = [c for c in (CATHETER, SETTING) if c not in X.columns]
        if missing:
            raise ValueError(
                f"{caller} reads the columns {[CATHETER, SETTING]} of X; X is "
                f"missing {missing} (see {_DOCS})."
            )
        if len(X) == 0:
            raise ValueError(f"{caller} got an empty DataFrame X (0 rows).")

        self.catheter, self.catheters = factorize_ids(X, CATHETER)
        setting_codes, setting_values = factorize_ids(X, SETTING)
        # Settings are compared as strings, so 1 and "1" (or a categorical
        # and a plain column) name the same setting.
        labels = np.array([str(v) for v in setting_values], dtype=object)
        label_codes, label_uniques = pd.factorize(labels, sort=False)
        setting = np.asarray(label_codes, dtype=np.intp)[setting_codes]
        combined = self.catheter * np.intp(len(label_uniques)) + setting
        pair, pair_keys = pd.factorize(combined, sort=False)
        self.pair = np.asarray(pair, dtype=np.intp)
        pair_keys = np.asarray(pair_keys, dtype=np.intp)
        self.pair_catheter = pair_keys // len(label_uniques)
        self.pair_setting = np.asarray(label_uniques, dtype=object)[pair_keys % len(label_uniques)]

        if RUN in X.columns:
            self._check_runs(X)

    def _check_runs(self, X):
        """Raise if a run id appears under more than one (catheter, setting) pair."""
        run, runs = factorize_ids(X, RUN)
        first = np.full(len(runs), -1, dtype=np.intp)
        first[run[::-1]] = np.arange(len(run) - 1, -1, -1)
        differs = self.pair != self.pair[first[run]]
        if differs.any():
            i = int(np.flatnonzero(differs)[0])
            j = int(first[run[i]])
            raise ValueError(
                f"Run {runs[run[i]]!r} appears under two (catheter, setting) pairs: "
                f"{self._describe(j)} at row position {j} and {self._describe(i)} at "
                f"row position {i}. Run ids must be unique over the data set "
                f"(see {_DOCS}); otherwise the rows of a run would be split."
            )

    def _describe(self, row):
        p = self.pair[row]
        return f"({self.catheters[self.pair_catheter[p]]!r}, {self.pair_setting[p]!r})"

    def testable_pairs(self, excluded):
        """Pair codes of every catheter whose setting is not excluded, in fold order."""
        keep = np.array([s not in excluded for s in self.pair_setting], dtype=bool)
        return [
            np.flatnonzero(keep & (self.pair_catheter == c))
            for c in range(len(self.catheters))
        ]


def _no_fold_error(caller, excluded):
    return ValueError(
        f"{caller} found no setting to test: every setting of X is in "
        f"exclude_settings={sorted(excluded)}."
    )


# ---------------------------------------------------------------------------
# base class
# ---------------------------------------------------------------------------
class _ParamSplitter(BaseCrossValidator):
    """``get_params`` and ``set_params`` from the constructor's arguments."""

    def get_params(self, deep=True):
        """Parameters of the splitter (for :func:`sklearn.base.clone`).

        Parameters
        ----------
        deep : bool, default=True
            Ignored; the splitters hold no nested objects.

        Returns
        -------
        params : dict
            Constructor argument names mapped to their values.
        """
        return {name: getattr(self, name) for name in self._param_names()}

    def set_params(self, **params):
        """Set constructor parameters.

        Parameters
        ----------
        **params : dict
            Parameter names and values.

        Returns
        -------
        self : object
        """
        valid = self._param_names()
        for name, value in params.items():
            if name not in valid:
                raise ValueError(
                    f"Invalid parameter {name!r} for {type(self).__name__}; "
                    f"valid parameters are {sorted(valid)}."
                )
            setattr(self, name, value)
        return self

    @classmethod
    def _param_names(cls):
        signature = inspect.signature(cls.__init__)
        return [p for p in signature.parameters if p != "self"]


class _RecordingSplitter(_ParamSplitter):
    """Common part: ``split`` and ``get_n_splits`` from a fold plan.

    Subclasses implement ``_plan(layout, counting=False)``, which returns the
    folds as a list of ``(catheter_code, test_pairs)``: the catheter of the
    fold and the (catheter, setting) pair codes it tests. The row masks are
    built one fold at a time in ``split``. With ``_within_catheter`` True the
    training set is the rest of the fold's catheter, otherwise all other
    catheters.
    """

    _within_catheter = True

    def _layout(self, X, method, groups):
        caller = f"{type(self).__name__}.{method}"
        if groups is not None:
            warnings.warn(
                GroupsNotUsedWarning(
                    f"{caller} got groups, which it does not use: it groups the rows by "
                    f"the {CATHETER!r} and {SETTING!r} columns of X. Leave groups out, or "
                    "use a scikit-learn group splitter (GroupKFold, LeaveOneGroupOut) to "
                    "fold by other groups."
                ),
                stacklevel=3,
            )
        return _Layout(X, caller)

    def split(self, X, y=None, groups=None):
        """Generate the row positions of the training and test set of every fold.

        Parameters
        ----------
        X : pandas.DataFrame
            Recordings in the long format (``docs/data_format.rst``); only the
            ``catheter`` and ``setting`` columns are read (and ``run``, when
            present, to check that no run id spans two settings).
        y : object, default=None
            Ignored, present for API compatibility.
        groups : object, default=None
            Not used: the folds come from the ``catheter`` and ``setting``
            columns of ``X``. Accepted so that code written for scikit-learn's
            group splitters runs, with a
            :class:`~skcath.exceptions.GroupsNotUsedWarning` when given.

        Yields
        ------
        train : ndarray of int
            Increasing row positions (for ``X.iloc``) of the training set.
        test : ndarray of int
            Increasing row positions of the test set.
        """
        layout = self._layout(X, "split", groups)
        for c, test_pairs in self._plan(layout):
            is_test = np.zeros(len(layout.pair_catheter), dtype=bool)
            is_test[test_pairs] = True
            test = is_test[layout.pair]
            if self._within_catheter:
                train = (layout.catheter == c) & ~test
            else:
                train = layout.catheter != c
            yield np.flatnonzero(train).astype(np.intp), np.flatnonzero(test).astype(np.intp)

    def get_n_splits(self, X=None, y=None, groups=None):
        """Number of folds for the recordings ``X``.

        Parameters
        ----------
        X : pandas.DataFrame
            Recordings in the long format; required, since the number of
            folds depends on the catheters and settings they contain.
        y : object, default=None
            Ignored.
        groups : object, default=None
            Not used; warns :class:`~skcath.exceptions.GroupsNotUsedWarning`
            when given.

        Returns
        -------
        n_splits : int
        """
        layout = self._layout(X, "get_n_splits", groups)
        return len(self._plan(layout, counting=True))


# ---------------------------------------------------------------------------
# splitters
# ---------------------------------------------------------------------------
class LeaveOneSettingOut(_RecordingSplitter):
    """Hold out one shaft setting at a time, within its catheter.

    For every catheter (in order of first appearance) and every one of its
    settings not in ``exclude_settings`` (in order of first appearance within
    the catheter), the test set is all rows of that (catheter, setting) pair,
    every repeat and both phases, and the training set is the rows of the
    **same catheter's** other settings. Other catheters never enter the fold.

    Parameters
    ----------
    exclude_settings : iterable of setting labels or str, default=None
        Settings never tested, for example a straight reference setting
        (``["S00"]``); their rows stay in the training set of every fold of
        their catheter. Labels are compared as strings (so categorical and
        integer setting columns work) and labels absent from the data are
        allowed. A single string is one label.

    See Also
    --------
    SettingGroupKFold : Hold out groups of settings within a catheter.
    LeaveOneCatheterOut : Hold out a whole catheter.

    Notes
    -----
    The number of folds is the number of (catheter, setting) pairs whose
    setting is not excluded. A catheter whose settings are all excluded gives
    no fold; a catheter with a single setting that is not excluded is an
    error, since holding it out leaves nothing to train on.

    Examples
    --------
    >>> import pandas as pd
    >>> from skcath.model_selection import LeaveOneSettingOut
    >>> X = pd.DataFrame({"catheter": ["C1"] * 4 + ["C2"] * 2,
    ...                   "setting": ["S00", "S01", "S01", "S02", "S00", "S01"]})
    >>> cv = LeaveOneSettingOut(exclude_settings=["S00"])
    >>> cv.get_n_splits(X)
    3
    >>> for train, test in cv.split(X):
    ...     print(train, test)
    [0 3] [1 2]
    [0 1 2] [3]
    [4] [5]
    """

    def __init__(self, *, exclude_settings=None):
        self.exclude_settings = exclude_settings

    def _plan(self, layout, counting=False):
        excluded = exclusion_set(self.exclude_settings)
        folds = []
        for c, pairs in enumerate(layout.testable_pairs(excluded)):
            if pairs.size and np.count_nonzero(layout.pair_catheter == c) == 1:
                raise ValueError(
                    f"Catheter {layout.catheters[c]!r} has a single setting "
                    f"({layout.pair_setting[pairs[0]]!r}): holding it out leaves no "
                    "row of the catheter to train on. Add it to exclude_settings or "
                    "leave the catheter out of X."
                )
            folds.extend((c, pairs[[k]]) for k in range(pairs.size))
        if not folds:
            raise _no_fold_error(type(self).__name__, excluded)
        return folds


class SettingGroupKFold(_RecordingSplitter):
    """K-fold over the shaft settings of each catheter, within the catheter.

    Every catheter's settings not in ``exclude_settings`` are split into
    ``n_splits`` groups of near-equal size (the first groups get one setting
    more when the count does not divide). Each group is held out in turn with
    all its runs; the training set is the rest of the **same catheter**. The
    folds are ``n_splits`` per catheter, catheters in order of first
    appearance.

    Parameters
    ----------
    n_splits : int, default=4
        Number of setting groups per catheter, at least 2.
    exclude_settings : iterable of setting labels or str, default=None
        Settings never tested but kept in training (see
        :class:`LeaveOneSettingOut`).
    shuffle : bool, default=False
        Without shuffling, the groups are consecutive settings in order of
        first appearance within the catheter. With shuffling, each catheter's
        settings are permuted before being grouped.
    random_state : int, RandomState instance or None, default=None
        Seed of the permutation when ``shuffle=True``; an int gives the same
        folds on every call of ``split``. Must be None when ``shuffle=False``.

    See Also
    --------
    LeaveOneSettingOut : One setting per fold.

    Notes
    -----
    A catheter whose settings are all excluded gives no fold; a catheter with
    at least one but fewer than ``n_splits`` testable settings is an error.

    Examples
    --------
    >>> import pandas as pd
    >>> from skcath.model_selection import SettingGroupKFold
    >>> X = pd.DataFrame({"catheter": "C1",
    ...                   "setting": ["S00", "S01", "S02", "S03", "S04", "S05"]})
    >>> cv = SettingGroupKFold(n_splits=2, exclude_settings=["S00"])
    >>> for train, test in cv.split(X):
    ...     print(train, test)
    [0 4 5] [1 2 3]
    [0 1 2 3] [4 5]
    """

    def __init__(self, n_splits=4, *, exclude_settings=None, shuffle=False, random_state=None):
        self.n_splits = n_splits
        self.exclude_settings = exclude_settings
        self.shuffle = shuffle
        self.random_state = random_state

    def _check_params(self):
        n_splits = self.n_splits
        if (
            not isinstance(n_splits, numbers.Integral)
            or isinstance(n_splits, bool)
            or n_splits < 2
        ):
            raise ValueError(
                f"n_splits must be an integer >= 2 (setting groups per catheter); "
                f"got {n_splits!r}."
            )
        if not isinstance(self.shuffle, (bool, np.bool_)):
            raise TypeError(f"shuffle must be True or False; got {self.shuffle!r}.")
        if not self.shuffle and self.random_state is not None:
            raise ValueError(
                "random_state has no effect when shuffle=False; leave it at None "
                "or pass shuffle=True."
            )

    def _plan(self, layout, counting=False):
        self._check_params()
        excluded = exclusion_set(self.exclude_settings)
        # Counting the folds must not draw from a shared RandomState.
        rng = check_random_state(self.random_state) if self.shuffle and not counting else None
        n_splits = int(self.n_splits)
        folds = []
        for c, pairs in enumerate(layout.testable_pairs(excluded)):
            if pairs.size == 0:
                continue
            if pairs.size < n_splits:
                raise ValueError(
                    f"n_splits={n_splits} is more than the {pairs.size} testable "
                    f"setting(s) of catheter {layout.catheters[c]!r} "
                    f"({list(layout.pair_setting[pairs])}); lower n_splits or use "
                    "LeaveOneSettingOut."
                )
            if rng is not None:
                pairs = pairs[rng.permutation(pairs.size)]
            folds.extend((c, group) for group in np.array_split(pairs, n_splits))
        if not folds:
            raise _no_fold_error(type(self).__name__, excluded)
        return folds


class LeaveOneCatheterOut(_RecordingSplitter):
    """Hold out one catheter at a time.

    For every catheter (in order of first appearance), the test set is its
    rows whose setting is not in ``exclude_settings`` and the training set is
    all rows of all other catheters, excluded settings included.

    Parameters
    ----------
    exclude_settings : iterable of setting labels or str, default=None
        Settings never tested (see :class:`LeaveOneSettingOut`); the other
        catheters' rows of these settings stay in training.

    See Also
    --------
    LeaveOneSettingOut : Hold out a setting within its catheter.

    Notes
    -----
    The number of folds is the number of catheters with at least one
    testable setting. At least two catheters are needed.

    Examples
    --------
    >>> import pandas as pd
    >>> from skcath.model_selection import LeaveOneCatheterOut
    >>> X = pd.DataFrame({"catheter": ["C1", "C1", "C2", "C2"],
    ...                   "setting": ["S00", "S01", "S00", "S01"]})
    >>> for train, test in LeaveOneCatheterOut(exclude_settings="S00").split(X):
    ...     print(train, test)
    [2 3] [1]
    [0 1] [3]
    """

    _within_catheter = False

    def __init__(self, *, exclude_settings=None):
        self.exclude_settings = exclude_settings

    def _plan(self, layout, counting=False):
        excluded = exclusion_set(self.exclude_settings)
        if len(layout.catheters) < 2:
            raise ValueError(
                f"{type(self).__name__} needs at least 2 catheters in X (one to "
                f"test, the others to train on); got {list(layout.catheters)}."
            )
        folds = []
        for c, pairs in enumerate(layout.testable_pairs(excluded)):
            if pairs.size:
                folds.append((c, pairs))
        if not folds:
            raise _no_fold_error(type(self).__name__, excluded)
        return folds
