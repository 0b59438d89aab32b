"""Tests of saving and loading fitted estimators with their versions (skcath.persist)."""

import copy
import io
import json
import pickle
import warnings
import zipfile

import joblib
import numpy as np
import pandas as pd
import pytest
import torch
from numpy.testing import assert_array_equal
from sklearn.base import clone
from sklearn.frozen import FrozenEstimator
from sklearn.pipeline import Pipeline
from sklearn.utils._param_validation import InvalidParameterError

import skcath
import skcath._version
from skcath import persist
from skcath.backbones import PCCBackbone, PDLBackbone, PolynomialBackbone
from skcath.datasets import make_benchmark
from skcath.persist import (
    IncompatibleVersionError,
    InconsistentVersionWarning,
    is_compatible_version,
)
from skcath.residuals import GRUResidual, MLPResidual, NoResidual

from _helpers import instrument

TINY = {"max_epochs": 1, "module__hidden_size": 8, "window_step_s": 20.0, "random_state": 0,
        "n_threads": 1}
BACKBONES = {"PCC": PCCBackbone, "PDL": PDLBackbone}
RESIDUALS = {
    "none": NoResidual,
    "MLP": lambda: MLPResidual(**TINY),
    "GRU": lambda: GRUResidual(**TINY),
}


@pytest.fixture(scope="module")
def data():
    """One catheter, one run of each of three shaft settings."""
    bench = make_benchmark(n_catheters=1, n_runs=1)
    keep = bench.X["setting"].astype(str).isin(["S01", "S02", "S03"]).to_numpy()
    return bench.X[keep].reset_index(drop=True), np.asarray(bench.y, dtype=float)[keep]


@pytest.fixture(scope="module")
def fitted(data):
    """Fitted backbone+residual pipelines (tiny networks, one epoch) by name."""
    X, y = data
    cache = {}

    def get(backbone, residual):
        if (backbone, residual) not in cache:
            pipe = Pipeline([("backbone", BACKBONES[backbone]()), ("residual", RESIDUALS[residual]())])
            cache[backbone, residual] = pipe.fit(X, y)
        return cache[backbone, residual]

    return get


def _set_saved_version(path, version):
    """Rewrite the skcath version recorded in a saved file."""
    with zipfile.ZipFile(path) as zf:
        members = {name: zf.read(name) for name in zf.namelist()}
    header = json.loads(members["skcath.json"])
    header["versions"]["skcath"] = version
    members["skcath.json"] = json.dumps(header).encode()
    with zipfile.ZipFile(path, "w") as zf:
        for name, content in members.items():
            zf.writestr(name, content)


@pytest.mark.parametrize("fmt", ["default", "joblib"])
@pytest.mark.parametrize("residual", list(RESIDUALS))
@pytest.mark.parametrize("backbone", list(BACKBONES))
def test_round_trip_identical_predictions(data, fitted, tmp_path, backbone, residual, fmt):
    X, _ = data
    pipe = fitted(backbone, residual)
    expected = pipe.predict(X)
    path = tmp_path / "pipe.skcath"
    with warnings.catch_warnings():
        warnings.simplefilter("error", InconsistentVersionWarning)
        if fmt == "default":
            persist.save(pipe, path)
            loaded = persist.load(path)
        else:
            persist.save(pipe, path, format="joblib")
            loaded = persist.load(path, allow_pickle=True)
    assert loaded is not pipe
    assert_array_equal(loaded.predict(X), expected)
    header = persist.read_versions(path)
    assert header["format"] == {"default": "skops", "joblib": "joblib"}[fmt]
    assert header["estimator"] == "sklearn.pipeline.Pipeline"
    assert header["versions"]["skcath"] == skcath.__version__
    assert header["versions"]["torch"] is not None
    assert header["versions"]["scikit-learn"] is not None


def test_saved_version_mismatch_is_refused(data, fitted, tmp_path):
    X, _ = data
    pipe = fitted("PDL", "GRU")
    path = tmp_path / "pipe.skcath"
    persist.save(pipe, path)
    _set_saved_version(path, "0.99.0")
    with pytest.raises(IncompatibleVersionError, match=r"0\.99\.0.*" + skcath.__version__.replace(".", r"\.")) as info:
        persist.load(path)
    assert "allow_version_mismatch=True" in str(info.value)
    assert "Refit" in str(info.value)
    with pytest.warns(InconsistentVersionWarning, match="0.99.0") as record:
        loaded = persist.load(path, allow_version_mismatch=True)
    assert len(record) == 1  # one warning from load, none from the unpickled estimators
    assert record[0].message.original_version == "0.99.0"
    assert record[0].message.current_version == skcath.__version__
    assert_array_equal(loaded.predict(X), pipe.predict(X))


