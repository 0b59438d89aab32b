"""scikit-learn's common estimator checks for the backbone estimators.

The backbones take recordings in the long format (``docs/data_format.rst``):
a pandas DataFrame with the id columns, ``t``, ``phase``, the motor angles,
torques and the sweep references, and they calibrate every run on its own
sweep rows. The generic checks that feed random numeric arrays cannot apply
to them; each such check is listed below with the reason, and is run in
strict mode, so a listed check that starts to pass fails the test suite.
Where a generic check tests a property that does apply, a test further down
checks the same property on long-format recordings.
"""

import joblib
import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_array_equal
from sklearn.base import clone
from sklearn.exceptions import NotFittedError
from sklearn.utils import get_tags
from sklearn.utils.estimator_checks import estimator_checks_generator, parametrize_with_checks

from _helpers import instrument
from skcath.backbones import PCCBackbone, PCCParams, PDLBackbone, PolynomialBackbone, pcc_tip
from skcath.backbones._pcc import _so3_exp
from skcath.datasets._protocol import random_walk_trajectory, sweep_trajectory

# Prefix of every reason below: why the generic check cannot run on a backbone.
_ARRAYS = "It feeds numeric arrays, but a backbone takes only long-format recordings"

EXPECTED_FAILED_CHECKS = {
    "check_complex_data": f"{_ARRAYS}; check_recordings refuses complex channels.",
    "check_dict_unchanged": (
        f"{_ARRAYS}; test_predict_and_transform_leave_the_estimator_unchanged checks the "
        "property."
    ),
    "check_dont_overwrite_parameters": (
        f"{_ARRAYS}; test_fit_sets_only_private_or_trailing_underscore_attributes "
        "checks the property."
    ),
    "check_dtype_object": f"{_ARRAYS}; check_recordings parses object columns of numbers.",
    "check_estimators_dtypes": f"{_ARRAYS}; test_numeric_dtypes_of_recordings checks dtypes.",
    "check_estimators_empty_data_messages": (
        f"{_ARRAYS}; test_empty_recordings_raise_value_error checks an empty DataFrame."
    ),
    "check_estimators_fit_returns_self": (
        f"{_ARRAYS}; test_fit_returns_self_and_keeps_parameters checks the property."
    ),
    "check_estimators_overwrite_params": (
        f"{_ARRAYS}; test_fit_returns_self_and_keeps_parameters checks the property."
    ),
    "check_estimators_pickle": f"{_ARRAYS}; test_pickle_round_trip checks the property.",
    "check_f_contiguous_array_estimator": f"{_ARRAYS}.",
    "check_fit1d": f"{_ARRAYS}; a 1-d array is refused with a TypeError.",
    "check_fit2d_1feature": f"{_ARRAYS}; every run needs all required columns.",
    "check_fit2d_1sample": f"{_ARRAYS}; every run needs a whole calibration sweep.",
    "check_fit2d_predict1d": f"{_ARRAYS}; a 1-d array is refused with a TypeError.",
    "check_fit_check_is_fitted": f"{_ARRAYS}; test_not_fitted_until_fit checks the property.",
    "check_fit_idempotent": f"{_ARRAYS}; test_fit_is_idempotent checks the property.",
    "check_fit_score_takes_y": f"{_ARRAYS}; fit(X, y) and score(X, y) are tested on recordings.",
    "check_methods_sample_order_invariance": (
        f"{_ARRAYS}; rows are time samples, and test_backbones checks that the order "
        "of the runs does not matter."
    ),
    "check_methods_subset_invariance": (
        f"{_ARRAYS}; each run is calibrated on its own sweep, and test_backbones checks "
        "that subsets of runs give the same predictions."
    ),
    "check_n_features_in": f"{_ARRAYS}; test_fit_records_columns checks the property.",
    "check_n_features_in_after_fitting": (
        f"{_ARRAYS}; test_fit_records_columns checks the property."
    ),
    "check_non_transformer_estimators_n_iter": (
        f"{_ARRAYS}; besides, fit runs no solver: calibrate(X).table holds each run's n_iter."
    ),
    "check_pipeline_consistency": f"{_ARRAYS}; test_backbones checks a Pipeline on recordings.",
    "check_positive_only_tag_during_fit": f"{_ARRAYS}.",
    "check_readonly_memmap_input": f"{_ARRAYS}; test_read_only_recordings checks the property.",
    "check_regressor_data_not_an_array": f"{_ARRAYS}.",
    "check_regressor_multioutput": f"{_ARRAYS}; test_backbones checks the (n, 3) output.",
    "check_regressors_int": f"{_ARRAYS}; test_numeric_dtypes_of_recordings checks int channels.",
    "check_regressors_no_decision_function": f"{_ARRAYS}.",
    "check_regressors_train": f"{_ARRAYS}; test_fit_rejects_bad_targets checks a short y.",
    "check_supervised_y_no_nan": (
        f"{_ARRAYS}; test_fit_rejects_bad_targets checks an infinite y (NaN marks a dropout)."
    ),
    "check_transformer_data_not_an_array": f"{_ARRAYS}.",
    "check_transformer_general": f"{_ARRAYS}; test_backbones checks transform on recordings.",
    "check_transformer_n_iter": (
        f"{_ARRAYS}; besides, fit runs no solver: calibrate(X).table holds each run's n_iter."
    ),
    "check_transformer_preserve_dtypes": f"{_ARRAYS}; b_x, b_y, b_z are always float64.",
}

