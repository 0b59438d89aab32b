"""Tests of the exported whole step of a started estimator (``export(est, path)``).

The graph, run by onnxruntime (CPU, one thread), is stepped through every
motion sample of a run from ``reset=True`` and compared with ``predict``
(float32, as fitted) at 1e-5 mm and with ``OnlineEstimator.step`` (float64)
at 1e-9 mm, for the PCC and PDL backbones with and without the play, the
polynomial backbone on one, two and three motors, each with GRU, MLP and no
residual, with and without torques. One case runs in a separate Python that
imports numpy and onnxruntime only. Then the TorchScript archive, the state
of a running estimator, the metadata, and bad input.

The networks are tiny and train for one epoch on one shortened run.
"""

import copy
import json
import subprocess
import sys
import textwrap
import warnings

import numpy as np
import pytest
from numpy.testing import assert_allclose
from sklearn.exceptions import NotFittedError
from sklearn.pipeline import Pipeline

from skcath.backbones import PCCBackbone, PDLBackbone, PolynomialBackbone
from skcath.exceptions import PipelineChangedWarning
from skcath.online import OnlineEstimator, export, export_io, step_state
from skcath.residuals import GRUResidual, MLPResidual, NoResidual

from _helpers import instrument, tiny_residual

ort = pytest.importorskip("onnxruntime")

#: the exported float64 step against the float32 predict (as fitted)
PREDICT_TOL_MM = 1e-5
#: the exported float64 step against the float64 OnlineEstimator.step
STEP_TOL_MM = 1e-9
RESIDUALS = {"gru": GRUResidual, "mlp": MLPResidual, "none": NoResidual}


def _key(backbone, residual, n_motors=2, *, play=False, torques=True, **params):
    """The key of a fitted pipeline of :func:`pipelines`."""
    return backbone, residual, n_motors, play, torques, tuple(params.items())


def _case(backbone, residual, n_motors=2, *, play=False, torques=True, **params):
    name = f"{backbone}{'-play' if play else ''}-{residual}-{n_motors}m"
    name += "" if torques else "-no-torques"
    name += "".join(f"-{k}={v}" for k, v in params.items())
    key = _key(backbone, residual, n_motors, play=play, torques=torques, **params)
    return pytest.param(key, id=name)


CASES = [
    *(_case(b, r, play=p) for b in ("pcc", "pdl") for p in (False, True)
      for r in ("gru", "mlp", "none")),
    _case("pdl", "gru", use_torque=False),
    _case("pdl", "gru", module__num_layers=2),
    *(_case("polynomial", r, n) for n in (1, 2, 3) for r in ("gru", "mlp", "none")),
    _case("polynomial", "gru", 1, torques=False),
    _case("polynomial", "mlp", 2, torques=False),
    _case("polynomial", "none", 3, torques=False),
    _case("polynomial", "gru", 3, torques=False),
]


@pytest.fixture(scope="module")
def pipelines():
    """Lazily fitted pipelines and the test run, keyed by case."""
    backbones, fitted = {}, {}

    def get(case):
        backbone_name, kind, n_motors, play, torques, params = case
        key = (backbone_name, n_motors, play, torques)
        if key not in backbones:
            train, y = instrument(n_motors, ["S02"], 200, torques=torques)
            run, _ = instrument(n_motors, ["S05"], 120, torques=torques)
            Backbone = {"pcc": PCCBackbone, "pdl": PDLBackbone,
                        "polynomial": PolynomialBackbone}[backbone_name]
            backbone = Backbone(hysteresis="play") if play else Backbone()
            backbone.fit(train)
            backbones[key] = (backbone, backbone.transform(train), y, run)
        if case not in fitted:
            backbone, Xb, y, run = backbones[key]
            Est = RESIDUALS[kind]
            if not torques:  # a rig without torque sensing
                params = (("use_torque", False), *params)
            residual = NoResidual() if Est is NoResidual else tiny_residual(
                Est, max_epochs=1, **dict(params))
            pipe = Pipeline([("backbone", backbone), ("residual", residual.fit(Xb, y))])
            fitted[case] = (pipe, run)
        return fitted[case]

    return get


def _session(path):
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    options.inter_op_num_threads = 1
    return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