def test_compatible_other_version_loads_with_warning(data, fitted, tmp_path, monkeypatch):
    X, _ = data
    pipe = fitted("PCC", "none")
    path = tmp_path / "pipe.skcath"
    persist.save(pipe, path)
    monkeypatch.setattr(skcath._version, "__version__", "0.1.5")
    with pytest.warns(InconsistentVersionWarning, match="0.1.5") as record:
        loaded = persist.load(path)
    assert len(record) == 1
    assert_array_equal(loaded.predict(X), pipe.predict(X))


@pytest.mark.parametrize(
    "saved, running, expected",
    [
        ("0.1.0.dev0", "0.1.0", True),
        ("0.1.0", "0.1.3", True),
        ("0.1.2", "0.2.0", False),
        ("0.2.0", "0.1.2", False),
        ("1.2.0", "1.5.1", True),
        ("1.9.0", "2.0.0", False),
        ("0.9", "1.0", False),
        ("2", "2.4rc1", True),
    ],
)
def test_is_compatible_version(saved, running, expected):
    assert is_compatible_version(saved, running) is expected


def test_is_compatible_version_rejects_garbage():
    with pytest.raises(ValueError, match="cannot parse the skcath version 'abc'"):
        is_compatible_version("abc", "0.1.0")


@pytest.mark.parametrize("residual", ["none", "GRU"])
def test_plain_pickle_warns_on_other_version(data, fitted, monkeypatch, residual):
    X, _ = data
    pipe = fitted("PDL", residual)
    expected = pipe.predict(X)
    payload = pickle.dumps(pipe)
    with warnings.catch_warnings():  # same version: silent
        warnings.simplefilter("error", InconsistentVersionWarning)
        same = pickle.loads(payload)
    assert_array_equal(same.predict(X), expected)
    assert not hasattr(same["residual"], "_skcath_version")
    assert not hasattr(same["backbone"], "_skcath_version")

    monkeypatch.setattr(skcath._version, "__version__", "7.0.0")
    with pytest.warns(InconsistentVersionWarning) as record:
        other = pickle.loads(payload)
    names = sorted(w.message.estimator_name for w in record)
    assert names == sorted({"none": ["PDLBackbone", "NoResidual"],
                            "GRU": ["PDLBackbone", "GRUResidual"]}[residual])
    message = str(record[0].message)
    assert skcath.__version__ in message and "7.0.0" in message
    assert_array_equal(other.predict(X), expected)


def test_joblib_dump_carries_version(data, fitted, tmp_path, monkeypatch):
    X, _ = data
    model = fitted("PDL", "MLP")["residual"]
    path = tmp_path / "residual.joblib"
    joblib.dump(model, path)
    monkeypatch.setattr(skcath._version, "__version__", "0.0.1")
    with pytest.warns(InconsistentVersionWarning, match="MLPResidual was pickled with skcath"):
        loaded = joblib.load(path)
    Xb = fitted("PDL", "MLP")["backbone"].transform(X)
    assert_array_equal(loaded.predict(Xb), model.predict(Xb))


def test_clone_and_deepcopy_are_silent(fitted):
    pipe = fitted("PDL", "GRU")
    with warnings.catch_warnings():
        warnings.simplefilter("error", InconsistentVersionWarning)
        copied = copy.deepcopy(pipe)
        clone(pipe)
    assert not hasattr(copied["residual"], "_skcath_version")


def test_skops_round_trip_backbones(data, fitted, tmp_path):
    pytest.importorskip("skops")
    X, y = data
    backbone_only = Pipeline([("backbone", PDLBackbone())]).fit(X, y)
    expected = backbone_only.predict(X)
    path = tmp_path / "pdl.skcath"
    persist.save(backbone_only, path, format="skops")
    # skcath's own classes are trusted by default, so nothing is left to trust
    assert "skcath.backbones._backbone.PDLBackbone" in persist.TRUSTED_TYPES
    assert persist.get_untrusted_types(path) == []
    loaded = persist.load(path)
    assert_array_equal(loaded.predict(X), expected)

    pipe = Pipeline([("backbone", PCCBackbone()), ("residual", NoResidual())]).fit(X, y)
    expected = pipe.predict(X)
    persist.save(pipe, path, format="skops")
    assert persist.get_untrusted_types(path) == []
    assert_array_equal(persist.load(path).predict(X), expected)


