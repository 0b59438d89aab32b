"""Safe by default: no file skcath reads runs code from the file unless the user says so.

Each place where skcath reads something that could hold a pickle or code
(docs/persistence.rst, "What skcath reads, and how it is kept safe") gets a
planted payload here: an object whose unpickling creates a marker folder.
Read by default, the file is refused (or its payload ignored) and the
marker is never created. Where a test opts in (``allow_pickle=True``), the
marker appears: the payload is a real one.

Also here: every estimator skcath makes saves in the default (pickle-free)
format and predicts (or streams on) bit for bit after loading, and a file
written with ``format="joblib"`` by skcath 0.1.0.dev0 still loads with the
opt-in.
"""

import ast
import os
import pickle
import warnings
import zipfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from numpy.testing import assert_array_equal
from sklearn.pipeline import Pipeline

import skcath
from skcath import persist
from skcath.backbones import PCCBackbone, PDLBackbone
from skcath.datasets import make_benchmark
from skcath.ensemble import SeedEnsembleRegressor
from skcath.exceptions import PickledFileError
from skcath.online import OnlineEstimator, ShaftChangeDetector
from skcath.residuals import GRUResidual, MLPResidual, NoResidual
from test_online import (  # noqa: F401  (fixtures)
    ENGINES,
    _split,
    _stream,
    data,
    pipelines,
    played,
    transformed,
)

from _helpers import tiny_residual

DATA = Path(__file__).parent / "data"


class _Payload:
    """An object whose unpickling creates the folder ``marker``: code from a file."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return os.mkdir, (self.marker,)


# ---------------------------------------------------------------------------
# skcath.persist: joblib files
# ---------------------------------------------------------------------------
def test_planted_pickle_in_a_saved_file_is_refused_by_default(tmp_path):
    marker = tmp_path / "payload-ran"
    path = tmp_path / "model.skcath"
    persist.save(_Payload(marker), path, format="joblib")
    with pytest.raises(PickledFileError) as info:
        persist.load(path)
    assert not marker.exists()
    message = str(info.value)
    # names the option, says why, says how to save the file again
    assert "allow_pickle=True" in message
    assert "runs any code the file contains" in message
    assert "skcath.persist.save(estimator, path)" in message and "format='skops'" in message
    assert isinstance(info.value, ValueError)
    # the opt-in runs the file's code: the payload above is a real one
    persist.load(path, allow_pickle=True)
    assert marker.exists()


def test_file_of_an_earlier_version_loads_with_the_opt_in(tmp_path):
    """A pipeline saved with ``format="joblib"`` by skcath 0.1.0.dev0 (commit a42352e).

    ``tests/data/pdl_joblib_0.1.skcath`` was written by that version with::

        bench = make_benchmark(n_catheters=1, n_runs=1)
        keep = bench.X["setting"].astype(str).isin(["S01", "S02", "S03"]).to_numpy()
        X, y = bench.X[keep].reset_index(drop=True), np.asarray(bench.y, dtype=float)[keep]
        pipe = Pipeline([("backbone", PDLBackbone()), ("residual", NoResidual())]).fit(X, y)
        persist.save(pipe, "tests/data/pdl_joblib_0.1.skcath")   # joblib, then the default
        rows = np.arange(0, len(X), 97)
        np.savez_compressed("tests/data/pdl_joblib_0.1_expected.npz", rows=rows,
                            tip=pipe.predict(X)[rows])
    """
    legacy = DATA / "pdl_joblib_0.1.skcath"
    assert persist.read_versions(legacy)["format"] == "joblib"
    with pytest.raises(PickledFileError, match=r"holds a Pipeline pickled by joblib"):
        persist.load(legacy)
    pipe = persist.load(legacy, allow_pickle=True)
    bench = make_benchmark(n_catheters=1, n_runs=1)
    keep = bench.X["setting"].astype(str).isin(["S01", "S02", "S03"]).to_numpy()
    X = bench.X[keep].reset_index(drop=True)
    with np.load(DATA / "pdl_joblib_0.1_expected.npz", allow_pickle=False) as expected:
        rows, tip = expected["rows"], expected["tip"]
    assert_array_equal(pipe.predict(X)[rows], tip)
    # saved again, as the message says: pickle-free, loaded without the opt-in
    path = tmp_path / "resaved.skcath"
    persist.save(pipe, path)
    assert persist.read_versions(path)["format"] == "skops"
    assert_array_equal(persist.load(path).predict(X)[rows], tip)


# ---------------------------------------------------------------------------
# skcath.persist: skops files
# ---------------------------------------------------------------------------
class _Forged:
    """Stored by skops as an object of the class it claims to be (a residual learner)."""

    def __init__(self, state):
        self.state = state

    def __getstate__(self):
        return self.state


_Forged.__module__ = "skcath.residuals._estimators"
_Forged.__name__ = _Forged.__qualname__ = "GRUResidual"


def test_forged_skops_file_with_a_skorch_net_is_refused(tmp_path):
    """A learner stored as itself: skorch's ``__setstate__`` would unpickle its bytes."""
    import skops.io as sio

    marker = tmp_path / "payload-ran"
    attributes = pickle.dumps({"module_": _Payload(marker)})
    forged = _Forged({"device": "cpu", "__cuda_dependent_attributes__": attributes})
    path = tmp_path / "forged.skcath"
    persist.save(forged, path)
    # the class it claims is among the types trusted by default (as a class) ...
    assert persist.get_untrusted_types(path) == []
    with pytest.raises(ValueError, match=r"forged\.skcath' holds a "
                                         r"skcath\.residuals\._estimators\.GRUResidual stored "
                                         r"as an object.*not loaded"):
        persist.load(path)
    assert not marker.exists()
    for trusted in (None, ["skcath.residuals._estimators.GRUResidual"]):
        with pytest.raises(ValueError, match="stored as an object"):
            persist.load(path, trusted=trusted)
    assert not marker.exists()
    # ... and skops alone, with that class trusted, runs the file's code
    with zipfile.ZipFile(path) as zf:
        payload = zf.read("estimator.skops")
    sio.loads(payload, trusted=["skcath.residuals._estimators.GRUResidual"])
    assert marker.exists()


