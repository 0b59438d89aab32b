"""Tests of skcath.model_selection: setting- and catheter-held-out splitters.

The expected folds are derived here from the ``catheter`` and ``setting``
columns with plain pandas, independently of the splitters' implementation,
on small hand-made recordings whose rows are interleaved across runs.
"""

import pickle
import warnings

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_array_equal
from sklearn.base import clone
from sklearn.compose import ColumnTransformer
from sklearn.dummy import DummyRegressor
from sklearn.model_selection import GridSearchCV, cross_val_score, cross_validate
from sklearn.neighbors import KNeighborsRegressor
from sklearn.pipeline import Pipeline

from skcath.exceptions import GroupsNotUsedWarning
from skcath.metrics import mean_per_run_rmse, run_rmse_scorer
from skcath.model_selection import (
    LeaveOneCatheterOut,
    LeaveOneSettingOut,
    SettingGroupKFold,
)

SPLITTERS = [LeaveOneSettingOut, SettingGroupKFold, LeaveOneCatheterOut]

# Settings per catheter, in order of first appearance in the recordings.
# "C2" comes first, and its settings are not in sorted order.
LAYOUT = {
    "C2": ["S00", "S05", "S02"],
    "C1": ["S03", "S00", "S01", "S02"],
}


# ---------------------------------------------------------------------------
# data
# ---------------------------------------------------------------------------
def _recordings(layout=LAYOUT, n_repeats=2, n_sweep=2, n_motion=3, seed=0):
    """Recordings in the long format, rows of different runs interleaved.

    Within a catheter, the rows of all its runs are merged in random order
    (time order kept within each run; runs first appear in the listed order),
    so the positions of a setting's rows are scattered.
    """
    rng = np.random.default_rng(seed)
    n = n_sweep + n_motion
    blocks = []
    for catheter, settings in layout.items():
        runs, keys = [], []
        for setting in settings:
            for r in range(n_repeats):
                runs.append(
                    pd.DataFrame(
                        {
                            "catheter": catheter,
                            "setting": setting,
                            "run": f"{catheter}-{setting}-R{r}",
                            "t": 0.1 * np.arange(n),
                            "phase": ["sweep"] * n_sweep + ["motion"] * n_motion,
                            "q1": rng.normal(0.0, 30.0, n),
                            "q2": rng.normal(0.0, 30.0, n),
                        }
                    )
                )
                # increasing keys within the run; its first row comes before
                # every random key, in run order
                key = np.sort(rng.uniform(0.01, 1.0, n))
                key[0] = 1e-6 * len(keys)
                keys.append(key)
        frame = pd.concat(runs, ignore_index=True)
        blocks.append(frame.iloc[np.argsort(np.concatenate(keys), kind="stable")])
    X = pd.concat(blocks, ignore_index=True)
    X.index = 100 + 3 * np.arange(len(X))  # labels that are not positions
    y = np.column_stack([X["q1"], X["q2"], X["q1"] - X["q2"]]) + rng.normal(0.0, 1.0, (len(X), 3))
    return X, y


@pytest.fixture(scope="module")
def data():
    return _recordings()


def _rows(X, catheter=None, settings=None, exclude=()):
    """Positions of the rows of a catheter (optionally some settings), as a sorted array."""
    keep = np.ones(len(X), dtype=bool)
    if catheter is not None:
        keep &= (X["catheter"] == catheter).to_numpy()
    if settings is not None:
        keep &= X["setting"].isin(settings).to_numpy()
    keep &= ~X["setting"].isin(exclude).to_numpy()
    return np.flatnonzero(keep)


def _check_common(X, folds):
    """Properties every fold must have: positions, disjointness, whole runs."""
    run = X["run"].to_numpy()
    for train, test in folds:
        assert train.dtype.kind == "i" and test.dtype.kind == "i"
        assert np.all(np.diff(train) > 0) and np.all(np.diff(test) > 0)
        assert len(test) > 0 and len(train) > 0
        assert np.intersect1d(train, test).size == 0
        # every run is entirely in the fold's train set, entirely in its test set, or absent
        for part in (train, test):
            for r in np.unique(run[part]):
                assert np.array_equal(np.flatnonzero(run == r), np.intersect1d(np.flatnonzero(run == r), part))


