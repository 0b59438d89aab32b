"""Tests of the streaming estimator ``skcath.online.OnlineEstimator``.

The central check: after ``start`` on a run's sweep, stepping through the
run's motion samples one at a time gives what ``Pipeline.predict`` gives for
that run, for every backbone (PCC, PDL, each also with the play of
``hysteresis="play"`` in front) and residual (NoResidual, MLP, GRU).
The float64 step path is compared with ``predict`` run in float64
(``module_.double()``) at 1e-9 mm, and with the float32 ``predict`` as
fitted at the documented float32 tolerance. Then the per-sample backbone
kernels, ``reset``, the bad-input policies, errors, and an attached detector.

The networks are tiny and train for one epoch on two shortened runs.
"""

import copy
import importlib.util
import os
import pickle
import subprocess
import sys
import warnings

import numpy as np
import pandas as pd
import pytest
import torch
from numpy.testing import assert_allclose
from sklearn.exceptions import NotFittedError
from sklearn.pipeline import Pipeline
from sklearn.utils._param_validation import InvalidParameterError

from skcath.backbones import (
    PCCBackbone,
    PDLBackbone,
    PolynomialBackbone,
    pcc_tip,
    pdl_tip,
    play_operator,
)
from skcath.datasets import benchmark_catheter, make_benchmark, simulate_run
from skcath.exceptions import PipelineChangedWarning
from skcath.frames import sweep_frame
from skcath.online import OnlineEstimator, ShaftChangeDetector, calibrate_sweep, export
from skcath.online._fast import BackboneStep
from skcath.online._fast import BackboneStep as PCCStep, BackboneStep as PDLStep
from skcath.residuals import GRUResidual, MLPResidual, NoResidual

from _helpers import instrument, tiny_residual

TRAIN_SETTINGS = ["S02", "S09"]
TEST_SETTING = "S05"
N_MOTION = 300
CHANNELS = ["q1", "q2", "tau1", "tau2"]
# float32 predict vs the float64 step: rounding of the float32 network
FLOAT32_TOL_MM = 1e-4
# float64 predict vs the float64 step
FLOAT64_TOL_MM = 1e-9
TIPS = {PCCBackbone: pcc_tip, PDLBackbone: pdl_tip}
ENGINES = [
    "numpy",
    pytest.param("numba", marks=pytest.mark.skipif(importlib.util.find_spec("numba") is None,
                                                   reason="the numba engine needs numba")),
]


def _shorten(X, settings, n_motion):
    motion = (X["phase"] == "motion").to_numpy()
    rank = pd.Series(motion, index=X.index).groupby(X["run"], observed=True).cumsum()
    return X["setting"].isin(settings).to_numpy() & (~motion | (rank.to_numpy() <= n_motion))


def _tiny(Est, **params):
    """The tiny residual learner of the test suite, trained for one epoch."""
    return tiny_residual(Est, **{"max_epochs": 1, **params})


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """Training rows (two shortened runs) and one shortened test run."""
    bench = make_benchmark(
        n_catheters=1, n_runs=1, cache=True, data_home=tmp_path_factory.mktemp("skcath_data")
    )
    X, y = bench.X, np.asarray(bench.y)
    train = _shorten(X, TRAIN_SETTINGS, N_MOTION)
    test = _shorten(X, [TEST_SETTING], 200)
    return X[train], y[train], X[test].reset_index(drop=True)


@pytest.fixture(scope="module")
def transformed(data):
    """Fitted backbones and their output on the training rows, per backbone class."""
    X, _, _ = data
    out = {}
    for Backbone in (PCCBackbone, PDLBackbone):
        backbone = Backbone().fit(X)
        out[Backbone] = (backbone, backbone.transform(X))
    return out


@pytest.fixture(scope="module")
def run_nominal(data, transformed):
    """The test run with the backbone columns, per backbone class (calibrated once)."""
    _, _, X_run = data
    return {B: backbone.transform(X_run) for B, (backbone, _) in transformed.items()}


@pytest.fixture(scope="module")
def pipelines(data, transformed):
    """Lazily built fitted pipelines, keyed by (backbone class, residual name, params)."""
    _, y, _ = data
    cache = {}

    def get(Backbone, kind, **params):
        key = (Backbone, kind, tuple(sorted(params.items())))
        if key not in cache:
            backbone, Xb = transformed[Backbone]
            if kind == "none":
                residual = NoResidual().fit(Xb, y)
            else:
                Est = {"mlp": MLPResidual, "gru": GRUResidual}[kind]
                residual = _tiny(Est, **params).fit(Xb, y)
            cache[key] = Pipeline([("backbone", backbone), ("residual", residual)])
        return cache[key]

    return get


@pytest.fixture(scope="module")
def played(data):
    """Lazily built fitted pipelines whose backbone plays the motor angles (``hysteresis="play"``).

    ``played(Backbone, kind)`` gives the pipeline and its backbone's output on
    the test run.
    """
    X, y, X_run = data
    backbones, cache = {}, {}

    def get(Backbone, kind):
        if Backbone not in backbones:
            backbone = Backbone(hysteresis="play").fit(X)
            backbones[Backbone] = (backbone, backbone.transform(X), backbone.transform(X_run))
        backbone, Xb, Xb_run = backbones[Backbone]
        if (Backbone, kind) not in cache:
            residual = NoResidual() if kind == "none" else _tiny(GRUResidual)
            cache[Backbone, kind] = Pipeline([("backbone", backbone), ("residual", residual.fit(Xb, y))])
        return cache[Backbone, kind], Xb_run

    return get


