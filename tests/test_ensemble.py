"""Tests of the seed ensemble (skcath.ensemble) and of its calibration metric.

SeedEnsembleRegressor is checked with scikit-learn's common checks on a
seeded decision tree (all apply, none is expected to fail), then for the
behaviour the uncertainty relies on: members differ only by their seeds,
same seed same numbers, mean and spread computed as documented, the
ensemble outside or inside a Pipeline, inputs left unchanged, clear errors.
``coverage`` is checked against Gaussian data, whose coverage is known. The
last tests fit tiny GRU residual ensembles on shortened simulated runs.
"""

import io

import joblib
import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose, assert_array_equal
from scipy.special import erf
from sklearn.base import clone
from sklearn.exceptions import NotFittedError
from sklearn.linear_model import LinearRegression
from sklearn.pipeline import Pipeline
from sklearn.preprocessing import StandardScaler
from sklearn.tree import DecisionTreeRegressor
from sklearn.utils import get_tags
from sklearn.utils._param_validation import InvalidParameterError
from sklearn.utils.estimator_checks import parametrize_with_checks

from skcath.backbones import PDLBackbone
from skcath.datasets import make_benchmark
from skcath.ensemble import SeedEnsembleRegressor, coverage, random_state_params
from skcath.metrics import mean_per_run_rmse
from skcath.residuals import GRUResidual


def _tree(**params):
    """A shallow decision tree whose fit depends on its seed (random feature subsets)."""
    params = {"max_features": 0.5, "max_depth": 4, **params}
    return DecisionTreeRegressor(**params)


@parametrize_with_checks(
    [SeedEnsembleRegressor(_tree(), n_estimators=3, random_state=0)], legacy=True
)
def test_sklearn_compatible_estimator(estimator, check):
    check(estimator)


@pytest.fixture(scope="module")
def tabular():
    rng = np.random.default_rng(0)
    X = rng.normal(size=(120, 5))
    y = np.column_stack([X[:, 0] + X[:, 1] ** 2, np.sin(X[:, 2])]) + 0.1 * rng.normal(size=(120, 2))
    return X, y


# ---------------------------------------------------------------------------
# meta-estimator
# ---------------------------------------------------------------------------
def test_members_get_their_own_seeds_and_differ(tabular):
    X, y = tabular
    ens = SeedEnsembleRegressor(_tree(), n_estimators=4, random_state=0).fit(X, y)
    assert len(ens.estimators_) == 4
    seeds = [m.random_state for m in ens.estimators_]
    assert len(set(seeds)) == 4 and all(isinstance(s, int) for s in seeds)
    assert ens.seeds_ == [{"random_state": s} for s in seeds]
    assert ens.estimator.random_state is None  # the template is left alone
    members = ens.predict_members(X)
    assert members.shape == (4, *y.shape)
    assert not np.allclose(members[0], members[1])


def test_mean_and_std_are_those_of_the_members(tabular):
    X, y = tabular
    ens = SeedEnsembleRegressor(_tree(), n_estimators=3, random_state=1).fit(X, y)
    members = np.stack([m.predict(X) for m in ens.estimators_])
    mean, std = ens.predict(X, return_std=True)
    assert mean.shape == std.shape == y.shape
    assert_allclose(mean, members.mean(axis=0))
    assert_allclose(std, members.std(axis=0, ddof=1))
    assert (std >= 0).all() and (std > 0).any()
    assert_array_equal(ens.predict(X), mean)
    # a single output gives 1-d mean and std
    mean1, std1 = clone(ens).fit(X, y[:, 0]).predict(X, return_std=True)
    assert mean1.shape == std1.shape == (len(X),)


def test_same_seed_same_numbers_other_seed_other_numbers(tabular):
    X, y = tabular
    a = SeedEnsembleRegressor(_tree(), random_state=0).fit(X, y).predict(X, return_std=True)
    b = SeedEnsembleRegressor(_tree(), random_state=0).fit(X, y).predict(X, return_std=True)
    c = SeedEnsembleRegressor(_tree(), random_state=1).fit(X, y).predict(X, return_std=True)
    assert_array_equal(a[0], b[0])
    assert_array_equal(a[1], b[1])
    assert not np.allclose(a[1], c[1])
    # a RandomState instance draws from its stream: two fits give two ensembles
    rs = np.random.RandomState(0)
    ens = SeedEnsembleRegressor(_tree(), random_state=rs)
    first = [m.random_state for m in ens.fit(X, y).estimators_]
    second = [m.random_state for m in ens.fit(X, y).estimators_]
    assert first != second


