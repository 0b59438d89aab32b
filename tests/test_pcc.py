"""Tests of the PCC backbone: model, analytic Jacobian and calibration."""

import dataclasses
import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skcath.backbones._pcc import (
    PCC_FREE_PARAMETERS,
    PCCParams,
    calibrate_pcc,
    pcc_jacobian,
    pcc_tip,
)
from skcath.datasets import simulate_run
from skcath.datasets._protocol import sweep_trajectory

E_Z = np.array([0.0, 0.0, 1.0])


def rot(rotvec):
    """Rotation matrix of a rotation vector (rad), independent of the module."""
    return Rotation.from_rotvec(np.asarray(rotvec, dtype=float)).as_matrix()


def tilted(tilt_deg, azimuth_deg, roll_deg=0.0):
    """``exp([w1, w2, 0]^) R_z(roll)`` tilting e_z by ``tilt_deg`` towards ``azimuth_deg``."""
    t, a = np.deg2rad(tilt_deg), np.deg2rad(azimuth_deg)
    return rot(t * np.array([-np.sin(a), np.cos(a), 0.0])) @ rot([0.0, 0.0, np.deg2rad(roll_deg)])


def reference_tip(q, prm):
    """Eq. pcc written naively (valid away from alpha = 0)."""
    u = (np.atleast_2d(q) - prm.q0) / prm.S_m @ prm.C.T + prm.u0
    a = np.linalg.norm(u, axis=1)
    h = np.column_stack([u * ((1 - np.cos(a)) / a**2)[:, None], np.sin(a) / a])
    return prm.L * h @ prm.R_g.T


def random_params(seed, *, q0_scale=3.0):
    """Random PCC parameters: any C (rotations, axis swaps, sign flips), tilt <= 40 deg."""
    rng = np.random.default_rng(seed)
    ang = rng.uniform(0, 2 * np.pi)
    C = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
    C = C @ np.diag(rng.uniform(0.4, 2.0, 2))
    if rng.random() < 0.5:
        C = C @ np.array([[0.0, 1.0], [1.0, 0.0]])
    C = np.diag(rng.choice([-1.0, 1.0], 2)) @ C + rng.normal(0, 0.15, (2, 2))
    return PCCParams(
        C=C,
        q0=rng.normal(0, q0_scale, 2),
        u0=rng.normal(0, 0.2, 2),
        S_m=60.0,
        L=rng.uniform(40, 70),
        R_g=tilted(rng.uniform(0, 40), rng.uniform(0, 360), rng.uniform(-180, 180)),
    )


def roll_of(R):
    """2-D rotation Q with R = (roll-free tilt) R_z, so that R_z h(u) = h(Q u)."""
    n = R[:, 2]
    t = np.arctan2(np.hypot(n[0], n[1]), n[2])
    axis = np.array([-n[1], n[0], 0.0]) / np.hypot(n[0], n[1])
    Rz = rot(t * axis).T @ R
    return Rz[:2, :2]


def sweep_data(prm):
    q = sweep_trajectory() + prm.q0
    return q, pcc_tip(q, prm)


def simulated_sweep(seed, setting="S01", **kwargs):
    X = simulate_run(random_state=seed, setting=setting, **kwargs).X
    s = X[X.phase == "sweep"]
    return s[["q1", "q2"]].to_numpy(copy=True), s[["ref_x", "ref_y", "ref_z"]].to_numpy(copy=True)


def as_vector(params):
    return np.array(list(params.to_dict().values()))


# ---------------------------------------------------------------------------
# model
# ---------------------------------------------------------------------------
def test_zero_bend_is_exact():
    prm = PCCParams(C=[[1.3, 0.2], [-0.4, 0.9]], q0=[2.0, -1.0], u0=[0.0, 0.0], S_m=60.0,
                    L=52.5, R_g=tilted(30, 70, 20))
    tip = pcc_tip(prm.q0, prm)
    assert tip.shape == (1, 3)
    np.testing.assert_array_equal(tip[0], prm.L * prm.R_g @ E_Z)
    tip, J = pcc_jacobian(prm.q0[None], prm)
    assert np.all(np.isfinite(J))


