"""Tests of the Prandtl-Ishlinskii hysteresis (``hysteresis="pi"``) in the streaming and exported step.

Backbones PDL, PCC and polynomial (one to three motors) with ``hysteresis="pi"``
and a GRU, an MLP or no residual: the compiled and the numpy step match the
float64 ``predict`` at 1e-6 mm on every motion sample, with and without the
samples' times, and with uneven times that the creep must read; the
the backbone's PI of a stream stepped at the model's ticks reads every
sample; the exported ONNX step (run by onnxruntime) matches the float32 ``predict`` at
1e-5 mm and the TorchScript archive the ONNX graph; ``reset``, ``resweep``
(the kept PI over a new sweep), pickling and :mod:`skcath.persist` resume
the stream bit for bit.

The networks are tiny and train for one epoch on a shortened run; the
identified hysteresis is checked to be a PI that is neither the identity
nor a single play, and one case to have creep.
"""

import io
import pickle

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from skcath import persist
from skcath.online import OnlineEstimator, export, step_state

from _helpers import instrument, pi_pipelines

#: the float64 step against the float64 predict (mm)
STEP_TOL_MM = 1e-6
#: the exported float64 step against the float32 predict (mm)
EXPORT_TOL_MM = 1e-5
N_MOTION = 60

CASES = [("pdl", "gru", 2), ("pcc", "mlp", 2), ("polynomial", "none", 1),
         ("polynomial", "gru", 3)]


class _Case(dict):
    """A fitted case; ``predict`` (float32, as fitted) and ``predict64`` computed once when read."""

    def __missing__(self, key):
        pipe = {"predict": self["pipe"], "predict64": self["pipe64"]}[key]
        if key == "predict" and not hasattr(pipe["residual"], "module_"):
            return self["predict64"]  # no network: one prediction
        self[key] = pipe.predict(self["run"])[self["motion"]]
        return self[key]


def _id(case):
    return "-".join(map(str, case)) + "m"


@pytest.fixture(scope="module")
def fitted():
    """Lazily: the pipeline, its float64 copy, the test run, both predictions, a started estimator."""
    cache = {}

    def get(case):
        if case not in cache:
            backbone_name, kind, n_motors = case
            pipe, pipe64, run, motion = pi_pipelines(backbone_name, kind, n_motors, N_MOTION)
            est = OnlineEstimator(pipe64, engine="numpy").start(run[~motion])
            cache[case] = _Case(pipe=pipe, pipe64=pipe64, run=run, motion=motion, est=est)
        return cache[case]

    return get


def _samples(est, run, motion):
    return (run.loc[motion, list(est.channels_)].to_numpy(),
            run.loc[motion, "t"].to_numpy())


def _on_engine(est, engine):
    """A copy of a started estimator on ``engine``, at its state (packed again as unpickling does)."""
    other = pickle.loads(pickle.dumps(est))
    other.set_params(engine=engine)
    return pickle.loads(pickle.dumps(other)).reset()


def _stream(est, samples, times=None):
    if times is None:
        return np.array([est.step(*s) for s in samples])
    return np.array([est.step(*s, t=t) for s, t in zip(samples, times)])


@pytest.mark.parametrize("case", CASES, ids=_id)
def test_identified_hysteresis_is_a_pi(fitted, case):
    est = fitted(case)["est"]
    model = est.hysteresis_
    assert model is not None and est.play_width_ == 0.0
    assert model.dead_band > 0.0 or model.weights[0] < 1.0  # not the identity
    if case[0] != "pcc":  # on this run PCC's is a single play (one weight)
        assert np.count_nonzero(model.weights) > 1
    size = model.thresholds.size + 2
    assert est.hysteresis_state_.shape == (est.hysteresis_.n_motors * size,)


@pytest.mark.parametrize("engine", ["numba", "numpy"])
@pytest.mark.parametrize("case", CASES, ids=_id)
def test_step_matches_predict(fitted, case, engine):
    if engine == "numba":
        pytest.importorskip("numba")
    d = fitted(case)
    est = _on_engine(d["est"], engine)
    assert est.engine_ == engine
    samples, times = _samples(est, d["run"], d["motion"])
    assert_allclose(_stream(est, samples), d["predict64"], rtol=0, atol=STEP_TOL_MM)
    est.reset()
    assert_allclose(_stream(est, samples, times), d["predict64"], rtol=0, atol=STEP_TOL_MM)