def _split(X_run):
    motion = (X_run["phase"] == "motion").to_numpy()
    return X_run[~motion], X_run.loc[motion, CHANNELS].to_numpy(), motion


def _stream(est, samples):
    return np.array([est.step(*s) for s in samples])


def _float64(pipe):
    """A copy of the pipeline whose network predicts in float64."""
    pipe64 = copy.deepcopy(pipe)
    residual = pipe64.steps[-1][1]
    if hasattr(residual, "module_"):
        residual.module_.double()
    return pipe64


# ---------------------------------------------------------------------------
# parity with Pipeline.predict
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("Backbone", [PCCBackbone, PDLBackbone])
@pytest.mark.parametrize(
    "kind, params",
    [
        ("none", {}),
        ("mlp", {}),
        ("gru", {}),
        ("gru", {"frame": "base"}),
    ],
    ids=["none", "mlp", "gru", "gru-base-frame"],
)
def test_step_matches_predict(data, pipelines, run_nominal, Backbone, kind, params):
    _, _, X_run = data
    pipe = pipelines(Backbone, kind, **params)
    sweep, samples, motion = _split(X_run)
    tips = _stream(OnlineEstimator(pipe).start(sweep), samples)
    assert tips.shape == (len(samples), 3)
    # the residual step of the float64 copy on the backbone's output: its predict
    Xb_run = run_nominal[Backbone]
    expected64 = _float64(pipe).steps[-1][1].predict(Xb_run)[motion]
    assert_allclose(tips, expected64, rtol=0, atol=FLOAT64_TOL_MM)
    expected = pipe.predict(X_run)[motion]
    assert_allclose(tips, expected, rtol=0, atol=FLOAT32_TOL_MM)
    # the float32 step rounds like the trained network: same tolerance
    tips32 = _stream(OnlineEstimator(pipe, dtype="float32").start(sweep), samples)
    assert_allclose(tips32, expected, rtol=0, atol=FLOAT32_TOL_MM)
    if kind != "none":  # the network is not a no-op on these runs
        nominal = Xb_run[["b_x", "b_y", "b_z"]].to_numpy()[motion]
        assert np.abs(tips - nominal).max() > 1e-3


@pytest.mark.parametrize(
    "params",
    [
        {"module__num_layers": 2},
        {"use_torque": False, "use_context": False},
        {"clip": 1e-3},
    ],
    ids=["two-layers", "no-torque-no-context", "tight-clip"],
)
def test_step_matches_predict_for_gru_variants(data, pipelines, run_nominal, params):
    _, _, X_run = data
    pipe = pipelines(PDLBackbone, "gru", **params)
    sweep, samples, motion = _split(X_run)
    tips = _stream(OnlineEstimator(pipe).start(sweep), samples)
    expected64 = _float64(pipe)["residual"].predict(run_nominal[PDLBackbone])[motion]
    assert_allclose(tips, expected64, rtol=0, atol=FLOAT64_TOL_MM)


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("Backbone", [PCCBackbone, PDLBackbone])
@pytest.mark.parametrize("kind", ["none", "gru"])
def test_step_with_a_play_matches_predict(data, played, Backbone, kind, engine):
    """With hysteresis="play" the step plays (q1, q2) from the sweep's end, as predict does."""
    _, _, X_run = data
    pipe, Xb_run = played(Backbone, kind)
    sweep, samples, motion = _split(X_run)
    est = OnlineEstimator(pipe, engine=engine).start(sweep)
    assert est.engine_ == engine
    width = pipe["backbone"].calibrate(X_run).play_widths[est.run_]
    assert 0.0 < est.play_width_ == width <= 20.0
    q_sweep = sweep[["q1", "q2"]].to_numpy()
    assert_allclose(est.play_state_, play_operator(q_sweep, width)[-1], rtol=0, atol=0)
    tips = _stream(est, samples)
    expected64 = _float64(pipe).steps[-1][1].predict(Xb_run)[motion]
    assert_allclose(tips, expected64, rtol=0, atol=FLOAT64_TOL_MM)
    assert_allclose(tips, pipe.predict(X_run)[motion], rtol=0, atol=FLOAT32_TOL_MM)
    # the play matters here: the backbone on the angles as they are is elsewhere
    nominal = Xb_run[["b_x", "b_y", "b_z"]].to_numpy()[motion]
    raw = TIPS[Backbone](samples[:, :2], est.backbone_params_)
    assert np.abs(nominal - raw).max() > 0.1
    # reset starts the play again from the sweep's end
    assert_allclose(_stream(est.reset(), samples[:50]), tips[:50], rtol=0, atol=0)


def test_backbone_alone_pipeline(data, transformed):
    _, _, X_run = data
    pipe = Pipeline([("backbone", transformed[PDLBackbone][0])])
    sweep, samples, motion = _split(X_run)
    tips = _stream(OnlineEstimator(pipe).start(sweep), samples)
    assert_allclose(tips, pipe.predict(X_run)[motion], rtol=0, atol=FLOAT64_TOL_MM)


def test_start_matches_backbone_calibration(data, pipelines):
    _, _, X_run = data
    pipe = pipelines(PDLBackbone, "gru")
    sweep, _, _ = _split(X_run)
    est = OnlineEstimator(pipe).start(sweep)
    backbone = pipe["backbone"]
    expected = backbone.calibrate(X_run).params[est.run_]
    assert est.run_ == X_run["run"].iloc[0]
    assert_allclose(est.backbone_params_.coef, expected.coef)
    assert est.rotation_.shape == (3, 3)
    assert_allclose(est.rotation_ @ est.rotation_.T, np.eye(3), atol=1e-12)
    assert est.context_.shape == (4,)
    params, nominal = calibrate_sweep(backbone, sweep)
    assert_allclose(params.coef, expected.coef)
    assert nominal.shape == (len(sweep), 3)
    q = sweep[["q1", "q2"]].to_numpy()
    assert est.q_amplitude_ == pytest.approx(np.linalg.norm(q - est.q_neutral_, axis=1).max())
    assert est.q_limit_ == pytest.approx(1.25 * est.q_amplitude_)