def test_test_data_is_interleaved(data):
    X, _ = data
    # the fixture really interleaves runs: a run's rows are not contiguous
    rows = np.flatnonzero((X["run"] == "C2-S05-R0").to_numpy())
    assert rows[-1] - rows[0] + 1 > rows.size
    for _, frame in X.groupby("run"):
        assert np.all(np.diff(frame["t"].to_numpy()) > 0)
        assert list(frame["phase"]) == ["sweep"] * 2 + ["motion"] * 3


# ---------------------------------------------------------------------------
# LeaveOneSettingOut
# ---------------------------------------------------------------------------
def test_leave_one_setting_out_folds(data):
    X, _ = data
    cv = LeaveOneSettingOut(exclude_settings=["S00"])
    folds = list(cv.split(X))
    expected_order = [("C2", "S05"), ("C2", "S02"), ("C1", "S03"), ("C1", "S01"), ("C1", "S02")]
    assert cv.get_n_splits(X) == len(folds) == 5
    _check_common(X, folds)
    for (train, test), (catheter, setting) in zip(folds, expected_order, strict=True):
        assert_array_equal(test, _rows(X, catheter, [setting]))
        # training set: the same catheter's other settings, the excluded one included
        assert_array_equal(train, np.setdiff1d(_rows(X, catheter), test))
        assert set(X["catheter"].iloc[train]) == {catheter}
        assert "S00" in set(X["setting"].iloc[train])
        assert "S00" not in set(X["setting"].iloc[test])
        assert X["run"].iloc[test].nunique() == 2  # both repeats held out together


def test_leave_one_setting_out_without_exclusion(data):
    X, _ = data
    folds = list(LeaveOneSettingOut().split(X))
    assert len(folds) == 7 == LeaveOneSettingOut().get_n_splits(X)
    tested = [tuple(X[["catheter", "setting"]].iloc[test[0]]) for _, test in folds]
    assert tested == [
        ("C2", "S00"), ("C2", "S05"), ("C2", "S02"),
        ("C1", "S03"), ("C1", "S00"), ("C1", "S01"), ("C1", "S02"),
    ]
    # every row is tested exactly once
    all_test = np.concatenate([test for _, test in folds])
    assert_array_equal(np.sort(all_test), np.arange(len(X)))


def test_same_setting_label_in_two_catheters_is_two_folds(data):
    X, _ = data
    folds = list(LeaveOneSettingOut(exclude_settings=["S00"]).split(X))
    s02 = [test for _, test in folds if set(X["setting"].iloc[test]) == {"S02"}]
    assert len(s02) == 2
    assert [set(X["catheter"].iloc[t]) for t in s02] == [{"C2"}, {"C1"}]


@pytest.mark.parametrize(
    "exclude, n_folds",
    [
        (None, 7),
        ("S00", 5),  # a single string is one label
        (["S00", "S02"], 3),
        (("S00", "S99"), 5),  # labels absent from the data are allowed
        (np.array(["S05"]), 6),
        (pd.Series(["S03", "S01"]), 5),
        ({"S00"}, 5),
    ],
)
def test_exclude_settings_forms(data, exclude, n_folds):
    X, _ = data
    cv = LeaveOneSettingOut(exclude_settings=exclude)
    assert cv.get_n_splits(X) == n_folds
    assert len(list(cv.split(X))) == n_folds


def test_catheter_with_only_excluded_settings_is_skipped(data):
    X, _ = data
    X = X.copy()
    X.loc[X["catheter"] == "C2", "setting"] = "S00"
    for cv in (LeaveOneSettingOut(exclude_settings=["S00"]), SettingGroupKFold(2, exclude_settings=["S00"])):
        folds = list(cv.split(X))
        assert len(folds) == cv.get_n_splits(X) == (3 if isinstance(cv, LeaveOneSettingOut) else 2)
        assert all(set(X["catheter"].iloc[test]) == {"C1"} for _, test in folds)