def _stream(session, samples, state=None):
    """Tips (n, 3) of the graph stepped through ``samples``, from ``reset`` unless given a state."""
    size = session.get_inputs()[1].shape[1]
    reset = np.array([state is None])
    state = np.zeros((1, size)) if state is None else state
    tips = []
    for sample in samples:
        tip, state, valid = session.run(None, {"sample": sample[None], "state": state,
                                               "reset": reset})
        assert valid[0]
        reset = np.array([False])
        tips.append(tip[0])
    return np.array(tips), state


def _started(pipe, run):
    motion = (run["phase"] == "motion").to_numpy()
    est = OnlineEstimator(pipe, engine="numpy").start(run[~motion])
    return est, run.loc[motion, list(est.channels_)].to_numpy(), motion


@pytest.mark.parametrize("case", CASES)
def test_exported_step_matches_predict(pipelines, tmp_path, case):
    pipe, run = pipelines(case)
    est, samples, motion = _started(pipe, run)
    path = export(est, tmp_path / "step.onnx")
    session = _session(path)
    inputs, outputs = export_io(est)
    assert [(i.name, tuple(i.shape)) for i in session.get_inputs()] == list(inputs.items())
    assert [(o.name, tuple(o.shape)) for o in session.get_outputs()] == list(outputs.items())
    tips, _ = _stream(session, samples)
    assert_allclose(tips, pipe.predict(run)[motion], rtol=0, atol=PREDICT_TOL_MM)
    steps = np.array([est.step(*sample) for sample in samples])
    assert_allclose(tips, steps, rtol=0, atol=STEP_TOL_MM)


_SCRIPT = textwrap.dedent('''
    import sys
    import numpy as np
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    session = ort.InferenceSession(sys.argv[1], options, providers=["CPUExecutionProvider"])
    samples = np.load(sys.argv[2])
    state = np.zeros((1, session.get_inputs()[1].shape[1]))
    reset = np.array([True])
    tips = []
    for sample in samples:
        tip, state, valid = session.run(None, {"sample": sample[None], "state": state,
                                               "reset": reset})
        reset = np.array([False])
        tips.append(tip[0])
    assert not [m for m in sys.modules if m.split(".")[0] == "skcath"]
    assert not [m for m in sys.modules if m.split(".")[0] == "torch"]
    np.save(sys.argv[3], np.array(tips))
''')


@pytest.mark.parametrize("case", [_case("pdl", "gru", play=True),
                                  _case("polynomial", "mlp", 3, torques=False)])
def test_exported_step_runs_without_skcath(pipelines, tmp_path, case):
    pipe, run = pipelines(case)
    est, samples, motion = _started(pipe, run)
    export(est, tmp_path / "step.onnx")
    (tmp_path / "run.py").write_text(_SCRIPT)
    np.save(tmp_path / "samples.npy", samples)
    subprocess.run(
        [sys.executable, "-I", str(tmp_path / "run.py"), str(tmp_path / "step.onnx"),
         str(tmp_path / "samples.npy"), str(tmp_path / "tips.npy")],
        check=True, cwd=tmp_path, timeout=300,
    )
    tips = np.load(tmp_path / "tips.npy")
    assert_allclose(tips, pipe.predict(run)[motion], rtol=0, atol=PREDICT_TOL_MM)


def test_torchscript_matches_onnx(pipelines, tmp_path):
    torch = pytest.importorskip("torch")
    pipe, run = pipelines(_key("pdl", "gru", play=True))
    est, samples, _ = _started(pipe, run)
    tips, _ = _stream(_session(export(est, tmp_path / "step.onnx")), samples)
    path = export(est, tmp_path / "step.pt", format="torchscript")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # torch.jit is deprecated in torch 2.13
        module = torch.jit.load(path)
    state = torch.zeros(1, export_io(est)[0]["state"][1], dtype=torch.float64)
    reset = torch.tensor([True])
    for sample, expected in zip(samples, tips):
        with torch.no_grad():
            tip, state, valid = module(torch.tensor(sample[None]), state, reset)
        reset = torch.tensor([False])
        assert bool(valid[0])
        assert_allclose(tip[0].numpy(), expected, rtol=0, atol=STEP_TOL_MM)


