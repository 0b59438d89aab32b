"""PolynomialBackbone: a memoryless polynomial of the motor angles as a backbone."""

from math import comb

import joblib
import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose, assert_array_equal
from sklearn.base import clone
from sklearn.pipeline import Pipeline
from sklearn.utils import get_tags
from sklearn.utils.estimator_checks import parametrize_with_checks
from test_common import EXPECTED_FAILED_CHECKS, run_check

from skcath import MOTOR_COLUMNS, REFERENCE_COLUMNS
from skcath.backbones import PolynomialBackbone, PolynomialParams, polynomial_kernel, polynomial_tip
from skcath.datasets import simulate_run
from skcath.residuals import NoResidual


# The backbone runs no solver, so the two n_iter checks pass; every other
# generic check fails as for the geometric backbones, on the array input.
EXPECTED = {k: v for k, v in EXPECTED_FAILED_CHECKS.items() if not k.endswith("_n_iter")}


@parametrize_with_checks(
    [PolynomialBackbone(), PolynomialBackbone(calibration="fit")],
    expected_failed_checks=lambda estimator: EXPECTED,
    xfail_strict=True,
)
def test_sklearn_compatible_estimator(estimator, check):
    run_check(estimator, check, EXPECTED)


def _two_runs(n_motors=2):
    """Two simulated runs (two units, two settings) of ``n_motors`` motors in the long format, and y."""
    a = simulate_run(random_state=0, setting="S01", run="run-a", n_motors=n_motors)
    b = simulate_run(random_state=1, setting="S09", run="run-b", n_motors=n_motors)
    X = pd.concat([a.X, b.X], ignore_index=True)
    for column in ("catheter", "setting", "run", "phase"):
        X[column] = X[column].astype(str)
    X.loc[X["run"] == "run-b", "catheter"] = "C2"
    return X, np.vstack([a.y, b.y])


@pytest.fixture(scope="module")
def recordings():
    """Two simulated runs (two units, two settings) in the long format, and y."""
    return _two_runs()


@pytest.fixture(scope="module")
def recordings_of(recordings):
    """``recordings_of(n)``: the two runs of ``recordings`` on the simulated instrument of ``n`` motors."""
    cache = {2: recordings}

    def get(n_motors):
        if n_motors not in cache:
            cache[n_motors] = _two_runs(n_motors)
        return cache[n_motors]

    return get


def _quadratic(q):
    """An exact degree-2 polynomial of the motor angles (mm)."""
    q1, q2 = q[:, 0], q[:, 1]
    return np.column_stack([3.0 + 0.5 * q1 - 0.01 * q1 * q2, -2.0 + 0.2 * q2, 40.0 + 0.003 * q1**2])


def test_tags_and_parameters():
    tags = get_tags(PolynomialBackbone())
    assert tags.estimator_type == "regressor" and tags.transformer_tags is not None
    assert not tags.target_tags.required and tags.target_tags.multi_output
    assert PolynomialBackbone().get_params() == {
        "degree": 3, "calibration": "sweep", "hysteresis": None, "max_play_deg": 20.0
    }


def test_sweep_calibration_fits_each_run_on_its_own_sweep(recordings):
    X, y = recordings
    est = PolynomialBackbone(degree=3).fit(X)
    assert est.polynomial_ is None
    b = est.predict(X)
    assert b.shape == (len(X), 3) and b.dtype == np.float64
    # per-run calibration: each run alone gives the same nominal tips
    for run in ("run-a", "run-b"):
        rows = (X["run"] == run).to_numpy()
        assert_allclose(est.predict(X[rows]), b[rows], rtol=0, atol=1e-9)
    # a good memoryless fit of the sweep, and a real one of the motion
    sweep = (X["phase"] == "sweep").to_numpy()
    ref = X[list(REFERENCE_COLUMNS)].to_numpy()
    spread = np.sqrt(np.mean(np.sum((ref[sweep] - ref[sweep].mean(axis=0)) ** 2, axis=1)))
    assert np.sqrt(np.mean(np.sum((b[sweep] - ref[sweep]) ** 2, axis=1))) < 0.3 * spread
    motion = ~sweep
    assert np.sqrt(np.mean(np.sum((b[motion] - y[motion]) ** 2, axis=1))) < 0.5 * spread
    # reference values on motion rows are never read
    X_bad = X.copy()
    X_bad.loc[motion, list(REFERENCE_COLUMNS)] = 1e6
    assert_array_equal(est.predict(X_bad), b)