class _OwnBackbone(PDLBackbone):
    """A class of the user's own: not trusted until named."""


def test_skops_refuses_a_type_of_the_users_own_until_trusted(data, tmp_path):
    X, y = data
    own = _OwnBackbone().fit(X)
    path = tmp_path / "own.skcath"
    persist.save(own, path)
    untrusted = persist.get_untrusted_types(path)
    assert untrusted == [f"{__name__}._OwnBackbone"]
    with pytest.raises(Exception, match="Untrusted types.*_OwnBackbone"):
        persist.load(path)
    assert_array_equal(persist.load(path, trusted=untrusted).predict(X), own.predict(X))


def test_skops_refuses_what_it_cannot_store(fitted, tmp_path):
    pytest.importorskip("skops")
    pipe = copy.deepcopy(fitted("PDL", "none"))
    pipe["backbone"].notes_ = pd.DataFrame({"a": [1.0]})  # skops stores no DataFrame
    with pytest.raises(ValueError, match="format='skops' cannot serialize.*format='joblib'"):
        persist.save(pipe, tmp_path / "mlp.skcath", format="skops")


@pytest.mark.parametrize("backbone", list(BACKBONES))
def test_skops_saves_a_freshly_fitted_backbone_pipeline(data, backbone, tmp_path):
    """Fitting (and predicting) leaves nothing in a backbone that skops cannot store."""
    pytest.importorskip("skops")
    X, y = data
    pipe = Pipeline([("backbone", BACKBONES[backbone]()), ("residual", NoResidual())]).fit(X, y)
    state = joblib.hash(vars(pipe["backbone"]))
    expected = pipe.predict(X)
    pipe["backbone"].transform(X)
    assert joblib.hash(vars(pipe["backbone"])) == state
    path = tmp_path / "pipe.skcath"
    persist.save(pipe, path, format="skops")
    loaded = persist.load(path, trusted=persist.get_untrusted_types(path))
    assert_array_equal(loaded.predict(X), expected)


def test_bad_arguments_and_files(fitted, tmp_path):
    pipe = fitted("PCC", "none")
    with pytest.raises(ValueError, match="format: expected one of"):
        persist.save(pipe, tmp_path / "x", format="pickle")
    with pytest.raises(ValueError, match="compress: expected an int"):
        persist.save(pipe, tmp_path / "x", compress=12)
    path = tmp_path / "pipe.skcath"
    persist.save(pipe, path, format="joblib")
    with pytest.raises(ValueError, match="trusted: only for skops-format files"):
        persist.load(path, trusted=["numpy.ndarray"])
    with pytest.raises(ValueError, match="only the skops format"):
        persist.get_untrusted_types(path)
    plain = tmp_path / "plain.joblib"
    joblib.dump(pipe, plain)
    with pytest.raises(ValueError, match="not a file written by skcath.persist.save"):
        persist.load(plain)
    with zipfile.ZipFile(tmp_path / "other.zip", "w") as zf:
        zf.writestr("a.txt", "a")
    with pytest.raises(ValueError, match="has no skcath.json"):
        persist.load(tmp_path / "other.zip")


def test_arguments_of_the_wrong_type_are_named(fitted, tmp_path):
    pipe = fitted("PCC", "none")
    with pytest.raises(InvalidParameterError, match="'path' parameter of save"):
        persist.save(pipe, 123)
    path = tmp_path / "pipe.skcath"
    persist.save(pipe, str(path))
    with pytest.raises(InvalidParameterError, match="'allow_version_mismatch' parameter of load"):
        persist.load(path, allow_version_mismatch="yes")
    with pytest.raises(InvalidParameterError, match="'trusted' parameter of load"):
        persist.load(path, trusted="numpy.ndarray")
    with pytest.raises(InvalidParameterError, match="'allow_pickle' parameter of load"):
        persist.load(path, allow_pickle="yes")
    for function in (persist.read_versions, persist.get_untrusted_types):
        with pytest.raises(InvalidParameterError, match=f"'path' parameter of {function.__name__}"):
            function(None)
    with pytest.raises(InvalidParameterError, match="'saved' parameter of is_compatible_version"):
        is_compatible_version(0.1)


# ---------------------------------------------------------------------------
# the pickle-free format for the residual learners
# ---------------------------------------------------------------------------
def _copy(pipe):
    """A copy of a fitted pipeline, saved as it is (predict keeps nothing of its call)."""
    return copy.deepcopy(pipe)


