"""Pickling a started ``skcath.online.OnlineEstimator``.

A started estimator keeps its recurrent state, its last sample and its
nominal tip as views into the kernels' buffers. A pickle must carry that
state: the loaded copy steps on exactly as the original would, ``reset``
of the copy resets the state the kernel uses, and ``nominal_`` keeps
following the steps. Checked on both engines, for the GRU (one and two
layers), the MLP, the backbone alone and a backbone with a play in front
(whose state travels too). A pickle holds the step ``start``
took from the pipeline: pickled after the pipeline was refit, the copy
steps as the original does (and warns that the pipeline changed).

The fixtures and helpers (tiny networks, one epoch on two shortened runs)
are those of ``test_online.py``.
"""

import copy
import pickle

import numpy as np
import pytest
from numpy.testing import assert_allclose

from skcath.backbones import PCCBackbone, PDLBackbone
from skcath.exceptions import PipelineChangedWarning
from skcath.online import OnlineEstimator
from test_online import (  # noqa: F401  (fixtures)
    ENGINES,
    _split,
    _stream,
    data,
    pipelines,
    played,
    transformed,
)

@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize(
    "Backbone, kind, params",
    [(PDLBackbone, "gru", {}), (PCCBackbone, "gru", {"module__num_layers": 2}),
     (PDLBackbone, "mlp", {}), (PCCBackbone, "none", {})],
    ids=["pdl-gru", "pcc-gru-2-layers", "pdl-mlp", "pcc-none"],
)
def test_pickled_estimator_steps_on_as_the_original(data, pipelines, engine, Backbone, kind,
                                                    params):
    _, _, X_run = data
    _check_round_trip(pipelines(Backbone, kind, **params), engine, X_run)


@pytest.mark.parametrize("engine", ENGINES)
def test_pickled_estimator_with_a_play_steps_on_as_the_original(data, played, engine):
    """The state of the play in front of the backbone travels with the pickle."""
    _, _, X_run = data
    est, clone = _check_round_trip(played(PDLBackbone, "gru")[0], engine, X_run)
    assert clone.play_width_ == est.play_width_ > 0.0


def _check_round_trip(pipe, engine, X_run):
    """A pickle taken after 40 steps steps on, resets and pickles again as the original.

    Returns the original estimator and its clone after those checks.
    """
    sweep, samples, _ = _split(X_run)
    est = OnlineEstimator(pipe, engine=engine).start(sweep)
    _stream(est, samples[:40])
    clone = pickle.loads(pickle.dumps(est))
    assert clone.engine_ == est.engine_ == engine
    assert clone.n_steps_ == 40
    assert_allclose(clone.nominal_, est.nominal_, rtol=0, atol=0)
    assert_allclose(clone.play_state_, est.play_state_, rtol=0, atol=0)
    # the state travelled: the next steps agree exactly
    ahead = _stream(est, samples[40:80])
    assert_allclose(_stream(clone, samples[40:80]), ahead, rtol=0, atol=0)
    # nominal_ still follows the clone's steps
    assert_allclose(clone.nominal_, est.nominal_, rtol=0, atol=0)
    # reset on the clone resets the state its kernel uses
    fresh = _stream(OnlineEstimator(pipe, engine=engine).start(sweep), samples[:30])
    assert_allclose(_stream(clone.reset(), samples[:30]), fresh, rtol=0, atol=0)
    # a second pickle of the original, which the first one left alone
    again = pickle.loads(pickle.dumps(est))
    assert_allclose(_stream(again, samples[80:90]), _stream(est, samples[80:90]), rtol=0, atol=0)
    return est, clone


def test_pickled_gru_state_is_not_the_start_state(data, pipelines):
    """The check above could pass with a zero state if the GRU forgot quickly: it does not."""
    _, _, X_run = data
    sweep, samples, _ = _split(X_run)
    pipe = pipelines(PDLBackbone, "gru")
    est = OnlineEstimator(pipe, engine="numpy").start(sweep)
    _stream(est, samples[:40])
    clone = pickle.loads(pickle.dumps(est))
    restarted = OnlineEstimator(pipe, engine="numpy").start(sweep)
    restarted._last[:] = list(est._last)  # same previous sample, zero hidden state
    assert np.abs(_stream(clone, samples[40:41]) - _stream(restarted, samples[40:41])).max() > 1e-6


@pytest.mark.parametrize("engine", ENGINES)
def test_pickled_unstarted_estimator(data, pipelines, engine):
    _, _, X_run = data
    sweep, samples, _ = _split(X_run)
    pipe = pipelines(PDLBackbone, "gru")
    clone = pickle.loads(pickle.dumps(OnlineEstimator(pipe, engine=engine, q_margin=0.5)))
    assert clone.get_params()["q_margin"] == 0.5
    with pytest.raises(Exception, match="has not been started"):
        clone.step(*samples[0])
    expected = _stream(OnlineEstimator(pipe, engine=engine).start(sweep), samples[:10])
    assert_allclose(_stream(clone.start(sweep), samples[:10]), expected, rtol=0, atol=0)


@pytest.mark.parametrize("engine", ENGINES)
def test_pickle_after_a_refit_keeps_the_step_of_start(data, pipelines, transformed, engine):
    """A pickle holds the step start took: the refit pipeline's weights do not mix in."""
    _, y, X_run = data
    sweep, samples, _ = _split(X_run)
    pipe = copy.deepcopy(pipelines(PDLBackbone, "mlp"))
    est = OnlineEstimator(pipe, engine=engine).start(sweep)
    _stream(est, samples[:20])
    pipe["residual"].set_params(random_state=1).fit(transformed[PDLBackbone][1], y)
    with pytest.warns(PipelineChangedWarning, match="was unpickled, but its pipeline"):
        clone = pickle.loads(pickle.dumps(est))
    assert_allclose(_stream(clone, samples[20:60]), _stream(est, samples[20:60]), rtol=0, atol=0)
    # the pickle carries the refit pipeline: started again, the copy steps it
    refit = _stream(OnlineEstimator(pipe, engine=engine).start(sweep), samples[:10])
    assert_allclose(_stream(clone.start(sweep), samples[:10]), refit, rtol=0, atol=0)
