"""Sample rates: the simulator's rate, the rate a learner records, and runs at other rates.

A residual learner counts time in samples. It records the rate of its
training runs (``rate_hz_``); ``predict`` brings a run recorded at another
rate, or unevenly, to that rate (:mod:`skcath._rate`), and the streaming
estimator steps the model at its own ticks. The runs at other rates come
from the simulator, which samples the same run (motion, catheter, drifts,
base pose) at any rate.
"""

import pickle

import joblib
import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose, assert_array_equal
from sklearn.frozen import FrozenEstimator
from sklearn.pipeline import Pipeline
from sklearn.utils._param_validation import InvalidParameterError

from skcath import persist
from skcath._rate import (
    MIN_RATE_FRACTION,
    TICK_TOLERANCE,
    model_ticks,
    to_model_rate,
    training_rate,
)
from skcath.backbones import BACKBONE_COLUMNS, PDLBackbone
from skcath.datasets import simulate_run
from skcath.datasets._benchmark import _cache_key
from skcath.datasets._protocol import protocol_trajectory, run_protocol
from skcath.online import OnlineEstimator
from skcath.residuals import GRUResidual
from skcath.sequences import resample_runs, run_rates

from _helpers import tiny_residual

CHANNELS = ["q1", "q2", "tau1", "tau2"]
B = list(BACKBONE_COLUMNS)
#: Seconds of motion kept of every simulated run.
MOTION_S = 30.0


# ---------------------------------------------------------------------------
# data
# ---------------------------------------------------------------------------
def _frame(times_by_run, phase_split=0.5):
    """Synthetic recordings: per run, ``q1 = t``, ``q2 = 2 t``, the first half sweep."""
    frames = []
    for run, t in times_by_run.items():
        t = np.asarray(t, dtype=float)
        n = len(t)
        sweep = np.arange(n) < int(phase_split * n)
        frames.append(pd.DataFrame({
            "catheter": "C1", "setting": "S00", "run": run, "t": t,
            "phase": np.where(sweep, "sweep", "motion"),
            "q1": t, "q2": 2 * t, "tau1": np.sin(t), "tau2": np.cos(t),
            "ref_x": np.where(sweep, t, np.nan), "ref_y": np.where(sweep, 0.0, np.nan),
            "ref_z": np.where(sweep, 50.0, np.nan), "note": "x",
        }))
    return pd.concat(frames, ignore_index=True)


def _simulated(setting, seed, rate_hz, run):
    """A simulated run at ``rate_hz``, its motion cut after :data:`MOTION_S` seconds."""
    data = simulate_run(setting=setting, random_state=seed, run=run, rate_hz=rate_hz)
    X = data.X
    first_motion = X.loc[X["phase"] == "motion", "t"].iloc[0]
    keep = (X["t"] <= first_motion + MOTION_S).to_numpy()
    X = X[keep].reset_index(drop=True)
    X["run"] = X["run"].astype(str)
    return X, data.y[keep], data.y_true[keep]


@pytest.fixture(scope="module")
def train():
    """Three 10 Hz runs (one low, two high bends)."""
    runs = [_simulated(s, k, 10.0, f"r{k}") for k, s in enumerate(["S02", "S09", "S13"])]
    return pd.concat([r[0] for r in runs], ignore_index=True), np.concatenate([r[1] for r in runs])


@pytest.fixture(scope="module")
def pipe(train):
    """PDL + a tiny GRU fitted at 10 Hz."""
    X, y = train
    return Pipeline([("backbone", PDLBackbone()),
                     ("residual", tiny_residual(GRUResidual, max_epochs=3))]).fit(X, y)


@pytest.fixture(scope="module")
def held():
    """A held-out setting's run, the same run at several rates (computed lazily)."""
    cache = {}

    def get(rate_hz):
        if rate_hz not in cache:
            cache[rate_hz] = _simulated("S05", 7, rate_hz, "h")
        return cache[rate_hz]

    return get


def _motion(X):
    return (X["phase"] == "motion").to_numpy()


def _at_times(X, times):
    """Rows of ``X`` at ``times`` (s), the nearest row at or after each."""
    t = X["t"].to_numpy()
    return np.minimum(np.searchsorted(t, np.asarray(times) - 1e-9), len(t) - 1)


def _rms(d):
    return float(np.sqrt(np.mean(np.sum(d**2, axis=1))))


