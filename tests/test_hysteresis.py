"""Tests of the play operator and of backbones with ``hysteresis="play"``.

The play kernel and its row loop against a plain Python reference, compiled
and as Python; width 0 leaves the angles as they are; the search of the
half-width; the exact width recovered from a recording generated through a
play; on a simulated run, the play lowers the sweep and motion RMSE of PDL
and PCC; the identification reads sweep rows only; ``calibrate`` and
``predict`` keep nothing; the default leaves the backbones as they were;
invalid parameters.
"""

import joblib
import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose, assert_array_equal
from sklearn.base import clone
from sklearn.utils._param_validation import InvalidParameterError

from skcath.backbones import (
    PCCBackbone,
    PCCParams,
    PDLBackbone,
    identify_play_width,
    pcc_tip,
    pdl_tip,
    play_kernel,
    play_operator,
)
from skcath.backbones._pcc import _so3_exp
from skcath.datasets import make_benchmark
from skcath.datasets._protocol import random_walk_trajectory, sweep_trajectory
from skcath.metrics import per_run_rmse

REF = ["ref_x", "ref_y", "ref_z"]
TIP = {PCCBackbone: pcc_tip, PDLBackbone: pdl_tip}


def _reference_play(q, width):
    """The play written out plainly, one motor and one row at a time."""
    z = np.empty_like(q)
    state = list(q[0])
    for t in range(len(q)):
        for i in range(2):
            if q[t, i] - width > state[i]:
                state[i] = q[t, i] - width
            elif q[t, i] + width < state[i]:
                state[i] = q[t, i] + width
            z[t, i] = state[i]
    return z


def _walk(seed, n=3000):
    rng = np.random.default_rng(seed)
    return np.cumsum(rng.normal(0.0, 1.5, (n, 2)), axis=0) + rng.uniform(-5, 5, 2)


# ---------------------------------------------------------------------------
# the operator
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("width", [0.25, 3.0, 11.5])
def test_play_operator_matches_a_plain_reference(width):
    q = _walk(0)
    z = play_operator(q, width)
    assert_allclose(z, _reference_play(q, width), rtol=0, atol=1e-12)
    assert np.abs(z - q).max() <= width + 1e-12
    assert np.abs(z - q).max() > 0.9 * width  # the play is taken up somewhere
    assert_array_equal(z[0], q[0])


def test_play_kernel_is_one_step():
    assert play_kernel(0.0, 5.0, 2.0) == 3.0  # pulled up
    assert play_kernel(3.0, 4.0, 2.0) == 3.0  # within the play: stays
    assert play_kernel(3.0, -1.0, 2.0) == 1.0  # pulled down
    assert play_kernel(-7.5, 1.25, 0.0) == 1.25


def test_play_as_python_equals_the_compiled_play(monkeypatch):
    """Without numba the same loop runs as Python, with the same result."""
    import skcath.backbones._hysteresis as hysteresis

    q = _walk(1)
    compiled = play_operator(q, 4.0)
    monkeypatch.setattr(hysteresis, "compiled", lambda func: None)
    assert_array_equal(play_operator(q, 4.0), compiled)


def test_width_zero_is_the_identity_bit_for_bit():
    q = _walk(2)
    assert_array_equal(play_operator(q, 0.0), q)
    assert_array_equal(play_operator(q[:1], 5.0), q[:1])
    assert play_operator(np.empty((0, 2)), 1.0).shape == (0, 2)


def test_play_operator_leaves_its_input_unchanged():
    q = _walk(3)
    before = q.copy()
    play_operator(q, 2.0)
    assert_array_equal(q, before)


@pytest.mark.parametrize(
    "q, width, error, match",
    [
        (np.zeros((5, 3)), 1.0, ValueError, r"q must have shape \(n, 2\)"),
        (np.array([[0.0, np.nan]]), 1.0, ValueError, "q must be finite"),
        (np.zeros((5, 2)), -1.0, InvalidParameterError, "'width'"),
        (np.zeros((5, 2)), np.inf, InvalidParameterError, "'width'"),
        (np.zeros((5, 2)), "1", InvalidParameterError, "'width'"),
    ],
    ids=["shape", "nan", "negative-width", "infinite-width", "text-width"],
)
def test_play_operator_rejects_bad_input(q, width, error, match):
    with pytest.raises(error, match=match):
        play_operator(q, width)