@pytest.mark.parametrize("case", [CASES[2], CASES[3]], ids=_id)
def test_numpy_engines_pi_steps_the_packed_arrays_as_the_kernel(fitted, case):
    """The PI on lists (the numpy engine's) leaves ``f`` as the kernel stepping ``f`` itself, bit for bit."""
    from skcath.online._layout import F_DT
    from skcath.online._pi_stream import _pi_angles_compiled, pi_angles

    c = fitted(case)
    est = c["est"]
    meta, f = est._packed.call.args[:2]
    samples, _ = _samples(est, c["run"], c["motion"])
    on_lists, on_array = f.copy(), f.copy()
    rng = np.random.default_rng(0)
    for sample in samples.tolist():
        on_lists[F_DT] = on_array[F_DT] = rng.uniform(0.0, 0.3)
        pi_angles(meta, on_lists, tuple(sample))
        _pi_angles_compiled(meta, on_array, tuple(sample))  # run as Python, on the array
    assert_array_equal(on_lists, on_array)
    assert not np.array_equal(on_lists, f)  # the state and the angles moved


@pytest.mark.parametrize("engine", ["numba", "numpy"])
def test_creep_reads_the_samples_times(fitted, engine):
    """Uneven times (no learned residual, whose model would resample them): the creep follows them."""
    if engine == "numba":
        pytest.importorskip("numba")
    d = fitted(("polynomial", "none", 1))
    assert d["est"].hysteresis_.creep_gain > 0.0
    run, motion = d["run"].copy(), d["motion"]
    rng = np.random.default_rng(0)
    t = run["t"].to_numpy()
    steps = np.diff(t[motion], prepend=t[~motion][-1]) * rng.uniform(0.7, 1.4, motion.sum())
    run.loc[motion, "t"] = t[~motion][-1] + np.cumsum(steps)
    expected = d["pipe"].predict(run)[motion]
    est = _on_engine(d["est"], engine)
    samples, times = _samples(est, run, motion)
    assert_allclose(_stream(est, samples, times), expected, rtol=0, atol=STEP_TOL_MM)
    # without the times the creep steps by the sweep's step, which these samples do not keep
    est.reset()
    assert np.abs(_stream(est, samples) - expected).max() > 100 * STEP_TOL_MM


def test_stream_at_another_rate_steps_the_backbones_pi_at_every_sample(fitted):
    """Motion at twice the model's rate: the stream ticks, and the backbone's PI reads every sample."""
    d = fitted(("polynomial", "gru", 3))
    run, motion = d["run"].copy(), d["motion"]
    end = run.loc[~motion, "t"].iloc[-1]
    run.loc[motion, "t"] = end + 0.5 * (run.loc[motion, "t"] - end)
    nominal = d["pipe"]["backbone"].predict(run)[motion]
    est = _on_engine(d["est"], "numpy")
    samples, times = _samples(est, run, motion)
    for sample, t, expected in zip(samples, times, nominal):
        tip = est.step(*sample, t=t)
        assert est.resampled_
        # the tip is the backbone's at the sample plus the residual of the latest tick
        assert_allclose(tip - est._residual_last, expected, rtol=0, atol=1e-9)


@pytest.mark.parametrize("case", [CASES[0], CASES[3]], ids=_id)
def test_reset_and_persistence_resume_bit_for_bit(fitted, case, tmp_path):
    d = fitted(case)
    est = _on_engine(d["est"], "numpy")
    samples, times = _samples(est, d["run"], d["motion"])
    whole = _stream(est, samples, times)
    est.reset()
    half = len(samples) // 2
    assert_array_equal(_stream(est, samples[:half], times[:half]), whole[:half])
    state = np.array(est.hysteresis_state_)
    path = tmp_path / "est.skcath"
    persist.save(est, path)
    for resumed in (pickle.loads(pickle.dumps(est)), persist.load(path)):
        assert_array_equal(resumed.hysteresis_state_, state)
        assert_array_equal(_stream(resumed, samples[half:], times[half:]), whole[half:])
    assert_array_equal(_stream(est, samples[half:], times[half:]), whole[half:])


