"""scikit-learn's common estimator checks for the residual learners.

The residual learners are the last step of a pipeline behind a backbone: they
take recordings in the long format (``docs/data_format.rst``) with the
backbone's nominal tip ``b_x, b_y, b_z`` appended, and learn per run along the
motion sequence. The generic checks that feed random numeric arrays cannot
apply to them; each such check is listed below with the reason, and is run in
strict mode, so a listed check that starts to pass fails the test suite.
GRUResidual and MLPResidual are skorch nets; two checks of the estimator API
fail because of how skorch stores its parameters, and are listed separately.
Where a generic check tests a property that does apply, a test in
``test_residuals.py`` checks the same property on long-format recordings;
the last test here checks the main ones on recordings of the simulated instruments of one
and of three motors.
"""

import pickle

import joblib
import pandas as pd
import pytest
import torch
from numpy.testing import assert_allclose, assert_array_equal
from sklearn.base import clone
from sklearn.utils.estimator_checks import estimator_checks_generator, parametrize_with_checks

from _helpers import instrument
from test_common import API_CHECKS, _check_name, _input_format_failure, run_check
from skcath.backbones import PolynomialBackbone
from skcath.residuals import GRUResidual, MLPResidual, NoResidual

# Prefix of every reason below: why the generic check cannot run on a residual learner.
_ARRAYS = (
    "It feeds numeric arrays, but a residual learner takes only long-format recordings "
    "with the backbone columns b_x, b_y, b_z"
)

INPUT_FORMAT_FAILURES = {
    "check_complex_data": f"{_ARRAYS}; check_recordings refuses complex channels.",
    "check_dict_unchanged": (
        f"{_ARRAYS}; test_predict_does_not_change_the_estimator checks the property."
    ),
    "check_dont_overwrite_parameters": (
        f"{_ARRAYS}; test_fit_sets_only_private_or_trailing_underscore_attributes "
        "checks the property."
    ),
    "check_dtype_object": f"{_ARRAYS}; check_recordings parses object columns of numbers.",
    "check_estimators_dtypes": f"{_ARRAYS}; test_numeric_dtypes_of_recordings checks dtypes.",
    "check_estimators_empty_data_messages": (
        f"{_ARRAYS}; test_empty_and_non_dataframe_input checks an empty DataFrame."
    ),
    "check_estimators_fit_returns_self": (
        f"{_ARRAYS}; test_fit_keeps_parameters checks the property."
    ),
    "check_estimators_overwrite_params": (
        f"{_ARRAYS}; test_fit_keeps_parameters checks the property."
    ),
    "check_estimators_pickle": (
        f"{_ARRAYS}; test_pickle_and_joblib_round_trip checks the property."
    ),
    "check_f_contiguous_array_estimator": f"{_ARRAYS}.",
    "check_fit1d": f"{_ARRAYS}; a 1-d array is refused with a TypeError.",
    "check_fit2d_1feature": (
        f"{_ARRAYS}; every run needs all required columns and the backbone columns."
    ),
    "check_fit2d_1sample": (
        f"{_ARRAYS}; every run needs a sweep, and a learner needs motion rows to learn from."
    ),
    "check_fit2d_predict1d": f"{_ARRAYS}; a 1-d array is refused with a TypeError.",
    "check_fit_check_is_fitted": f"{_ARRAYS}; test_not_fitted checks the property.",
    "check_fit_idempotent": (
        f"{_ARRAYS}; test_random_state_makes_fits_reproducible checks the property."
    ),
    "check_fit_score_takes_y": f"{_ARRAYS}; fit(X, y) and score(X, y) are tested on recordings.",
    "check_methods_sample_order_invariance": (
        f"{_ARRAYS}; rows are time samples of sequences, and "
        "test_runs_are_predicted_independently checks that the order of the runs "
        "and interleaving their rows do not matter."
    ),
    "check_methods_subset_invariance": (
        f"{_ARRAYS}; each run is a sequence of its own, and "
        "test_runs_are_predicted_independently checks that subsets of runs give the "
        "same predictions."
    ),
    "check_n_features_in": f"{_ARRAYS}; test_fit_keeps_parameters checks the property.",
    "check_n_features_in_after_fitting": (
        f"{_ARRAYS}; test_fit_keeps_parameters checks the property."
    ),
    "check_pipeline_consistency": (
        f"{_ARRAYS}; test_pipeline_fit_predict checks a Pipeline on recordings."
    ),
    "check_positive_only_tag_during_fit": f"{_ARRAYS}.",
    "check_readonly_memmap_input": f"{_ARRAYS}; test_read_only_recordings checks the property.",
    "check_regressor_data_not_an_array": f"{_ARRAYS}.",
    "check_regressor_multioutput": (
        f"{_ARRAYS}; test_pipeline_fit_predict checks the (n, 3) output."
    ),
    "check_regressors_int": f"{_ARRAYS}; test_numeric_dtypes_of_recordings checks int channels.",
    "check_regressors_no_decision_function": f"{_ARRAYS}.",
    "check_regressors_train": f"{_ARRAYS}; test_fit_rejects_bad_targets checks a short y.",
    "check_supervised_y_no_nan": (
        f"{_ARRAYS}; test_fit_rejects_bad_targets checks an infinite y (NaN marks a dropout)."
    ),
}

