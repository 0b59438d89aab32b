"""Tests of ``skcath.online.export``: the residual's stepping network as ONNX / TorchScript.

Each exported graph is stepped through the motion samples of a run, with the
run's rotation and context from ``OnlineEstimator.start`` and the nominal tip
from its backbone kernel, and compared with ``Pipeline.predict``: float64
graphs with the float64 ``predict`` (``module_.double()``) at 1e-9 mm,
float32 graphs with the float32 ``predict`` at 1e-4 mm. ONNX graphs run in
onnxruntime on the CPU with one thread.
"""

import copy
import warnings

import numpy as np
import pandas as pd
import pytest
import torch
from numpy.testing import assert_allclose
from sklearn.pipeline import Pipeline

from skcath.backbones import PDLBackbone, PolynomialBackbone
from skcath.datasets import make_benchmark
from skcath.online import OnlineEstimator, export, export_io
from skcath.residuals import GRUResidual, MLPResidual, NoResidual

from _helpers import instrument, tiny_residual

def _shorten(X, settings, n_motion):
    motion = (X["phase"] == "motion").to_numpy()
    rank = pd.Series(motion, index=X.index).groupby(X["run"], observed=True).cumsum()
    return X["setting"].isin(settings).to_numpy() & (~motion | (rank.to_numpy() <= n_motion))


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    bench = make_benchmark(
        n_catheters=1, n_runs=1, cache=True, data_home=tmp_path_factory.mktemp("skcath_data")
    )
    X, y = bench.X, np.asarray(bench.y)
    train = _shorten(X, ["S02", "S09"], 300)
    test = _shorten(X, ["S05"], 150)
    backbone = PDLBackbone().fit(X[train])
    X_run = X[test].reset_index(drop=True)
    return backbone, backbone.transform(X[train]), y[train], X_run, backbone.transform(X_run)


@pytest.fixture(scope="module")
def pipelines(data):
    backbone, Xb, y, _, _ = data
    cache = {}

    def get(Est, **params):
        key = (Est, tuple(sorted(params.items())))
        if key not in cache:
            base = dict(
                max_epochs=1, batch_size=16, window_s=5.0, burn_in_s=1.0, sweep_stride_s=5.0,
                n_threads=1, random_state=0, module__hidden_size=8,
                module__encoder_hidden_size=8, module__context_size=4,
            )
            base.update(params)
            cache[key] = Pipeline([("backbone", backbone), ("residual", Est(**base).fit(Xb, y))])
        return cache[key]

    return get


def _onnx_runner(path):
    ort = pytest.importorskip("onnxruntime")
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    options.inter_op_num_threads = 1
    session = ort.InferenceSession(path, options, providers=["CPUExecutionProvider"])
    return lambda feed: session.run(None, feed), session


def _torchscript_runner(path, names):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # torch.jit is deprecated in torch 2.13
        module = torch.jit.load(path)

    def run(feed):
        with torch.no_grad():
            out = module(*[torch.from_numpy(feed[name]) for name in names])
        out = out if isinstance(out, tuple) else (out,)
        return [o.numpy() for o in out]

    return run


def _stream_graph(run, pipe, X_run, dtype):
    """Tips of the motion samples from the exported step graph.

    The step features ``[q, dq, (tau,) b]`` are built here from the motor
    columns, for any number of motors.
    """
    motion = (X_run["phase"] == "motion").to_numpy()
    sweep = X_run[~motion]
    est = OnlineEstimator(pipe, dtype="float64" if dtype == np.float64 else "float32")
    est.start(sweep)
    inputs, _ = export_io(pipe)
    use_torque = pipe["residual"].use_torque
    n = len([c for c in est.channels_ if c.startswith("q")])
    hidden = np.zeros(inputs["hidden"], dtype) if "hidden" in inputs else None
    last = sweep[list(est.channels_[:n])].to_numpy()[-1]
    tips = []
    for sample in X_run.loc[motion, list(est.channels_)].to_numpy():
        est.step(*sample)
        b = est.nominal_.copy()
        q = sample[:n]
        features = [*q, *(q - last), *(sample[n:] if use_torque else [])]
        last = q
        feed = {"features": np.array([[*features, *b]], dtype)}
        if "rotation" in inputs:
            feed["rotation"] = est.rotation_.astype(dtype)
        if "context" in inputs:
            feed["context"] = est.context_[None].astype(dtype)
        if hidden is not None:
            feed["hidden"] = hidden
        out = run(feed)
        if hidden is not None:
            hidden = out[1]
        tips.append(b + out[0][0])
    return np.array(tips), motion


def _expected(pipe, X_run, Xb_run, dtype):
    motion = (X_run["phase"] == "motion").to_numpy()
    if dtype == np.float32:
        return pipe.predict(X_run)[motion]
    residual = copy.deepcopy(pipe["residual"])
    residual.module_.double()
    return residual.predict(Xb_run)[motion]


def _export(pipe, path, fmt, dtype):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # exporter deprecation notices
        return export(pipe, path, fmt, dtype=np.dtype(dtype).name)


@pytest.mark.parametrize("Est", [GRUResidual, MLPResidual])
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_onnx_matches_predict(data, pipelines, tmp_path, Est, dtype):
    pytest.importorskip("onnxruntime")
    _, _, _, X_run, Xb_run = data
    pipe = pipelines(Est)
    path = _export(pipe, tmp_path / "step.onnx", "onnx", dtype)
    run, session = _onnx_runner(path)
    inputs, outputs = export_io(pipe)
    assert [i.name for i in session.get_inputs()] == list(inputs)
    assert [tuple(i.shape) for i in session.get_inputs()] == list(inputs.values())
    assert [o.name for o in session.get_outputs()] == list(outputs)
    tips, _ = _stream_graph(run, pipe, X_run, dtype)
    tol = 1e-9 if dtype == np.float64 else 1e-4
    assert_allclose(tips, _expected(pipe, X_run, Xb_run, dtype), rtol=0, atol=tol)


