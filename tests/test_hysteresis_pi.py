"""Tests of the Prandtl-Ishlinskii hysteresis and of backbones with ``hysteresis="pi"``.

The operator: one term is the play; weights and parameters are checked;
the inverse PI undoes the forward PI, the full inverse is a right inverse
with dead band and creep; the stepping forms equal the row forms and
continue them from the rows' final state; the creep
reads the times, not the sample count. The identification recovers a known
PI from a sweep simulated through it; a sweep too flat or too short falls
back to no hysteresis with a warning naming the run; a sweep without
hysteresis is not fitted. The streaming step with the PI is tested in
test_online_pi.py.
"""

import numpy as np
import pandas as pd
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from skcath.backbones import (
    PCCBackbone,
    PDLBackbone,
    PolynomialBackbone,
    PrandtlIshlinskii,
    pcc_tip,
    play_operator,
)
from skcath.backbones._pi import PI_GRID_FRACTIONS
from skcath.backbones._pi_sweep import soft_play

GRID = np.asarray(PI_GRID_FRACTIONS) * 20.0


def _walk(seed, n=3000, m=2):
    rng = np.random.default_rng(seed)
    return np.cumsum(rng.normal(0.0, 1.5, (n, m)), axis=0)


def _times(n, dt=0.1):
    return np.arange(n) * dt


def _model(**kw):
    args = dict(thresholds=GRID, weights=[0.4, 0.3, 0.2, 0.1], dead_band=1.5,
                asymmetry=[0.3, -0.2], creep_gain=0.2, creep_tau_s=3.0)
    args.update(kw)
    return PrandtlIshlinskii(**args)


# ---------------------------------------------------------------------------
# the operator
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("width", [0.0, 0.7, 6.0])
def test_one_term_pi_is_the_play(width):
    q = _walk(0)
    z = PrandtlIshlinskii.play(width).forward(q, _times(len(q)))
    assert_allclose(z, play_operator(q, width), rtol=0, atol=1e-12)


def test_zero_dead_band_on_the_first_threshold_is_the_identity():
    q = _walk(1)
    assert_array_equal(PrandtlIshlinskii.identity(GRID).forward(q, _times(len(q))), q)


@pytest.mark.parametrize(
    "kw, match",
    [
        (dict(weights=[0.5, -0.1, 0.3, 0.3]), "weights must be >= 0"),
        (dict(weights=[0.5, 0.1, 0.3, 0.3]), "sum to 1"),
        (dict(thresholds=[1.0, 2.0, 3.0, 4.0]), "thresholds must increase from 0"),
        (dict(dead_band=-1.0), "dead_band"),
        (dict(asymmetry=[0.95, 0.0]), "asymmetry"),
        (dict(creep_gain=0.7), "creep_gain"),
        (dict(creep_tau_s=0.0), "creep_tau_s"),
    ],
)
def test_parameters_are_checked(kw, match):
    with pytest.raises(ValueError, match=match):
        _model(**kw)


def test_inverse_undoes_the_pi_part():
    q = _walk(2)
    t = _times(len(q))
    for weights in ([0.4, 0.3, 0.2, 0.1], [1.0, 0.0, 0.0, 0.0], [0.2, 0.0, 0.5, 0.3]):
        model = _model(weights=weights, dead_band=0.0, asymmetry=[0.0, 0.0], creep_gain=0.0)
        assert_allclose(model.inverse(model.forward(q, t), t), q, rtol=0, atol=1e-9)
    # with creep too (no dead band): the creep's inverse is exact
    model = _model(dead_band=0.0, asymmetry=[0.0, 0.0])
    assert_allclose(model.inverse(model.forward(q, t), t), q, rtol=0, atol=1e-9)


@pytest.mark.parametrize("weights", [[0.4, 0.3, 0.2, 0.1], [0.0, 0.3, 0.0, 0.7]])
def test_inverse_is_a_right_inverse_with_dead_band_and_creep(weights):
    v = _walk(3)
    t = np.cumsum(np.random.default_rng(3).uniform(0.02, 0.2, len(v)))
    model = _model(weights=weights)
    q = model.inverse(v, t)
    assert_allclose(model.forward(q, t), v, rtol=0, atol=1e-9)
    # the dead band is not invisible: the command leads the wanted angle
    assert np.abs(q - v).max() > 1.0


