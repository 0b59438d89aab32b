"""Time scales in seconds: the residual learners' windows, burn-in and sweep blocks.

A learner's time scales are given in seconds and turned into samples at the
rate of its training runs, so that the defaults mean the same time at any
rate; the detector's per-sample CUSUM warns at another rate than its
defaults' (``docs/residuals.rst``, *Sample rates*).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from numpy.testing import assert_allclose
from sklearn.pipeline import Pipeline

from skcath._rate import training_rate
from skcath.backbones import PDLBackbone
from skcath.datasets import simulate_run
from skcath.exceptions import SampleRateWarning
from skcath.online import ShaftChangeDetector
from skcath.protocol import FULL, QUICK
from skcath.residuals import GRUResidual, MLPResidual
from skcath.residuals._time_scales import time_scales, to_samples
from skcath.sequences import resample_runs

#: Seconds of motion kept after the sweep: long enough for three 20 s windows.
MOTION_S = 60.0
#: The learners' time scales in samples at 10 Hz before they were given in seconds:
#: (window, window_step, burn_in, sweep_stride) of the full and quick schedules.
SAMPLES_AT_10_HZ = {
    ("full", GRUResidual): (200, 150, 50, 40),
    ("full", MLPResidual): (200, 200, 0, 40),
    ("quick", GRUResidual): (200, 200, 50, 40),
    ("quick", MLPResidual): (200, 200, 0, 40),
}
#: A small network with the default time scales.
SMALL = dict(max_epochs=1, module__hidden_size=4, module__encoder_hidden_size=4,
             module__context_size=2, n_threads=1, random_state=0)


def _run(rate_hz, setting="S05", seed=3):
    """One simulated run at ``rate_hz`` with :data:`MOTION_S` seconds of motion."""
    data = simulate_run(setting=setting, random_state=seed, run="r", rate_hz=rate_hz)
    X = data.X
    first_motion = X.loc[X["phase"] == "motion", "t"].iloc[0]
    keep = (X["t"] <= first_motion + MOTION_S).to_numpy()
    return X[keep].reset_index(drop=True), np.asarray(data.y)[keep]


@pytest.fixture(scope="module")
def runs():
    """The same run at 10 and 40 Hz (computed lazily)."""
    cache = {}

    def get(rate_hz):
        if rate_hz not in cache:
            cache[rate_hz] = _run(rate_hz)
        return cache[rate_hz]

    return get


def _fitted_windows(learner, X, y, monkeypatch):
    """``learner`` fitted in a pipeline after PDL, and the training data its network got."""
    seen = []
    original = type(learner).get_split_datasets

    def spy(self, data, target=None, **fit_params):
        seen.append(data)
        return original(self, data, target, **fit_params)

    monkeypatch.setattr(type(learner), "get_split_datasets", spy)
    pipe = Pipeline([("backbone", PDLBackbone()), ("residual", learner)]).fit(X, y)
    return pipe.named_steps["residual"], seen[0]


def test_the_defaults_are_the_same_time_at_10_and_40_hz(runs, monkeypatch):
    # A network stepping at the recordings' own rate (rate_hz=None) counts the
    # default time scales in samples at that rate.
    fitted = {}
    for rate in (10.0, 40.0):
        X, y = runs(rate)
        fitted[rate] = _fitted_windows(GRUResidual(rate_hz=None, **SMALL), X, y, monkeypatch)
    slow, fast = fitted[10.0][0], fitted[40.0][0]
    assert (slow.window_, slow.window_step_, slow.burn_in_, slow.sweep_stride_) == (200, 150, 50, 40)
    assert (fast.window_, fast.window_step_, fast.burn_in_, fast.sweep_stride_) == (
        800, 600, 200, 160
    )
    for name in ("window_", "window_step_", "burn_in_", "sweep_stride_"):
        assert getattr(slow, name) / slow.rate_hz_ == pytest.approx(getattr(fast, name) / fast.rate_hz_)
    # the network trains on windows of 20 s at either rate, and the sweep of the
    # same run becomes about as many context-encoder steps
    slow_data, fast_data = fitted[10.0][1], fitted[40.0][1]
    assert slow_data["features"].shape[1] == 200 and fast_data["features"].shape[1] == 800
    assert abs(int(fast_data["sweep_length"][0]) - int(slow_data["sweep_length"][0])) <= 1
    # the burn-in masks 5 s of a window that starts inside the run
    inside = fast_data["mask"][1]
    assert not inside[:200].any() and inside[200:].any()


def test_by_default_the_network_steps_every_tenth_of_a_second(runs, monkeypatch):
    # rate_hz=10.0: 40 Hz recordings are trained on at 10 Hz ticks, with the
    # windows, blocks and sweep of a model fitted at 10 Hz.
    X10, y10 = runs(10.0)
    X40, y40 = runs(40.0)
    slow, slow_data = _fitted_windows(GRUResidual(**SMALL), X10, y10, monkeypatch)
    fast, fast_data = _fitted_windows(GRUResidual(**SMALL), X40, y40, monkeypatch)
    assert GRUResidual().rate_hz == MLPResidual().rate_hz == 10.0
    assert fast.rate_hz_ == pytest.approx(10.0, rel=1e-6)
    assert (fast.window_, fast.window_step_, fast.burn_in_, fast.sweep_stride_) == (
        200, 150, 50, 40)
    assert fast_data["features"].shape[1] == slow_data["features"].shape[1] == 200
    assert abs(int(fast_data["sweep_length"][0]) - int(slow_data["sweep_length"][0])) <= 1
    # at 10 Hz the default changes nothing: the runs are taken as they are
    native, native_data = _fitted_windows(GRUResidual(rate_hz=None, **SMALL), X10, y10,
                                          monkeypatch)
    assert native.rate_hz_ == slow.rate_hz_
    for key in ("features", "mask"):
        np.testing.assert_array_equal(native_data[key], slow_data[key])


def test_the_conversion_is_exact_at_the_benchmark_rate(runs):
    X, _ = runs(10.0)
    rate = training_rate(X, "test")
    scales, exact = time_scales(GRUResidual(), rate), time_scales(GRUResidual(), 10.0)
    assert rate != 10.0  # 1 / the median step of t = k / 10 Hz is not 10.0 to the last bit
    assert (scales.window, scales.window_step, scales.burn_in, scales.sweep_stride) == (
        exact.window, exact.window_step, exact.burn_in, exact.sweep_stride)
    assert to_samples(20.0, rate) == 200 and to_samples(4.0, rate) == 40
    assert to_samples(0.25, 10.0) == 2 and to_samples(0.35, 10.0) == 4  # round(): ties to even


@pytest.mark.parametrize("schedule", [FULL, QUICK], ids=lambda s: s.name)
@pytest.mark.parametrize("Est", [GRUResidual, MLPResidual])
def test_schedules_keep_their_sample_counts_at_10_hz(schedule, Est):
    for stage in (schedule.pretrain_params, schedule.finetune_params):
        learner = Est(**schedule.model_params, **stage)
        scales = time_scales(learner, 10.0)
        counts = (scales.window, scales.window_step, scales.burn_in, scales.sweep_stride)
        assert counts == SAMPLES_AT_10_HZ[schedule.name, Est]


def test_a_time_scale_too_short_at_the_fitted_rate_names_its_parameter(runs):
    # 0.04 s is 2 samples at 40 Hz (1.6) but 0 at 10 Hz (0.4)
    X40, y40 = runs(40.0)
    pipe = Pipeline([("backbone", PDLBackbone()),
                     ("residual", GRUResidual(sweep_stride_s=0.04, rate_hz=None, **SMALL))])
    pipe.fit(X40, y40)
    assert pipe.named_steps["residual"].sweep_stride_ == 2
    X10, y10 = runs(10.0)
    residual = GRUResidual(sweep_stride_s=0.04, **SMALL)
    with pytest.raises(ValueError, match=r"sweep_stride_s=0\.04 s is 0 sample\(s\) at the "
                                         r"fitted rate of 10 Hz.*at least 1"):
        Pipeline([("backbone", PDLBackbone()), ("residual", residual)]).fit(X10, y10)
    with pytest.raises(ValueError, match=r"window_s=0\.1 s is 1 sample"):
        time_scales(GRUResidual(window_s=0.1, burn_in_s=0.0), 10.0)


@pytest.mark.parametrize("Est", [GRUResidual, MLPResidual])
@pytest.mark.parametrize(
    "old, new",
    [("window", "window_s"), ("window_step", "window_step_s"), ("burn_in", "burn_in_s"),
     ("sweep_stride", "sweep_stride_s")],
)
def test_a_former_name_in_samples_fails_clearly(Est, old, new):
    with pytest.raises(TypeError, match=f"does not take '{old}' \\(samples\\).*{new}="):
        Est(**{old: 10})
    with pytest.raises(ValueError, match=f"does not take '{old}'.*{new}="):
        Est().set_params(**{old: 10})
    pipe = Pipeline([("backbone", PDLBackbone()), ("residual", Est())])
    with pytest.raises(ValueError, match=f"{new}="):
        pipe.set_params(**{f"residual__{old}": 10})


def _sweep(rate_hz):
    X, _ = _run(rate_hz, setting="S01", seed=0)
    return X[X["phase"] == "sweep"]


def test_detector_warns_when_its_per_sample_defaults_meet_another_rate():
    sweep = _sweep(40.0)
    with pytest.warns(SampleRateWarning, match="threshold=130.0 and drift=1.5 were chosen at 10 Hz"):
        ShaftChangeDetector(rate_hz=40.0).start(sweep)
    with pytest.warns(SampleRateWarning, match="drift=1.5 was chosen"):
        ShaftChangeDetector(rate_hz=40.0, threshold=500.0).start(sweep)
    # the declared rate and the sweep's times disagree
    with pytest.warns(SampleRateWarning, match=r"rate_hz=10.0, but the sweep's times are at 40 Hz"):
        ShaftChangeDetector(threshold=500.0, drift=2.0).start(sweep)
    with warnings.catch_warnings():
        warnings.simplefilter("error", SampleRateWarning)
        ShaftChangeDetector(rate_hz=40.0, threshold=500.0, drift=2.0).start(sweep)
        ShaftChangeDetector().start(_sweep(10.0))


def test_a_model_rate_trains_on_the_runs_resampled_to_it(runs):
    X, y = runs(40.0)
    X_in, y_in = X.copy(), y.copy()
    pipe = Pipeline([("backbone", PDLBackbone()),
                     ("residual", GRUResidual(rate_hz=10.0, **SMALL))]).fit(X, y)
    residual = pipe.named_steps["residual"]
    assert residual.rate_hz_ == pytest.approx(10.0) and residual.window_ == 200
    assert X.equals(X_in) and np.array_equal(y, y_in, equal_nan=True)
    # the same learner fitted by hand on the backbone's output and the tips at 10 Hz
    Xb = pipe.named_steps["backbone"].transform(X)
    Z = resample_runs(Xb.assign(tip_x=y[:, 0], tip_y=y[:, 1], tip_z=y[:, 2]), 10.0)
    tips = ["tip_x", "tip_y", "tip_z"]
    by_hand = GRUResidual(**SMALL).fit(Z.drop(columns=tips), Z[tips].to_numpy())
    assert_allclose(pipe.predict(X), by_hand.predict(Xb), atol=1e-9)
    assert list(residual.feature_names_in_) == list(Xb.columns)