def test_skops_file_with_a_function_is_refused_by_default(tmp_path):
    marker = tmp_path / "payload-ran"
    path = tmp_path / "function.skcath"
    persist.save({"call": os.mkdir, "args": [str(marker)]}, path)
    assert persist.get_untrusted_types(path) == ["posix.mkdir"]
    with pytest.raises(Exception, match=r"Untrusted types.*mkdir"):
        persist.load(path)
    assert not marker.exists()


# ---------------------------------------------------------------------------
# the other readers
# ---------------------------------------------------------------------------
def test_planted_pickle_in_load_params_is_refused(data, pipelines, tmp_path):
    """skorch's ``load_params`` reads with ``torch.load(weights_only=True)``."""
    marker = tmp_path / "payload-ran"
    path = tmp_path / "params.pt"
    torch.save({"weight": _Payload(marker)}, path)
    learner = pipelines(PDLBackbone, "gru")["residual"]
    assert learner.torch_load_kwargs is None  # skorch's default: weights only
    with pytest.raises(pickle.UnpicklingError, match="Weights only load failed"):
        learner.load_params(f_params=path)
    assert not marker.exists()


def test_planted_pickle_in_a_parquet_recording_never_runs(tmp_path):
    """pyarrow (>= 14.0.1) does not unpickle the old Python extension type's metadata."""
    pa = pytest.importorskip("pyarrow")
    pq = pytest.importorskip("pyarrow.parquet")
    from skcath.io import read_recording

    marker = tmp_path / "payload-ran"
    planted = {b"ARROW:extension:name": b"arrow.py_extension_type",
               b"ARROW:extension:metadata": pickle.dumps(_Payload(marker))}
    n = 20
    columns = {name: pa.array(np.linspace(0.0, 1.0, n)) for name in
               ("t", "q1", "q2", "tau1", "tau2", "x", "y", "z")}
    fields = [pa.field(name, pa.float64(), metadata=planted if name == "q1" else None)
              for name in columns]
    path = tmp_path / "run.parquet"
    pq.write_table(pa.Table.from_arrays(list(columns.values()), schema=pa.schema(fields)), path)
    try:
        read_recording(path)
    except (ValueError, TypeError):
        pass  # what a recording lacks is not the point here
    assert not marker.exists()


def test_planted_code_in_a_ros_bag_message_definition_never_runs(tmp_path):
    """rosbags generates classes from a bag's message definitions: code in one is not run."""
    rosbag1 = pytest.importorskip("rosbags.rosbag1")
    from rosbags.typesys import Stores, get_typestore, get_types_from_msg

    from skcath.io import read_rosbag

    marker = tmp_path / "payload-ran"
    run = f'__import__("os").mkdir({str(marker)!r})'
    definition = (f"string C=x'; {run} #\n"  # a constant: its value is the rest of the line
                  f"float64 a = {run}\n"
                  f'int32 b  # """; {run}; """\n')
    store = get_typestore(Stores.ROS1_NOETIC)
    store.register(get_types_from_msg(definition, "evil_msgs/msg/Evil"))  # for its hash
    _, md5 = store.generate_msgdef("evil_msgs/msg/Evil")
    path = tmp_path / "planted.bag"
    with rosbag1.Writer(path) as writer:
        connection = writer.add_connection("/evil", "evil_msgs/msg/Evil", msgdef=definition,
                                           md5sum=md5)
        writer.write(connection, 1_700_000_000 * 10**9, bytes(16))
    # the bag is opened and its definitions registered; the topics asked for are missing
    with pytest.raises(ValueError, match=r"the bag has no topic '/joints'.*\['/evil'\]"):
        read_rosbag(path, {"joint_states": "/joints", "q1": "m1", "q2": "m2", "tip": "/tip"},
                    tolerance=0.005)
    assert not marker.exists()


