"""The gallery examples run headless, and those of the user's path give the right numbers."""

import os
import runpy
from pathlib import Path

import numpy as np
import pytest

from skcath.metrics import mean_per_run_rmse, per_run_rmse

EXAMPLES = sorted((Path(__file__).resolve().parents[1] / "examples").rglob("plot_*.py"))


def _constant_rmse(y, X, train, test):
    """Mean per-run RMSE (mm) on ``test`` of the mean tip of the motion rows of ``train``."""
    motion = (X["phase"] == "motion").to_numpy()
    rows = np.zeros(len(X), dtype=bool)
    rows[train] = True
    mean_tip = np.nanmean(y[rows & motion], axis=0)
    return mean_per_run_rmse(y[test], np.broadcast_to(mean_tip, (len(test), 3)), X.iloc[test])


def _check_streaming(ns):
    # the stream is predict, sample for sample, up to the torque dropout
    clean = ns["clean"]
    assert np.abs(ns["tips"][clean] - ns["offline"][clean]).max() < 1e-4
    # and tracks the tip: far below the spread of the run's tip about its mean
    motion = ns["is_motion"]
    y_run = ns["y_run"][motion]
    error = np.sqrt(np.nanmean(np.sum((ns["tips"] - y_run) ** 2, axis=1)))
    spread = np.sqrt(np.nanmean(np.sum((y_run - np.nanmean(y_run, axis=0)) ** 2, axis=1)))
    assert error < 0.5 * spread
    # the exported step's inputs: 9 step features, the sweep frame, the context
    # and the GRU's hidden state of the example's 32 units
    inputs, outputs = ns["inputs"], ns["outputs"]
    assert list(inputs) == ["features", "rotation", "context", "hidden"]
    assert inputs["features"] == (1, 9) and inputs["rotation"] == (3, 3)
    assert inputs["hidden"][1:] == (1, 32)
    assert outputs == {"residual": (1, 3), "hidden_out": inputs["hidden"]}


def _check_own_recordings(ns):
    # the tip read from the exported files is the simulator's (6 decimals written)
    X, y = ns["X"], ns["y"]
    for run_id, sim in ns["simulated"].items():
        in_run = (X["run"] == run_id).to_numpy()
        assert (np.isnan(y[in_run]) == np.isnan(np.asarray(sim.y))).all()
        assert np.nanmax(np.abs(y[in_run] - sim.y)) < 1e-3
        assert (X.loc[in_run, "phase"].to_numpy() == sim.X["phase"].to_numpy()).all()
    # the backbone calibrated on each run's sweep is far better than the mean tip
    # (measured: 9.1 and 6.1 mm against 21.2 and 12.2 mm)
    motion = (X["phase"] == "motion").to_numpy()
    rmse = per_run_rmse(y, ns["nominal"], X)
    constant = per_run_rmse(y, np.broadcast_to(np.nanmean(y[motion], axis=0), y.shape), X)
    assert (rmse < 0.65 * constant).all()


def _check_group_cross_validation(ns):
    X, y = ns["X"], np.asarray(ns["y"])
    # every splitter holds each run out at most once, and the straight S00 never
    s00 = np.isin(ns["runs"], ns["data"].runs.loc[ns["data"].runs["setting"] == "S00", "run"])
    for cv in ns["splitters"].values():
        held_out = ns["fold_matrix"](cv) == 2
        assert held_out.sum(axis=0).max() == 1
        assert not held_out[:, s00].any()
    # each fold of each pipeline is far better than the mean tip of its training runs
    for result in ns["scores"].values():
        folds = zip(result["test_score"], result["indices"]["train"], result["indices"]["test"])
        for score, train, test in folds:
            assert -score < 0.5 * _constant_rmse(y, X, train, test)


#: Checks of the numbers of the examples on the user's path, by file name.
CHECKS = {
    "plot_streaming.py": _check_streaming,
    "plot_own_recordings.py": _check_own_recordings,
    "plot_group_cross_validation.py": _check_group_cross_validation,
}


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.name)
def test_example_runs(path, tmp_path, monkeypatch):
    """Each example executes top to bottom with a non-interactive backend."""
    matplotlib = pytest.importorskip("matplotlib")
    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    monkeypatch.setenv("SKCATH_DATA", os.environ.get("SKCATH_TEST_DATA", str(tmp_path)))
    monkeypatch.setattr(plt, "show", lambda *args, **kwargs: None)
    try:
        namespace = runpy.run_path(str(path), run_name="__main__")
        assert plt.get_fignums(), f"{path.name} made no figure"
    finally:
        plt.close("all")
    if path.name in CHECKS:
        CHECKS[path.name](namespace)


def test_examples_found():
    """The gallery is not empty, and every checked example is in it."""
    assert EXAMPLES
    assert set(CHECKS) <= {path.name for path in EXAMPLES}