def test_encode_context_gives_the_context_of_start(data, pipelines):
    X, _, X_run = data
    residual = pipelines(PDLBackbone, "gru")["residual"]
    z = residual.encode_context(X)  # one context per run, in order of appearance
    assert z.shape == (2, 4) and z.dtype == np.float64
    first = X[(X["run"] == X["run"].iloc[0]).to_numpy()]
    assert_allclose(residual.encode_context(first), z[:1], rtol=0, atol=1e-6)
    sweep, _, _ = _split(X_run)
    est = OnlineEstimator(pipelines(PDLBackbone, "gru")).start(sweep)
    assert_allclose(residual.encode_context(sweep, dtype="float64")[0], est.context_, rtol=0, atol=0)
    with pytest.raises(ValueError, match="use_context=False"):
        pipelines(PDLBackbone, "gru", use_torque=False, use_context=False)["residual"].encode_context(X)
    with pytest.raises(NotFittedError):
        GRUResidual().encode_context(X)


def test_importing_the_package_does_not_import_numba():
    import skcath

    code = "import sys, skcath, skcath.backbones, skcath.online; assert 'numba' not in sys.modules"
    root = os.path.dirname(os.path.dirname(skcath.__file__))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([root, os.environ.get("PYTHONPATH", "")]))
    subprocess.run([sys.executable, "-c", code], check=True, env=env, cwd=root)


# ---------------------------------------------------------------------------
# backbone kernels
# ---------------------------------------------------------------------------
def _backbone_probe(data, transformed, Backbone, seed):
    """Calibrated parameters of the test run's sweep and motor samples to probe them."""
    _, _, X_run = data
    sweep, _, _ = _split(X_run)
    params, _ = calibrate_sweep(transformed[Backbone][0], sweep)
    q_neutral = params.q0 if Backbone is PCCBackbone else params.q_neutral
    amplitude = np.abs(sweep[["q1", "q2"]].to_numpy() - q_neutral).max()
    rng = np.random.default_rng(seed)
    q = q_neutral + rng.uniform(-1.3, 1.3, size=(500, 2)) * amplitude
    # exactly neutral, exactly on a ray, and far out (closed-form branch of PCC)
    return params, np.vstack([q, q_neutral, q_neutral + [amplitude, 0.0], q[:1] * 5.0])


@pytest.mark.parametrize("Backbone, tip, Step", [(PCCBackbone, pcc_tip, PCCStep), (PDLBackbone, pdl_tip, PDLStep)])
def test_backbone_kernels_match_vectorised_backbones(data, transformed, Backbone, tip, Step):
    params, q = _backbone_probe(data, transformed, Backbone, seed=0)
    kernel = Step(params)
    got = np.array([kernel(a, b) for a, b in q])
    assert_allclose(got, tip(q, params), rtol=0, atol=1e-10)


# ---------------------------------------------------------------------------
# state
# ---------------------------------------------------------------------------
def test_reset_restarts_the_motion_sequence(data, pipelines):
    _, _, X_run = data
    sweep, samples, _ = _split(X_run)
    est = OnlineEstimator(pipelines(PDLBackbone, "gru")).start(sweep)
    first = _stream(est, samples[:50])
    assert est.n_steps_ == 50
    est.reset()
    assert est.n_steps_ == 0
    assert_allclose(_stream(est, samples[:50]), first, rtol=0, atol=0)
    # a GRU carries state: the same sample later in the sequence gives another tip
    est.reset()
    _stream(est, samples[:20])
    assert np.abs(est.step(*samples[0]) - first[0]).max() > 0


def test_step_out_and_attributes(data, pipelines, run_nominal):
    _, _, X_run = data
    sweep, samples, motion = _split(X_run)
    pipe = pipelines(PCCBackbone, "mlp")
    est = OnlineEstimator(pipe).start(sweep)
    buf = np.empty(3)
    result = est.step(*samples[0], out=buf)
    assert result is buf
    nominal = run_nominal[PCCBackbone][["b_x", "b_y", "b_z"]].to_numpy()[motion][0]
    assert_allclose(est.nominal_, nominal, atol=1e-9)
    fresh = est.step(*samples[1])
    assert fresh is not buf and fresh.shape == (3,) and fresh.dtype == np.float64


def test_start_leaves_inputs_unchanged(data, pipelines):
    _, _, X_run = data
    sweep, _, _ = _split(X_run)
    sweep_before = sweep.copy()
    pipe = pipelines(PDLBackbone, "gru")
    state = {k: v.clone() for k, v in pipe["residual"].module_.state_dict().items()}
    OnlineEstimator(pipe).start(sweep)
    pd.testing.assert_frame_equal(sweep, sweep_before)
    for k, v in pipe["residual"].module_.state_dict().items():
        assert v.dtype == state[k].dtype and bool((v == state[k]).all())


