"""Tests of the compiled (numba) engine of ``skcath.online.OnlineEstimator``.

The numba engine must give what the numpy engine and ``Pipeline.predict``
give: for every backbone (PCC, PDL) and residual (NoResidual, MLP, GRU) the
float64 step is compared with the float64 ``predict`` at 1e-9 mm, and the
float32 step with the numpy engine's float32 step. Then the compiled
backbone and nonlinearities on their own, weights that float32 does not
hold, the input checks and state handling on this engine, and the choice of
engine with and without numba.

The fixtures and helpers (tiny networks, one epoch on two shortened runs)
are those of ``test_online.py``.
"""

import sys

import numpy as np
import pytest
import torch
from numpy.testing import assert_allclose
from sklearn.pipeline import Pipeline
from sklearn.utils._param_validation import InvalidParameterError

pytest.importorskip(
    "numba", reason='the numba engine needs numba (pip install "skcath[fast]")'
)

import skcath.online  # noqa: E402
from skcath.backbones import PCCBackbone, PDLBackbone, pcc_tip, pdl_tip  # noqa: E402
from skcath.online import OnlineEstimator, calibrate_sweep  # noqa: E402
from skcath.online._fast import BackboneStep as PCCStep, BackboneStep as PDLStep  # noqa: E402
from skcath.online._jit import JitStep, _exp, _tanh  # noqa: E402
from test_online import (  # noqa: E402,F401  (fixtures)
    CHANNELS,
    FLOAT64_TOL_MM,
    _float64,
    _backbone_probe,
    _split,
    _stream,
    data,
    pipelines,
    run_nominal,
    transformed,
)

# float32 steps of the two engines: different summation orders, nonlinearities
FLOAT32_ENGINES_TOL_MM = 1e-5


def _engines(pipe, sweep, samples, dtype="float64", **params):
    """Tips of the numba and the numpy engine, and the numba estimator."""
    est = OnlineEstimator(pipe, dtype=dtype, engine="numba", **params).start(sweep)
    assert est.engine_ == "numba"
    tips = _stream(est, samples)
    ref = _stream(OnlineEstimator(pipe, dtype=dtype, engine="numpy", **params).start(sweep),
                  samples)
    return tips, ref, est


# ---------------------------------------------------------------------------
# parity
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("Backbone", [PCCBackbone, PDLBackbone])
@pytest.mark.parametrize(
    "kind, params",
    [("none", {}), ("mlp", {}), ("gru", {}), ("gru", {"frame": "base"})],
    ids=["none", "mlp", "gru", "gru-base-frame"],
)
def test_numba_step_matches_predict(data, pipelines, run_nominal, Backbone, kind, params):
    _, _, X_run = data
    pipe = pipelines(Backbone, kind, **params)
    sweep, samples, motion = _split(X_run)
    tips, ref, _ = _engines(pipe, sweep, samples)
    expected64 = _float64(pipe).steps[-1][1].predict(run_nominal[Backbone])[motion]
    assert_allclose(tips, expected64, rtol=0, atol=FLOAT64_TOL_MM)
    assert_allclose(tips, ref, rtol=0, atol=FLOAT64_TOL_MM)
    tips32, ref32, est32 = _engines(pipe, sweep, samples, dtype="float32")
    assert_allclose(tips32, ref32, rtol=0, atol=FLOAT32_ENGINES_TOL_MM)
    if kind != "none":
        assert est32._packed.w.dtype == np.float32
        nominal = run_nominal[Backbone][["b_x", "b_y", "b_z"]].to_numpy()[motion]
        assert np.abs(tips - nominal).max() > 1e-3  # the network is not a no-op


@pytest.mark.parametrize(
    "params",
    [{"module__num_layers": 2}, {"use_torque": False, "use_context": False}, {"clip": 1e-3}],
    ids=["two-layers", "no-torque-no-context", "tight-clip"],
)
def test_numba_step_matches_predict_for_gru_variants(data, pipelines, run_nominal, params):
    _, _, X_run = data
    pipe = pipelines(PDLBackbone, "gru", **params)
    sweep, samples, motion = _split(X_run)
    tips, ref, _ = _engines(pipe, sweep, samples)
    expected64 = _float64(pipe)["residual"].predict(run_nominal[PDLBackbone])[motion]
    assert_allclose(tips, expected64, rtol=0, atol=FLOAT64_TOL_MM)
    tips32, ref32, _ = _engines(pipe, sweep, samples, dtype="float32")
    assert_allclose(tips32, ref32, rtol=0, atol=FLOAT32_ENGINES_TOL_MM)


def test_numba_backbone_alone(data, transformed):
    _, _, X_run = data
    pipe = Pipeline([("backbone", transformed[PCCBackbone][0])])
    sweep, samples, motion = _split(X_run)
    tips, _, _ = _engines(pipe, sweep, samples)
    assert_allclose(tips, pipe.predict(X_run)[motion], rtol=0, atol=FLOAT64_TOL_MM)