def test_parallel_members_equal_sequential(tabular):
    X, y = tabular
    seq = SeedEnsembleRegressor(_tree(), n_estimators=3, random_state=0).fit(X, y)
    par = SeedEnsembleRegressor(_tree(), n_estimators=3, random_state=0, n_jobs=2).fit(X, y)
    assert_array_equal(par.predict_members(X), seq.predict_members(X))


def test_pipeline_inside_and_ensemble_inside_pipeline(tabular):
    X, y = tabular
    # a pipeline as the members: its nested seed parameter is set
    outer = SeedEnsembleRegressor(
        Pipeline([("scale", StandardScaler()), ("tree", _tree())]), n_estimators=3, random_state=0
    )
    assert random_state_params(outer.estimator) == ["tree__random_state"]
    outer.fit(X, y)
    assert all(isinstance(m["tree"].random_state, int) for m in outer.estimators_)
    # the ensemble as the last step: Pipeline.predict passes return_std on
    inner = Pipeline(
        [("scale", StandardScaler()),
         ("ensemble", SeedEnsembleRegressor(_tree(), n_estimators=3, random_state=0))]
    ).fit(X, y)
    mean_o, std_o = outer.predict(X, return_std=True)
    mean_i, std_i = inner.predict(X, return_std=True)
    # same seeds, same scaled data: the two arrangements give the same numbers
    assert_allclose(mean_i, mean_o)
    assert_allclose(std_i, std_o)
    assert_allclose(inner.predict(X), mean_o)
    assert inner.score(X, y) == pytest.approx(outer.score(X, y))


def test_inputs_are_not_modified(tabular):
    X, y = tabular
    Xf = pd.DataFrame(X, columns=[f"f{i}" for i in range(X.shape[1])])
    X0, y0 = Xf.copy(), y.copy()
    ens = SeedEnsembleRegressor(_tree(), random_state=0).fit(Xf, y)
    ens.predict(Xf, return_std=True)
    pd.testing.assert_frame_equal(Xf, X0)
    assert_array_equal(y, y0)
    assert list(ens.feature_names_in_) == list(Xf.columns)
    assert ens.n_features_in_ == X.shape[1]


def test_not_fitted_errors(tabular):
    X, y = tabular
    ens = SeedEnsembleRegressor(_tree())
    for call in (ens.predict, ens.predict_members):
        with pytest.raises(NotFittedError):
            call(X)
    assert not hasattr(ens, "n_features_in_")


@pytest.mark.parametrize(
    "params, match",
    [
        (
            {"n_estimators": 1},
            "'n_estimators' parameter of SeedEnsembleRegressor must be an int in the range "
            "\\[2, inf\\)",
        ),
        ({"n_estimators": 2.5}, "'n_estimators' parameter"),
        ({"n_jobs": "all"}, "'n_jobs' parameter"),
        ({"random_state": "seed"}, "'random_state' parameter"),
        ({"estimator": "tree"}, "'estimator' parameter .* implementing 'fit' and 'predict'"),
    ],
)
def test_bad_parameters_raise_clear_errors(tabular, params, match):
    X, y = tabular
    ens = SeedEnsembleRegressor(_tree()).set_params(**params)
    with pytest.raises(InvalidParameterError, match=match):
        ens.fit(X, y)


def test_estimator_without_seed_is_refused(tabular):
    X, y = tabular
    match = "LinearRegression has none, so all 5 members would be the same"
    with pytest.raises(ValueError, match=match):
        SeedEnsembleRegressor(LinearRegression()).fit(X, y)
    pipe = Pipeline([("scale", StandardScaler()), ("linear", LinearRegression())])
    with pytest.raises(ValueError, match="seed parameter"):
        SeedEnsembleRegressor(pipe).fit(X, y)