def test_onnx_graph_has_no_gru_node(data, pipelines, tmp_path):
    onnx = pytest.importorskip("onnx")
    path = _export(pipelines(GRUResidual), tmp_path / "step.onnx", "onnx", np.float32)
    model = onnx.load(path)
    onnx.checker.check_model(model)
    ops = {node.op_type for node in model.graph.node}
    assert "GRU" not in ops and {"Sigmoid", "Tanh"} <= ops


@pytest.mark.parametrize(
    "params",
    [{}, {"module__num_layers": 2, "frame": "base", "use_context": False, "use_torque": False}],
    ids=["default", "two-layers-base-no-context-no-torque"],
)
def test_torchscript_matches_predict(data, pipelines, tmp_path, params):
    _, _, _, X_run, Xb_run = data
    pipe = pipelines(GRUResidual, **params)
    path = _export(pipe, tmp_path / "step.pt", "torchscript", np.float64)
    inputs, outputs = export_io(pipe)
    run = _torchscript_runner(path, list(inputs))
    tips, _ = _stream_graph(run, pipe, X_run, np.float64)
    assert_allclose(tips, _expected(pipe, X_run, Xb_run, np.float64), rtol=0, atol=1e-9)


def test_export_io_names_and_shapes(pipelines):
    inputs, outputs = export_io(pipelines(GRUResidual))
    assert inputs == {"features": (1, 9), "rotation": (3, 3), "context": (1, 4), "hidden": (1, 1, 8)}
    assert outputs == {"residual": (1, 3), "hidden_out": (1, 1, 8)}
    inputs, outputs = export_io(pipelines(MLPResidual))
    assert inputs == {"features": (1, 9), "rotation": (3, 3), "context": (1, 4)}
    assert outputs == {"residual": (1, 3)}
    inputs, _ = export_io(
        pipelines(GRUResidual, module__num_layers=2, frame="base", use_context=False, use_torque=False)
    )
    assert inputs == {"features": (1, 7), "hidden": (2, 1, 8)}


def test_export_errors(data, pipelines, tmp_path):
    backbone, Xb, y, _, _ = data
    with pytest.raises(ValueError, match="format must be one of"):
        export(pipelines(GRUResidual), tmp_path / "x", "tflite")
    with pytest.raises(ValueError, match="dtype must be"):
        export(pipelines(GRUResidual), tmp_path / "x", "onnx", dtype="float16")
    plain = Pipeline([("backbone", backbone), ("residual", NoResidual().fit(Xb, y))])
    with pytest.raises(ValueError, match="no network to export"):
        export(plain, tmp_path / "x.onnx")
    assert not (tmp_path / "x.onnx").exists()


@pytest.mark.parametrize(
    "Est, params",
    [(GRUResidual, {}), (GRUResidual, {"module__num_layers": 2}), (MLPResidual, {})],
    ids=["gru", "gru-two-layers", "mlp"],
)
def test_module_step_matches_forward(pipelines, Est, params):
    """The step the export traces is the network's forward, one time step at a time."""
    module = copy.deepcopy(pipelines(Est, **params)["residual"].module_).double()
    names = list(module.state_dict())
    generator = torch.Generator().manual_seed(0)
    features = torch.randn(2, 7, 9, generator=generator, dtype=torch.float64)
    sweep = torch.randn(2, 5, 4, generator=generator, dtype=torch.float64)
    lengths = torch.tensor([5, 3])
    with torch.no_grad():
        expected = module(features, sweep, lengths)
        z = module.encoder(sweep, lengths)
        hidden = None
        for t in range(features.shape[1]):
            F, hidden = module.step(torch.cat([features[:, t], z], dim=1), hidden)
            assert_allclose(F.numpy(), expected[:, t].numpy(), rtol=0, atol=1e-12)
    if Est is GRUResidual:
        assert hidden.shape == (module.gru.num_layers, 2, module.gru.hidden_size)
    assert list(module.state_dict()) == names  # the cells are not submodules


# ---------------------------------------------------------------------------
# one and three motors (the polynomial backbone)
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("n_motors, Est", [(1, GRUResidual), (3, GRUResidual), (3, MLPResidual)])
def test_onnx_matches_predict_for_any_number_of_motors(tmp_path, n_motors, Est, dtype):
    pytest.importorskip("onnxruntime")
    # the rows of ``data`` on the simulated instrument of ``n_motors`` motors
    train, y = instrument(n_motors, ["S02", "S09"], 300)
    run, _ = instrument(n_motors, ["S05"], 150)
    backbone = PolynomialBackbone().fit(train)
    residual = tiny_residual(Est, max_epochs=1).fit(backbone.transform(train), y)
    pipe = Pipeline([("backbone", backbone), ("residual", residual)])
    inputs, _ = export_io(pipe)
    assert inputs["features"] == (1, 3 * n_motors + 3)
    path = _export(pipe, tmp_path / "step.onnx", "onnx", dtype)
    tips, _ = _stream_graph(_onnx_runner(path)[0], pipe, run, dtype)
    tol = 1e-9 if dtype == np.float64 else 1e-4
    assert_allclose(tips, _expected(pipe, run, backbone.transform(run), dtype), rtol=0, atol=tol)