def test_state_of_a_running_estimator_continues_the_stream(pipelines, tmp_path):
    pipe, run = pipelines(_key("pdl", "gru", play=True))
    est, samples, _ = _started(pipe, run)
    session = _session(export(est, tmp_path / "step.onnx"))
    initial = step_state(est)
    _, after_reset = _stream(session, samples[:1])
    est.step(*samples[0])
    assert_allclose(after_reset, step_state(est), rtol=0, atol=STEP_TOL_MM)
    for sample in samples[1:40]:
        est.step(*sample)
    tips, _ = _stream(session, samples[40:], state=step_state(est))
    steps = np.array([est.step(*sample) for sample in samples[40:]])
    assert_allclose(tips, steps, rtol=0, atol=STEP_TOL_MM)
    est.reset()
    assert_allclose(step_state(est), initial, rtol=0, atol=0)


def test_metadata_describe_the_step(pipelines, tmp_path):
    onnx = pytest.importorskip("onnx")
    pipe, run = pipelines(_key("pdl", "gru", play=True))
    est, _, _ = _started(pipe, run)
    model = onnx.load(export(est, tmp_path / "step.onnx"))
    onnx.checker.check_model(model)
    meta = {p.key: p.value for p in model.metadata_props}
    assert json.loads(meta["skcath.channels"]) == list(est.channels_)
    H = pipe["residual"].module_.gru.hidden_size
    assert json.loads(meta["skcath.state_layout"]) == [
        ["previous_angles", 2], ["played_angles", 2], ["hidden_0", H]]
    assert json.loads(meta["skcath.rate_hz"]) == est.rate_hz_
    assert json.loads(meta["skcath.q_limit"]) == est.q_limit_
    assert export_io(est)[0]["state"] == (1, 4 + H)
    motion = (run["phase"] == "motion").to_numpy()
    unlimited = OnlineEstimator(pipe, q_margin=None, engine="numpy").start(run[~motion])
    model = onnx.load(export(unlimited, tmp_path / "unlimited.onnx"))
    assert json.loads({p.key: p.value for p in model.metadata_props}["skcath.q_limit"]) is None


def test_bad_samples_leave_the_state(pipelines, tmp_path):
    pipe, run = pipelines(_key("pdl", "gru", play=True))
    est, samples, _ = _started(pipe, run)
    session = _session(export(est, tmp_path / "step.onnx"))
    _, state = _stream(session, samples[:5])
    far = samples[5].copy()
    far[0] = est.q_neutral_[0] + 2 * est.q_limit_
    nan = samples[5].copy()
    nan[2] = np.nan
    for bad in (far, nan):
        tip, out, valid = session.run(None, {"sample": bad[None], "state": state,
                                             "reset": np.array([False])})
        assert not valid[0]
        assert np.isnan(tip).all()
        assert_allclose(out, state, rtol=0, atol=0)
    with pytest.raises(ValueError):
        est.step(*nan)
    wide = np.r_[samples[5], 0.0][None]
    with pytest.raises(ort.capi.onnxruntime_pybind11_state.InvalidArgument, match="sample"):
        session.run(None, {"sample": wide, "state": state, "reset": np.array([False])})
    other = np.zeros((1, state.shape[1] + 1))  # the state of a larger network
    with pytest.raises(ort.capi.onnxruntime_pybind11_state.InvalidArgument, match="state"):
        session.run(None, {"sample": samples[5][None], "state": other,
                           "reset": np.array([False])})


def test_export_errors(pipelines, tmp_path):
    pipe, run = pipelines(_key("pdl", "none"))
    with pytest.raises(NotFittedError, match="start"):
        export(OnlineEstimator(pipe), tmp_path / "x.onnx")
    with pytest.raises(NotFittedError, match="start"):
        step_state(OnlineEstimator(pipe))
    est, _, _ = _started(pipe, run)
    with pytest.raises(ValueError, match="dtype must be 'float64'"):
        export(est, tmp_path / "x.onnx", dtype="float32")
    with pytest.raises(ValueError, match="format must be one of"):
        export(est, tmp_path / "x.onnx", format="tflite")
    assert not (tmp_path / "x.onnx").exists()


def test_export_steps_the_pipeline_as_it_was_at_start(pipelines, tmp_path):
    pipe, run = pipelines(_key("pdl", "mlp"))
    pipe = copy.deepcopy(pipe)
    est, samples, motion = _started(pipe, run)
    expected = pipe.predict(run)[motion]
    pipe["residual"].set_params(clip=0.01)  # the pipeline changes after start
    with pytest.warns(PipelineChangedWarning, match="exported"):
        path = export(est, tmp_path / "step.onnx")
    tips, _ = _stream(_session(path), samples)
    assert_allclose(tips, expected, rtol=0, atol=PREDICT_TOL_MM)