def test_no_fold_at_all_is_an_error(data):
    X, _ = data
    every = ["S00", "S01", "S02", "S03", "S05"]
    for cv in (
        LeaveOneSettingOut(exclude_settings=every),
        SettingGroupKFold(2, exclude_settings=every),
        LeaveOneCatheterOut(exclude_settings=every),
    ):
        with pytest.raises(ValueError, match="no setting to test"):
            list(cv.split(X))
        with pytest.raises(ValueError, match="no setting to test"):
            cv.get_n_splits(X)


def test_catheter_with_a_single_setting_is_an_error(data):
    X, _ = data
    X = X.copy()
    X.loc[X["catheter"] == "C2", "setting"] = "S07"
    with pytest.raises(ValueError, match="Catheter 'C2' has a single setting \\('S07'\\)"):
        list(LeaveOneSettingOut().split(X))
    # excluded, it gives no fold and no error
    assert LeaveOneSettingOut(exclude_settings=["S07"]).get_n_splits(X) == 4


def test_settings_compare_as_strings(data):
    X, _ = data
    # integer setting ids, a categorical copy, and exclusion given as str or int
    as_int = X.assign(setting=X["setting"].str[1:].astype(int))
    as_cat = X.assign(setting=X["setting"].astype(pd.CategoricalDtype(["S09", "S05", "S03", "S02", "S01", "S00"])))
    reference = list(LeaveOneSettingOut(exclude_settings=["S00"]).split(X))
    for frame, exclude in ((as_int, ["0"]), (as_int, [0]), (as_cat, ["S00"])):
        folds = list(LeaveOneSettingOut(exclude_settings=exclude).split(frame))
        assert len(folds) == len(reference)
        for (a_train, a_test), (b_train, b_test) in zip(folds, reference, strict=True):
            assert_array_equal(a_train, b_train)
            assert_array_equal(a_test, b_test)


def test_mixed_int_and_str_labels_name_one_setting(data):
    X, _ = data
    setting = X["setting"].to_numpy(dtype=object)  # a copy
    setting[(X["run"] == "C1-S01-R0").to_numpy()] = "1"
    setting[(X["run"] == "C1-S01-R1").to_numpy()] = 1
    X = X.assign(setting=setting)
    # "1" and 1 are the same setting: one fold with both repeats, not two folds
    folds = list(LeaveOneSettingOut(exclude_settings=["S00"]).split(X))
    assert len(folds) == 5
    test = folds[3][1]
    assert set(X["run"].iloc[test]) == {"C1-S01-R0", "C1-S01-R1"}


# ---------------------------------------------------------------------------
# SettingGroupKFold
# ---------------------------------------------------------------------------
def test_setting_group_kfold_groups(data):
    X, _ = data
    cv = SettingGroupKFold(n_splits=2, exclude_settings=["S00"])
    folds = list(cv.split(X))
    assert cv.get_n_splits(X) == len(folds) == 4  # 2 catheters x 2 groups
    _check_common(X, folds)
    # consecutive settings in order of first appearance; first groups larger
    expected = [("C2", ["S05"]), ("C2", ["S02"]), ("C1", ["S03", "S01"]), ("C1", ["S02"])]
    for (train, test), (catheter, settings) in zip(folds, expected, strict=True):
        assert_array_equal(test, _rows(X, catheter, settings))
        assert_array_equal(train, np.setdiff1d(_rows(X, catheter), test))
        assert "S00" in set(X["setting"].iloc[train])


def test_setting_group_kfold_near_equal_sizes():
    settings = [f"S{k:02d}" for k in range(17)]
    X, _ = _recordings({"C1": settings, "C2": settings[::-1]}, n_repeats=1, n_sweep=1, n_motion=1)
    cv = SettingGroupKFold(n_splits=5, exclude_settings=["S00"])
    folds = list(cv.split(X))
    assert len(folds) == 10
    sizes = [X["setting"].iloc[test].nunique() for _, test in folds]
    assert sizes == [4, 3, 3, 3, 3] * 2
    for catheter in ("C1", "C2"):
        tested = [
            s
            for _, test in folds
            if X["catheter"].iloc[test[0]] == catheter
            for s in X["setting"].iloc[test].unique()
        ]
        assert sorted(tested) == settings[1:]  # each bent setting tested once
    # C2 lists its settings in reverse: its first group is S16..S13
    assert set(X["setting"].iloc[folds[5][1]]) == {"S16", "S15", "S14", "S13"}