#: The calls of the package that read something that could hold a pickle or
#: code: each is listed in docs/persistence.rst with how it is kept safe.
READERS = {
    ("skcath/persist.py", "joblib.load"),
    ("skcath/datasets/_cache.py", "np.load"),
}
_READING = {"load", "loads", "read_pickle", "jit.load", "Unpickler", "InferenceSession"}


def _calls(tree):
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            yield node, ast.unparse(node.func)


def test_every_reader_of_code_or_pickles_is_a_known_one():
    """No call in the package reads a pickle, a torch file or a graph but the listed ones."""
    root = Path(skcath.__file__).parent
    found = set()
    for path in root.rglob("*.py"):
        tree = ast.parse(path.read_text())
        for node, name in _calls(tree):
            last = name.split(".")[-1]
            qualified = ".".join(name.split(".")[-2:])
            if last in _READING or qualified in _READING:
                if name in ("json.loads", "sio.loads") or name.endswith("_read_member"):
                    continue  # JSON text; skops, with its trusted types
                found.add((path.relative_to(root.parent).as_posix(), name))
                if name == "np.load":  # never with pickles
                    keywords = {k.arg: ast.unparse(k.value) for k in node.keywords}
                    assert keywords.get("allow_pickle") == "False", (path, ast.unparse(node))
    assert found == READERS