ESTIMATORS = [PCCBackbone(), PDLBackbone()]


#: Checks of the estimator API itself (parameters, cloning, repr, tags),
#: which do not feed arrays and so must apply to every estimator.
API_CHECKS = (
    "check_no_attributes_set_in_init",
    "check_parameters_default_constructible",
    "check_get_params_invariance",
    "check_set_params",
    "check_estimator_repr",
    "check_do_not_raise_errors_in_init_or_set_params",
    "check_estimator_cloneable",
    "check_estimators_unfitted",
    "check_mixin_order",
    "check_valid_tag_types",
)


def _expected_failed_checks(estimator):
    return EXPECTED_FAILED_CHECKS


def _check_name(check):
    return getattr(check, "func", check).__name__


def _input_format_failure(exc):
    """Whether ``exc`` comes from refusing an input that is not a recordings DataFrame."""
    while exc is not None:
        if isinstance(exc, TypeError) and "long recording format" in str(exc):
            return True
        exc = exc.__cause__ or exc.__context__
    return False


def run_check(estimator, check, expected_failures):
    """Run one sklearn check; an expected failure raises a short AssertionError.

    Strict: a listed check that passes is reported as a failure (xfail_strict).
    """
    name = _check_name(check)
    if name not in expected_failures:
        check(estimator)
        return
    try:
        check(estimator)
    except Exception as exc:
        # a short error instead of the check's traceback: formatting tracebacks
        # through estimator_checks.py for every expected failure takes seconds
        raise AssertionError(f"{name}: {type(exc).__name__}: {exc}"[:500]) from None


@parametrize_with_checks(
    ESTIMATORS, expected_failed_checks=_expected_failed_checks, xfail_strict=True
)
def test_sklearn_compatible_estimator(estimator, check):
    run_check(estimator, check, EXPECTED_FAILED_CHECKS)


@pytest.mark.parametrize("estimator", ESTIMATORS, ids=lambda e: type(e).__name__)
def test_expected_failures_are_real_and_only_about_the_input_format(estimator):
    checks = list(estimator_checks_generator(estimator, legacy=True, mark=None))
    names = {_check_name(check) for _, check in checks}
    # every entry names a check that is run on the estimator (no stale entry)
    assert set(EXPECTED_FAILED_CHECKS) <= names
    # and each listed check fails because of the numeric-array input, not for
    # another reason that the list would hide
    for est, check in checks:
        if _check_name(check) in EXPECTED_FAILED_CHECKS:
            with pytest.raises(Exception) as info:
                check(est)
            assert _input_format_failure(info.value), (_check_name(check), info.value)
    # the checks of the API itself all run without an expected failure
    for name in (*API_CHECKS, "check_transformers_unfitted"):
        assert name in names and name not in EXPECTED_FAILED_CHECKS