@pytest.mark.parametrize("residual", list(RESIDUALS))
def test_skops_round_trip_residual_learners(data, fitted, tmp_path, residual):
    pytest.importorskip("skops")
    X, y = data
    expected = fitted("PDL", residual).predict(X)
    pipe = _copy(fitted("PDL", residual))
    path = tmp_path / "pdl.skcath"
    persist.save(pipe, path, format="skops")
    assert persist.read_versions(path)["format"] == "skops"
    assert persist.get_untrusted_types(path) == []
    loaded = persist.load(path)
    assert_array_equal(loaded.predict(X), expected)  # bit for bit
    assert type(loaded["residual"]) is type(pipe["residual"])
    own = pipe["residual"].get_params(deep=False)
    theirs = loaded["residual"].get_params(deep=False)
    assert {k: v for k, v in theirs.items() if not k.startswith("_")} == {
        k: v for k, v in own.items() if not k.startswith("_")}
    if residual != "none":
        assert len(loaded["residual"].history_) == len(pipe["residual"].history_)
        # the optimizer state is stored too: training goes on as it would have
        Xb = pipe["backbone"].transform(X)
        pipe["residual"].partial_fit(Xb, y)
        loaded["residual"].partial_fit(Xb, y)
        assert_array_equal(loaded["residual"].predict(Xb), pipe["residual"].predict(Xb))


def _nodes(schema):
    """Every node of a skops schema (a dict with a ``__loader__``)."""
    found = []
    if isinstance(schema, dict):
        if "__loader__" in schema:
            found.append(schema)
        for value in schema.values():
            found += _nodes(value)
    elif isinstance(schema, list):
        for value in schema:
            found += _nodes(value)
    return found


def test_skops_file_of_a_residual_learner_holds_no_pickle(data, fitted, tmp_path):
    pytest.importorskip("skops")
    pipe = _copy(fitted("PDL", "GRU"))
    before = {k: v.clone() for k, v in pipe["residual"].module_.state_dict().items()}
    path = tmp_path / "gru.skcath"
    persist.save(pipe, path, format="skops")
    for key, value in pipe["residual"].module_.state_dict().items():  # saving changed nothing
        assert torch.equal(value, before[key])
    with zipfile.ZipFile(path) as zf:
        assert sorted(zf.namelist()) == ["estimator.skops", "skcath.json"]
        payload = zipfile.ZipFile(io.BytesIO(zf.read("estimator.skops")))
    names = payload.namelist()
    assert "schema.json" in names
    nodes = _nodes(json.loads(payload.read("schema.json")))
    assert {"ObjectNode", "TypeNode", "NdArrayNode"} <= {node["__loader__"] for node in nodes}
    # no bytes for skorch's __setstate__ to unpickle, no torch or skorch object
    assert "BytesNode" not in {node["__loader__"] for node in nodes}
    packages = {str(node.get("__module__")).split(".")[0] for node in nodes}
    assert not packages & {"torch", "skorch"}
    for name in names:
        if name != "schema.json":
            assert name.endswith(".npy")
            np.load(io.BytesIO(payload.read(name)), allow_pickle=False)


def test_skops_file_trained_in_float64_keeps_its_precision(data, fitted, tmp_path):
    pytest.importorskip("skops")
    X, _ = data
    pipe = _copy(fitted("PDL", "MLP"))
    pipe["residual"].module_.double()
    path = tmp_path / "mlp64.skcath"
    persist.save(pipe, path, format="skops")
    loaded = persist.load(path, trusted=persist.get_untrusted_types(path))
    assert next(loaded["residual"].module_.parameters()).dtype == torch.float64
    assert_array_equal(loaded.predict(X), pipe.predict(X))


def test_skops_keeps_a_pretrained_learner_and_an_unfitted_one(data, fitted, tmp_path):
    pytest.importorskip("skops")
    X, y = data
    source = fitted("PDL", "GRU")["residual"]
    Xb = fitted("PDL", "GRU")["backbone"].transform(X)
    tuned = GRUResidual(**{**TINY, "lr": 5e-4}, pretrained=FrozenEstimator(source)).fit(Xb, y)
    path = tmp_path / "tuned.skcath"
    persist.save(tuned, path, format="skops")
    loaded = persist.load(path, trusted=persist.get_untrusted_types(path))
    assert_array_equal(loaded.predict(Xb), tuned.predict(Xb))
    assert isinstance(loaded.pretrained, FrozenEstimator)
    assert_array_equal(loaded.pretrained.estimator.predict(Xb), source.predict(Xb))

    persist.save(MLPResidual(**TINY), path, format="skops")
    unfitted = persist.load(path, trusted=persist.get_untrusted_types(path))
    assert not unfitted.initialized_
    assert unfitted.get_params()["module__hidden_size"] == TINY["module__hidden_size"]