def test_started_estimator_keeps_its_step_when_the_pipeline_is_refit(data, pipelines,
                                                                    transformed):
    """start takes the step from the pipeline; a refit in place changes it only at start."""
    _, y, X_run = data
    sweep, samples, _ = _split(X_run)
    pipe = copy.deepcopy(pipelines(PDLBackbone, "gru"))
    est = OnlineEstimator(pipe).start(sweep)
    before = _stream(est, samples[:30])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        est.reset()  # nothing changed: no warning
        pipe.set_params(residual__verbose=0)  # not read by the step
        est.reset()
    pipe["residual"].set_params(random_state=1).fit(transformed[PDLBackbone][1], y)
    refit = _stream(OnlineEstimator(pipe).start(sweep), samples[:30])
    assert np.abs(refit - before).max() > 1e-3
    with pytest.warns(PipelineChangedWarning, match=r"was reset, but its pipeline has been "
                      r"refit or its parameters set since start\(\)(.|\n)*start\(sweep\) again"):
        est.reset()
    assert_allclose(_stream(est, samples[:30]), before, rtol=0, atol=0)
    # started again, it steps the refit pipeline, without a warning
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert_allclose(_stream(est.start(sweep), samples[:30]), refit, rtol=0, atol=0)
        est.reset()
    # the backbone's parameters count too
    pipe["backbone"].set_params(max_iter=50)
    with pytest.warns(PipelineChangedWarning):
        est.reset()
    # so does a pipeline that can no longer be streamed; the estimator still steps
    pipe.steps[1] = ("residual", GRUResidual())
    with pytest.warns(PipelineChangedWarning):
        est.reset()
    assert_allclose(_stream(est, samples[:30]), refit, rtol=0, atol=0)


@pytest.mark.parametrize("convert", [int, np.float32, np.float64, np.int64],
                         ids=["int", "float32", "float64", "int64"])
def test_step_takes_integers_and_numpy_scalars(data, pipelines, convert):
    _, _, X_run = data
    sweep, samples, _ = _split(X_run)
    est = OnlineEstimator(pipelines(PDLBackbone, "mlp")).start(sweep)
    rounded = np.round(samples[:5]).astype(float)
    expected = _stream(OnlineEstimator(pipelines(PDLBackbone, "mlp")).start(sweep), rounded)
    tips = np.array([est.step(*(convert(v) for v in s)) for s in rounded])
    assert_allclose(tips, expected, rtol=0, atol=0)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
@pytest.mark.parametrize("kind", ["gru", "mlp"])
def test_learner_trained_on_a_gpu_streams_and_exports_on_the_cpu(data, transformed, kind,
                                                                  tmp_path):
    X, y, X_run = data
    sweep, samples, motion = _split(X_run)
    backbone, Xb = transformed[PDLBackbone]
    Est = {"mlp": MLPResidual, "gru": GRUResidual}[kind]
    residual = _tiny(Est, device="cuda").fit(Xb, y)
    pipe = Pipeline([("backbone", backbone), ("residual", residual)])
    expected = pipe.predict(X_run)[motion]
    est = OnlineEstimator(pipe).start(sweep)
    # predict runs on the GPU, whose kernels may round as TF32 (1e-3 relative)
    assert_allclose(_stream(est, samples), expected, rtol=0, atol=1e-2)
    assert next(residual.module_.parameters()).device.type == "cuda"
    export(pipe, tmp_path / "step.pt", format="torchscript")
    assert next(torch.jit.load(tmp_path / "step.pt").parameters()).device.type == "cpu"


# ---------------------------------------------------------------------------
# bad input
# ---------------------------------------------------------------------------
def test_step_before_start_raises():
    est = OnlineEstimator(Pipeline([("backbone", PDLBackbone())]))
    with pytest.raises(NotFittedError, match=r"call start\(sweep\)"):
        est.step(0.0, 0.0, 0.0, 0.0)
    with pytest.raises(NotFittedError, match="start"):
        est.reset()


@pytest.mark.parametrize("channel", [0, 1, 2, 3])
@pytest.mark.parametrize("value", [np.nan, np.inf])
@pytest.mark.parametrize("engine", ["auto", "numpy"])  # auto: numba where installed
def test_non_finite_sample_raises_and_keeps_state(data, pipelines, channel, value, engine):
    _, _, X_run = data
    sweep, samples, _ = _split(X_run)
    pipe = pipelines(PDLBackbone, "gru")
    est = OnlineEstimator(pipe, engine=engine).start(sweep)
    reference = _stream(OnlineEstimator(pipe, engine=engine).start(sweep), samples[:3])
    est.step(*samples[0])
    bad = list(samples[1])
    bad[channel] = value
    with pytest.raises(ValueError, match=f"non-finite value for {CHANNELS[channel]}"):
        est.step(*bad)
    assert est.n_steps_ == 1
    # the rejected sample left no trace: the next sample continues the sequence
    assert_allclose(est.step(*samples[1]), reference[1], rtol=0, atol=0)


def test_out_of_range_motor_angles(data, pipelines):
    _, _, X_run = data
    sweep, samples, _ = _split(X_run)
    pipe = pipelines(PDLBackbone, "none")
    est = OnlineEstimator(pipe).start(sweep)
    far = est.q_neutral_ + [1.3 * est.q_limit_, 0.0]
    with pytest.raises(ValueError, match="out of range.*q_margin"):
        est.step(far[0], far[1], 0.0, 0.0)
    loose = OnlineEstimator(pipe, q_margin=None).start(sweep)
    assert loose.q_limit_ == np.inf
    assert np.isfinite(loose.step(far[0], far[1], 0.0, 0.0)).all()
    tight = OnlineEstimator(pipe, q_margin=1.0).start(sweep)
    assert tight.q_limit_ == pytest.approx(2.0 * est.q_limit_ / 1.25)