# Only the skorch nets have partial_fit.
PARTIAL_FIT_FAILURES = {
    "check_estimators_partial_fit_n_features": (
        f"{_ARRAYS}; test_warm_start_continues_training checks partial_fit."
    ),
}

# Only the skorch nets take sample_weight in fit.
SAMPLE_WEIGHT_FAILURES = {
    "check_sample_weights_pandas_series": (
        f"{_ARRAYS}; test_sample_weight_forms_and_errors checks a pandas Series."
    ),
    "check_sample_weights_not_an_array": (
        f"{_ARRAYS}; test_sample_weight_forms_and_errors checks a list."
    ),
    "check_sample_weights_list": (
        f"{_ARRAYS}; test_sample_weight_forms_and_errors checks a list."
    ),
    "check_sample_weights_shape": (
        f"{_ARRAYS}; test_sample_weight_forms_and_errors checks a wrong length."
    ),
    "check_sample_weights_not_overwritten": (
        f"{_ARRAYS}; test_sample_weight_forms_and_errors checks the property."
    ),
    "check_all_zero_sample_weights_error": (
        f"{_ARRAYS}; test_sample_weight_forms_and_errors checks all-zero weights."
    ),
    "check_sample_weight_equivalence_on_dense_data": (
        f"{_ARRAYS}; test_zero_weighted_run_gives_the_model_without_it checks that a "
        "run of weight 0 gives the model fitted without it."
    ),
}

# Checks of the estimator API that skorch's NeuralNet does not pass.
SKORCH_FAILURES = {
    "check_no_attributes_set_in_init": (
        "skorch's NeuralNet.__init__ stores the module__* and iterator_* arguments as "
        "attributes and sets history_, initialized_ and virtual_params_; "
        "test_clone_and_nested_params checks that get_params and clone keep the parameters."
    ),
    "check_set_params": (
        "skorch's get_params lists its private _params_to_validate set, which the check "
        "overwrites with numbers that set_params then cannot use; "
        "test_clone_and_nested_params checks set_params."
    ),
}

LEARNER_FAILURES = {
    **INPUT_FORMAT_FAILURES,
    **PARTIAL_FIT_FAILURES,
    **SAMPLE_WEIGHT_FAILURES,
    **SKORCH_FAILURES,
}

# Tiny networks: the checks that do run (unfitted errors, parameters) build them.
_TINY = dict(
    max_epochs=1,
    window_s=2.0,
    burn_in_s=0.5,
    sweep_stride_s=2.0,
    n_threads=1,
    random_state=0,
    module__hidden_size=4,
    module__encoder_hidden_size=4,
    module__context_size=2,
)
ESTIMATORS = [
    NoResidual(),
    GRUResidual(module__head_hidden_size=4, **_TINY),
    MLPResidual(**_TINY),
]


def _expected_failed_checks(estimator):
    if isinstance(estimator, NoResidual):
        return INPUT_FORMAT_FAILURES
    return LEARNER_FAILURES




# check_set_params warns for every parameter that skorch cannot take a number for
_SET_PARAMS_WARNING = "ignore:TypeError occurred during set_params:UserWarning"
_CHANGED_WARNING = "ignore:Estimator's parameters changed after set_params:UserWarning"