def test_setting_group_kfold_shuffle_is_seeded():
    settings = [f"S{k:02d}" for k in range(13)]
    X, _ = _recordings({"C1": settings}, n_repeats=1, n_sweep=1, n_motion=1)

    def groups(cv):
        return [tuple(sorted(set(X["setting"].iloc[test]))) for _, test in cv.split(X)]

    plain = groups(SettingGroupKFold(3, exclude_settings="S00"))
    first = groups(SettingGroupKFold(3, exclude_settings="S00", shuffle=True, random_state=0))
    assert first == groups(SettingGroupKFold(3, exclude_settings="S00", shuffle=True, random_state=0))
    cv = SettingGroupKFold(3, exclude_settings="S00", shuffle=True, random_state=0)
    assert groups(cv) == groups(cv)  # an int seed gives the same folds on every call
    others = {
        tuple(groups(SettingGroupKFold(3, exclude_settings="S00", shuffle=True, random_state=s)))
        for s in range(1, 6)
    }
    assert len(others | {tuple(first)}) > 1
    assert any(g != tuple(plain) for g in others)
    for g in [first, *others]:
        assert sorted(s for group in g for s in group) == settings[1:]
        assert sorted(len(group) for group in g) == [4, 4, 4]


def test_setting_group_kfold_counting_does_not_consume_the_generator(data):
    X, _ = data
    a = SettingGroupKFold(2, shuffle=True, random_state=np.random.RandomState(3))
    b = SettingGroupKFold(2, shuffle=True, random_state=np.random.RandomState(3))
    a.get_n_splits(X)
    for (a_train, a_test), (b_train, b_test) in zip(a.split(X), b.split(X), strict=True):
        assert_array_equal(a_test, b_test)


def test_setting_group_kfold_parameter_errors(data):
    X, _ = data
    with pytest.raises(ValueError, match=r"n_splits=3 is more than the 2 testable setting\(s\) of catheter 'C2'"):
        list(SettingGroupKFold(3, exclude_settings=["S00"]).split(X))
    with pytest.raises(ValueError, match="n_splits=3"):
        SettingGroupKFold(3, exclude_settings=["S00"]).get_n_splits(X)
    for bad in (1, 0, 2.0, True, "2", None):
        with pytest.raises(ValueError, match="n_splits must be an integer >= 2"):
            list(SettingGroupKFold(bad).split(X))
    with pytest.raises(ValueError, match="random_state has no effect when shuffle=False"):
        list(SettingGroupKFold(2, random_state=0).split(X))
    with pytest.raises(TypeError, match="shuffle must be True or False"):
        list(SettingGroupKFold(2, shuffle="yes").split(X))
    # numpy integers are integers
    assert SettingGroupKFold(np.int64(2)).get_n_splits(X) == 4


# ---------------------------------------------------------------------------
# LeaveOneCatheterOut
# ---------------------------------------------------------------------------
def test_leave_one_catheter_out_folds(data):
    X, _ = data
    cv = LeaveOneCatheterOut(exclude_settings=["S00"])
    folds = list(cv.split(X))
    assert cv.get_n_splits(X) == len(folds) == 2
    _check_common(X, folds)
    for (train, test), catheter in zip(folds, ["C2", "C1"], strict=True):
        assert_array_equal(test, _rows(X, catheter, exclude=["S00"]))
        other = np.flatnonzero((X["catheter"] != catheter).to_numpy())
        assert_array_equal(train, other)  # all other rows, excluded settings included
        assert "S00" in set(X["setting"].iloc[train])
        assert "S00" not in set(X["setting"].iloc[test])


def test_leave_one_catheter_out_needs_two_catheters(data):
    X, _ = data
    with pytest.raises(ValueError, match="at least 2 catheters"):
        list(LeaveOneCatheterOut().split(X[X["catheter"] == "C1"]))


def test_leave_one_catheter_out_skips_catheter_without_test_rows(data):
    X, _ = data
    X = X.copy()
    X.loc[X["catheter"] == "C2", "setting"] = "S00"
    folds = list(LeaveOneCatheterOut(exclude_settings="S00").split(X))
    assert len(folds) == 1
    train, test = folds[0]
    assert set(X["catheter"].iloc[test]) == {"C1"}
    assert set(X["catheter"].iloc[train]) == {"C2"}