def test_weights_not_held_by_float32_are_kept_in_float64(data, pipelines):
    """A float64 network whose weights float32 cannot hold steps like the numpy engine."""
    _, _, X_run = data
    pipe = _float64(pipelines(PDLBackbone, "gru"))
    module = pipe["residual"].module_
    rng = np.random.default_rng(0)
    with torch.no_grad():
        for p in module.parameters():
            p.add_(torch.from_numpy(rng.normal(0.0, 1e-6, p.shape)))
    sweep, samples, _ = _split(X_run)
    tips, ref, est = _engines(pipe, sweep, samples[:100])
    assert_allclose(tips, ref, rtol=0, atol=FLOAT64_TOL_MM)
    # nothing of this network was stored in float32
    assert est._packed.w32.size == 1 and est._packed.w.size > 100
    # as fitted (float32 weights), the weights left unfolded are stored in float32:
    # W_hh (the biases sit in the block of the inputs) and the head's hidden layer
    fitted = pipelines(PDLBackbone, "gru")
    kernel = OnlineEstimator(fitted, engine="numba").start(sweep)._packed
    H, hidden = fitted["residual"].module_.gru.hidden_size, fitted["residual"].module_.head[0]
    assert kernel.w32.size == 3 * H * H + hidden.out_features * (hidden.in_features + 1)


# ---------------------------------------------------------------------------
# compiled parts
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("Backbone, tip, Step",
                         [(PCCBackbone, pcc_tip, PCCStep), (PDLBackbone, pdl_tip, PDLStep)])
def test_compiled_backbones_match_vectorised_backbones(data, transformed, Backbone, tip, Step):
    params, q = _backbone_probe(data, transformed, Backbone, seed=1)
    kernel = JitStep(Step(params), None, np.inf, False)
    out = np.empty(3)
    got = np.empty_like(q, shape=(len(q), 3))
    for k, (a, b) in enumerate(q):
        kernel(a, b, 0.0, 0.0, out)
        got[k] = out
        assert_allclose(kernel.nominal, out, rtol=0, atol=0)
    assert_allclose(got, tip(q, params), rtol=0, atol=1e-10)


def test_compiled_exp_and_tanh():
    rng = np.random.default_rng(2)
    x = np.concatenate([rng.normal(0.0, 10.0, 2000), rng.uniform(-700.0, 700.0, 2000),
                        [0.0, -0.0, 1e-300, -1e-20, 0.5 * np.log(2.0), 708.0, -708.0]])
    got = x.copy()
    _exp(got)
    assert_allclose(got, np.exp(x), rtol=1e-15, atol=0)
    # beyond +-708 the argument is clipped: finite, no overflow to inf or 0
    extreme = np.array([-1e4, -750.0, 750.0, 1e4])
    _exp(extreme)
    assert_allclose(extreme, np.exp([-708.0, -708.0, 708.0, 708.0]), rtol=1e-15)
    y = np.concatenate([x[:2000] / 10.0, [0.0, 1e-300, -1e-9, 30.0, -30.0, 1e4, -1e4]])
    got = y.copy()
    _tanh(got)
    assert_allclose(got, np.tanh(y), rtol=0, atol=5e-16)  # a few ulp of 1
    assert np.abs(got).max() <= 1.0


def test_compiled_exp_and_tanh_in_float32():
    """float32 arrays are evaluated in float32, within a few units in the last place."""
    rng = np.random.default_rng(3)
    x = np.concatenate([rng.normal(0.0, 10.0, 2000), rng.uniform(-87.0, 88.0, 2000),
                        [0.0, -0.0, 1e-30, -1e-20, 0.5 * np.log(2.0), 88.0, -87.0]])
    x = x.astype(np.float32)
    got = x.copy()
    _exp(got)
    assert got.dtype == np.float32
    assert_allclose(got, np.exp(x.astype(np.float64)), rtol=3 * 2.0**-23, atol=0)
    # beyond [-87, 88] the argument is clipped: finite and normal
    extreme = np.array([-1e4, -100.0, 100.0, 1e4], dtype=np.float32)
    _exp(extreme)
    assert_allclose(extreme, np.exp([-87.0, -87.0, 88.0, 88.0]), rtol=3 * 2.0**-23)
    y = np.concatenate([x[:2000] / 10.0, np.float32([0.0, 1e-30, -1e-6, 30.0, -30.0, 1e4])])
    got = y.copy()
    _tanh(got)
    assert_allclose(got, np.tanh(y.astype(np.float64)), rtol=0, atol=3 * 2.0**-24)
    assert np.abs(got).max() <= 1.0


# ---------------------------------------------------------------------------
# state and bad input on the numba engine
# ---------------------------------------------------------------------------
def test_numba_reset_out_and_attributes(data, pipelines, run_nominal):
    _, _, X_run = data
    sweep, samples, motion = _split(X_run)
    pipe = pipelines(PCCBackbone, "gru")
    est = OnlineEstimator(pipe, engine="numba").start(sweep)
    buf = np.empty(3)
    assert est.step(*samples[0], out=buf) is buf
    nominal = run_nominal[PCCBackbone][["b_x", "b_y", "b_z"]].to_numpy()[motion]
    assert_allclose(est.nominal_, nominal[0], atol=1e-9)
    first = np.vstack([buf, _stream(est, samples[1:30])])
    assert est.n_steps_ == 30
    assert_allclose(est.nominal_, nominal[29], atol=1e-9)
    est.reset()
    assert est.n_steps_ == 0
    assert_allclose(_stream(est, samples[:30]), first, rtol=0, atol=0)
    with pytest.raises(ValueError, match="out must be a writeable float64 array of shape"):
        est.step(*samples[0], out=np.empty(3, dtype=np.float32))
    assert est.n_steps_ == 30
    # a new start gives a fresh state and the same tips
    assert_allclose(_stream(est.start(sweep), samples[:30]), first, rtol=0, atol=0)


