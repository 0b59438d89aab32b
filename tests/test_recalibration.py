"""MotorRecalibration: the backbone's calibration renewed from a sweep of the motors alone."""

import pickle

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose
from sklearn.pipeline import Pipeline
from sklearn.utils._param_validation import InvalidParameterError

from skcath import persist
from skcath.backbones import PDLBackbone, pdl_tip
from skcath.datasets import benchmark_catheter, make_benchmark, simulate_run
from skcath.online import MotorRecalibration, OnlineEstimator, ShaftChangeDetector
from skcath.online._recalibration import interpolate_polar, polar_grid

REFERENCE = ["ref_x", "ref_y", "ref_z"]
CHANNELS = ["q1", "q2", "tau1", "tau2"]


# ---------------------------------------------------------------------------
# the grid and its interpolation
# ---------------------------------------------------------------------------
def test_interpolation_is_exact_on_the_grid_and_linear_between():
    centre, amplitude = np.array([1.5, -2.0]), 60.0
    grid = polar_grid(centre, amplitude, 8, 3)
    assert grid.shape == (25, 2)
    assert_allclose(grid[0], centre)
    assert_allclose(np.hypot(*(grid[1:] - centre).T), np.repeat([20.0, 40.0, 60.0], 8))
    values = np.random.default_rng(0).normal(size=(25, 3))
    assert_allclose(interpolate_polar(values, grid, centre, amplitude, 8, 3), values, atol=1e-12)
    # halfway along a ray between rings, and halfway between two directions on a ring
    mid_ray = centre + [30.0, 0.0]
    assert_allclose(interpolate_polar(values, mid_ray[None], centre, amplitude, 8, 3)[0],
                    (values[1] + values[9]) / 2, atol=1e-12)
    mid_dir = centre + 20.0 * np.array([np.cos(np.pi / 8), np.sin(np.pi / 8)])
    assert_allclose(interpolate_polar(values, mid_dir[None], centre, amplitude, 8, 3)[0],
                    (values[1] + values[2]) / 2, atol=1e-12)
    # across the last direction back to the first (periodic), and held beyond the amplitude
    last = centre + 40.0 * np.array([np.cos(-np.pi / 8), np.sin(-np.pi / 8)])
    assert_allclose(interpolate_polar(values, last[None], centre, amplitude, 8, 3)[0],
                    (values[9] + values[16]) / 2, atol=1e-12)
    far = centre + [90.0, 0.0]
    assert_allclose(interpolate_polar(values, far[None], centre, amplitude, 8, 3)[0], values[17],
                    atol=1e-12)


# ---------------------------------------------------------------------------
# fitting and predicting
# ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def training(tmp_path_factory):
    """Tracked recordings of catheters C2 and C3 in every setting (sweeps only)."""
    bench = make_benchmark(n_catheters=3, n_runs=1, cache=False)
    X = bench.X[(bench.X["phase"] == "sweep").to_numpy() & (bench.X["catheter"] != "C1").to_numpy()]
    return X.reset_index(drop=True)


@pytest.fixture(scope="module")
def fitted(training):
    return MotorRecalibration().fit(training)


@pytest.fixture(scope="module")
def changed():
    """A run of C1 in S05 whose shaft moves to S13, then sweeps again (first sweep, tracked re-sweep, motion)."""
    data = simulate_run(
        catheter=benchmark_catheter(1), setting="S05", setting_after="S13", change_after_s=30.0,
        resweep=True, random_state=1,
    )
    X, y = data.X, np.asarray(data.y)
    first = X[((X["run"] == "run-0") & (X["phase"] == "sweep")).to_numpy()]
    after_rows = (X["run"] == "run-0/after").to_numpy()
    after = X[after_rows].reset_index(drop=True)
    n_sweep = int((after["phase"] == "sweep").sum())
    return first, after.iloc[:n_sweep], after.iloc[n_sweep:], y[after_rows][n_sweep:]


def test_fit_pairs_runs_within_each_catheter(fitted, training):
    n = training.groupby("catheter", observed=True)["run"].nunique()
    assert fitted.n_pairs_ == int((n * (n - 1)).sum())
    assert fitted.alpha_ in fitted.cv_rmse_
    assert fitted.cv_rmse_[fitted.alpha_] == min(fitted.cv_rmse_.values())
    # the held-out catheter's change is predicted better than by keeping the old calibration
    assert fitted.cv_rmse_[fitted.alpha_] < fitted.change_rmse_
    assert fitted.ridge_.coef_.shape == (3 * 25, 58)