# ---------------------------------------------------------------------------
# the search of the half-width
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("best", [0.0, 0.7, 5.3, 13.95, 20.0])
def test_identify_play_width_finds_the_minimum(best):
    calls = []

    def cost(w):
        calls.append(w)
        return 1.0 + (w - best) ** 2

    width = identify_play_width(cost, 20.0)
    assert 0.0 <= width <= 20.0
    assert width == pytest.approx(best, abs=0.1)
    assert width in calls  # the width returned was evaluated
    assert len(calls) < 30


def test_identify_play_width_never_fits_worse_than_no_play():
    # a cost that rises from 0 with a dip of its own between the grid widths
    cost = lambda w: 1.0 + w - 0.5 * np.exp(-(((w - 3.0) / 0.3) ** 2))  # noqa: E731
    assert identify_play_width(cost, 20.0) == 0.0


def test_identify_play_width_with_a_range_below_one_grid_step():
    width = identify_play_width(lambda w: (w - 0.4) ** 2, 1.0)
    assert width == pytest.approx(0.4, abs=0.1)


# ---------------------------------------------------------------------------
# backbones with a play, on a recording generated through a play
# ---------------------------------------------------------------------------
def _played_recording(width, seed=0):
    """One run whose references are a known PCC backbone on the played angles."""
    rng = np.random.default_rng(seed)
    q_sweep = sweep_trajectory()
    q_motion = random_walk_trajectory(rng, 800, n_steps=40, radius_deg=60.0)
    q = np.vstack([q_sweep, q_motion])
    truth = PCCParams(C=[[1.2, 0.1], [-0.05, 1.1]], q0=[0.0, 0.0], u0=[0.02, -0.03], S_m=60.0,
                      L=55.0, R_g=_so3_exp(np.array([0.2, -0.1, 0.3])))
    p = pcc_tip(play_operator(q, width), truth)
    n, n_sweep = len(q), len(q_sweep)
    ref = p.copy()
    ref[n_sweep:] = np.nan
    X = pd.DataFrame({
        "catheter": "C9", "setting": "S1", "run": "played", "t": 0.1 * np.arange(n),
        "phase": ["sweep"] * n_sweep + ["motion"] * (n - n_sweep),
        "q1": q[:, 0], "q2": q[:, 1],
        "tau1": np.sin(0.01 * np.arange(n)), "tau2": np.cos(0.01 * np.arange(n)),
        "ref_x": ref[:, 0], "ref_y": ref[:, 1], "ref_z": ref[:, 2],
    })
    return X, p


def test_the_width_of_a_played_recording_is_recovered():
    X, p = _played_recording(5.3)
    est = PCCBackbone(hysteresis="play").fit(X)
    calibration = est.calibrate(X)
    width = calibration.play_widths["played"]
    assert width == pytest.approx(5.3, abs=0.1)
    assert calibration.table.loc["played", "play_width_deg"] == width
    assert calibration.table.loc["played", "rmse_mm"] < 0.1
    motion = (X["phase"] == "motion").to_numpy()
    assert np.linalg.norm(calibration.nominal - p, axis=1)[motion].max() < 0.5
    # the nominal tips are the parameters on the played angles of the whole run
    params = calibration.params["played"]
    q = X[["q1", "q2"]].to_numpy()
    assert_allclose(calibration.nominal, pcc_tip(play_operator(q, width), params), rtol=0,
                    atol=1e-9)
    # without the play the same recording is fitted much worse
    without = PCCBackbone().fit(X).calibrate(X)
    assert without.table.loc["played", "rmse_mm"] > 10 * calibration.table.loc["played",
                                                                               "rmse_mm"]
    assert without.play_widths == {"played": 0.0}
    assert (without.table["play_width_deg"] == 0.0).all()