def test_inverse_weights_in_closed_form():
    r, u, extra = _model(weights=[0.5, 0.5, 0.0, 0.0]).inverse_terms()
    assert extra == 0.0
    assert_allclose(r, [0.0, 0.5 * GRID[1]])
    assert_allclose(u, [2.0, -1.0])  # 1 / w0, -w1 / (W1 W0)
    _, _, extra = _model(weights=[0.0, 0.0, 1.0, 0.0]).inverse_terms()
    assert extra == GRID[2]  # leading plays without weight are dead band


def test_stepping_forms_equal_the_rows():
    model = _model()
    q = _walk(4, n=500)
    t = _times(len(q))
    state, out = model.initial_state(q[0]), []
    for i in range(len(q)):
        before = state.copy()
        new, v = model.step(state, q[i], t[i] - t[i - 1] if i else 0.0)
        assert_array_equal(state, before)  # state in, state out
        state = new
        out.append(v)
    assert_allclose(np.array(out), model.forward(q, t), rtol=0, atol=1e-12)
    state, out = model.initial_inverse_state(q[0]), []
    for i in range(len(q)):
        state, qi = model.inverse_step(state, q[i], t[i] - t[i - 1] if i else 0.0)
        out.append(qi)
    assert_allclose(np.array(out), model.inverse(q, t), rtol=0, atol=1e-12)


def test_rows_run_alike_as_python_and_compiled(monkeypatch):
    """The one row loop of the forward and inverse forms gives the same angles uncompiled."""
    from skcath.backbones import _pi

    model = _model()
    q = _walk(5, n=300)
    t = _times(len(q))
    v, back = model.forward(q, t), model.inverse(q, t)
    monkeypatch.setattr(_pi, "compiled", lambda func: None)
    assert_allclose(model.forward(q, t), v, rtol=0, atol=1e-12)
    assert_allclose(model.inverse(q, t), back, rtol=0, atol=1e-12)
    assert_allclose(model.forward(model.inverse(q, t), t), q, rtol=0, atol=1e-9)


@pytest.mark.parametrize("compiled", [True, False])
def test_forward_returns_the_state_the_step_continues_from(monkeypatch, compiled):
    """The rows' final state, stepped on, gives the rows of the whole run, compiled or not."""
    from skcath.backbones import _pi

    if not compiled:
        monkeypatch.setattr(_pi, "compiled", lambda func: None)
    model = _model()
    q = _walk(6, n=200)
    t = _times(len(q))
    head, state = model.forward(q[:120], t[:120], return_state=True)
    assert_array_equal(head, model.forward(q[:120], t[:120]))
    assert state.shape == (2 * (GRID.size + 2),)
    tail = []
    for i in range(120, len(q)):
        state, v = model.step(state, q[i], t[i] - t[i - 1])
        tail.append(v)
    assert_array_equal(np.vstack([head, tail]), model.forward(q, t))
    assert model.forward(q[:0], t[:0], return_state=True)[1] is None


def test_creep_reads_seconds_not_samples():
    """The same motion sampled at 10 and 100 Hz relaxes on the same time scale."""
    model = _model(dead_band=0.0, weights=[1.0, 0, 0, 0], creep_gain=0.3, creep_tau_s=2.0)
    t10, t100 = np.arange(0, 20, 0.1), np.arange(0, 20, 0.01)
    step10 = np.where(t10 >= 1.0, 10.0, 0.0)[:, None].repeat(2, axis=1)
    step100 = np.where(t100 >= 1.0, 10.0, 0.0)[:, None].repeat(2, axis=1)
    v10 = model.forward(step10, t10)[:, 0]
    v100 = model.forward(step100, t100)[:, 0]
    at = np.searchsorted(t100, t10[t10 >= 1.5])
    assert_allclose(v10[t10 >= 1.5], v100[at], atol=0.2)
    # overshoot by kappa / (1 - kappa) of the step, relaxed by exp(-1) after one tau
    overshoot = 10.0 * 0.3 / 0.7
    assert v100[np.searchsorted(t100, 3.0)] == pytest.approx(10.0 + overshoot / np.e, abs=0.1)
    assert abs(v10[-1] - 10.0) < 0.01


def test_forward_rejects_bad_input():
    model = _model()
    with pytest.raises(ValueError, match="t must have shape"):
        model.forward(np.zeros((5, 2)), np.zeros(4))
    with pytest.raises(ValueError, match="t must not decrease"):
        model.forward(np.zeros((3, 2)), [0.0, 1.0, 0.5])
    with pytest.raises(ValueError, match="2 motor"):
        model.forward(np.zeros((3, 3)), _times(3))
    q = _walk(5, n=10)
    before = q.copy()
    model.forward(q, _times(10))
    assert_array_equal(q, before)