@pytest.mark.parametrize("alpha", [0.05, 0.7, 1.5, 1.999, 2.0, 2.5, 3.0])
def test_tip_matches_closed_form(alpha):
    prm = PCCParams(C=np.eye(2), q0=[0, 0], u0=alpha * np.array([0.6, -0.8]), S_m=60.0,
                    L=48.0, R_g=tilted(25, 200, 45))
    q = np.array([[0.0, 0.0], [1e-3, 2e-3], [-1e-3, 0.5e-3]])
    np.testing.assert_allclose(pcc_tip(q, prm), reference_tip(q, prm), rtol=1e-13, atol=1e-12)


@pytest.mark.parametrize("alpha", [1e-8, 1e-4])
def test_tip_small_bend_matches_series(alpha):
    d = np.array([0.8, 0.6])
    prm = PCCParams(C=np.eye(2), q0=[0, 0], u0=alpha * d, S_m=1.0, L=1.0, R_g=np.eye(3))
    f = 0.5 - alpha**2 / 24 + alpha**4 / 720
    s = 1.0 - alpha**2 / 6 + alpha**4 / 120
    np.testing.assert_allclose(pcc_tip([0.0, 0.0], prm)[0], [alpha * d[0] * f, alpha * d[1] * f, s],
                               rtol=1e-15, atol=0)


def test_continuous_across_series_threshold():
    d = np.array([0.6, 0.8])
    tips, jacs = [], []
    for alpha in (2.0 - 1e-13, 2.0, 2.0 + 1e-13):
        prm = PCCParams(C=np.eye(2), q0=[0, 0], u0=alpha * d, S_m=60.0, L=50.0, R_g=tilted(10, 30))
        tip, J = pcc_jacobian(np.zeros((1, 2)), prm)
        tips.append(tip)
        jacs.append(J)
    np.testing.assert_allclose(tips[0], tips[2], rtol=0, atol=1e-11)
    np.testing.assert_allclose(jacs[0], jacs[1], rtol=0, atol=1e-10)
    np.testing.assert_allclose(jacs[1], jacs[2], rtol=0, atol=1e-10)


def finite_difference_jacobian(q, prm, roll_deg):
    """Central differences of pcc_tip w.r.t. (C, u0, L, w) with the roll fixed."""
    n = prm.R_g[:, 2]
    t = np.arctan2(np.hypot(n[0], n[1]), n[2])
    w = t * np.array([-n[1], n[0]]) / np.hypot(n[0], n[1])
    theta = np.concatenate([prm.C.ravel(), prm.u0, [prm.L], w])

    def tip(th):
        return pcc_tip(q, PCCParams(
            C=th[:4].reshape(2, 2), q0=prm.q0, u0=th[4:6], S_m=prm.S_m, L=th[6],
            R_g=rot([th[7], th[8], 0.0]) @ rot([0, 0, np.deg2rad(roll_deg)])))

    J = np.empty((len(q), 3, 9))
    for k in range(9):
        h = 1e-6 * max(1.0, abs(theta[k]))
        e = np.zeros(9)
        e[k] = h
        J[:, :, k] = (tip(theta + e) - tip(theta - e)) / (2 * h)
    return J


@pytest.mark.parametrize("alpha", [0.0, 1e-8, 1e-3, 1.0, 2.0, 2.5])
@pytest.mark.parametrize("roll_deg", [0.0, 35.0])
def test_jacobian_matches_finite_differences(alpha, roll_deg):
    # Dyadic numbers: u = C v + u0 is exactly `alpha * d` (exactly 0 for alpha = 0).
    C = np.array([[1.25, -0.5], [0.75, 2.0]])
    q = np.array([[1.0, -0.5]])
    v = q / 2.0
    d = np.array([0.6, 0.8])
    u0 = alpha * d - v[0] @ C.T
    prm = PCCParams(C=C, q0=[0.0, 0.0], u0=u0, S_m=2.0, L=55.0, R_g=tilted(32, 120, roll_deg))
    tip, J = pcc_jacobian(q, prm)
    np.testing.assert_array_equal(tip, pcc_tip(q, prm))
    J_fd = finite_difference_jacobian(q, prm, roll_deg)
    scale = np.maximum(np.linalg.norm(J_fd, axis=(0, 1)), 1.0)
    err = np.linalg.norm(J - J_fd, axis=(0, 1)) / scale
    assert err.max() < 1e-6, dict(zip(PCC_FREE_PARAMETERS, err))