# ---------------------------------------------------------------------------
# on the simulated benchmark
# ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """One bent-shaft run of the simulated benchmark (default mechanism): X, y."""
    bench = make_benchmark(n_catheters=1, n_runs=1, cache=True,
                           data_home=tmp_path_factory.mktemp("skcath_data"))
    rows = (bench.X["run"] == bench.X["run"].unique()[2]).to_numpy()
    return bench.X[rows].reset_index(drop=True), np.asarray(bench.y)[rows]


@pytest.fixture(scope="module")
def calibrations(run):
    """calibrate() of each backbone with and without the play, on ``run``."""
    X, _ = run
    return {(Est, h): Est(hysteresis=h).fit(X).calibrate(X)
            for Est in (PCCBackbone, PDLBackbone) for h in (None, "play")}


@pytest.mark.parametrize("Est", [PCCBackbone, PDLBackbone])
def test_play_lowers_sweep_and_motion_rmse(Est, run, calibrations):
    X, y = run
    plain, played = calibrations[Est, None], calibrations[Est, "play"]
    name = X["run"].iloc[0]
    width = played.play_widths[name]
    assert 0.5 < width < 20.0  # within the search range, not at a bound
    assert played.table.loc[name, "rmse_mm"] < 0.8 * plain.table.loc[name, "rmse_mm"]
    motion_rmse = {h: per_run_rmse(y, c.nominal, X).loc[name] for h, c in
                   ((None, plain), ("play", played))}
    assert motion_rmse["play"] < 0.9 * motion_rmse[None]


@pytest.mark.parametrize("Est", [PCCBackbone, PDLBackbone])
def test_identification_reads_sweep_rows_only(Est, run, calibrations):
    X, y = run
    motion = (X["phase"] == "motion").to_numpy()
    rng = np.random.default_rng(0)
    for values in (y[motion], rng.normal(0.0, 100.0, (motion.sum(), 3))):
        X2 = X.copy()
        X2.loc[motion, REF] = values
        calibration = Est(hysteresis="play").fit(X2).calibrate(X2)
        expected = calibrations[Est, "play"]
        assert calibration.play_widths == expected.play_widths
        assert_array_equal(calibration.nominal, expected.nominal)
    # and the motion rows' angles do not move the width
    X3 = X.copy()
    X3.loc[motion, ["q1", "q2"]] *= 0.5
    assert Est(hysteresis="play").fit(X3).calibrate(X3).play_widths == expected.play_widths


@pytest.mark.parametrize("Est", [PCCBackbone, PDLBackbone])
def test_predict_and_calibrate_keep_nothing_and_change_no_input(Est, run, calibrations):
    X, y = run
    X_before, y_before = X.copy(deep=True), y.copy()
    est = Est(hysteresis="play").fit(X)
    state = joblib.hash(vars(est))
    assert_array_equal(est.predict(X), calibrations[Est, "play"].nominal)
    Xt = est.transform(X)
    assert_array_equal(Xt[["b_x", "b_y", "b_z"]].to_numpy(), calibrations[Est, "play"].nominal)
    assert joblib.hash(vars(est)) == state
    pd.testing.assert_frame_equal(X, X_before)
    assert_array_equal(y, y_before)
    # a clone calibrates alike
    assert_array_equal(clone(est).fit(X).predict(X), calibrations[Est, "play"].nominal)


@pytest.mark.parametrize("Est", [PCCBackbone, PDLBackbone])
def test_default_is_the_backbone_without_play(Est, run, calibrations):
    X, _ = run
    assert Est().get_params()["hysteresis"] is None
    plain = calibrations[Est, None]
    name = X["run"].iloc[0]
    q = X[["q1", "q2"]].to_numpy()
    assert_array_equal(plain.nominal, TIP[Est](q, plain.params[name]))


@pytest.mark.parametrize("Est", [PCCBackbone, PDLBackbone])
@pytest.mark.parametrize(
    "params",
    [{"hysteresis": "backlash"}, {"hysteresis": True}, {"max_play_deg": 0.0},
     {"max_play_deg": -2.0}, {"max_play_deg": np.inf}, {"max_play_deg": 400.0},
     {"max_play_deg": "20"}],
)
def test_invalid_hysteresis_parameters_raise_at_fit(Est, params, run):
    X, _ = run
    est = Est(**params)
    with pytest.raises(InvalidParameterError, match=next(iter(params))):
        est.fit(X)