def test_recalibration_of_a_held_out_catheter_moves_the_tip_towards_the_new_one(fitted, changed):
    """On C1 (not in training), the predicted re-sweep tip is closer to the tracked one than the kept calibration."""
    first, tracked, _, _ = changed
    backbone = PDLBackbone().fit(first)
    kept = backbone.calibrate(first).params["run-0"]
    q = tracked[["q1", "q2"]].to_numpy()
    predicted = fitted.recalibrate(first, tracked.drop(columns=REFERENCE), params=kept)
    truth = tracked[REFERENCE].to_numpy()
    stale = np.sqrt(np.mean(np.sum((pdl_tip(q, kept) - truth) ** 2, axis=1)))
    renewed = np.sqrt(np.mean(np.sum((predicted[REFERENCE].to_numpy() - truth) ** 2, axis=1)))
    assert renewed < 0.8 * stale
    # the same without params: the sweep is calibrated with the estimator's backbone
    again = fitted.recalibrate(first, tracked.drop(columns=REFERENCE))
    assert_allclose(again[REFERENCE].to_numpy(), predicted[REFERENCE].to_numpy(), atol=1e-9)
    # a copy of the re-sweep: its other columns as they were
    pd.testing.assert_frame_equal(predicted.drop(columns=REFERENCE), tracked.drop(columns=REFERENCE))


def test_no_change_predicts_no_change(fitted, changed):
    first, _, _, _ = changed
    kept = PDLBackbone().fit(first).calibrate(first).params["run-0"]
    change = fitted.predict_change(kept, first, first)
    assert_allclose(change, 0.0, atol=1e-9)


def test_parameters_are_validated_in_fit(training):
    with pytest.raises(InvalidParameterError, match="alpha"):
        MotorRecalibration(alpha=-1.0).fit(training)
    with pytest.raises(InvalidParameterError, match="n_directions"):
        MotorRecalibration(n_directions=2).fit(training)


def test_fixed_alpha_and_groups(training):
    groups = training["catheter"].astype(str).to_numpy()
    by_column = MotorRecalibration(alpha=100.0).fit(training)
    by_groups = MotorRecalibration(alpha=100.0).fit(training.drop(columns="catheter").assign(
        catheter="one"), groups=groups)
    assert by_column.cv_rmse_ is None and by_column.alpha_ == 100.0
    assert_allclose(by_groups.ridge_.coef_, by_column.ridge_.coef_)


def test_fit_is_deterministic_and_leaves_its_input_unchanged(training, fitted):
    before = training.copy(deep=True)
    again = MotorRecalibration().fit(training)
    pd.testing.assert_frame_equal(training, before, check_exact=True)
    assert_allclose(again.ridge_.coef_, fitted.ridge_.coef_, rtol=0, atol=0)


# ---------------------------------------------------------------------------
# OnlineEstimator.resweep(recalibration=...)
# ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def backbone_alone(changed):
    first, _, _, _ = changed
    return Pipeline([("backbone", PDLBackbone().fit(first))])


def test_resweep_with_a_recalibration_starts_on_the_predicted_sweep(fitted, changed, backbone_alone):
    first, tracked, motion, y = changed
    motor_only = tracked.drop(columns=REFERENCE)
    est = OnlineEstimator(backbone_alone, detector=ShaftChangeDetector()).start(first)
    kept = est.backbone_params_
    assert est.resweep(motor_only, recalibration=fitted) is est
    expected = OnlineEstimator(backbone_alone).start(fitted.recalibrate(first, motor_only, params=kept))
    assert_allclose(est.backbone_params_.coef, expected.backbone_params_.coef, rtol=0, atol=0)
    assert est.run_ == "run-0/after" and est.shaft_changed_ is False
    samples = motion[CHANNELS].to_numpy()
    renewed = np.array([est.step(*s).copy() for s in samples])
    stale = OnlineEstimator(backbone_alone).start(first).resweep(motor_only)
    kept_tips = np.array([stale.step(*s).copy() for s in samples])

    def rmse(tips):
        return np.sqrt(np.nanmean(np.sum((tips - y) ** 2, axis=1)))

    assert rmse(renewed) < 0.8 * rmse(kept_tips)
    # a second re-sweep starts from the predicted one: the same sweep again changes nothing
    params = est.backbone_params_
    est.resweep(motor_only, recalibration=fitted)
    assert_allclose(est.backbone_params_.coef, params.coef, atol=1e-6)
    # pickled, the estimator can still recalibrate
    loaded = pickle.loads(pickle.dumps(est))
    loaded.resweep(motor_only, recalibration=fitted)
    assert_allclose(loaded.backbone_params_.coef, params.coef, atol=1e-6)


def test_a_saved_recalibration_predicts_the_same(fitted, changed, tmp_path):
    """persist.save / load keeps the fitted regression: the same predicted tip."""
    first, tracked, _, _ = changed
    path = tmp_path / "recalibration.skcath"
    persist.save(fitted, path)
    loaded = persist.load(path)
    motor_only = tracked.drop(columns=REFERENCE)
    pd.testing.assert_frame_equal(loaded.recalibrate(first, motor_only),
                                  fitted.recalibrate(first, motor_only), check_exact=True)