def test_hold_policy_replaces_bad_channels_by_last_values(data, pipelines):
    _, _, X_run = data
    sweep, samples, _ = _split(X_run)
    pipe = pipelines(PDLBackbone, "gru")
    held = OnlineEstimator(pipe, on_invalid="hold").start(sweep)
    plain = OnlineEstimator(pipe).start(sweep)
    for k in range(3):
        assert_allclose(held.step(*samples[k]), plain.step(*samples[k]), rtol=0, atol=0)
    # NaN torque: held at the previous torque, the other channels used
    q1, q2, _, tau2 = samples[3]
    tip = held.step(q1, q2, np.nan, tau2)
    assert np.isfinite(tip).all()
    assert_allclose(tip, plain.step(q1, q2, samples[2][2], tau2), rtol=0, atol=0)
    # out-of-range angles: both held at the previous angles
    far = held.q_neutral_ + [2.0 * held.q_limit_, 0.0]
    tip = held.step(far[0], far[1], *samples[4][2:])
    assert_allclose(tip, plain.step(q1, q2, *samples[4][2:]), rtol=0, atol=0)
    assert held.n_held_ == 2 and held.n_steps_ == 5


def test_hold_on_the_first_step_uses_the_last_sweep_sample(data, pipelines):
    _, _, X_run = data
    sweep, samples, _ = _split(X_run)
    pipe = pipelines(PCCBackbone, "gru")
    held = OnlineEstimator(pipe, on_invalid="hold").start(sweep)
    plain = OnlineEstimator(pipe).start(sweep)
    last = sweep[CHANNELS].to_numpy()[-1]
    tip = held.step(np.nan, np.nan, np.nan, np.nan)
    assert_allclose(tip, plain.step(*last), rtol=0, atol=0)


def test_step_rejects_non_numbers(data, pipelines):
    _, _, X_run = data
    sweep, _, _ = _split(X_run)
    est = OnlineEstimator(pipelines(PDLBackbone, "none")).start(sweep)
    with pytest.raises(TypeError, match="four numbers"):
        est.step("a", 0.0, 0.0, 0.0)


def test_start_errors(data, pipelines, transformed):
    X, y, X_run = data
    sweep, _, _ = _split(X_run)
    pipe = pipelines(PDLBackbone, "none")
    with pytest.raises(ValueError, match="only rows with 'phase' == 'sweep'"):
        OnlineEstimator(pipe).start(X_run)
    with pytest.raises(ValueError, match="exactly one run; got 2 runs"):
        OnlineEstimator(pipe).start(X[X["phase"] == "sweep"])
    with pytest.raises(TypeError, match="fitted sklearn Pipeline"):
        OnlineEstimator(PDLBackbone().fit(X)).start(sweep)
    with pytest.raises(NotFittedError):
        OnlineEstimator(Pipeline([("backbone", PDLBackbone())])).start(sweep)
    unfitted = Pipeline([("backbone", transformed[PDLBackbone][0]), ("residual", GRUResidual())])
    with pytest.raises(NotFittedError, match="GRUResidual of pipeline is not fitted"):
        OnlineEstimator(unfitted).start(sweep)
    with pytest.raises(InvalidParameterError, match="dtype"):
        OnlineEstimator(pipe, dtype="float16").start(sweep)
    with pytest.raises(InvalidParameterError, match="on_invalid"):
        OnlineEstimator(pipe, on_invalid="ignore").start(sweep)
    # a failed start leaves no usable estimator behind
    est = OnlineEstimator(pipe).start(sweep)
    with pytest.raises(ValueError, match="exactly one run"):
        est.start(X[X["phase"] == "sweep"])
    with pytest.raises(NotFittedError, match="has not been started"):
        est.step(0.0, 0.0, 0.0, 0.0)


# ---------------------------------------------------------------------------
# detector
# ---------------------------------------------------------------------------
class _FakeDetector:
    """Flags a change when q1 exceeds a threshold; records what it was given."""

    def __init__(self, threshold):
        self.threshold = threshold
        self.started_with = None
        self.samples = []

    def start(self, sweep):
        self.started_with = sweep
        return self

    def step(self, q1, q2, tau1, tau2):
        self.samples.append((q1, q2, tau1, tau2))
        return q1 > self.threshold


def test_detector_is_started_and_stepped_with_the_same_data(data, pipelines):
    _, _, X_run = data
    sweep, samples, _ = _split(X_run)
    threshold = float(np.median(samples[:20, 0]))
    detector = _FakeDetector(threshold)
    est = OnlineEstimator(pipelines(PDLBackbone, "none"), detector=detector).start(sweep)
    assert est.shaft_changed_ is False
    assert detector.started_with is None and detector.samples == []  # left as given
    started = est.detector_
    assert_allclose(started.started_with[CHANNELS].to_numpy(), sweep[CHANNELS].to_numpy())
    flags = []
    for s in samples[:20]:
        est.step(*s)
        flags.append(est.shaft_changed_)
    assert flags == [bool(s[0] > threshold) for s in samples[:20]]
    assert_allclose(np.array(started.samples), samples[:20])
    assert detector.samples == []
    with pytest.raises(InvalidParameterError, match="detector"):
        OnlineEstimator(pipelines(PDLBackbone, "none"), detector=object()).start(sweep)


def test_no_detector_no_flag(data, pipelines):
    _, _, X_run = data
    sweep, _, _ = _split(X_run)
    est = OnlineEstimator(pipelines(PDLBackbone, "none")).start(sweep)
    assert not hasattr(est, "shaft_changed_")