def test_jacobian_at_many_points():
    prm = random_params(3)
    q = np.random.default_rng(0).uniform(-60, 60, (50, 2)) + prm.q0
    tip, J = pcc_jacobian(q, prm)
    assert tip.shape == (50, 3) and J.shape == (50, 3, 9)
    roll = np.rad2deg(np.arctan2(roll_of(prm.R_g)[1, 0], roll_of(prm.R_g)[0, 0]))
    J_fd = finite_difference_jacobian(q, prm, roll)
    assert np.abs(J - J_fd).max() < 1e-6 * np.abs(J_fd).max()


# ---------------------------------------------------------------------------
# parameters
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("angle", [0.0, 1e-9, 0.3, 2.0, np.pi - 1e-9, np.pi])
def test_to_dict_round_trip(angle):
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    prm = PCCParams(C=[[1, 2], [3, 4]], q0=[1, 2], u0=[0.1, -0.2], S_m=60, L=50,
                    R_g=rot(angle * axis))
    d = prm.to_dict()
    assert list(d) == ["C11", "C12", "C21", "C22", "q0_1", "q0_2", "u0_1", "u0_2", "S_m", "L",
                       "rg_x", "rg_y", "rg_z"]
    json.dumps(d)
    back = PCCParams.from_dict(d)
    np.testing.assert_allclose(back.R_g, prm.R_g, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm([d["rg_x"], d["rg_y"], d["rg_z"]]), angle, atol=1e-12)
    np.testing.assert_array_equal(back.C, prm.C)


def test_params_validation_and_immutability():
    good = dict(C=np.eye(2), q0=[0, 0], u0=[0, 0], S_m=60.0, L=50.0, R_g=np.eye(3))
    for key, bad in [("C", np.eye(3)), ("q0", [0, 0, 0]), ("u0", [np.nan, 0]), ("S_m", 0.0),
                     ("L", -1.0), ("R_g", np.diag([1.0, 1.0, -1.0])), ("R_g", 2 * np.eye(3))]:
        with pytest.raises(ValueError, match=key):
            PCCParams(**{**good, key: bad})
    C = np.eye(2)
    prm = PCCParams(**{**good, "C": C})
    C[0, 0] = 5.0
    assert prm.C[0, 0] == 1.0
    with pytest.raises(ValueError):
        prm.C[0, 0] = 2.0


# ---------------------------------------------------------------------------
# calibration on exact PCC data
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("seed", range(6))
def test_recovers_noise_free_pcc(seed):
    true = random_params(seed)
    q, p = sweep_data(true)
    est, info = calibrate_pcc(q, p, q0=true.q0, S_m=true.S_m, return_info=True)
    assert info["converged"] and info["rmse_mm"] <= 1e-6
    assert info["n_samples"] == len(q)
    assert abs(est.L - true.L) <= 1e-6
    np.testing.assert_allclose(est.R_g @ E_Z, true.R_g @ E_Z, atol=1e-8)
    assert abs(est.to_dict()["rg_z"]) <= 1e-12  # no roll in the fitted rotation
    Q = roll_of(true.R_g)
    np.testing.assert_allclose(est.C, Q @ true.C, atol=1e-7)
    np.testing.assert_allclose(est.u0, Q @ true.u0, atol=1e-7)
    q_new = np.random.default_rng(seed + 100).uniform(-60, 60, (300, 2)) + true.q0
    np.testing.assert_allclose(pcc_tip(q_new, est), pcc_tip(q_new, true), rtol=0, atol=1e-6)