# ---------------------------------------------------------------------------
# identification on a sweep simulated through a known PI
# ---------------------------------------------------------------------------
def _sweep(amplitude, n_per_leg=40):
    legs = []
    for k in range(8):
        d = np.array([np.cos(k * np.pi / 4), np.sin(k * np.pi / 4)])
        ramp = np.linspace(0.0, 1.0, n_per_leg)[:, None] * d * amplitude
        legs += [ramp, ramp[::-1], np.zeros((5, 2))]
    return np.concatenate([np.zeros((5, 2)), *legs])


def _recording(q, tips, run="R1"):
    n = len(q)
    return pd.DataFrame({
        "catheter": "C1", "setting": "S01", "run": run, "t": _times(n), "phase": "sweep", "q1": q[:, 0], "q2": q[:, 1],
        "tau1": 0.0, "tau2": 0.0,
        "ref_x": tips[:, 0], "ref_y": tips[:, 1], "ref_z": tips[:, 2],
    })


@pytest.fixture(scope="module")
def pcc_params():
    from skcath.backbones import PCCParams

    return PCCParams(C=np.array([[1.2, 0.1], [-0.05, 1.1]]), u0=np.zeros(2), L=60.0,
                     R_g=np.eye(3), q0=np.zeros(2), S_m=40.0)


def test_identification_recovers_a_known_pi(pcc_params):
    # a PI of the identified family: half the lag in the dead band, half in the plays
    true = soft_play(5.0, 0.5, max_play_deg=20.0)
    assert true.dead_band > 0 and true.weights[1] > 0
    q = _sweep(40.0)
    X = _recording(q, pcc_tip(true.forward(q, _times(len(q))), pcc_params))
    calibration = PCCBackbone(hysteresis="pi").fit(X).calibrate(X)
    found = calibration.hysteresis["R1"]
    assert calibration.table["rmse_mm"].iloc[0] < 0.05
    z_true, z_found = (m.forward(q, _times(len(q))) for m in (true, found))
    # the effective angles agree up to the scale the backbone absorbs
    scale = np.sum(z_found * z_true) / np.sum(z_true * z_true)
    assert np.abs(z_found - scale * z_true).max() < 0.2
    play = PCCBackbone(hysteresis="play").fit(X).calibrate(X)
    assert calibration.table["rmse_mm"].iloc[0] < play.table["rmse_mm"].iloc[0]
    assert {"pi_w0", "pi_dead_band_deg", "pi_creep_tau_s"} <= set(calibration.table.columns)


def test_no_hysteresis_is_not_fitted(pcc_params):
    q = _sweep(40.0)
    rng = np.random.default_rng(0)
    tips = pcc_tip(q, pcc_params) + rng.normal(0.0, 0.05, (len(q), 3))
    X = _recording(q, tips)
    found = PCCBackbone(hysteresis="pi").fit(X).calibrate(X).hysteresis["R1"]
    assert_array_equal(found.weights, np.eye(1, GRID.size).ravel())
    assert found.dead_band == 0.0 and found.creep_gain == 0.0


def test_a_flat_sweep_falls_back_with_a_warning(pcc_params):
    q = _sweep(8.0)  # reversals of 8 deg cannot show plays of 5 deg and more
    X = _recording(q, pcc_tip(q, pcc_params))
    with pytest.warns(UserWarning, match=r"run 'R1'.*without hysteresis"):
        calibration = PCCBackbone(hysteresis="pi", max_play_deg=40.0).fit(X).calibrate(X)
    assert calibration.hysteresis["R1"].dead_band == 0.0
    no = PCCBackbone().fit(X).calibrate(X)
    assert_allclose(calibration.nominal, no.nominal, atol=1e-9)


def test_a_short_sweep_falls_back_with_a_warning():
    from skcath.backbones._pi import SweepProblem
    from skcath.backbones._pi_sweep import identify_sweep_pi

    q = _sweep(40.0)[:30]
    target = np.column_stack([q, np.zeros(len(q))])

    def calibrate(z):  # a linear backbone fitted by least squares
        coef = np.linalg.lstsq(z, target, rcond=None)[0]
        return coef, {"rmse_mm": float(np.sqrt(np.mean((z @ coef - target) ** 2)))}

    problem = SweepProblem([(q, _times(len(q)))], target, calibrate, lambda z, c: z @ c)
    with pytest.warns(UserWarning, match=r"30 rows .* too few to identify.*run 'R1'"):
        model, _, _ = identify_sweep_pi(problem, max_play_deg=20.0, n_motors=2, where="run 'R1'")
    assert model.dead_band == 0.0 and model.weights[0] == 1.0