# ---------------------------------------------------------------------------
# every estimator skcath makes, in the default format
# ---------------------------------------------------------------------------
def _round_trip(estimator, path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        persist.save(estimator, path)
        assert persist.read_versions(path)["format"] == "skops"
        assert persist.get_untrusted_types(path) == []
        return persist.load(path)


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize(
    "Backbone, kind, params",
    [(PDLBackbone, "gru", {}), (PCCBackbone, "gru", {"module__num_layers": 2}),
     (PDLBackbone, "mlp", {}), (PCCBackbone, "none", {})],
    ids=["pdl-gru", "pcc-gru-2-layers", "pdl-mlp", "pcc-none"],
)
def test_started_estimator_resumes_its_stream(data, pipelines, tmp_path, engine, Backbone, kind,
                                              params):
    _, _, X_run = data
    sweep, samples, _ = _split(X_run)
    pipe = pipelines(Backbone, kind, **params)
    est = OnlineEstimator(pipe, engine=engine, detector=ShaftChangeDetector()).start(sweep)
    _stream(est, samples[:40])
    loaded = _round_trip(est, tmp_path / "started.skcath")
    assert persist.read_versions(tmp_path / "started.skcath")["estimator"] == (
        "skcath.online._estimator.OnlineEstimator")
    assert loaded.engine_ == engine and loaded.n_steps_ == 40
    assert_array_equal(loaded.nominal_, est.nominal_)
    pd.testing.assert_frame_equal(loaded._calibration_sweep, est._calibration_sweep,
                                  check_exact=True)
    assert_array_equal(loaded.context_, est.context_)
    # the stream goes on bit for bit, the detector's too
    assert_array_equal(_stream(loaded, samples[40:100]), _stream(est, samples[40:100]))
    assert loaded.detector_.statistic_ == est.detector_.statistic_
    assert loaded.detector_.n_steps_ == est.detector_.n_steps_ == 100
    # the pipeline it holds predicts as the saved one
    assert_array_equal(loaded.pipeline.predict(X_run), pipe.predict(X_run))
    # and starting again gives the original's steps
    fresh = _stream(OnlineEstimator(pipe, engine=engine).start(sweep), samples[:20])
    assert_array_equal(_stream(loaded.reset(), samples[:20]), fresh)


def test_started_estimator_with_a_play_and_an_unstarted_one(data, played, tmp_path):
    _, _, X_run = data
    sweep, samples, _ = _split(X_run)
    pipe = played(PDLBackbone, "gru")[0]
    est = OnlineEstimator(pipe).start(sweep)
    _stream(est, samples[:30])
    loaded = _round_trip(est, tmp_path / "played.skcath")
    assert loaded.play_width_ == est.play_width_ > 0.0
    assert_array_equal(loaded.play_state_, est.play_state_)
    assert_array_equal(_stream(loaded, samples[30:60]), _stream(est, samples[30:60]))

    unstarted = _round_trip(OnlineEstimator(pipe, q_margin=0.5), tmp_path / "unstarted.skcath")
    assert unstarted.get_params()["q_margin"] == 0.5
    with pytest.raises(Exception, match="has not been started"):
        unstarted.step(*samples[0])
    expected = _stream(OnlineEstimator(pipe).start(sweep), samples[:10])
    assert_array_equal(_stream(unstarted.start(sweep), samples[:10]), expected)


def test_started_estimator_is_checked_as_other_files(data, pipelines, tmp_path):
    """Versions are checked; a class of the user's own in it must be trusted by name."""
    _, _, X_run = data
    sweep, samples, _ = _split(X_run)
    est = OnlineEstimator(pipelines(PDLBackbone, "mlp")).start(sweep)
    path = tmp_path / "started.skcath"
    persist.save(est, path)
    with zipfile.ZipFile(path) as zf:
        members = {name: zf.read(name) for name in zf.namelist()}
    members["skcath.json"] = members["skcath.json"].replace(
        skcath.__version__.encode(), b"99.0.0")
    with zipfile.ZipFile(path, "w") as zf:
        for name, content in members.items():
            zf.writestr(name, content)
    with pytest.raises(persist.IncompatibleVersionError, match="OnlineEstimator saved with "
                                                                "skcath 99.0.0"):
        persist.load(path)

    own = OnlineEstimator(pipelines(PDLBackbone, "mlp"), detector=_OwnDetector()).start(sweep)
    persist.save(own, path)
    assert persist.get_untrusted_types(path) == [f"{__name__}._OwnDetector"]
    with pytest.raises(Exception, match="Untrusted types.*_OwnDetector"):
        persist.load(path)
    loaded = persist.load(path, trusted=[f"{__name__}._OwnDetector"])
    assert_array_equal(_stream(loaded, samples[:10]), _stream(own, samples[:10]))


class _OwnDetector(ShaftChangeDetector):
    """A detector of the user's own."""


def test_shaft_change_detector_resumes(data, tmp_path):
    _, _, X_run = data
    sweep, samples, _ = _split(X_run)
    detector = ShaftChangeDetector().start(sweep)
    for sample in samples[:50]:
        detector.step(*sample)
    loaded = _round_trip(detector, tmp_path / "detector.skcath")
    for sample in samples[50:120]:
        assert loaded.step(*sample) == detector.step(*sample)
    assert loaded.statistic_ == detector.statistic_
    assert loaded.n_steps_ == detector.n_steps_


def test_seed_ensemble_of_pipelines(data, transformed, tmp_path):
    X, y, _ = data
    member = Pipeline([("backbone", PDLBackbone()),
                       ("residual", tiny_residual(MLPResidual, max_epochs=1))])
    ensemble = SeedEnsembleRegressor(member, n_estimators=2, random_state=0).fit(X, y)
    loaded = _round_trip(ensemble, tmp_path / "ensemble.skcath")
    mean, std = ensemble.predict(X, return_std=True)
    loaded_mean, loaded_std = loaded.predict(X, return_std=True)
    assert_array_equal(loaded_mean, mean)
    assert_array_equal(loaded_std, std)
    assert [type(m["residual"]) for m in loaded.estimators_] == [MLPResidual] * 2


def test_backbones_and_learners_alone(data, transformed, pipelines, tmp_path):
    X, _, _ = data
    for Backbone in (PCCBackbone, PDLBackbone):
        backbone, Xb = transformed[Backbone]
        loaded = _round_trip(backbone, tmp_path / "b.skcath")
        pd.testing.assert_frame_equal(loaded.transform(X), Xb, check_exact=True)
    Xb = transformed[PDLBackbone][1]
    for kind, Est in (("gru", GRUResidual), ("mlp", MLPResidual), ("none", NoResidual)):
        learner = pipelines(PDLBackbone, kind)["residual"]
        loaded = _round_trip(learner, tmp_path / "r.skcath")
        assert type(loaded) is Est
        assert_array_equal(loaded.predict(Xb), learner.predict(Xb))


def test_a_data_frame_outside_an_online_estimator_still_needs_joblib(tmp_path):
    frame = pd.DataFrame({"a": [1.0]})
    with pytest.raises(ValueError, match="format='skops' cannot serialize.*allow_pickle=True"):
        persist.save({"notes": frame}, tmp_path / "frame.skcath")
    # the explicit choice stays available
    persist.save({"notes": frame}, tmp_path / "frame.skcath", format="joblib")
    loaded = persist.load(tmp_path / "frame.skcath", allow_pickle=True)
    pd.testing.assert_frame_equal(loaded["notes"], frame)