@pytest.mark.parametrize("C", [
    [[0.0, 1.5], [1.5, 0.0]],        # axis swap
    [[-1.2, 0.0], [0.0, 1.2]],       # sign flip (reflection)
    [[0.0, -1.0], [1.8, 0.0]],       # swap and flip
    [[0.9, -1.2], [1.2, 0.9]],       # rotation by 53 deg
])
def test_converges_for_any_coupling_and_40_deg_tilt(C):
    true = PCCParams(C=C, q0=[0, 0], u0=[0.15, -0.1], S_m=60.0, L=45.0, R_g=tilted(40, 250, 60))
    q, p = sweep_data(true)
    est, info = calibrate_pcc(q, p, return_info=True)
    assert info["rmse_mm"] <= 1e-6
    np.testing.assert_allclose(est.R_g @ E_Z, true.R_g @ E_Z, atol=1e-8)


def test_init_is_reexpressed_exactly():
    true = random_params(7)
    q, p = sweep_data(true)
    # init with other q0 / S_m and with a roll: calibration keeps the fixed gauge
    est, info = calibrate_pcc(q, p, q0=[0.0, 0.0], S_m=45.0, init=true, return_info=True)
    assert info["rmse_mm"] <= 1e-9 and info["n_iter"] <= 2
    np.testing.assert_array_equal(est.q0, [0.0, 0.0])
    assert est.S_m == 45.0
    q_new = np.random.default_rng(1).uniform(-50, 50, (100, 2))
    np.testing.assert_allclose(pcc_tip(q_new, est), pcc_tip(q_new, true), atol=1e-8)


def test_default_gauge():
    true = random_params(2, q0_scale=0.0)
    q, p = sweep_data(true)
    est = calibrate_pcc(q, p)
    np.testing.assert_array_equal(est.q0, [0.0, 0.0])
    assert est.S_m == pytest.approx(np.max(np.linalg.norm(q, axis=1)))


# ---------------------------------------------------------------------------
# masking and validation
# ---------------------------------------------------------------------------
def test_nan_rows_are_ignored():
    q, p = simulated_sweep(4)
    rng = np.random.default_rng(0)
    p_nan = p.copy()
    rows = rng.choice(len(p), 400, replace=False)
    p_nan[rows[:200]] = np.nan
    p_nan[rows[200:], rng.integers(0, 3, 200)] = np.nan  # partially missing rows
    keep = ~np.isnan(p_nan).any(axis=1)
    a, ia = calibrate_pcc(q, p_nan, return_info=True)
    b, ib = calibrate_pcc(q[keep], p[keep], return_info=True)
    np.testing.assert_array_equal(as_vector(a), as_vector(b))
    assert ia == ib and ia["n_samples"] == keep.sum()


def test_inputs_not_modified():
    q, p = simulated_sweep(5)
    p[::7, 1] = np.nan
    q0 = np.array([0.0, 0.0])
    init = calibrate_pcc(q, p)
    copies = q.copy(), p.copy(), q0.copy(), init.C.copy()
    calibrate_pcc(q, p, q0=q0, init=init)
    pcc_jacobian(q, init)
    for before, after in zip(copies, (q, p, q0, init.C)):
        np.testing.assert_array_equal(before, after)