# ---------------------------------------------------------------------------
# the same properties on long-format recordings
# ---------------------------------------------------------------------------
def _recordings():
    """Two short runs of a noisy PCC catheter, in the long format, and y."""
    rng = np.random.default_rng(0)
    frames, targets = [], []
    for k, run in enumerate(["run-a", "run-b"]):
        truth = PCCParams(
            C=[[1.2, 0.1 * k], [-0.1, 1.0]],
            q0=[0.0, 0.0],
            u0=[0.02, -0.01 * k],
            S_m=60.0,
            L=55.0 + 3.0 * k,
            R_g=_so3_exp(np.array([0.1, -0.2, 0.3 * k])),
        )
        q = np.vstack(
            [sweep_trajectory(speed_deg_s=12.0), random_walk_trajectory(rng, 300, n_steps=20)]
        )
        n_sweep = len(q) - 300
        y = pcc_tip(q, truth) + rng.normal(0.0, 0.2, (len(q), 3))
        ref = y.copy()
        ref[n_sweep:] = np.nan
        frames.append(
            pd.DataFrame(
                {
                    "catheter": "C1",
                    "setting": f"S{k}",
                    "run": run,
                    "t": 0.1 * np.arange(len(q)),
                    "phase": ["sweep"] * n_sweep + ["motion"] * 300,
                    "q1": q[:, 0],
                    "q2": q[:, 1],
                    "tau1": rng.normal(0.0, 1.0, len(q)),
                    "tau2": rng.normal(0.0, 1.0, len(q)),
                    "ref_x": ref[:, 0],
                    "ref_y": ref[:, 1],
                    "ref_z": ref[:, 2],
                }
            )
        )
        targets.append(y)
    return pd.concat(frames, ignore_index=True), np.vstack(targets)


@pytest.fixture(scope="module")
def recordings():
    return _recordings()


@pytest.fixture(params=[PCCBackbone, PDLBackbone], ids=lambda c: c.__name__)
def Est(request):
    return request.param


def test_tags(Est):
    tags = get_tags(Est())
    assert tags.estimator_type == "regressor"
    assert tags.transformer_tags is not None
    assert tags.target_tags.multi_output and not tags.target_tags.single_output
    assert not tags.target_tags.required  # fit(X) works without y
    assert tags.input_tags.allow_nan and tags.input_tags.string


def test_fit_returns_self_and_keeps_parameters(Est, recordings):
    X, y = recordings
    est = Est(n_rays=8, max_iter=30, n_jobs=None)
    params = est.get_params(deep=True)
    before = joblib.hash(params)
    assert est.fit(X, y) is est
    assert est.fit(X) is est
    assert joblib.hash(est.get_params(deep=True)) == before
    est.predict(X)
    assert joblib.hash(est.get_params(deep=True)) == before


def test_fit_sets_only_private_or_trailing_underscore_attributes(Est, recordings):
    X, y = recordings
    est = Est()
    public_before = {k for k in vars(est) if not k.startswith("_")}
    est.fit(X, y)
    est.predict(X)
    added = {k for k in vars(est) if not k.startswith("_")} - public_before
    assert added and all(k.endswith("_") for k in added)


def test_predict_and_transform_leave_the_estimator_unchanged(Est, recordings):
    """check_dict_unchanged on recordings: the attributes are the same objects, unchanged."""
    X, y = recordings
    est = Est().fit(X, y)
    for method in ("predict", "transform", "calibrate", "score"):
        dict_before = est.__dict__.copy()
        state = joblib.hash(est.__dict__)
        getattr(est, method)(*((X, y) if method == "score" else (X,)))
        assert est.__dict__ == dict_before, f"{method} changes __dict__"
        assert joblib.hash(est.__dict__) == state, f"{method} changes an attribute's value"


def test_fit_records_columns(Est, recordings):
    X, _ = recordings
    Xe = X.assign(extra=1.0)
    est = Est().fit(Xe)
    assert est.n_features_in_ == X.shape[1] + 1
    assert list(est.feature_names_in_) == list(Xe.columns)
    assert est.feature_names_in_.dtype == object


def test_not_fitted_until_fit(Est, recordings):
    X, y = recordings
    est = Est()
    for method in (est.predict, est.transform):
        with pytest.raises(NotFittedError):
            method(X)
    with pytest.raises(NotFittedError):
        est.get_feature_names_out()
    with pytest.raises(NotFittedError):
        est.score(X, y)
    assert not hasattr(est, "calibrations_")