# ---------------------------------------------------------------------------
# shared behaviour and errors
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("Splitter", SPLITTERS)
def test_groups_and_y_are_ignored(data, Splitter):
    X, y = data
    cv = Splitter() if Splitter is not SettingGroupKFold else Splitter(2)
    plain = list(cv.split(X))
    garbage = np.arange(len(X)) % 2
    with pytest.warns(GroupsNotUsedWarning, match=r"\.split got groups, which it does not use"):
        with_groups = list(cv.split(X, y, groups=garbage))
    with pytest.warns(GroupsNotUsedWarning, match=r"\.get_n_splits got groups"):
        n_splits = cv.get_n_splits(X, y, garbage)
    assert len(plain) == len(with_groups) == n_splits
    for (a, b), (c, d) in zip(plain, with_groups, strict=True):
        assert_array_equal(a, c)
        assert_array_equal(b, d)


@pytest.mark.parametrize("Splitter", SPLITTERS)
def test_no_warning_without_groups(data, Splitter):
    X, y = data
    cv = Splitter() if Splitter is not SettingGroupKFold else Splitter(2)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        list(cv.split(X, y))
        cv.get_n_splits(X, y, None)


@pytest.mark.parametrize("Splitter", SPLITTERS)
def test_input_is_not_modified(data, Splitter):
    X, _ = data
    X = X.assign(setting=X["setting"].astype("category"))
    before = X.copy()
    cv = Splitter(exclude_settings=["S00"])
    if Splitter is SettingGroupKFold:
        cv.set_params(n_splits=2)
    list(cv.split(X))
    cv.get_n_splits(X)
    pd.testing.assert_frame_equal(X, before)
    assert cv.exclude_settings == ["S00"]


@pytest.mark.parametrize("Splitter", SPLITTERS)
def test_bad_recordings_are_named(data, Splitter):
    X, _ = data
    cv = Splitter()
    with pytest.raises(ValueError, match="needs the recordings X"):
        cv.get_n_splits()
    with pytest.raises(TypeError, match=r"pandas DataFrame.*'catheter' and 'setting'.*numpy"):
        list(cv.split(X.to_numpy()))
    with pytest.raises(ValueError, match=r"missing \['setting'\]"):
        list(cv.split(X.drop(columns="setting")))
    with pytest.raises(ValueError, match=r"missing \['catheter'\]"):
        cv.get_n_splits(X.drop(columns="catheter"))
    with pytest.raises(ValueError, match="empty"):
        list(cv.split(X.iloc[:0]))
    bad = X.copy()
    bad.iloc[4, bad.columns.get_loc("setting")] = None
    with pytest.raises(ValueError, match=r"'setting' contains 1 missing id.*position 4"):
        list(cv.split(bad))
    with pytest.raises(TypeError, match="exclude_settings must be None or an iterable"):
        list(Splitter(exclude_settings=0).split(X))


@pytest.mark.parametrize("Splitter", SPLITTERS)
def test_run_spanning_two_settings_is_an_error(data, Splitter):
    X, _ = data
    X = X.copy()
    rows = np.flatnonzero((X["run"] == "C1-S01-R0").to_numpy())
    X.iloc[rows[-1], X.columns.get_loc("setting")] = "S02"
    with pytest.raises(ValueError, match=r"Run 'C1-S01-R0' appears under two \(catheter, setting\) pairs"):
        list(Splitter().split(X))


@pytest.mark.parametrize("Splitter", SPLITTERS)
def test_repr_clone_pickle(data, Splitter):
    X, _ = data
    cv = Splitter(exclude_settings=["S00"])
    if Splitter is SettingGroupKFold:
        cv.set_params(n_splits=2)
        assert repr(cv).startswith("SettingGroupKFold(exclude_settings=['S00'], n_splits=2,")
    else:
        assert repr(cv) == f"{Splitter.__name__}(exclude_settings=['S00'])"
    copy = clone(cv)
    assert copy is not cv and copy.get_params() == cv.get_params()
    restored = pickle.loads(pickle.dumps(cv))
    for (a, b), (c, d) in zip(cv.split(X), restored.split(X), strict=True):
        assert_array_equal(a, c)
        assert_array_equal(b, d)
    with pytest.raises(ValueError, match="Invalid parameter 'n_folds'"):
        cv.set_params(n_folds=3)
    assert cv.set_params(exclude_settings=None) is cv
    assert cv.exclude_settings is None