def test_errors_name_the_argument():
    q, p = sweep_data(random_params(0, q0_scale=0.0))
    with pytest.raises(ValueError, match=r"q must have shape \(n, 2\)"):
        calibrate_pcc(np.column_stack([q, q[:, :1]]), p)
    with pytest.raises(ValueError, match=r"p must have shape \(n, 3\)"):
        calibrate_pcc(q, p[:, :2])
    with pytest.raises(ValueError, match="p has"):
        calibrate_pcc(q, p[:-1])
    with pytest.raises(ValueError, match="q must be finite"):
        calibrate_pcc(np.where(np.arange(len(q))[:, None] == 3, np.nan, q), p)
    rows = np.linspace(0, len(p) - 1, 10).astype(int)
    p_few = np.full_like(p, np.nan)
    p_few[rows[:9]] = p[rows[:9]]
    with pytest.raises(ValueError, match="at least 10"):
        calibrate_pcc(q, p_few)
    p_few[rows[9]] = p[rows[9]]
    calibrate_pcc(q, p_few)  # 10 rows are enough
    with pytest.raises(ValueError, match="S_m"):
        calibrate_pcc(q, p, S_m=-1.0)
    with pytest.raises(ValueError, match="q0"):
        calibrate_pcc(q, p, q0=[0.0])
    with pytest.raises(ValueError, match="p must not contain"):
        calibrate_pcc(q, np.where(np.arange(len(q))[:, None] == 3, np.inf, p))
    with pytest.raises(ValueError, match="max_iter"):
        calibrate_pcc(q, p, max_iter=0)
    with pytest.raises(TypeError, match="init"):
        calibrate_pcc(q, p, init={"L": 1.0})
    with pytest.raises(TypeError, match="params"):
        pcc_tip(q, {"L": 1.0})
    with pytest.raises(ValueError, match="q must have shape"):
        pcc_tip(np.zeros((4, 3)), random_params(0))


# ---------------------------------------------------------------------------
# simulated sweeps (not PCC: a few mm of model error)
# ---------------------------------------------------------------------------
# Measured fit RMSE / sweep spread (simulator version 6): S00 7.13 / 28.2 mm
# (0.25), S05 5.81 / 18.8 (0.31), S12 6.89 / 12.0 (0.58), S16 6.21 / 10.5 (0.59).
# On version 5 the loops of the unit of seed 3 at the high bend S16 exceeded 0.6
# of the spread (7.32 / 12.1 mm, 0.604); version 6 pulls that unit's parameters
# towards the family's middle and the ratio is 0.594, just inside the bound.
# Each case is held to its measured ratio plus a quarter (at most 0.6): a fit a
# quarter worse than measured fails.
@pytest.mark.parametrize(
    "seed, setting, measured_ratio",
    [(0, "S00", 0.25), (1, "S05", 0.31), (2, "S12", 0.58), (3, "S16", 0.594)],
)
def test_fits_simulated_sweep(seed, setting, measured_ratio):
    q, p = simulated_sweep(seed, setting, dropout_rate=0.02)
    prm, info = calibrate_pcc(q, p, return_info=True)
    assert info["converged"]
    # the simulator is not PCC and has ~10 mm hysteresis loops between the
    # outward and return strokes: the fit must still explain most of the motion
    keep = ~np.isnan(p).any(axis=1)
    spread = np.sqrt(np.mean(np.sum((p[keep] - p[keep].mean(axis=0)) ** 2, axis=1)))
    assert 0.3 < info["rmse_mm"] < min(1.25 * measured_ratio, 0.6) * spread
    assert 30.0 < prm.L < 90.0
    # the fit is a least-squares minimum: no small change of the free
    # parameters (C, u0, L) lowers the sweep error
    rng = np.random.default_rng(seed)
    for _ in range(20):
        trial = dataclasses.replace(
            prm,
            C=prm.C + rng.normal(0.0, 1e-3, (2, 2)),
            u0=prm.u0 + rng.normal(0.0, 1e-3, 2),
            L=prm.L * (1.0 + rng.normal(0.0, 1e-3)),
        )
        trial_rmse = np.sqrt(np.mean(np.sum((pcc_tip(q[keep], trial) - p[keep]) ** 2, axis=1)))
        assert trial_rmse >= info["rmse_mm"] * (1.0 - 1e-9)
    keep = ~np.isnan(p).any(axis=1)
    resid = np.linalg.norm(pcc_tip(q[keep], prm) - p[keep], axis=1)
    assert np.sqrt(np.mean(resid**2)) == pytest.approx(info["rmse_mm"], rel=1e-12)


@pytest.mark.parametrize("seed", [0, 6])
def test_sample_order_does_not_matter(seed):
    q, p = simulated_sweep(seed)
    a = calibrate_pcc(q, p)
    perm = np.random.default_rng(seed).permutation(len(q))
    b = calibrate_pcc(q[perm], p[perm])
    np.testing.assert_allclose(as_vector(a), as_vector(b), rtol=1e-8, atol=1e-8)
