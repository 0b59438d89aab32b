"""The path of a sweep through ``OnlineEstimator.start``: checked once, layered.

``start`` checks the sweep's rows once (``skcath.online._sweep.check_sweep``)
and passes their arrays down: the backbone's calibration, the sweep brought
to the residual's rate, the sweep frame and the context never check,
factorize or sort the rows again. The calls are traced with
``sys.setprofile`` (``tests/module_trace.py``, which defines *entering*,
*below* and *re-entering*); ``benchmarks/trace_start_path.py`` prints the
same trace.
"""

import pytest
from sklearn.pipeline import Pipeline

from skcath.backbones import PCCBackbone, PDLBackbone, PolynomialBackbone
from skcath.online import OnlineEstimator, ShaftChangeDetector
from skcath.residuals import GRUResidual, MLPResidual

from _helpers import instrument, tiny_residual
from module_trace import ModuleTracer

TRAIN_SETTINGS = ("S02", "S09")
TEST_SETTING = "S05"


@pytest.fixture(scope="module")
def data():
    """Training rows (two shortened runs) and the sweep rows of a third run."""
    X, y = instrument(2, TRAIN_SETTINGS, n_motion=300)
    run, _ = instrument(2, (TEST_SETTING,), n_motion=0)
    return X, y, run[(run["phase"] == "sweep").to_numpy()]


def _started_trace(pipe, sweep, **params):
    """The :class:`ModuleTracer` of ``OnlineEstimator(pipe, **params).start(sweep)``, and the estimator."""
    OnlineEstimator(pipe, engine="numpy", **params).start(sweep)  # imports, first-call caches
    estimator = OnlineEstimator(pipe, engine="numpy", **params)
    with ModuleTracer() as tracer:
        estimator.start(sweep)
    return tracer, estimator


CASES = {
    "PDL + GRU": (PDLBackbone, GRUResidual, {}),
    "PCC + MLP, base frame": (PCCBackbone, MLPResidual, {"frame": "base", "use_torque": False}),
    "polynomial + GRU": (PolynomialBackbone, GRUResidual, {}),
}


@pytest.mark.parametrize("every", [1, 2], ids=["at the model's rate", "resampled"])
@pytest.mark.parametrize("case", list(CASES))
def test_start_checks_the_sweep_once_and_never_goes_back_up(data, case, every):
    X, y, sweep = data
    Backbone, Residual, params = CASES[case]
    pipe = Pipeline([("backbone", Backbone()),
                     ("residual", tiny_residual(Residual, max_epochs=1, **params))]).fit(X, y)
    tracer, estimator = _started_trace(pipe, sweep.iloc[::every])
    assert estimator.resampled_ == (every > 1)

    entries = tracer.entries("_validation")
    assert len(entries) <= 2, entries
    assert [callee for _, callee in entries][0] == "_validation.check_recordings"
    assert tracer.visits("_validation") == 1
    assert tracer.re_entries() == []
    # the rows are assigned to runs and sorted by run once, inside check_recordings
    assert tracer.entries("_runs") == []
    # the sweep is brought to the model's rate once, from its times
    assert [callee for _, callee in tracer.entries("_rate")] == ["_rate.run_at_rate"]


def test_a_detector_starts_on_the_checked_sweep_without_another_check(data):
    X, y, sweep = data
    pipe = Pipeline([("backbone", PDLBackbone()),
                     ("residual", tiny_residual(GRUResidual, max_epochs=1))]).fit(X, y)
    tracer, estimator = _started_trace(pipe, sweep, detector=ShaftChangeDetector())
    assert hasattr(estimator.detector_, "coef_")
    assert len(tracer.entries("_validation")) <= 2
    assert tracer.re_entries() == []


def test_the_tracer_sees_a_module_that_is_called_back_into():
    # a call from _validation_columns back into _validation, which called it
    tracer = ModuleTracer()
    tracer.crossings = [
        (0, "online._sweep.check_sweep", "_validation.check_recordings", False),
        (1, "_validation.check_recordings", "_validation_columns.factorize_ids", False),
        (2, "_validation_columns.factorize_ids", "_validation.check_target", True),
        (0, "online._estimator._start", "_runs.run_codes", False),
        (1, "_runs.run_codes", "_validation_columns.factorize_ids", False),
    ]
    tracer._callers = [object() for _ in tracer.crossings]
    assert tracer.re_entries() == [
        ("_validation.check_recordings", "_validation_columns.factorize_ids"),
        ("_validation_columns.factorize_ids", "_validation.check_target"),
    ]
    # entries from outside the family: from online._sweep and from _runs
    assert [caller for caller, _ in tracer.entries("_validation")] == [
        "online._sweep.check_sweep", "_runs.run_codes",
    ]


def test_the_tracer_leaves_out_the_solver_callbacks(data):
    X, y, sweep = data
    pipe = Pipeline([("backbone", PDLBackbone())]).fit(X, y)
    tracer, _ = _started_trace(pipe, sweep)
    solver = [(caller, callee) for _, caller, callee, _ in tracer.crossings
              if caller.startswith("backbones._lm.")]
    assert solver == []  # its calls of the objective are callbacks
    assert any(callee.startswith("backbones._lm.") for _, _, callee, _ in tracer.crossings)
    assert tracer.re_entries() == []