def test_resweep_keeps_the_pi_over_the_new_sweep(fitted):
    d = fitted(("pdl", "gru", 2))
    est = _on_engine(d["est"], "numpy")
    run, motion = d["run"], d["motion"]
    samples, _ = _samples(est, run, motion)
    model = est.hysteresis_
    # the same sweep again, without the tracker: the stream is the one after start
    est.resweep(run[~motion].drop(columns=["ref_x", "ref_y", "ref_z"]))
    assert est.hysteresis_.to_dict() == model.to_dict()
    assert_allclose(_stream(est, samples), d["predict64"], rtol=0, atol=STEP_TOL_MM)
    # another run's sweep: the kept PI runs from rest over it and continues into the motion
    other, _ = instrument(2, ["S09"], 5)
    moving = (other["phase"] == "motion").to_numpy()
    est.resweep(other[~moving])
    assert est.hysteresis_.to_dict() == model.to_dict()
    q = other[["q1", "q2"]].to_numpy()
    effective = model.forward(q, other["t"].to_numpy())
    est.step(*other.loc[moving, list(est.channels_)].to_numpy()[0])
    expected = est._backbone(*effective[np.flatnonzero(moving)[0]])
    assert_allclose(est.nominal_, expected, rtol=0, atol=1e-9)


def _onnx_stream(path, samples, dt):
    ort = pytest.importorskip("onnxruntime")
    options = ort.SessionOptions()
    options.intra_op_num_threads = options.inter_op_num_threads = 1
    session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    names = [i.name for i in session.get_inputs()]
    assert names == ["sample", "state", "reset", "dt"]
    state = np.zeros((1, session.get_inputs()[1].shape[1]))
    reset, tips = np.array([True]), []
    for sample, step in zip(samples, dt):
        tip, state, valid = session.run(None, {"sample": sample[None], "state": state,
                                               "reset": reset, "dt": np.array([step])})
        assert valid[0]
        reset = np.array([False])
        tips.append(tip[0])
    return np.array(tips), state


@pytest.mark.parametrize("case", CASES, ids=_id)
def test_exported_step_matches_predict(fitted, case, tmp_path):
    pytest.importorskip("onnx")
    d = fitted(case)
    est = _on_engine(d["est"], "numpy")
    samples, times = _samples(est, d["run"], d["motion"])
    dt = np.diff(times, prepend=d["run"].loc[~d["motion"], "t"].iloc[-1])
    path = export(est, tmp_path / "step.onnx")
    tips, state = _onnx_stream(path, samples, dt)
    assert_allclose(tips, d["predict"], rtol=0, atol=EXPORT_TOL_MM)
    steps = _stream(est, samples, times)
    assert_allclose(tips, steps, rtol=0, atol=1e-9)
    assert_allclose(state, step_state(est), rtol=0, atol=1e-9)


def test_torchscript_matches_onnx(fitted, tmp_path):
    torch = pytest.importorskip("torch")
    d = fitted(("pdl", "gru", 2))
    est = _on_engine(d["est"], "numpy")
    samples, times = _samples(est, d["run"], d["motion"])
    dt = np.diff(times, prepend=d["run"].loc[~d["motion"], "t"].iloc[-1])
    onnx_tips, _ = _onnx_stream(export(est, tmp_path / "step.onnx"), samples, dt)
    module = torch.jit.load(export(est, tmp_path / "step.pt", format="torchscript"))
    state, reset, tips = torch.as_tensor(step_state(est)), torch.tensor([True]), []
    for sample, step in zip(samples, dt):
        tip, state, _ = module(torch.as_tensor(sample[None]), state, reset,
                               torch.tensor([step], dtype=torch.float64))
        reset = torch.tensor([False])
        tips.append(tip[0].numpy())
    assert_allclose(np.array(tips), onnx_tips, rtol=0, atol=1e-12)
    buffer = io.BytesIO()
    torch.jit.save(module, buffer)  # the archive is self-contained
