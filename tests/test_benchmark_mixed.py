"""Tests of the benchmark whose catheter units differ in kind (``make_benchmark(mechanism="mixed")``)."""

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_array_equal
from sklearn.utils._param_validation import InvalidParameterError

from skcath.datasets import MECHANISMS, SIMULATOR_VERSION, benchmark_catheter, make_benchmark
from skcath.datasets import _benchmark

ID_COLUMNS = ["catheter", "setting", "run", "phase"]


@pytest.fixture(autouse=True)
def _isolated_data_home(tmp_path, monkeypatch):
    """Keep every cache this module may write out of the user's home."""
    monkeypatch.setenv("SKCATH_DATA", str(tmp_path / "default_home"))


@pytest.fixture(scope="module")
def mixed():
    """Units C1-C3, one run per setting, one mechanism each."""
    return make_benchmark(n_catheters=3, n_runs=1, mechanism="mixed", unit_spread=1.0, cache=False)


def _unit_rows(bunch, name):
    """The recordings of unit ``name`` in ``bunch``: X (ids as text), y, y_true, sensors, runs."""
    rows = np.flatnonzero((bunch.X["catheter"].astype(str) == name).to_numpy())
    X = bunch.X.iloc[rows].astype({c: str for c in ID_COLUMNS}).reset_index(drop=True)
    runs = bunch.runs[bunch.runs["catheter"] == name].drop(columns="mechanism", errors="ignore")
    return X, bunch.y[rows], bunch.y_true[rows], bunch.sensors.iloc[rows].reset_index(drop=True), \
        runs.reset_index(drop=True)


def _assert_same_recordings(a, b):
    pd.testing.assert_frame_equal(a[0], b[0], check_exact=True)
    for x, y in zip(a[1:4], b[1:4]):
        assert_array_equal(np.asarray(x), np.asarray(y))
    pd.testing.assert_frame_equal(a[4], b[4], check_exact=True)


def test_default_benchmark_keeps_its_cache_key_and_file_name(tmp_path):
    key = _benchmark._cache_key(4, 3, "play", 0, False, unit_spread=0.35, run_variation=None,
                                catheters=None)
    assert key == {"version": SIMULATOR_VERSION, "n_catheters": 4, "n_runs": 3, "mechanism": "play",
                   "random_state": 0}
    # a single mechanism named for every unit is that mechanism's benchmark, cached as it
    make_benchmark(n_catheters=1, n_runs=1, data_home=tmp_path / "a")
    same = make_benchmark(n_catheters=2, n_runs=1, mechanism=["bouc_wen", "bouc_wen"],
                          data_home=tmp_path / "b")
    one = make_benchmark(n_catheters=2, n_runs=1, mechanism="bouc_wen", cache=False)
    assert same.mechanism == "bouc_wen" and "mechanisms" not in same
    assert "mechanism" not in same.runs
    pd.testing.assert_frame_equal(same.X, one.X, check_exact=True)
    assert_array_equal(same.y, one.y)
    (written,) = (tmp_path / "b").glob("*.npz")
    expected = _benchmark._cache_path(
        _benchmark._cache_key(2, 1, "bouc_wen", 0, False, unit_spread=0.35, run_variation=None,
                              catheters=None),
        tmp_path / "b",
    )
    assert written == expected
    (default,) = (tmp_path / "a").glob("*.npz")
    assert default.name.startswith("benchmark-play-")


def test_mixed_units_get_mechanism_k_mod_3(mixed):
    assert mixed.mechanism == "mixed"
    assert mixed.mechanisms == {"C1": "play", "C2": "bouc_wen", "C3": "dahl_creep"}
    per_unit = mixed.runs.groupby("catheter")["mechanism"].agg(set)
    assert per_unit.to_dict() == {"C1": {"play"}, "C2": {"bouc_wen"}, "C3": {"dahl_creep"}}
    assert "C1 play, C2 bouc_wen, C3 dahl_creep" in mixed.DESCR
    # rows in unit order, the id columns categorical as in every benchmark
    assert list(pd.unique(mixed.X["catheter"].astype(str))) == ["C1", "C2", "C3"]
    assert all(isinstance(mixed.X[c].dtype, pd.CategoricalDtype) for c in ID_COLUMNS)
    assert len(mixed.y) == len(mixed.X) == len(mixed.sensors) == len(mixed.y_true)
    assert mixed.noise_floor == pytest.approx(mixed.runs["noise_floor_mm"].mean())