def test_numba_out_strided_or_made_read_only(data, pipelines):
    """A strided ``out`` gets the tip in its own elements; one made read-only is refused."""
    _, _, X_run = data
    sweep, samples, _ = _split(X_run)
    pipe = pipelines(PDLBackbone, "gru")
    est = OnlineEstimator(pipe, engine="numba").start(sweep)
    expected = _stream(OnlineEstimator(pipe, engine="numba").start(sweep), samples[:6])
    wide = np.full((6, 2), -1.0)
    strided = wide[:, 0][::2]  # shape (3,), every other element of a column
    for k in range(3):
        assert est.step(*samples[k], out=strided) is strided
        assert_allclose(strided, expected[k], rtol=0, atol=0)
    assert np.all(wide[:, 1] == -1.0) and np.all(wide[1::2, 0] == -1.0)
    buf = np.empty(3)
    est.step(*samples[3], out=buf)
    assert_allclose(buf, expected[3], rtol=0, atol=0)
    buf.flags.writeable = False
    with pytest.raises(ValueError, match="out must be a writeable float64 array of shape"):
        est.step(*samples[4], out=buf)
    assert est.n_steps_ == 4
    assert_allclose(est.step(*samples[4]), expected[4], rtol=0, atol=0)


def test_numba_hold_policy_matches_numpy_engine(data, pipelines):
    _, _, X_run = data
    sweep, samples, _ = _split(X_run)
    pipe = pipelines(PDLBackbone, "gru")
    held = {e: OnlineEstimator(pipe, on_invalid="hold", engine=e).start(sweep)
            for e in ("numba", "numpy")}
    far = held["numba"].q_neutral_ + [2.0 * held["numba"].q_limit_, 0.0]
    stream = [(np.nan, np.nan, np.nan, np.nan), samples[0],
              (samples[1][0], np.inf, *samples[1][2:]), samples[2],
              (far[0], far[1], *samples[3][2:]), samples[4]]
    tips = {e: _stream(est, stream) for e, est in held.items()}
    assert np.isfinite(tips["numba"]).all()
    assert_allclose(tips["numba"], tips["numpy"], rtol=0, atol=FLOAT64_TOL_MM)
    assert held["numba"].n_held_ == 3 and held["numba"].n_steps_ == 6


def test_numba_detector_is_stepped(data, pipelines):
    _, _, X_run = data
    sweep, samples, _ = _split(X_run)

    class Detector:
        def start(self, sweep):
            self.samples = []
            return self

        def step(self, q1, q2, tau1, tau2):
            self.samples.append((q1, q2, tau1, tau2))
            return len(self.samples) % 2 == 0

    est = OnlineEstimator(pipelines(PDLBackbone, "mlp"), detector=Detector(),
                          engine="numba").start(sweep)
    flags = []
    for s in samples[:4]:
        est.step(*s)
        flags.append(est.shaft_changed_)
    assert flags == [False, True, False, True]
    assert_allclose(np.array(est.detector_.samples), samples[:4])


# ---------------------------------------------------------------------------
# engine choice
# ---------------------------------------------------------------------------
def test_engine_choice(data, pipelines):
    _, _, X_run = data
    sweep, _, _ = _split(X_run)
    pipe = pipelines(PDLBackbone, "none")
    assert OnlineEstimator(pipe).start(sweep).engine_ == "numba"
    assert OnlineEstimator(pipe, engine="numpy").start(sweep).engine_ == "numpy"
    with pytest.raises(InvalidParameterError, match="engine"):
        OnlineEstimator(pipe, engine="cython").start(sweep)


def test_engine_without_numba(data, pipelines, monkeypatch):
    _, _, X_run = data
    sweep, samples, _ = _split(X_run)
    pipe = pipelines(PDLBackbone, "mlp")
    expected = _stream(OnlineEstimator(pipe, engine="numpy").start(sweep), samples[:5])
    # as if numba were not installed
    monkeypatch.setitem(sys.modules, "numba", None)
    monkeypatch.delitem(sys.modules, "skcath.online._jit")
    monkeypatch.delattr(skcath.online, "_jit")
    with pytest.raises(ImportError, match=r'engine="numba" needs numba.*skcath\[fast\]'):
        OnlineEstimator(pipe, engine="numba").start(sweep)
    est = OnlineEstimator(pipe).start(sweep)
    assert est.engine_ == "numpy"
    assert_allclose(_stream(est, samples[:5]), expected, rtol=0, atol=0)