# ---------------------------------------------------------------------------
# rates of runs and resampling (skcath._rate)
# ---------------------------------------------------------------------------
def test_run_rates_are_one_over_the_median_step():
    t40 = np.arange(200) / 40.0
    t40[100:] += 0.5  # a gap does not move the median
    X = _frame({"a": np.arange(50) / 10.0, "b": t40, "c": [0.0]})
    rates = run_rates(X)
    assert list(rates.index) == ["a", "b", "c"]
    assert_allclose(rates.to_numpy()[:2], [10.0, 40.0])
    assert np.isnan(rates["c"])


def test_training_rate_refuses_runs_at_other_rates_by_name():
    X = _frame({"a": np.arange(60) / 10.0, "b": np.arange(60) / 10.5, "c": np.arange(60) / 20.0})
    with pytest.raises(ValueError, match=r"M learns time in samples, so its training runs "
                       r"must share one sample rate; most rows are at 10\.5 Hz, but run\(s\) 'c' at 20 Hz differ by more "
                       r"than 10 % \(RATE_TOLERANCE\)"):
        training_rate(X, "M")
    assert training_rate(X[X["run"] != "c"], "M") == pytest.approx(1 / np.median(
        np.r_[np.full(59, 0.1), np.full(59, 1 / 10.5)]))
    assert training_rate(_frame({"a": [0.0]}), "M") is None