@pytest.mark.parametrize("number", [1, 2, 3])
def test_each_unit_runs_the_runs_of_its_mechanism(mixed, number):
    name = f"C{number}"
    mechanism = MECHANISMS[number - 1]
    alone = make_benchmark(
        n_runs=1, mechanism=mechanism, unit_spread=1.0, cache=False,
        catheters=[benchmark_catheter(number, unit_spread=1.0)],
    )
    _assert_same_recordings(_unit_rows(mixed, name), _unit_rows(alone, name))
    # and not those of another mechanism
    other = make_benchmark(
        n_runs=1, mechanism=MECHANISMS[number % 3], unit_spread=1.0, cache=False,
        catheters=[benchmark_catheter(number, unit_spread=1.0)],
    )
    assert not np.allclose(_unit_rows(mixed, name)[2], _unit_rows(other, name)[2])


def test_a_sequence_names_each_units_mechanism(mixed):
    units = [benchmark_catheter(k, unit_spread=1.0) for k in (2, 3)]
    given = make_benchmark(n_runs=1, catheters=units, mechanism=("dahl_creep", "play"), cache=False)
    assert given.mechanisms == {"C2": "dahl_creep", "C3": "play"}
    # C2 with Dahl friction is not the C2 of the mixed benchmark (Bouc-Wen) ...
    assert not np.allclose(_unit_rows(given, "C2")[2], _unit_rows(mixed, "C2")[2])
    # ... and "mixed" is the sequence of k mod 3
    again = make_benchmark(n_runs=1, catheters=units, mechanism="mixed", cache=False)
    _assert_same_recordings(_unit_rows(again, "C3"), _unit_rows(mixed, "C3"))


def test_random_state_reproduces_the_mixed_benchmark(tmp_path):
    kwargs = {"n_catheters": 2, "n_runs": 1, "mechanism": "mixed"}
    first = make_benchmark(random_state=3, cache=False, **kwargs)
    second = make_benchmark(random_state=3, cache=False, **kwargs)
    for name in ("C1", "C2"):
        _assert_same_recordings(_unit_rows(first, name), _unit_rows(second, name))
    other = make_benchmark(random_state=4, cache=False, **kwargs)
    assert not np.allclose(first.y_true[:100], other.y_true[:100])


def test_mixed_benchmark_is_cached_apart_and_read_back(tmp_path, monkeypatch):
    first = make_benchmark(n_catheters=2, n_runs=1, mechanism="mixed", data_home=tmp_path)
    calls = []
    monkeypatch.setattr(_benchmark, "simulate_mixed", lambda *a, **k: calls.append(1))
    again = make_benchmark(n_catheters=2, n_runs=1, mechanism=["play", "bouc_wen"], data_home=tmp_path)
    assert not calls
    assert again.mechanisms == first.mechanisms == {"C1": "play", "C2": "bouc_wen"}
    pd.testing.assert_frame_equal(again.runs, first.runs, check_exact=True)
    assert_array_equal(again.y, first.y)
    (path,) = tmp_path.glob("*.npz")
    assert path.name.startswith("benchmark-mixed-")
    assert again.key["mechanisms"] == ["play", "bouc_wen"]


@pytest.mark.parametrize(
    "mechanism, error, match",
    [
        ("mix", InvalidParameterError, "mechanism"),
        (3, InvalidParameterError, "mechanism"),
        (("play", "bouc_wen"), ValueError, r"mechanism: .* one per unit; got 2 for 3 units"),
        (("play", "bouc_wen", "coulomb"), ValueError, r"mechanism: .*\['coulomb'\]"),
        (["play", 1, "play"], ValueError, r"mechanism: .*\[1\]"),
    ],
)
def test_bad_mechanism_is_named(mechanism, error, match):
    with pytest.raises(error, match=match):
        make_benchmark(n_catheters=3, n_runs=1, mechanism=mechanism, cache=False)