@pytest.mark.filterwarnings(_SET_PARAMS_WARNING)
@pytest.mark.filterwarnings(_CHANGED_WARNING)
@parametrize_with_checks(
    ESTIMATORS, expected_failed_checks=_expected_failed_checks, xfail_strict=True
)
def test_sklearn_compatible_estimator(estimator, check):
    run_check(estimator, check, _expected_failed_checks(estimator))


@pytest.mark.filterwarnings(_SET_PARAMS_WARNING)
@pytest.mark.filterwarnings(_CHANGED_WARNING)
@pytest.mark.parametrize("estimator", ESTIMATORS, ids=lambda e: type(e).__name__)
def test_expected_failures_are_real_and_for_the_stated_reason(estimator):
    expected = _expected_failed_checks(estimator)
    checks = list(estimator_checks_generator(estimator, legacy=True, mark=None))
    names = {_check_name(check) for _, check in checks}
    # every entry names a check that is run on the estimator (no stale entry)
    assert set(expected) <= names
    # and each listed check fails for the reason given, not for another reason
    # that the list would hide
    for est, check in checks:
        name = _check_name(check)
        if name not in expected:
            continue
        with pytest.raises(Exception) as info:
            check(est)
        if name == "check_no_attributes_set_in_init":
            assert "virtual_params_" in str(info.value), info.value
        elif name == "check_set_params":
            # skorch calls _params_to_validate.add after the check set it to a number
            assert isinstance(info.value, AttributeError), info.value
            assert "has no attribute 'add'" in str(info.value), info.value
        elif name == "check_sample_weights_pandas_series":
            # the check passes a DataFrame of numbers, refused for its columns,
            # and says the weights were refused
            refused = info.value.__context__
            assert "recordings are missing the column(s)" in str(refused), info.value
        else:
            assert _input_format_failure(info.value), (name, info.value)
    # the checks of the API itself run without an expected failure, apart
    # from the two that skorch's parameter handling fails
    for name in (*API_CHECKS, "check_requires_y_none"):
        if name == "check_requires_y_none" and isinstance(estimator, NoResidual):
            continue  # y is optional
        assert name in names
        assert name not in expected or name in SKORCH_FAILURES


# ---------------------------------------------------------------------------
# the properties of the generic checks, on recordings of one and three motors
# ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def recordings_of():
    """``recordings_of(n)``: short recordings of the simulated instrument of ``n`` motors
    with a polynomial backbone, and y."""
    cache = {}

    def get(n_motors):
        if n_motors not in cache:
            Xn, y = instrument(n_motors, ("S02", "S09", "S13"), 120)
            cache[n_motors] = (PolynomialBackbone().fit(Xn).transform(Xn), y)
        return cache[n_motors]

    return get


@pytest.mark.parametrize("n_motors", [1, 3])
@pytest.mark.parametrize("estimator", ESTIMATORS, ids=lambda e: type(e).__name__)
def test_common_properties_on_recordings_of_other_motors(recordings_of, estimator, n_motors):
    """fit returns self and keeps the parameters; predict changes nothing; pickling,
    refitting and predicting runs one at a time give the same tips; the input is unchanged."""
    Xb, y = recordings_of(n_motors)
    X_before = Xb.copy()
    est = clone(estimator)

    def own(params):  # skorch lists its (stateful once trained) callbacks among them
        return {k: v for k, v in params.items() if not k.startswith("callbacks")}

    params = joblib.hash(own(est.get_params()))
    assert est.fit(Xb, y) is est
    assert joblib.hash(own(est.get_params())) == params
    assert est.n_features_in_ == Xb.shape[1]
    assert list(est.feature_names_in_) == list(Xb.columns)
    before = dict(vars(est))
    module = getattr(est, "module_", None)
    weights = {} if module is None else {k: v.clone() for k, v in module.state_dict().items()}
    pred = est.predict(Xb)
    assert vars(est).keys() == before.keys()
    assert all(vars(est)[k] is before[k] for k in before)
    for key, value in weights.items():
        assert torch.equal(module.state_dict()[key], value)
    assert_array_equal(pickle.loads(pickle.dumps(est)).predict(Xb), pred)
    assert_array_equal(clone(estimator).fit(Xb, y).predict(Xb), pred)
    for run in Xb["run"].unique():
        rows = (Xb["run"] == run).to_numpy()
        assert_allclose(est.predict(Xb[rows]), pred[rows], rtol=0, atol=1e-5)
    pd.testing.assert_frame_equal(Xb, X_before)