def test_skops_state_of_another_class_is_refused(tmp_path):
    pytest.importorskip("skops")
    from skcath._torch_state import ResidualLearnerState

    state = ResidualLearnerState.of(GRUResidual())
    state.learner = PDLBackbone  # a file that claims a backbone is a residual learner
    path = tmp_path / "forged.skcath"
    persist.save(state, path, format="skops")
    untrusted = persist.get_untrusted_types(path)
    with pytest.raises(ValueError, match=r"forged\.skcath'.*PDLBackbone.*not one of "
                                         r"\['GRUResidual', 'MLPResidual'\]"):
        persist.load(path, trusted=untrusted)


# ---------------------------------------------------------------------------
# damaged files and the suffix
# ---------------------------------------------------------------------------
def _rewrite(path, **members):
    """Rewrite the archive at ``path`` with some members replaced (None drops one)."""
    with zipfile.ZipFile(path) as zf:
        content = {name: zf.read(name) for name in zf.namelist()}
    content.update(members)
    with zipfile.ZipFile(path, "w") as zf:
        for name, value in content.items():
            if value is not None:
                zf.writestr(name, value)


def test_damaged_skops_payload_names_the_file(tmp_path):
    pytest.importorskip("skops")
    path = tmp_path / "none.skcath"
    persist.save(NoResidual(), path, format="skops")
    _rewrite(path, **{"estimator.skops": b"not a skops file"})
    for function in (persist.load, persist.get_untrusted_types):
        with pytest.raises(ValueError, match=r"none\.skcath' cannot be loaded: its "
                                             r"estimator\.skops cannot be read by skops"):
            function(path)


def test_damaged_joblib_payload_names_the_file(tmp_path):
    path = tmp_path / "none.skcath"
    persist.save(NoResidual(), path, format="joblib")
    _rewrite(path, **{"estimator.joblib": b"\x80\x04"})
    with pytest.raises(ValueError, match=r"none\.skcath' cannot be loaded: its "
                                         r"estimator\.joblib cannot be unpickled"):
        persist.load(path, allow_pickle=True)


def test_suffix_skcath_is_silent(tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        persist.save(NoResidual(), tmp_path / "a.skcath")
        persist.save(NoResidual(), tmp_path / "b.SKCATH")
    assert persist.SUFFIX == ".skcath"


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks loading without a GPU")
def test_skops_state_of_a_cuda_learner_loads_on_the_cpu(data, fitted, tmp_path):
    pytest.importorskip("skops")
    from skorch.exceptions import DeviceWarning

    from skcath._torch_state import ResidualLearnerState

    X, _ = data
    learner = fitted("PDL", "GRU")["residual"]
    Xb = fitted("PDL", "GRU")["backbone"].transform(X)
    state = ResidualLearnerState.of(learner)
    state.params["device"] = "cuda"  # as saved from a learner trained on a GPU
    path = tmp_path / "cuda.skcath"
    persist.save(state, path, format="skops")
    with pytest.warns(DeviceWarning, match="no CUDA devices"):
        loaded = persist.load(path, trusted=persist.get_untrusted_types(path))
    assert loaded.device == "cpu"
    assert_array_equal(loaded.predict(Xb), learner.predict(Xb))


# ---------------------------------------------------------------------------
# one and three motors
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("n_motors", [1, 3])
@pytest.mark.parametrize("Est", [GRUResidual, MLPResidual])
def test_round_trips_of_other_numbers_of_motors(tmp_path, n_motors, Est):
    """joblib and skops files of a learner fitted on one or three motors predict alike."""
    Xn, y = instrument(n_motors, ["S01", "S02", "S03"])
    pipe = Pipeline([("backbone", PolynomialBackbone()), ("residual", Est(**TINY))]).fit(Xn, y)
    assert pipe["residual"].n_motors_ == n_motors
    expected = pipe.predict(Xn)
    persist.save(pipe, tmp_path / "joblib.skcath", format="joblib")
    assert_array_equal(persist.load(tmp_path / "joblib.skcath", allow_pickle=True).predict(Xn),
                       expected)
    pytest.importorskip("skops")
    path = tmp_path / "skops.skcath"
    persist.save(_copy(pipe), path, format="skops")
    loaded = persist.load(path, trusted=persist.get_untrusted_types(path))
    assert loaded["residual"].n_motors_ == n_motors
    assert_array_equal(loaded.predict(Xn), expected)