def test_bad_out_is_refused_before_the_state_moves(data, pipelines):
    """A wrong ``out`` raises a clear error and leaves the estimator as it was."""
    _, _, X_run = data
    sweep, samples, _ = _split(X_run)
    est = OnlineEstimator(pipelines(PDLBackbone, "gru")).start(sweep)
    reference = OnlineEstimator(pipelines(PDLBackbone, "gru")).start(sweep)
    for bad in (np.empty(2), np.empty(3, dtype=np.float32), [0.0, 0.0, 0.0]):
        with pytest.raises(ValueError, match="out must be a writeable float64 array of shape"):
            est.step(*samples[0], out=bad)
    assert est.n_steps_ == 0
    for s in samples[:5]:
        assert_allclose(est.step(*s), reference.step(*s), rtol=0, atol=0)


# ---------------------------------------------------------------------------
# re-sweep without the tracker
# ---------------------------------------------------------------------------
REFERENCE = ["ref_x", "ref_y", "ref_z"]


@pytest.fixture(scope="module")
def reswept():
    """A run of C1 in S05 whose shaft moves to S13, then sweeps again.

    Returns the first (tracked) sweep, the re-sweep without its reference
    columns, the tracked re-sweep, and the first 200 motion rows after the
    re-sweep (its recording up to there).
    """
    data = simulate_run(
        catheter=benchmark_catheter(1), setting="S05", setting_after="S13", change_after_s=30.0,
        resweep=True, random_state=1,
    )
    X = data.X
    first = X[((X["run"] == "run-0") & (X["phase"] == "sweep")).to_numpy()]
    after = X[(X["run"] == "run-0/after").to_numpy()].reset_index(drop=True)
    n_sweep = int((after["phase"] == "sweep").sum())
    tracked = after.iloc[:n_sweep]
    return first, tracked.drop(columns=REFERENCE), tracked, after.iloc[: n_sweep + 200]


def _kept_frame(recording, backbone, params, play_width=0.0):
    """``recording`` with the backbone columns of the calibration ``params``: what a motor-only re-sweep steps.

    With a ``play_width`` (deg), the motor angles of the recording pass through that play first.
    """
    evaluate = pdl_tip if isinstance(backbone, PDLBackbone) else pcc_tip
    nominal = evaluate(play_operator(recording[["q1", "q2"]].to_numpy(), play_width), params)
    return recording.assign(b_x=nominal[:, 0], b_y=nominal[:, 1], b_z=nominal[:, 2])


@pytest.mark.parametrize("Backbone", [PCCBackbone, PDLBackbone])
@pytest.mark.parametrize("engine", ENGINES)
def test_resweep_keeps_the_calibration_and_renews_the_context(pipelines, reswept, Backbone, engine):
    first, motor_only, _, after = reswept
    pipe = pipelines(Backbone, "gru")
    est = OnlineEstimator(pipe, engine=engine).start(first)
    kept, stale_context = est.backbone_params_, est.context_.copy()
    assert est.resweep(motor_only) is est
    assert est.backbone_params_ is kept
    assert est.run_ == "run-0/after" and est.n_steps_ == 0
    residual = pipe["residual"]
    expected = residual.encode_context(motor_only.assign(ref_x=np.nan, ref_y=np.nan, ref_z=np.nan),
                                       dtype="float64")[0]
    assert_allclose(est.context_, expected, rtol=0, atol=0)
    assert np.abs(est.context_ - stale_context).max() > 1e-3
    # what predict gives for the new sweep and motion with the kept calibration's nominal tip
    frame = _kept_frame(after, pipe["backbone"], kept)
    motion = (after["phase"] == "motion").to_numpy()
    q = motor_only[["q1", "q2"]].to_numpy()
    nominal = frame.loc[~motion, ["b_x", "b_y", "b_z"]].to_numpy()
    assert_allclose(est.rotation_, sweep_frame(q, nominal), rtol=0, atol=1e-12)
    tips = _stream(est, after.loc[motion, CHANNELS].to_numpy())
    expected = _float64(pipe)["residual"].predict(frame)[motion]
    assert_allclose(tips, expected, rtol=0, atol=FLOAT64_TOL_MM)


@pytest.mark.parametrize("engine", ENGINES)
def test_resweep_keeps_the_play(played, reswept, engine):
    """With hysteresis="play", resweep keeps the half-width and plays the new sweep's angles."""
    first, motor_only, _, after = reswept
    pipe, _ = played(PDLBackbone, "gru")
    est = OnlineEstimator(pipe, engine=engine).start(first)
    kept, width = est.backbone_params_, est.play_width_
    assert width > 0.0
    est.resweep(motor_only)
    assert est.backbone_params_ is kept and est.play_width_ == width
    q = motor_only[["q1", "q2"]].to_numpy()
    assert_allclose(est.play_state_, play_operator(q, width)[-1], rtol=0, atol=0)
    # predict on the new sweep and motion with the kept calibration and play
    frame = _kept_frame(after, pipe["backbone"], kept, width)
    motion = (after["phase"] == "motion").to_numpy()
    nominal = frame.loc[~motion, ["b_x", "b_y", "b_z"]].to_numpy()
    assert_allclose(est.rotation_, sweep_frame(q, nominal), rtol=0, atol=1e-12)
    tips = _stream(est, after.loc[motion, CHANNELS].to_numpy())
    expected = _float64(pipe)["residual"].predict(frame)[motion]
    assert_allclose(tips, expected, rtol=0, atol=FLOAT64_TOL_MM)
    # a re-sweep that ends elsewhere moves the play's starting state with it
    shifted = motor_only.assign(q1=motor_only["q1"] + 2.0)
    est.resweep(shifted)
    q_first = first[["q1", "q2"]].to_numpy()
    assert_allclose(est.play_state_, play_operator(q + [2.0, 0.0], width)[-1], rtol=0, atol=0)
    assert np.abs(est.play_state_ - play_operator(q_first, width)[-1]).max() > 1.0