def test_resample_runs_interpolates_in_time_and_keeps_holds():
    t = np.arange(0, 10.0, 0.25)  # 4 Hz
    X = _frame({"a": t})
    held_q = np.repeat([0.0, 5.0, 5.0, 5.0, 5.0, 2.0, 2.0, 2.0], 5)  # held values
    X["q1"] = held_q
    before = X.copy()
    out = resample_runs(X, 10.0)
    pd.testing.assert_frame_equal(X, before)
    assert list(out.columns) == [c for c in X.columns if c != "note"]
    assert_allclose(out["t"], model_ticks(0.0, t[-1], 10.0))
    assert_allclose(out["q2"], 2 * out["t"], atol=1e-12)  # linear in time
    assert_allclose(out["q1"], np.interp(out["t"], t, held_q))
    inside_hold = (out["t"] >= 1.25) & (out["t"] <= 5.0)
    assert (out.loc[inside_hold, "q1"] == 5.0).all()
    last_sweep = t[len(t) // 2 - 1]
    assert_array_equal(out["phase"], np.where(out["t"] <= last_sweep, "sweep", "motion"))
    assert out["ref_x"].notna().sum() == (out["t"] <= last_sweep).sum()
    with pytest.raises(InvalidParameterError, match="rate_hz"):
        resample_runs(X, 0.0)


def test_regular_runs_are_taken_as_they_are():
    rng = np.random.default_rng(0)
    t = np.arange(100) / 10.0 + rng.uniform(-0.003, 0.003, 100)  # within the tolerance
    X = _frame({"a": t, "b": np.arange(100) / 10.0})
    assert to_model_rate(X, 10.0, "M") is None
    assert to_model_rate(X, None, "M") is None


def test_runs_at_another_rate_or_uneven_are_brought_to_the_model_rate():
    rng = np.random.default_rng(0)
    jitter = np.arange(100) / 10.0 + rng.uniform(-0.01, 0.01, 100)  # +-10 %
    X = _frame({"regular": np.arange(100) / 10.0, "fast": np.arange(400) / 40.0,
                "jitter": jitter})
    at_rate = to_model_rate(X, 10.0, "M")
    assert list(at_rate.resampled) == ["fast", "jitter"]
    kept = (X["run"] == "regular").to_numpy()
    pd.testing.assert_frame_equal(
        at_rate.X.iloc[: kept.sum()].drop(columns="note"),
        X[kept].drop(columns="note"), check_dtype=False,
    )
    fast = at_rate.X[at_rate.X["run"] == "fast"]
    assert_allclose(np.diff(fast["t"]), 0.1)
    # values on the ticks come back to the rows by linear interpolation in time
    values = at_rate.X[["q1", "q2"]].to_numpy()
    back = at_rate.to_rows(values)
    assert_array_equal(back[kept], X.loc[kept, ["q1", "q2"]].to_numpy())
    last_tick = X["run"].map(at_rate.X.groupby("run")["t"].max()).to_numpy()
    inside = ~kept & _motion(X) & (X["t"].to_numpy() <= last_tick)
    assert_allclose(back[inside], X.loc[inside, ["q1", "q2"]].to_numpy(), atol=1e-9)
    after = ~kept & (X["t"].to_numpy() > last_tick)  # held at the last tick
    assert after.any() and np.all(back[after, 0] == X["run"][after].map(
        at_rate.X.groupby("run")["q1"].last()).to_numpy())


def test_a_run_too_slow_for_the_model_is_refused():
    X = _frame({"ok": np.arange(40) / 10.0, "slow": np.arange(40) / 1.5})
    with pytest.raises(ValueError, match=r"M was fitted at 10 Hz and steps at that rate; "
                       r"run\(s\) 'slow' at 1\.5 Hz are recorded slower than 0\.2 times"):
        to_model_rate(X, 10.0, "M")
    assert to_model_rate(X[X["run"] == "ok"], 10.0, "M") is None
    assert MIN_RATE_FRACTION * 10.0 == pytest.approx(2.0)


# ---------------------------------------------------------------------------
# the simulator's rate
# ---------------------------------------------------------------------------
def test_protocol_is_the_same_motion_at_every_rate():
    q10, n10 = run_protocol(np.random.default_rng(3))
    trajectory = protocol_trajectory(np.random.default_rng(3))
    assert_array_equal(trajectory.sample()[0], q10)
    q40, n40 = trajectory.sample(40.0)
    assert_array_equal(q40[::4], q10)
    assert len(q40) == 4 * (len(q10) - 1) + 1
    assert n40 == 4 * (n10 - 1) + 1  # the samples up to the sweep's last one
    q4, _ = trajectory.sample(4.0)
    t4 = np.arange(len(q4)) / 4.0
    on_base = np.isclose(t4 * 10.0, np.round(t4 * 10.0))
    assert_allclose(q4[on_base], q10[np.round(t4[on_base] * 10).astype(int)], atol=1e-12)


def test_simulated_run_at_another_rate_is_the_same_run():
    a = simulate_run(setting="S09", random_state=3)
    b = simulate_run(setting="S09", random_state=3, rate_hz=40.0)
    assert b.runs["n_samples"].item() == 4 * (a.runs["n_samples"].item() - 1) + 1
    assert_allclose(np.diff(b.X["t"]), 0.025)
    every4 = np.arange(0, len(b.X), 4)
    assert_array_equal(b.X[["q1", "q2"]].to_numpy()[every4], a.X[["q1", "q2"]].to_numpy())
    assert_array_equal(b.X["phase"].to_numpy()[every4], a.X["phase"].to_numpy())
    # the same base pose: the base sensor's mean position over the run
    base = ["base_px", "base_py", "base_pz"]
    assert_allclose(b.sensors[base].mean(), a.sensors[base].mean(), atol=0.02)
    # the same physics, up to its time discretisation: within the sensor noise
    assert _rms(b.y_true[every4] - a.y_true) < 0.3
    # fresh noise of the same standard deviation per sample
    noise_a, noise_b = a.y - a.y_true, b.y - b.y_true
    assert_allclose(np.nanstd(noise_b, axis=0), np.nanstd(noise_a, axis=0), rtol=0.15)
    assert not np.allclose(noise_b[every4], noise_a)


def test_default_rate_keeps_the_benchmark_and_its_cache_key():
    kwargs = dict(unit_spread=0.35, run_variation=None, catheters=None)
    key = _cache_key(4, 3, "play", 0, False, **kwargs)
    assert key == {"version": key["version"], "n_catheters": 4, "n_runs": 3,
                   "mechanism": "play", "random_state": 0}
    assert _cache_key(4, 3, "play", 0, False, rate_hz=10.0, **kwargs) == key
    assert _cache_key(4, 3, "play", 0, False, rate_hz=40.0, **kwargs)["rate_hz"] == 40.0
    with pytest.raises(InvalidParameterError, match="rate_hz"):
        simulate_run(rate_hz=0.5)


# ---------------------------------------------------------------------------
# residual learners: the rate they record, and runs at other rates
# ---------------------------------------------------------------------------
def test_learner_records_its_rate_and_keeps_it_when_saved(pipe, tmp_path):
    residual = pipe.named_steps["residual"]
    assert residual.rate_hz_ == pytest.approx(10.0)
    for copy in (pickle.loads(pickle.dumps(residual)),
                 joblib.load(_dumped(residual, tmp_path / "r.joblib"))):
        assert copy.rate_hz_ == residual.rate_hz_
    pytest.importorskip("skops")
    path = tmp_path / "pipe.skcath"
    persist.save(pipe, path, format="skops")
    loaded = persist.load(path, trusted=persist.get_untrusted_types(path))
    assert loaded.named_steps["residual"].rate_hz_ == residual.rate_hz_


def _dumped(obj, path):
    joblib.dump(obj, path)
    return path


def test_training_runs_at_two_rates_are_refused(train, held):
    X, y = train
    Xb = PDLBackbone().fit(X).transform(X)
    X40, y40, _ = held(40.0)
    Xb40 = PDLBackbone().fit(X40).transform(X40)
    both = pd.concat([Xb, Xb40], ignore_index=True)
    with pytest.raises(ValueError, match=r"GRUResidual learns time in samples, so its training "
                       r"runs must share one sample rate; most rows are at 40 Hz, but "
                       r"run\(s\) 'r0' at 10 Hz, 'r1' at 10 Hz, 'r2' at 10 Hz differ"):
        tiny_residual(GRUResidual, rate_hz=None).fit(both, np.vstack([y, y40]))
    # by default the network steps at 10 Hz, and the 40 Hz runs are resampled
    mixed = tiny_residual(GRUResidual, max_epochs=1).fit(both, np.vstack([y, y40]))
    assert mixed.rate_hz_ == pytest.approx(10.0, rel=1e-6)
    fitted = tiny_residual(GRUResidual, max_epochs=1, rate_hz=None).fit(Xb, y)
    with pytest.raises(ValueError, match=r"counts time in samples at 10 Hz, the rate it was "
                       r"first fitted \(or pretrained\) at, but these training runs are at 40 Hz"):
        fitted.partial_fit(Xb40, y40)
    tuned = tiny_residual(GRUResidual, max_epochs=1, rate_hz=None,
                          pretrained=FrozenEstimator(fitted))
    with pytest.raises(ValueError, match="counts time in samples at 10 Hz"):
        tuned.fit(Xb40, y40)
    assert tuned.fit(Xb, y).rate_hz_ == fitted.rate_hz_


@pytest.mark.parametrize("rate_hz", [20.0, 40.0])
def test_run_at_a_multiple_of_the_rate_is_predicted_as_at_the_model_rate(pipe, held, rate_hz):
    """The same run at 2x and 4x the rate: the 10 Hz prediction, not a mis-read one."""
    X10, _, _ = held(10.0)
    Xr, _, _ = held(rate_hz)
    motion = _motion(X10)
    rows = _at_times(Xr, X10.loc[motion, "t"])
    p10 = pipe.predict(X10)[motion]
    pr = pipe.predict(Xr)[rows]
    residual = pipe.named_steps["residual"]
    rate = residual.rate_hz_
    residual.rate_hz_ = None  # as if the rows were samples at the model's rate
    try:
        misread = pipe.predict(Xr)[rows]
    finally:
        residual.rate_hz_ = rate
    assert _rms(pr - p10) < 0.2
    assert _rms(pr - p10) < 0.5 * _rms(misread - p10)


def test_uneven_times_are_resampled_and_small_jitter_is_not(pipe, held):
    X10, _, _ = held(10.0)
    rng = np.random.default_rng(1)
    expected = pipe.predict(X10)
    small = X10.assign(t=X10["t"] + rng.uniform(-0.003, 0.003, len(X10)))
    assert_array_equal(pipe.predict(small), expected)  # within 10 %: the rows as they are
    jitter = X10.assign(t=X10["t"] + rng.uniform(-0.01, 0.01, len(X10)))  # +-10 % of a step
    Xb = pipe.named_steps["backbone"].transform(jitter)
    assert to_model_rate(Xb, 10.0, "M") is not None
    motion = _motion(X10)
    assert _rms(pipe.predict(jitter)[motion] - expected[motion]) < 0.2


def test_context_at_another_rate_is_that_of_the_resampled_sweep(pipe, held):
    residual = pipe.named_steps["residual"]
    X40, _, _ = held(40.0)
    sweep = X40[~_motion(X40)]
    z = residual.encode_context(sweep)
    assert_array_equal(z, residual.encode_context(resample_runs(sweep, residual.rate_hz_)))
    X10, _, _ = held(10.0)
    assert_allclose(z, residual.encode_context(X10[~_motion(X10)]), atol=0.1)


# ---------------------------------------------------------------------------
# streaming at another rate
# ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def pipe64(pipe):
    """The pipeline with its network in float64, for comparisons without float32 rounding."""
    copy = pickle.loads(pickle.dumps(pipe))
    copy.named_steps["residual"].module_.double()
    return copy


def _stream(est, X, with_time=True):
    """Start ``est`` on the sweep of ``X`` and step the motion rows; the tips."""
    est.start(X[~_motion(X)])
    rows = X.loc[_motion(X), ["t", *CHANNELS]].to_numpy()
    if with_time:
        return np.array([est.step(*r[1:], t=r[0]) for r in rows])
    return np.array([est.step(*r[1:]) for r in rows])


def _motion_ticks(pipe, X):
    """The backbone's tips of ``X`` and the offline residual at the run's motion ticks."""
    backbone, residual = pipe.named_steps["backbone"], pipe.named_steps["residual"]
    Xb = backbone.transform(X)
    ticks = to_model_rate(Xb, residual.rate_hz_, "M").X
    on = (ticks["phase"] == "motion").to_numpy()
    return Xb, ticks.loc[on, "t"].to_numpy(), residual.predict_residual(ticks)[on]


def _held_residual(pipe, X):
    """What the stream returns: the backbone at each row plus the residual of the latest tick.

    The residual at the model's ticks is the offline one of the run on its
    ticks; a motion row before the first motion tick gets none.
    """
    Xb, t_ticks, r = _motion_ticks(pipe, X)
    motion = _motion(X)
    rate = pipe.named_steps["residual"].rate_hz_
    latest = np.searchsorted(t_ticks, X.loc[motion, "t"].to_numpy() + TICK_TOLERANCE / rate,
                             side="right") - 1
    held = np.where(latest[:, None] >= 0, r[np.maximum(latest, 0)], 0.0)
    return Xb.loc[motion, B].to_numpy() + held


def test_stream_at_twice_the_rate_steps_the_model_at_its_ticks(pipe64, held):
    X20, _, _ = held(20.0)
    est = OnlineEstimator(pipe64, engine="numpy")
    tips = _stream(est, X20)
    assert est.resampled_ and est.rate_hz_ == pytest.approx(10.0)
    assert_allclose(tips, _held_residual(pipe64, X20), rtol=0, atol=1e-8)
    # on the rows that fall on a tick, the stream is predict
    predicted = pipe64.predict(X20)[_motion(X20)]
    _, t_ticks, r = _motion_ticks(pipe64, X20)
    t = X20.loc[_motion(X20), "t"].to_numpy()
    on_tick = np.isin(np.round(t, 9), np.round(t_ticks, 9))
    assert 0.4 < on_tick.mean() < 0.6
    assert_allclose(tips[on_tick], predicted[on_tick], rtol=0, atol=1e-8)
    # after the first motion tick, the held residual differs from predict's
    # interpolated one by at most the residual's change within one tick
    after = t >= t_ticks[0]
    bound = np.abs(np.diff(r, axis=0)).max()
    assert np.abs(tips - predicted)[after].max() <= bound + 1e-8


def test_jittered_stream_follows_the_ticks(pipe64, held):
    X10, _, _ = held(10.0)
    rng = np.random.default_rng(2)
    jitter = X10.assign(t=X10["t"] + rng.uniform(-0.01, 0.01, len(X10)))
    tips = _stream(OnlineEstimator(pipe64, engine="numpy"), jitter)
    # the step evaluates the backbone at the interpolated angles where predict
    # interpolates the backbone's tips: a small difference
    assert_allclose(tips, _held_residual(pipe64, jitter), rtol=0, atol=0.05)


def test_stream_at_the_model_rate_is_the_same_with_or_without_times(pipe, held):
    X10, _, _ = held(10.0)
    est = OnlineEstimator(pipe, engine="numpy")
    without = _stream(est, X10, with_time=False)
    with_time = _stream(est, X10)
    assert not est.resampled_
    assert_array_equal(with_time, without)
    # a sample late by half a step: stepped at the ticks from the last sample on
    est.start(X10[~_motion(X10)])
    rows = X10.loc[_motion(X10), ["t", *CHANNELS]].to_numpy()
    for r in rows[:5]:
        est.step(*r[1:], t=r[0])
    est.step(*rows[5, 1:], t=rows[5, 0] + 0.05)
    assert est.resampled_ and est._tick0 == rows[4, 0]
    with pytest.raises(ValueError, match=r"every sample needs its time: pass "
                       r"step\(\.\.\., t=seconds\)"):
        est.step(*rows[6, 1:])


def test_started_stream_at_another_rate_survives_pickling(pipe, held):
    X40, _, _ = held(40.0)
    motion = X40.loc[_motion(X40), ["t", *CHANNELS]].to_numpy()[:200]
    est = OnlineEstimator(pipe, engine="numpy").start(X40[~_motion(X40)])
    for r in motion[:101]:
        est.step(*r[1:], t=r[0])
    copy = pickle.loads(pickle.dumps(est))
    rest = np.array([est.step(*r[1:], t=r[0]) for r in motion[101:]])
    assert_array_equal(np.array([copy.step(*r[1:], t=r[0]) for r in motion[101:]]), rest)

