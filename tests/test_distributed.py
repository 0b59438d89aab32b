"""The evaluation protocol on a dask.distributed cluster gives the local results.

A local cluster of two single-threaded worker processes runs a tiny protocol
(two catheters, one run of four shaft settings each, one epoch, small
networks) through joblib's dask backend, as ``reproduce --backend dask`` does;
every prediction and table must equal the ``n_jobs=1`` run. Skipped when
``dask.distributed`` is not installed.
"""

import pandas as pd
import pytest
from joblib import parallel_config
from numpy.testing import assert_array_equal

from skcath.protocol import compute_tables, run_protocol

from _helpers import benchmark_settings, tiny_schedule

distributed = pytest.importorskip("distributed")

EXCLUDED = "S00"
SETTINGS = ("S00", "S01", "S02", "S03")
TINY = tiny_schedule(seeds=(0,), variants=("PDL+GRU", "PDL+MLP"))


@pytest.fixture(scope="module")
def data():
    return benchmark_settings(SETTINGS)


def _assert_same(result, expected):
    assert list(result.predictions) == list(expected.predictions)
    for method, by_seed in expected.predictions.items():
        assert list(result.predictions[method]) == list(by_seed)
        for seed, values in by_seed.items():
            assert_array_equal(result.predictions[method][seed], values)
    pd.testing.assert_frame_equal(result.X, expected.X)
    tables = compute_tables(result, n_bootstrap=50, random_state=0)
    tables_expected = compute_tables(expected, n_bootstrap=50, random_state=0)
    assert set(tables) == set(tables_expected)
    for key, table in tables_expected.items():
        pd.testing.assert_frame_equal(tables[key], table)


def test_dask_cluster_gives_the_local_results(data):
    X, y = data
    expected = run_protocol(X, y, schedule=TINY, exclude_settings=[EXCLUDED], n_jobs=1)
    with (
        distributed.LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
        ) as cluster,
        distributed.Client(cluster) as client,
        parallel_config(backend="dask"),
    ):
        with distributed.get_task_stream(client) as stream:
            result = run_protocol(X, y, schedule=TINY, exclude_settings=[EXCLUDED], n_jobs=-1)
        # the models were trained on the workers, not in this process
        used = {task["worker"] for task in stream.data}
        assert used and used <= set(client.scheduler_info()["workers"])
    _assert_same(result, expected)
    assert len(result.timings) == len(expected.timings)


# ---------------------------------------------------------------------------
# python -m skcath reproduce --backend dask
# ---------------------------------------------------------------------------
class _Stop(Exception):
    """Raised by the run_protocol spy once it has looked at the joblib backend."""


@pytest.fixture
def reproduce_spy(data, monkeypatch, tmp_path):
    """Run ``reproduce`` on a small CSV up to run_protocol; record the backend it runs under."""
    from joblib.parallel import get_active_backend

    from skcath import protocol

    X, y = data
    frame = X.copy()
    for k, axis in enumerate("xyz"):
        frame[f"p_{axis}"] = y[:, k]
    path = tmp_path / "recordings.csv"
    frame.to_csv(path, index=False)
    calls = []

    def spy(X, y, **kwargs):
        backend, _ = get_active_backend()
        record = {"backend": type(backend).__name__, "n_jobs": kwargs["n_jobs"]}
        if record["backend"] == "DaskDistributedBackend":
            record["nthreads"] = distributed.get_client().nthreads()
        calls.append(record)
        raise _Stop

    monkeypatch.setattr(protocol, "run_protocol", spy)
    argv = ["reproduce", "--data", str(path), "--out", str(tmp_path / "out"), "--no-figures"]
    return argv, calls


def test_reproduce_backend_dask_starts_a_local_cluster(reproduce_spy):
    from skcath._cli import main

    argv, calls = reproduce_spy
    with pytest.raises(_Stop):
        main([*argv, "--backend", "dask", "--n-jobs", "2"])
    (call,) = calls
    assert call["backend"] == "DaskDistributedBackend"
    assert call["n_jobs"] == 2
    assert sorted(call["nthreads"].values()) == [1, 1]  # two single-threaded workers
    with pytest.raises(_Stop):  # the default backend again once the command is done
        main([*argv, "--n-jobs", "1"])
    assert calls[1]["backend"] != "DaskDistributedBackend"


def test_reproduce_backend_dask_connects_to_a_scheduler(reproduce_spy):
    from skcath._cli import main

    argv, calls = reproduce_spy
    with distributed.LocalCluster(
        n_workers=3, threads_per_worker=1, processes=False, dashboard_address=None
    ) as cluster:
        with pytest.raises(_Stop):
            main([*argv, "--backend", "dask", "--scheduler", cluster.scheduler_address])
    (call,) = calls
    assert call["backend"] == "DaskDistributedBackend"
    assert len(call["nthreads"]) == 3


def test_reproduce_scheduler_needs_dask_backend(reproduce_spy, capsys):
    from skcath._cli import main

    argv, calls = reproduce_spy
    with pytest.raises(SystemExit) as excinfo:
        main([*argv, "--scheduler", "tcp://127.0.0.1:8786"])
    assert excinfo.value.code == 2
    assert "argument --scheduler: only with --backend dask or --backend ray" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main([*argv, "--backend", "spark"])
    assert "argument --backend: invalid choice" in capsys.readouterr().err
    assert calls == []


def test_ray_cluster_gives_the_local_results(data):
    """The same tiny protocol on a local Ray cluster (skipped without Ray)."""
    ray = pytest.importorskip("ray")
    from ray.util.joblib import register_ray

    X, y = data
    expected = run_protocol(X, y, schedule=TINY, exclude_settings=[EXCLUDED], n_jobs=1)
    register_ray()
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        with parallel_config(backend="ray"):
            result = run_protocol(X, y, schedule=TINY, exclude_settings=[EXCLUDED], n_jobs=2)
    finally:
        ray.shutdown()
    _assert_same(result, expected)