def test_a_higher_degree_fits_the_sweep_better(recordings):
    X, _ = recordings
    sweep = (X["phase"] == "sweep").to_numpy()
    ref = X[list(REFERENCE_COLUMNS)].to_numpy()[sweep]
    errors = [
        np.mean((PolynomialBackbone(degree=d).fit(X).predict(X)[sweep] - ref) ** 2) for d in (1, 3)
    ]
    assert errors[1] < errors[0]


def _with_target(X, y):
    """``X`` with the reference tip equal to ``y`` on sweep rows (the same measurement)."""
    sweep = (X["phase"] == "sweep").to_numpy()[:, None]
    ref = np.where(sweep, y, np.nan)
    return X.assign(**{name: ref[:, j] for j, name in enumerate(REFERENCE_COLUMNS)})


def test_fit_calibration_recovers_a_polynomial_and_skips_nan_targets(recordings):
    X, _ = recordings
    q = X[list(MOTOR_COLUMNS)].to_numpy()
    y = _quadratic(q)
    X = _with_target(X, y)
    est = PolynomialBackbone(degree=2, calibration="fit").fit(X, y)
    assert est.polynomial_ is not None
    assert_allclose(est.predict(X), y, atol=1e-6)
    # degree 1 cannot represent it
    assert np.abs(PolynomialBackbone(degree=1, calibration="fit").fit(X, y).predict(X) - y).max() > 1.0
    # tracker dropouts are skipped, not fatal
    y_nan = y.copy()
    y_nan[::3] = np.nan
    assert_allclose(PolynomialBackbone(degree=2, calibration="fit").fit(X, y_nan).predict(X), y, atol=1e-6)
    # fitted once: the sweep references play no part
    X_ref = X.assign(ref_x=0.0, ref_y=0.0, ref_z=0.0)
    assert_array_equal(est.predict(X_ref), est.predict(X))


def test_fit_calibration_needs_no_sweep(recordings):
    X, _ = recordings
    y = _quadratic(X[list(MOTOR_COLUMNS)].to_numpy())
    no_sweep = X.assign(phase="motion")
    est = PolynomialBackbone(degree=2, calibration="fit").fit(no_sweep, y)
    assert_allclose(est.predict(no_sweep), y, atol=1e-6)
    with pytest.raises(ValueError, match="sweep"):
        PolynomialBackbone().fit(no_sweep)


def test_predict_and_transform_leave_the_estimator_and_the_input_alone(recordings):
    X, y = recordings
    for est in (PolynomialBackbone().fit(X), PolynomialBackbone(calibration="fit").fit(X, y)):
        before = joblib.hash(vars(est))
        X_before = X.copy()
        Xt = est.transform(X)
        b = est.predict(X)
        assert joblib.hash(vars(est)) == before
        pd.testing.assert_frame_equal(X, X_before)
        assert list(Xt.columns) == [*X.columns, "b_x", "b_y", "b_z"]
        assert_array_equal(Xt[["b_x", "b_y", "b_z"]].to_numpy(), b)
        assert list(est.get_feature_names_out()) == list(Xt.columns)
        assert_array_equal(clone(est).fit(X, y).predict(X), b)


def test_transform_needs_the_columns_seen_in_fit(recordings):
    X, _ = recordings
    est = PolynomialBackbone().fit(X)
    with pytest.raises(ValueError, match="unseen at fit time:\n- extra"):
        est.transform(X.assign(extra=1.0))
    with pytest.raises(ValueError, match="same order"):
        est.transform(X[[*X.columns[1:], X.columns[0]]])


def test_pipeline_with_a_residual(recordings):
    X, y = recordings
    pipe = Pipeline([("backbone", PolynomialBackbone(calibration="fit")), ("residual", NoResidual())])
    pred = pipe.fit(X, y).predict(X)
    assert_array_equal(pred, PolynomialBackbone(calibration="fit").fit(X, y).predict(X))
    assert pipe.score(X, y) < 0


def test_pickle_round_trip(recordings):
    X, y = recordings
    est = PolynomialBackbone(calibration="fit").fit(X, y)
    assert_array_equal(joblib.load(_dump(est)).predict(X), est.predict(X))


def _dump(obj):
    import io

    buffer = io.BytesIO()
    joblib.dump(obj, buffer)
    buffer.seek(0)
    return buffer