def test_fit_is_idempotent(Est, recordings):
    X, y = recordings
    est = Est()
    first = est.fit(X, y).predict(X)
    assert_array_equal(est.fit(X, y).predict(X), first)
    assert_array_equal(est.fit(X).predict(X), first)
    assert_array_equal(clone(est).fit(X).predict(X), first)


def test_pickle_round_trip(Est, recordings):
    X, _ = recordings
    est = Est().fit(X)
    pred = est.predict(X)
    assert_array_equal(joblib.load(_dump(est)).predict(X), pred)


def _dump(obj):
    import io

    buffer = io.BytesIO()
    joblib.dump(obj, buffer)
    buffer.seek(0)
    return buffer


def test_empty_recordings_raise_value_error(Est, recordings):
    X, _ = recordings
    with pytest.raises(ValueError, match="empty"):
        Est().fit(X.iloc[:0])
    est = Est().fit(X)
    with pytest.raises(ValueError, match="empty"):
        est.predict(X.iloc[:0])


def test_non_dataframe_input_raises_type_error(Est, recordings):
    X, _ = recordings
    with pytest.raises(TypeError, match="DataFrame"):
        Est().fit(X.to_numpy())
    est = Est().fit(X)
    with pytest.raises(TypeError, match="DataFrame"):
        est.predict(X.to_numpy())


def test_fit_rejects_bad_targets(Est, recordings):
    X, y = recordings
    with pytest.raises(ValueError, match="rows"):
        Est().fit(X, y[:-1])
    y_inf = y.copy()
    y_inf[3, 1] = np.inf
    with pytest.raises(ValueError, match="infinite"):
        Est().fit(X, y_inf)
    y_nan = y.copy()
    y_nan[3] = np.nan  # a tracker dropout is legal
    assert Est().fit(X, y_nan).n_features_in_ == X.shape[1]


def test_numeric_dtypes_of_recordings(Est, recordings):
    X, _ = recordings
    pred = Est().fit(X).predict(X)
    # integer torques and float32 references: converted, same predictions
    X2 = X.astype({"tau1": np.int64, "tau2": np.int32})
    X2[["ref_x", "ref_y", "ref_z"]] = X2[["ref_x", "ref_y", "ref_z"]].astype(np.float32)
    pred2 = Est().fit(X2).predict(X2)
    assert pred2.dtype == np.float64
    assert np.abs(pred2 - pred).max() < 1e-2
    # integer motor angles (rounded encoder readings) still calibrate
    X3 = X.assign(q1=X["q1"].round().astype(int), q2=X["q2"].round().astype(int))
    pred3 = Est().fit(X3).predict(X3)
    assert pred3.dtype == np.float64 and np.isfinite(pred3).all()


def test_read_only_recordings(Est, recordings):
    X, _ = recordings
    pred = Est().fit(X).predict(X)
    arrays = {}
    for name in X.columns:
        values = X[name].to_numpy(copy=True)
        values.flags.writeable = False
        arrays[name] = values
    X_ro = pd.DataFrame(arrays, copy=False)
    assert not X_ro["q1"].to_numpy().flags.writeable
    assert_array_equal(Est().fit(X_ro).predict(X_ro), pred)


# ---------------------------------------------------------------------------
# the polynomial backbone on the simulated instruments of one, two and three motors
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("n_motors", [1, 2, 3])
def test_polynomial_backbone_properties_on_each_instrument(n_motors):
    """fit returns self and keeps the parameters; predict changes nothing; pickling
    and refitting give the same tips; the input is unchanged."""
    X, y = instrument(n_motors, ("S02", "S09"), 100)
    X_before = X.copy()
    for calibration in ("sweep", "fit"):
        est = PolynomialBackbone(degree=2, calibration=calibration)
        params = joblib.hash(est.get_params())
        assert est.fit(X, y) is est
        assert joblib.hash(est.get_params()) == params
        assert est.n_motors_ == n_motors
        state = joblib.hash(est.__dict__)
        pred = est.predict(X)
        assert joblib.hash(est.__dict__) == state
        assert pred.shape == (len(X), 3) and np.isfinite(pred).all()
        assert_array_equal(joblib.load(_dump(est)).predict(X), pred)
        assert_array_equal(clone(est).fit(X, y).predict(X), pred)
    pd.testing.assert_frame_equal(X, X_before)