def test_setting_group_kfold_repr_and_params():
    cv = SettingGroupKFold(3, exclude_settings=("S00",), shuffle=True, random_state=7)
    assert repr(cv) == (
        "SettingGroupKFold(exclude_settings=('S00',), n_splits=3, random_state=7,\n         shuffle=True)"
    )
    assert cv.get_params() == {"n_splits": 3, "exclude_settings": ("S00",), "shuffle": True, "random_state": 7}
    assert clone(cv).get_params() == cv.get_params()
    # the constructor only stores: invalid values fail at split time, not before
    lazy = SettingGroupKFold(n_splits=1)
    assert lazy.n_splits == 1


# ---------------------------------------------------------------------------
# use with scikit-learn's model-selection tools
# ---------------------------------------------------------------------------
def _dummy_scores(X, y, cv):
    """Held-out mean per-run RMSE of a training-mean predictor, fold by fold."""
    scores = []
    for train, test in cv.split(X):
        pred = np.tile(y[train].mean(axis=0), (len(test), 1))
        scores.append(mean_per_run_rmse(y[test], pred, X.iloc[test]))
    return np.array(scores)


@pytest.mark.parametrize(
    "cv",
    [
        LeaveOneSettingOut(exclude_settings=["S00"]),
        SettingGroupKFold(2, exclude_settings=["S00"]),
        LeaveOneCatheterOut(exclude_settings=["S00"]),
    ],
    ids=["setting", "kfold", "catheter"],
)
def test_cross_validate(data, cv):
    X, y = data
    out = cross_validate(DummyRegressor(), X, y, cv=cv, scoring=run_rmse_scorer, return_indices=True)
    assert len(out["test_score"]) == cv.get_n_splits(X)
    np.testing.assert_allclose(-out["test_score"], _dummy_scores(X, y, cv), rtol=1e-12)
    for k, (train, test) in enumerate(cv.split(X)):
        assert_array_equal(out["indices"]["train"][k], train)
        assert_array_equal(out["indices"]["test"][k], test)
    groups = X["catheter"].to_numpy()  # passed and ignored, with a warning
    with pytest.warns(GroupsNotUsedWarning):
        with_groups = cross_val_score(
            DummyRegressor(), X, y, groups=groups, cv=cv, scoring=run_rmse_scorer
        )
    np.testing.assert_allclose(with_groups, out["test_score"], rtol=1e-12)


def test_grid_search(data):
    X, y = data
    pipe = Pipeline(
        [
            ("motors", ColumnTransformer([("q", "passthrough", ["q1", "q2"])])),
            ("knn", KNeighborsRegressor()),
        ]
    )
    cv = LeaveOneSettingOut(exclude_settings=["S00"])
    grid = GridSearchCV(pipe, {"knn__n_neighbors": [1, 5]}, cv=cv, scoring=run_rmse_scorer)
    with pytest.warns(GroupsNotUsedWarning):
        grid.fit(X, y, groups=X["setting"])
    n = cv.get_n_splits(X)
    assert [k for k in grid.cv_results_ if k.startswith("split") and k.endswith("_test_score")] == [
        f"split{i}_test_score" for i in range(n)
    ]
    # fold 0 of the search is the first setting held out, scored as by hand
    train, test = next(cv.split(X))
    model = clone(pipe).set_params(knn__n_neighbors=5).fit(X.iloc[train], y[train])
    expected = -mean_per_run_rmse(y[test], model.predict(X.iloc[test]), X.iloc[test])
    assert grid.cv_results_["split0_test_score"][1] == pytest.approx(expected, rel=1e-12)
    mean = [grid.cv_results_["mean_test_score"][i] for i in range(2)]
    assert grid.best_params_ == {"knn__n_neighbors": [1, 5][int(np.argmax(mean))]}