def test_pickle_round_trip_and_tags(tabular):
    X, y = tabular
    ens = SeedEnsembleRegressor(_tree(), n_estimators=2, random_state=0).fit(X, y)
    buffer = io.BytesIO()
    joblib.dump(ens, buffer)
    buffer.seek(0)
    loaded = joblib.load(buffer)
    for a, b in zip(loaded.predict(X, return_std=True), ens.predict(X, return_std=True)):
        assert_array_equal(a, b)
    tags = get_tags(SeedEnsembleRegressor(GRUResidual()))
    assert tags.estimator_type == "regressor"
    assert tags.input_tags.string and tags.input_tags.allow_nan  # from the residual
    assert tags.target_tags.multi_output and not tags.target_tags.single_output


# ---------------------------------------------------------------------------
# coverage
# ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def gaussian():
    """Errors drawn from the predicted Gaussians: a calibrated prediction."""
    rng = np.random.default_rng(0)
    n = 60_000
    mean = rng.normal(0.0, 10.0, (n, 3))
    std = rng.uniform(0.5, 3.0, (n, 3))
    return mean + std * rng.standard_normal((n, 3)), mean, std


def test_coverage_recovers_the_gaussian_fractions(gaussian):
    y, mean, std = gaussian
    expected = erf(np.array([1.0, 2.0]) / np.sqrt(2.0))  # 0.683, 0.954
    assert_allclose(coverage(y, mean, std), expected, atol=0.005)
    assert_allclose(coverage(y, mean, std, joint=True), expected, atol=0.005)
    raw = coverage(y, mean, std, multioutput="raw_values")
    assert raw.shape == (2, 3)
    assert_allclose(raw, np.repeat(expected[:, None], 3, axis=1), atol=0.008)
    # over-confidence (std too small by 2) and under-confidence are seen
    assert_allclose(coverage(y, mean, std / 2), erf(np.array([0.5, 1.0]) / np.sqrt(2)), atol=0.005)
    assert coverage(y, mean, 2 * std, k=1) == pytest.approx(erf(np.sqrt(2)), abs=0.005)
    # a scalar k gives a float (one value per output with raw_values)
    assert isinstance(coverage(y, mean, std, k=1.0), float)
    assert coverage(y, mean, std, k=3.0, multioutput="raw_values").shape == (3,)


def test_coverage_weights_runs_equally_and_skips_nan_rows():
    # run "a": 3 samples, 1 covered; run "b": 1 sample, covered
    y = np.array([0.0, 5.0, 5.0, 0.5, np.nan])
    mean = np.zeros(5)
    std = np.ones(5)
    runs = np.array(["a", "a", "a", "b", "b"])
    assert coverage(y, mean, std, k=1) == pytest.approx(2 / 4)
    assert coverage(y, mean, std, k=1, runs=runs) == pytest.approx((1 / 3 + 1) / 2)
    # a run with no finite reference is left out
    runs_c = np.array(["a", "a", "a", "b", "c"])
    assert coverage(y, mean, std, k=1, runs=runs_c) == pytest.approx((1 / 3 + 1) / 2)


def test_coverage_zero_std_and_joint_radius():
    y = np.array([[0.0, 1.0, 0.0], [1.0, 1.0, 1.0]])
    mean = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 0.0]])
    std = np.zeros((2, 3))
    # with std 0 only an exact prediction is covered
    assert_allclose(coverage(y, mean, std, k=1, multioutput="raw_values"), [0.5, 0.5, 0.5])
    assert coverage(y, mean, std, k=1, joint=True) == pytest.approx(0.5)
    # joint radii for 3 outputs: chi2_3 quantiles 3.53 (1 sigma) and 8.02 (2 sigma)
    s = np.ones((1, 3))
    e = np.full((1, 3), 1.1)  # sum of squares 3.63: outside at 1 sigma, inside at 2
    assert_array_equal(coverage(e, np.zeros((1, 3)), s, joint=True), [0.0, 1.0])


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        ({"y_std": -np.ones((4, 3))}, ValueError, "non-negative"),
        ({"y_mean": np.zeros((4, 2))}, ValueError, "y_mean must have the shape of y_true"),
        ({"y_std": np.full((4, 3), np.nan)}, ValueError, "y_std contains NaN"),
        ({"k": 0}, ValueError, "k must be a positive"),
        ({"k": []}, ValueError, "k must be a positive"),
        ({"runs": np.arange(3)}, ValueError, "one run id per sample"),
        ({"multioutput": "variance_weighted"}, ValueError, "multioutput"),
        ({"joint": True, "multioutput": "raw_values"}, ValueError, "joint=True"),
        ({"joint": "yes"}, TypeError, "joint must be True or False"),
    ],
)
def test_coverage_rejects_bad_input(kwargs, error, match):
    args = {"y_true": np.zeros((4, 3)), "y_mean": np.zeros((4, 3)), "y_std": np.ones((4, 3))}
    args.update(kwargs)
    with pytest.raises(error, match=match):
        coverage(**args)


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"y_true": 3.0}, "y_true"),
        ({"y_std": "wide"}, "y_std"),
        ({"k": "one"}, "k"),
        ({"runs": "run-1"}, "runs"),
    ],
)
def test_coverage_names_the_bad_argument(kwargs, name):
    args = {"y_true": np.zeros((4, 3)), "y_mean": np.zeros((4, 3)), "y_std": np.ones((4, 3))}
    args.update(kwargs)
    with pytest.raises(InvalidParameterError, match=f"The '{name}' parameter of coverage"):
        coverage(**args)