def test_bad_input_is_a_clear_error(recordings):
    X, y = recordings
    with pytest.raises(ValueError, match="degree"):
        PolynomialBackbone(degree=0).fit(X)
    with pytest.raises(ValueError, match="calibration"):
        PolynomialBackbone(calibration="once").fit(X, y)
    with pytest.raises(ValueError, match="y is None"):
        PolynomialBackbone(calibration="fit").fit(X)
    with pytest.raises(ValueError, match="q1"):
        PolynomialBackbone().fit(X.drop(columns="q1"))
    with pytest.raises(ValueError, match="rows"):
        PolynomialBackbone(calibration="fit").fit(X, y[:-1])
    # a sweep too short for the degree names the run
    short = X.copy()
    first_b = int(np.flatnonzero((X["run"] == "run-b").to_numpy())[0])
    short.loc[(short["run"] == "run-b").to_numpy() & (short.index >= first_b + 5), "phase"] = "motion"
    est = PolynomialBackbone(degree=3).fit(short)
    with pytest.raises(ValueError, match="run 'run-b'"):
        est.predict(short)
    all_nan = np.full_like(y, np.nan)
    with pytest.raises(ValueError, match="finite tip position"):
        PolynomialBackbone(calibration="fit").fit(X, all_nan)


# ---------------------------------------------------------------------------
# any number of motors; the kernel and the calibration
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("n_motors", [1, 2, 3])
def test_any_number_of_motors(recordings_of, n_motors):
    Xn, y = recordings_of(n_motors)
    motors = [f"q{k}" for k in range(1, n_motors + 1)]
    sweep = (Xn["phase"] == "sweep").to_numpy()
    ref = Xn[list(REFERENCE_COLUMNS)].to_numpy()
    for calibration in ("sweep", "fit"):
        est = PolynomialBackbone(degree=2, calibration=calibration).fit(Xn, y)
        assert est.n_motors_ == n_motors
        b = est.predict(Xn)
        assert b.shape == (len(Xn), 3) and np.isfinite(b).all()
        cal = est.calibrate(Xn)
        assert_array_equal(cal.nominal, b)
        params = cal.params["run-a"]
        assert params.n_motors == n_motors
        assert params.powers.shape == (comb(n_motors + 2, 2), n_motors)
        assert cal.table.loc["run-a", "n_motors"] == n_motors
        rows = (Xn["run"] == "run-a").to_numpy()
        assert_allclose(polynomial_tip(Xn.loc[rows, motors].to_numpy(), params), b[rows],
                        rtol=0, atol=0)
    # the sweep fit: the sweep RMSE of the table is that of the nominal tips
    est = PolynomialBackbone(degree=2).fit(Xn)
    cal = est.calibrate(Xn)
    rows = sweep & (Xn["run"] == "run-b").to_numpy()
    rmse = np.sqrt(np.mean(np.sum((cal.nominal[rows] - ref[rows]) ** 2, axis=1)))
    assert cal.table.loc["run-b", "rmse_mm"] == pytest.approx(rmse)
    assert (cal.table["play_width_deg"] == 0).all()


@pytest.mark.parametrize("n_motors", [1, 3])
def test_kernel_is_the_fitted_polynomial(recordings_of, n_motors):
    """polynomial_kernel on the packed parameters gives the scikit-learn polynomial."""
    Xn, y = recordings_of(n_motors)
    est = PolynomialBackbone(degree=3, calibration="fit").fit(Xn, y)
    q = Xn[[f"q{k}" for k in range(1, n_motors + 1)]].to_numpy()
    expected = est.polynomial_.predict(q)
    params = PolynomialParams.from_polynomial(est.polynomial_)
    assert_allclose(est.predict(Xn), expected, rtol=0, atol=1e-9)
    theta = params.pack()
    for k in (0, 100, len(q) - 1):
        assert_allclose(polynomial_kernel(theta, q[k]), expected[k], rtol=0, atol=1e-9)
        assert_allclose(polynomial_kernel(theta.tolist(), q[k].tolist()), expected[k],
                        rtol=0, atol=1e-9)
    with pytest.raises(ValueError, match=rf"q must have shape \(n, {n_motors}\)"):
        polynomial_tip(q[:, :1] if n_motors == 3 else np.c_[q, q], params)


def test_fitted_polynomial_refuses_another_number_of_motors(recordings, recordings_of):
    X, y = recordings
    X3, _ = recordings_of(3)
    est = PolynomialBackbone(calibration="fit").fit(X, y)
    with pytest.raises(ValueError, match=r"fitted on recordings of 2 motor\(s\), but X has 3 "
                       r"\(q1, q2, q3\)"):
        est.predict(X3)
    # calibrated on each sweep, the number of motors may differ from fit's
    b = PolynomialBackbone().fit(X).predict(X3)
    assert np.isfinite(b).all()