def test_resweep_never_reads_the_reference(pipelines, reswept):
    first, motor_only, tracked, after = reswept
    samples = after.loc[after["phase"] == "motion", CHANNELS].to_numpy()
    results = []
    for sweep in (motor_only, tracked, tracked.assign(ref_x=np.nan, ref_y=np.nan, ref_z=np.nan),
                  tracked.assign(ref_x=1e6, ref_y=-1e6, ref_z=np.inf)):
        est = OnlineEstimator(pipelines(PDLBackbone, "gru")).start(first).resweep(sweep)
        results.append((est.context_, est.rotation_, est.q_neutral_, _stream(est, samples)))
    for result in results[1:]:
        for got, want in zip(result, results[0]):
            assert_allclose(got, want, rtol=0, atol=0)


def test_resweep_on_the_sweep_of_start_is_start(pipelines, reswept):
    first, _, _, after = reswept
    samples = after.loc[after["phase"] == "motion", CHANNELS].to_numpy()
    started = OnlineEstimator(pipelines(PDLBackbone, "gru")).start(first)
    reswept_est = OnlineEstimator(pipelines(PDLBackbone, "gru")).start(first).resweep(
        first.drop(columns=REFERENCE)
    )
    for name in ("context_", "rotation_", "q_neutral_", "q_amplitude_", "q_limit_"):
        assert_allclose(getattr(reswept_est, name), getattr(started, name), rtol=0, atol=1e-12)
    assert_allclose(_stream(reswept_est, samples), _stream(started, samples), rtol=0, atol=1e-9)


def test_start_on_the_tracked_resweep_calibrates_again(pipelines, reswept):
    first, motor_only, tracked, _ = reswept
    pipe = pipelines(PDLBackbone, "gru")
    motor = OnlineEstimator(pipe).start(first).resweep(motor_only)
    full = OnlineEstimator(pipe).start(first).start(tracked)
    assert_allclose(full.context_, motor.context_, rtol=0, atol=0)  # the same motors and torques
    new = pipe["backbone"].calibrate(tracked).params["run-0/after"]
    assert_allclose(full.backbone_params_.coef, new.coef)
    assert not np.allclose(motor.backbone_params_.coef, new.coef)


def test_resweep_of_a_backbone_alone_keeps_its_tips(transformed, reswept):
    first, motor_only, _, after = reswept
    backbone = transformed[PDLBackbone][0]
    est = OnlineEstimator(Pipeline([("backbone", backbone)])).start(first).resweep(motor_only)
    assert est.context_ is None and est.rotation_ is None
    motion = (after["phase"] == "motion").to_numpy()
    expected = _kept_frame(after, backbone, est.backbone_params_).loc[motion, ["b_x", "b_y", "b_z"]]
    tips = _stream(est, after.loc[motion, CHANNELS].to_numpy())
    assert_allclose(tips, expected.to_numpy(), rtol=0, atol=FLOAT64_TOL_MM)
    # the range check follows the new sweep's motor angles
    q = motor_only[["q1", "q2"]].to_numpy()
    assert est.q_amplitude_ == pytest.approx(np.linalg.norm(q - est.q_neutral_, axis=1).max())


def test_resweep_restarts_the_detector(pipelines, reswept):
    first, motor_only, _, after = reswept
    est = OnlineEstimator(pipelines(PDLBackbone, "none"), detector=ShaftChangeDetector()).start(first)
    for s in after.loc[after["phase"] == "motion", CHANNELS].to_numpy()[:50]:
        est.step(*s)
    est.resweep(motor_only)
    assert est.shaft_changed_ is False and est.detector_.n_steps_ == 0
    fresh = ShaftChangeDetector().start(motor_only)
    assert_allclose(est.detector_.coef_, fresh.coef_, rtol=0, atol=0)
    assert est.detector is not est.detector_ and not hasattr(est.detector, "coef_")


def test_resweep_pickles(pipelines, reswept):
    first, motor_only, _, after = reswept
    samples = after.loc[after["phase"] == "motion", CHANNELS].to_numpy()
    est = OnlineEstimator(pipelines(PDLBackbone, "gru")).start(first).resweep(motor_only)
    _stream(est, samples[:10])
    loaded = pickle.loads(pickle.dumps(est))
    assert_allclose(_stream(loaded, samples[10:]), _stream(est, samples[10:]), rtol=0, atol=0)


def test_resweep_errors_leave_the_estimator_as_it_was(data, pipelines, reswept):
    X, y, _ = data
    first, motor_only, _, after = reswept
    with pytest.raises(NotFittedError, match="has not been started"):
        OnlineEstimator(pipelines(PDLBackbone, "gru")).resweep(motor_only)
    pipe = copy.deepcopy(pipelines(PDLBackbone, "gru"))
    est = OnlineEstimator(pipe).start(first)
    context, rotation = est.context_.copy(), est.rotation_.copy()
    bad = [
        (after.drop(columns=REFERENCE), "only rows with 'phase' == 'sweep'"),
        (pd.concat([motor_only, first.drop(columns=REFERENCE)]), "exactly one run"),
        (motor_only.drop(columns="tau2"), "tau2"),
        (motor_only.iloc[:1500], "rays"),
    ]
    for sweep, match in bad:
        with pytest.raises(ValueError, match=match):
            est.resweep(sweep)
    pipe["residual"].set_params(clip=10.0)
    with pytest.raises(ValueError, match="refit or its parameters set since start"):
        est.resweep(motor_only)
    assert_allclose(est.context_, context, rtol=0, atol=0)
    assert_allclose(est.rotation_, rotation, rtol=0, atol=0)
    assert est.run_ == "run-0"