# ---------------------------------------------------------------------------
# end to end: GRU residual ensembles on simulated recordings
# ---------------------------------------------------------------------------
TRAIN_SETTINGS = ["S02", "S09", "S13"]
TEST_SETTINGS = ["S05"]


def _gru():
    return GRUResidual(
        max_epochs=1,
        batch_size=16,
        window_s=5.0,
        burn_in_s=1.0,
        sweep_stride_s=5.0,
        n_threads=1,
        module__hidden_size=8,
        module__encoder_hidden_size=8,
        module__context_size=4,
        module__head_hidden_size=8,
    )


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    """Train and test recordings: one run per setting, sweep and 200 motion rows."""
    data = make_benchmark(
        n_catheters=1, n_runs=1, cache=True, data_home=tmp_path_factory.mktemp("skcath_data")
    )
    X, y = data.X, np.asarray(data.y)
    motion = (X["phase"] == "motion").to_numpy()
    rank = pd.Series(motion, index=X.index).groupby(X["run"], observed=True).cumsum().to_numpy()
    short = ~motion | (rank <= 200)
    train = short & X["setting"].isin(TRAIN_SETTINGS).to_numpy()
    test = short & X["setting"].isin(TEST_SETTINGS).to_numpy()
    return X[train], y[train], X[test], y[test]


def test_gru_ensemble_outside_and_inside_the_pipeline(recordings):
    X, y, X_test, y_test = recordings
    X0, X_test0 = X.copy(), X_test.copy()
    outer = SeedEnsembleRegressor(
        Pipeline([("backbone", PDLBackbone()), ("residual", _gru())]),
        n_estimators=2,
        random_state=0,
    ).fit(X, y)
    inner = Pipeline(
        [("backbone", PDLBackbone()),
         ("residual", SeedEnsembleRegressor(_gru(), n_estimators=2, random_state=0))]
    ).fit(X, y)
    mean, std = outer.predict(X_test, return_std=True)
    assert mean.shape == std.shape == (len(X_test), 3)
    motion = (X_test["phase"] == "motion").to_numpy()
    # the members agree on the sweep rows (both predict the backbone) and
    # differ during motion, where their residuals differ
    assert_array_equal(std[~motion], 0.0)
    assert (std[motion] > 0).mean() > 0.99
    # same member seeds, deterministic backbone: the same mean and spread
    mean_i, std_i = inner.predict(X_test, return_std=True)
    assert_allclose(mean_i, mean, atol=1e-6)
    assert_allclose(std_i, std, atol=1e-6)
    # score: the negated mean per-run RMSE of the mean, as for one pipeline
    rmse = mean_per_run_rmse(y_test, mean, X_test)
    assert outer.score(X_test, y_test) == pytest.approx(-rmse)
    assert inner.score(X_test, y_test) == pytest.approx(-rmse, rel=1e-6)
    # coverage of the held-out motion rows is a fraction for each k
    cov = coverage(y_test[motion], mean[motion], std[motion], runs=X_test["run"][motion])
    assert cov.shape == (2,) and 0 <= cov[0] <= cov[1] <= 1
    pd.testing.assert_frame_equal(X, X0)
    pd.testing.assert_frame_equal(X_test, X_test0)


def test_docstring_examples():
    import doctest

    import skcath.ensemble

    result = doctest.testmod(skcath.ensemble, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0 and result.failed == 0