def test_polynomial_fit_with_pi_lowers_the_error_of_a_looped_recording():
    true = PrandtlIshlinskii(GRID, [0.3, 0.4, 0.3, 0.0], dead_band=1.0, asymmetry=[0.0, 0.0])
    t = _times(1200)
    q = np.column_stack([40.0 * np.sin(2 * np.pi * t / 30.0), np.zeros_like(t)])
    z = true.forward(q, t)
    tips = np.column_stack([z[:, 0], 0.01 * z[:, 0] ** 2, np.zeros_like(t)])
    X = _recording(q, tips)
    X.loc[20:, "phase"] = "motion"
    y = X[["ref_x", "ref_y", "ref_z"]].to_numpy()
    plain = PolynomialBackbone(calibration="fit").fit(X, y)
    pi = PolynomialBackbone(calibration="fit", hysteresis="pi").fit(X, y)
    error = [np.sqrt(np.mean(np.sum((b.predict(X) - y) ** 2, axis=1))) for b in (plain, pi)]
    assert error[1] < 0.2 * error[0]
    assert pi.hysteresis_.weights[0] < 1.0


def test_default_backbones_have_no_hysteresis_columns(pcc_params):
    q = _sweep(40.0)
    X = _recording(q, pcc_tip(q, pcc_params))
    calibration = PDLBackbone().fit(X).calibrate(X)
    assert not any(c.startswith("pi_") for c in calibration.table.columns)
    assert "hysteresis" not in calibration


def test_polynomial_sweep_calibration_with_pi(pcc_params):
    true = PrandtlIshlinskii(GRID, [0.5, 0.0, 0.5, 0.0], dead_band=2.0, asymmetry=[0.0, 0.0])
    q = _sweep(40.0)
    X = _recording(q, pcc_tip(true.forward(q, _times(len(q))), pcc_params))
    plain = PolynomialBackbone(degree=4).fit(X).calibrate(X)
    pi = PolynomialBackbone(degree=4, hysteresis="pi").fit(X).calibrate(X)
    assert pi.table["rmse_mm"].iloc[0] < 0.5 * plain.table["rmse_mm"].iloc[0]
    assert pi.hysteresis["R1"].dead_band > 0.5
    assert "hysteresis" not in plain and "pi_w0" not in plain.table


def test_soft_play_keeps_the_loop_width_and_is_the_play_without_softness():
    q = np.column_stack([30.0 * np.sin(np.linspace(0.0, 6 * np.pi, 400)), np.zeros(400)])
    t = _times(len(q))
    assert_array_equal(soft_play(4.0, 0.0, 20.0).forward(q, t),
                       PrandtlIshlinskii.play(4.0).forward(q, t))
    soft = soft_play(6.0, 0.8, 20.0)
    assert soft.dead_band + np.sum(soft.weights * soft.thresholds) == pytest.approx(6.0)
    # after a long travel the lag of the effective angle is the loop half-width
    ramp = np.column_stack([np.linspace(0.0, 60.0, 200), np.zeros(200)])
    assert ramp[-1, 0] - soft.forward(ramp, _times(200))[-1, 0] == pytest.approx(6.0)
    with pytest.raises(ValueError, match="softness"):
        soft_play(1.0, 0.8, 20.0)  # the dead band would be negative


def test_pdl_identifies_the_pi_by_its_own_calibration(pcc_params):
    # PDL's calibration fits every ray on its own rows: the PI it keeps is the
    # one of the lowest such RMSE, so a soft loop beats the play's
    true = soft_play(5.0, 0.6, max_play_deg=20.0)
    q = _sweep(40.0)
    X = _recording(q, pcc_tip(true.forward(q, _times(len(q))), pcc_params))
    pi = PDLBackbone(hysteresis="pi").fit(X).calibrate(X)
    play = PDLBackbone(hysteresis="play").fit(X).calibrate(X)
    assert pi.table["rmse_mm"].iloc[0] < 0.95 * play.table["rmse_mm"].iloc[0]
    assert pi.hysteresis["R1"].weights[1] > 0.1