def test_resweep_leaves_its_input_unchanged(pipelines, reswept):
    first, motor_only, _, _ = reswept
    before = motor_only.copy(deep=True)
    OnlineEstimator(pipelines(PDLBackbone, "gru")).start(first).resweep(motor_only)
    pd.testing.assert_frame_equal(motor_only, before, check_exact=True)
# one, two and three motors (the polynomial backbone), with and without torques
# ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def motor_pipelines():
    """Lazily fitted PolynomialBackbone pipelines on the simulated instrument of ``n`` motors.

    ``motor_pipelines(n, kind, torques)`` gives the pipeline, the test run of
    ``n`` motors and its backbone output: the rows of ``data`` on that
    instrument.
    """
    cache = {}

    def get(n_motors, kind, torques=True):
        key = (n_motors, kind, torques)
        if key not in cache:
            Xn, y = instrument(n_motors, TRAIN_SETTINGS, N_MOTION, torques=torques)
            run, _ = instrument(n_motors, [TEST_SETTING], 200, torques=torques)
            backbone = PolynomialBackbone().fit(Xn)
            Xb = backbone.transform(Xn)
            if kind == "none":
                residual = NoResidual().fit(Xb, y)
            else:
                Est = {"mlp": MLPResidual, "gru": GRUResidual}[kind]
                residual = _tiny(Est, use_torque=torques).fit(Xb, y)
            pipe = Pipeline([("backbone", backbone), ("residual", residual)])
            cache[key] = (pipe, run, backbone.transform(run))
        return cache[key]

    return get


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize(
    "n_motors, kind, torques",
    [(1, "gru", True), (3, "gru", True), (3, "mlp", True), (1, "none", True),
     (3, "gru", False), (2, "gru", False)],
    ids=["one-gru", "three-gru", "three-mlp", "one-none", "three-no-torque", "two-no-torque"],
)
def test_step_matches_predict_for_any_number_of_motors(motor_pipelines, n_motors, kind, torques,
                                                       engine):
    pipe, X_run, Xb_run = motor_pipelines(n_motors, kind, torques)
    motion = (X_run["phase"] == "motion").to_numpy()
    est = OnlineEstimator(pipe, engine=engine).start(X_run[~motion])
    channels = [f"q{k}" for k in range(1, n_motors + 1)]
    channels += [f"tau{k}" for k in range(1, n_motors + 1)] if torques else []
    assert est.channels_ == tuple(channels)
    assert est.q_neutral_.shape == (n_motors,)
    tips = _stream(est, X_run.loc[motion, channels].to_numpy())
    expected64 = _float64(pipe).steps[-1][1].predict(Xb_run)[motion]
    assert_allclose(tips, expected64, rtol=0, atol=FLOAT64_TOL_MM)
    assert_allclose(tips, pipe.predict(X_run)[motion], rtol=0, atol=FLOAT32_TOL_MM)
    if kind != "none":
        nominal = Xb_run[["b_x", "b_y", "b_z"]].to_numpy()[motion]
        assert np.abs(tips - nominal).max() > 1e-3
    # the backbone evaluated on its own, by the step's kernel
    kernel = BackboneStep(est.backbone_params_)
    first = X_run.loc[motion, channels[:n_motors]].to_numpy()[0]
    assert_allclose(kernel(*first), Xb_run.loc[motion, ["b_x", "b_y", "b_z"]].to_numpy()[0],
                    rtol=0, atol=FLOAT64_TOL_MM)


def test_bad_samples_of_three_motors(motor_pipelines):
    """The channel names, the range over all motors, and holding apply to every motor."""
    pipe, X_run, _ = motor_pipelines(3, "gru")
    motion = (X_run["phase"] == "motion").to_numpy()
    sweep = X_run[~motion]
    sample = X_run.loc[motion, ["q1", "q2", "q3", "tau1", "tau2", "tau3"]].to_numpy()[0]
    est = OnlineEstimator(pipe).start(sweep)
    bad = sample.copy()
    bad[5] = np.nan
    with pytest.raises(ValueError, match=r"non-finite value for tau3 \(q1=.* deg, q2=.* deg, "
                       r"q3=.* deg, tau1=.*, tau2=.*, tau3=nan\)"):
        est.step(*bad)
    far = sample.copy()
    far[2] = est.q_neutral_[2] + 2 * est.q_limit_
    with pytest.raises(ValueError, match=r"\(q1, q2, q3\) = .* deg lies .* deg from the neutral"):
        est.step(*far)
    with pytest.raises(TypeError, match=r"step takes six numbers, q1, q2, q3 \(deg\), tau1, tau2, "
                       r"tau3, one per channel of the recordings; got 4"):
        est.step(*sample[:4])
    assert est.n_steps_ == 0
    held = OnlineEstimator(pipe, on_invalid="hold").start(sweep)
    plain = OnlineEstimator(pipe).start(sweep)
    last = sweep[["q1", "q2", "q3", "tau1", "tau2", "tau3"]].to_numpy()[-1]
    assert_allclose(held.step(*far), plain.step(*last[:3], *sample[3:]), rtol=0, atol=0)
    assert held.n_held_ == 1
