"""Tests of skcath.backbones._pdl: the per-direction linear (PDL) backbone."""

import dataclasses
import json

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from skcath.backbones import _pdl
from skcath.backbones._lm import levenberg_marquardt
from skcath.backbones._pdl import COEF_NAMES, PDLParams, calibrate_pdl, pdl_tip
from skcath.datasets import simulate_run
from skcath.datasets._protocol import sweep_trajectory

TWO_PI = 2.0 * np.pi
AMPLITUDE = 60.0


# ---------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------
def _wrap(angle):
    return (np.asarray(angle, dtype=float) + np.pi) % TWO_PI - np.pi


def _directions(first_deg=0.0, n_rays=8):
    """Commanded ray directions (rad), wrapped into [-pi, pi) and sorted."""
    return np.sort(_wrap(np.deg2rad(first_deg + 360.0 * np.arange(n_rays) / n_rays)))


def _labels(q, q_neutral, directions):
    """Ray index of each sample from the known trajectory; neutral where q = q_n."""
    v = q - q_neutral
    rho = np.hypot(v[:, 0], v[:, 1])
    psi = np.arctan2(v[:, 1], v[:, 0])
    labels = np.argmin(np.abs(_wrap(psi[:, None] - directions[None, :])), axis=1)
    neutral = rho < 1e-9
    labels[neutral] = -1
    return labels, neutral


def _sweep(first_deg=0.0, q_neutral=(0.0, 0.0)):
    """Sweep trajectory with its labels: q (n, 2), labels, neutral, directions."""
    q_neutral = np.asarray(q_neutral, dtype=float)
    directions = _directions(first_deg)
    traj = sweep_trajectory(amplitude_deg=AMPLITUDE, first_direction_deg=first_deg)
    labels, neutral = _labels(traj, np.zeros(2), directions)
    return traj + q_neutral, labels, neutral, directions


def _random_params(rng, directions, *, q_neutral=(0.0, 0.0), mirrored=False):
    """Plausible parameters: gamma up to ~1.4 rad and d up to ~45 mm at rho = 60 deg.

    ``d = (1 + m) P gamma / 2 + e rho^2`` with ``m > 0`` and ``e >= 0`` keeps
    ``d > P sin(gamma / 2)`` (positive discriminant) on every ray and, by
    convexity, between rays. ``phi0`` follows ``psi`` (or ``-psi`` when
    mirrored) with a common offset and a little scatter.
    """
    n_rays = len(directions)
    p0 = np.array([2.0, -23.0, 48.0]) + rng.normal(0.0, 4.0, 3)
    big_p = np.linalg.norm(p0)
    a_g = rng.uniform(0.012, 0.02, n_rays)
    gamma_end = rng.uniform(0.8, 1.4, n_rays)
    b_g = (gamma_end - AMPLITUDE * a_g) / AMPLITUDE**2
    margin = rng.uniform(0.03, 0.3, (n_rays, 2))
    a_d = (1.0 + margin[:, 0]) * big_p * a_g / 2.0
    b_d = (1.0 + margin[:, 0]) * big_p * b_g / 2.0 + margin[:, 1] * 1e-3
    sign = -1.0 if mirrored else 1.0
    phi0 = sign * directions + rng.uniform(-np.pi, np.pi) + rng.normal(0.0, 0.1, n_rays)
    phi0 += _wrap(phi0[0]) - phi0[0]  # first offset in [-pi, pi), as calibrate_pdl returns it
    s_phi = rng.uniform(-0.004, 0.004, n_rays)
    return PDLParams(
        p0=p0,
        basis=_pdl._neutral_basis(p0),
        q_neutral=np.asarray(q_neutral, dtype=float),
        directions=directions,
        coef=np.column_stack([a_g, b_g, a_d, b_d, phi0, s_phi]),
        rho0=AMPLITUDE / 2.0,
    )


def _rmse(a, b):
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


def _assert_coef_close(estimated, truth, rtol=1e-6):
    """Coefficients equal to ``rtol`` relative to the scale of each column."""
    scale = np.max(np.abs(truth), axis=0)
    err = np.max(np.abs(estimated - truth), axis=0)
    assert np.all(err <= rtol * scale), dict(zip(COEF_NAMES, err / scale))


def _assert_same_params(a, b, rtol=1e-12):
    for name in ("p0", "basis", "q_neutral", "directions", "coef"):
        assert_allclose(getattr(a, name), getattr(b, name), rtol=rtol, atol=1e-12, err_msg=name)
    assert a.rho0 == pytest.approx(b.rho0, rel=rtol)


def _on_direction(rho, psi, q_neutral=(0.0, 0.0)):
    rho = np.atleast_1d(np.asarray(rho, dtype=float))
    psi = np.broadcast_to(np.asarray(psi, dtype=float), rho.shape)
    return np.asarray(q_neutral) + np.column_stack([rho * np.cos(psi), rho * np.sin(psi)])


def _ray_tip(params, rho, c):
    return _pdl._tip_from_coef(np.asarray(rho, dtype=float), c, params.p0, params.basis, params.rho0)


# ---------------------------------------------------------------------------
# exact per-ray data
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_exact_data_recovered(seed):
    rng = np.random.default_rng(seed)
    q, labels, neutral, directions = _sweep()
    truth = _random_params(rng, directions)
    p = pdl_tip(q, truth)
    est, info = calibrate_pdl(q, p, labels, directions, neutral, return_info=True)
    assert _rmse(pdl_tip(q, est), p) <= 1e-6
    assert info["rmse_mm"] <= 1e-6
    _assert_coef_close(est.coef, truth.coef)
    _assert_same_params(est, truth, rtol=1e-9)
    assert info["converged"]


@pytest.mark.parametrize("mirrored", [False, True])
def test_start_direction_and_neutral_offset(mirrored):
    rng = np.random.default_rng(7)
    q_n = np.array([1.5, -2.0])
    q, labels, neutral, directions = _sweep(first_deg=22.5, q_neutral=q_n)
    assert_allclose(np.rad2deg(directions), -157.5 + 45.0 * np.arange(8))
    truth = _random_params(rng, directions, q_neutral=q_n, mirrored=mirrored)
    p = pdl_tip(q, truth)
    est = calibrate_pdl(q, p, labels, directions, neutral)
    assert_allclose(est.q_neutral, q_n, atol=1e-12)
    assert _rmse(pdl_tip(q, est), p) <= 1e-6
    _assert_coef_close(est.coef, truth.coef)
    steps = np.diff(est.coef[:, 4])
    assert np.all(steps < 0) if mirrored else np.all(steps > 0)
    expected_winding = -TWO_PI if mirrored else TWO_PI
    assert _pdl._winding(est.coef[:, 4]) == pytest.approx(expected_winding)


def test_mirrored_winding_continuity_across_wrap():
    rng = np.random.default_rng(11)
    q, labels, neutral, directions = _sweep()
    truth = _random_params(rng, directions, mirrored=True)
    est = calibrate_pdl(q, pdl_tip(q, truth), labels, directions, neutral)
    rho = np.linspace(1.0, 60.0, 7)
    before = pdl_tip(_on_direction(rho, np.pi - 1e-9), est)
    after = pdl_tip(_on_direction(rho, -np.pi + 1e-9), est)
    assert np.max(np.abs(before - after)) < 1e-6


def test_row_order_does_not_matter():
    rng = np.random.default_rng(3)
    q, labels, neutral, directions = _sweep(first_deg=22.5)
    truth = _random_params(rng, directions)
    p = pdl_tip(q, truth) + rng.normal(0.0, 0.3, (len(q), 3))
    perm = rng.permutation(len(q))
    a = calibrate_pdl(q, p, labels, directions, neutral)
    b = calibrate_pdl(q[perm], p[perm], labels[perm], directions, neutral[perm])
    _assert_same_params(a, b, rtol=1e-6)


def test_refinement_recovers_from_a_perturbed_start(monkeypatch):
    rng = np.random.default_rng(5)
    q, labels, neutral, directions = _sweep()
    truth = _random_params(rng, directions)
    p = pdl_tip(q, truth)
    initial = _pdl._initial_ray_coef

    def perturbed(*args):
        c = initial(*args)
        return c * (1.0 + rng.uniform(-0.1, 0.1, c.shape)) + np.r_[0.0, 0.0, 0.0, 0.0, 0.05, 0.0]

    monkeypatch.setattr(_pdl, "_initial_ray_coef", perturbed)
    est, info = calibrate_pdl(q, p, labels, directions, neutral, return_info=True)
    assert info["rmse_mm"] <= 1e-6
    assert np.all(info["ray_n_iter"] > 2)
    _assert_coef_close(est.coef, truth.coef)


def test_constant_curvature_catheter_is_approximated():
    # noise-free constant-curvature arc (L = 50 mm, 1.5 rad at rho = 60 deg): not
    # exactly a PDL model, and its reconstruction is ill-conditioned at small
    # bends; measured fit RMSE 0.39 mm, 0.45 mm between rays
    from skcath.datasets._kinematics import sine_ratio, versine_ratio

    def arc(q):
        rho, psi = np.hypot(q[:, 0], q[:, 1]), np.arctan2(q[:, 1], q[:, 0])
        bend = 1.5 / 60.0 * rho
        lateral = 50.0 * versine_ratio(bend)
        return np.column_stack([lateral * np.cos(psi), lateral * np.sin(psi), 50.0 * sine_ratio(bend)])

    q, labels, neutral, directions = _sweep()
    params, info = calibrate_pdl(q, arc(q), labels, directions, neutral, return_info=True)
    assert info["rmse_mm"] < 0.5 and info["converged"]
    q_between = np.random.default_rng(0).uniform(-42.0, 42.0, (500, 2))
    assert _rmse(pdl_tip(q_between, params), arc(q_between)) < 0.6


# ---------------------------------------------------------------------------
# Jacobian
# ---------------------------------------------------------------------------
def _finite_difference(fun, c, step=1e-7):
    cols = []
    for j in range(c.shape[-1]):
        dc = np.zeros_like(c)
        dc[..., j] = step * max(1.0, np.max(np.abs(c[..., j])))
        cols.append((fun(c + dc) - fun(c - dc)) / (2.0 * dc[..., j].max()))
    return np.stack(cols, axis=-1)


@pytest.mark.parametrize("clamped", [False, True])
def test_coefficient_jacobian_matches_finite_differences(clamped):
    rng = np.random.default_rng(0)
    truth = _random_params(rng, _directions())
    rho = np.linspace(2.0, 60.0, 25)
    c = truth.coef[rng.integers(0, 8, len(rho))].copy()
    c[:, 5] = rng.uniform(-0.004, 0.004, len(rho))
    if clamped:  # d well below P sin(gamma / 2): the square root is clamped at 0
        c[:, 2:4] *= 0.3
    gamma, dist, _ = _pdl._responses(rho, c, truth.rho0)
    disc = dist**2 - (np.linalg.norm(truth.p0) * np.sin(gamma / 2.0)) ** 2
    assert np.all(disc < 0) if clamped else np.all(disc > 0)
    _, jac = _pdl._tip_from_coef(rho, c, truth.p0, truth.basis, truth.rho0, jac=True)
    fd = _finite_difference(lambda cc: _ray_tip(truth, rho, cc), c)
    assert_allclose(jac, fd, rtol=1e-5, atol=1e-6 * np.max(np.abs(fd)))


def test_ray_problem_jacobian_and_cost():
    rng = np.random.default_rng(1)
    truth = _random_params(rng, _directions())
    rho = rng.uniform(0.0, 60.0, 40)
    p_ref = _ray_tip(truth, rho, truth.coef[2]) + rng.normal(0.0, 0.5, (40, 3))
    problem = _pdl._RayProblem(rho, p_ref, truth.p0, truth.basis, truth.rho0)
    c = truth.coef[2] * 1.02
    res, jac = problem(c)
    # residuals in the rotated basis: same norm as the 3-D errors
    assert res @ res == pytest.approx(np.sum((_ray_tip(truth, rho, c) - p_ref) ** 2))
    assert_array_equal(problem(c, jac=False), res)
    fd = _finite_difference(lambda cc: problem(cc, jac=False), c)
    assert_allclose(jac, fd, rtol=1e-5, atol=1e-6 * np.max(np.abs(fd)))
    result = levenberg_marquardt(problem, c, ftol=1e-12)
    assert result.cost < 0.5 * res @ res


def test_finite_at_neutral_and_zero_distance():
    rng = np.random.default_rng(2)
    truth = _random_params(rng, _directions())
    c = np.tile(truth.coef[1], (4, 1))
    c[2:, 2:4] = 0.0  # d = 0 with gamma > 0: fully clamped
    rho = np.array([0.0, 0.0, 10.0, 60.0])
    p, jac = _pdl._tip_from_coef(rho, c, truth.p0, truth.basis, truth.rho0, jac=True)
    assert np.all(np.isfinite(p)) and np.all(np.isfinite(jac))
    assert_array_equal(p[:2], np.tile(truth.p0, (2, 1)))
    problem = _pdl._RayProblem(rho, np.tile(truth.p0, (4, 1)), truth.p0, truth.basis, truth.rho0)
    res, jac = problem(truth.coef[1])
    assert np.all(np.isfinite(res)) and np.all(np.isfinite(jac))


# ---------------------------------------------------------------------------
# interpolation between rays
# ---------------------------------------------------------------------------
@pytest.fixture(params=[0.0, 22.5], ids=["first-0", "first-22.5"])
def params(request):
    rng = np.random.default_rng(42)
    return _random_params(rng, _directions(request.param), q_neutral=(0.7, -1.1))


def test_query_on_a_ray_equals_that_ray(params):
    rho = np.linspace(0.5, 60.0, 9)
    for k, psi in enumerate(params.directions):
        p = pdl_tip(_on_direction(rho, psi, params.q_neutral), params)
        assert_allclose(p, _ray_tip(params, rho, params.coef[k]), atol=1e-9)


def test_halfway_uses_average_coefficients(params):
    rho = np.linspace(0.5, 60.0, 9)
    coef, n_rays = params.coef, params.n_rays
    for k in range(n_rays):
        upper = coef[(k + 1) % n_rays].copy()
        span = params.directions[(k + 1) % n_rays] - params.directions[k]
        if k == n_rays - 1:  # wrap-around: periodic continuation, phi0 one turn on
            upper[4] += TWO_PI
            span += TWO_PI
        psi = params.directions[k] + 0.5 * span
        p = pdl_tip(_on_direction(rho, psi, params.q_neutral), params)
        assert_allclose(p, _ray_tip(params, rho, 0.5 * (coef[k] + upper)), atol=1e-9)


def test_continuous_across_wrap_and_rays(params):
    rho = np.linspace(0.5, 60.0, 9)
    eps = 1e-9
    before = pdl_tip(_on_direction(rho, np.pi - eps, params.q_neutral), params)
    after = pdl_tip(_on_direction(rho, -np.pi + eps, params.q_neutral), params)
    assert np.max(np.abs(before - after)) < 1e-6
    for psi in params.directions:
        before = pdl_tip(_on_direction(rho, psi - eps, params.q_neutral), params)
        after = pdl_tip(_on_direction(rho, psi + eps, params.q_neutral), params)
        assert np.max(np.abs(before - after)) < 1e-6


def test_dense_direction_scan_has_no_jump(params):
    psi = np.linspace(-np.pi, np.pi, 20001)
    p = pdl_tip(_on_direction(np.full_like(psi, 45.0), psi, params.q_neutral), params)
    steps = np.linalg.norm(np.diff(p, axis=0), axis=1)
    assert steps.max() < 0.05  # about 45 mm of tip travel over 20000 steps


def test_offsets_shifted_by_whole_turns_give_the_same_tips(params):
    coef = np.array(params.coef)
    coef[3, 4] += TWO_PI
    coef[6, 4] -= 2.0 * TWO_PI
    shifted = PDLParams(params.p0, params.basis, params.q_neutral, params.directions, coef, params.rho0)
    psi = np.linspace(-np.pi, np.pi, 721)
    q = _on_direction(np.full_like(psi, 50.0), psi, params.q_neutral)
    assert_allclose(pdl_tip(q, shifted), pdl_tip(q, params), atol=1e-9)


def test_neutral_gives_p0_exactly(params):
    p = pdl_tip(np.array([params.q_neutral, params.q_neutral]), params)
    assert_array_equal(p, np.tile(params.p0, (2, 1)))


# ---------------------------------------------------------------------------
# parameters
# ---------------------------------------------------------------------------
def test_params_to_dict_round_trip_and_json(params):
    flat = params.to_dict()
    assert all(isinstance(v, (int, float)) for v in flat.values())
    assert flat["n_rays"] == 8 and "s_phi_7" in flat and "n0_z" in flat
    again = PDLParams.from_dict(json.loads(json.dumps(flat)))
    _assert_same_params(again, params, rtol=0.0)


def test_params_are_read_only_copies(params):
    coef = np.array(params.coef)
    copy = PDLParams(params.p0, params.basis, params.q_neutral, params.directions, coef, params.rho0)
    coef[0, 0] = 99.0
    assert copy.coef[0, 0] != 99.0
    with pytest.raises(ValueError):
        copy.coef[0, 0] = 1.0


def test_basis_is_orthonormal_and_right_handed():
    for p0 in ([2.0, -23.0, 48.0], [50.0, 1.0, 0.5], [0.0, 0.0, -40.0]):
        basis = _pdl._neutral_basis(p0)
        assert_allclose(basis @ basis.T, np.eye(3), atol=1e-15)
        assert_allclose(np.cross(basis[0], basis[1]), basis[2], atol=1e-15)
        assert_allclose(basis[2], np.asarray(p0) / np.linalg.norm(p0))


# ---------------------------------------------------------------------------
# missing references, inputs, errors
# ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def noisy_sweep():
    rng = np.random.default_rng(9)
    q, labels, neutral, directions = _sweep()
    truth = _random_params(rng, directions)
    p = pdl_tip(q, truth) + rng.normal(0.0, 0.5, (len(q), 3))
    return q, p, labels, neutral, directions


def test_nan_rows_ignored(noisy_sweep):
    q, p, labels, neutral, directions = noisy_sweep
    rng = np.random.default_rng(0)
    lost = rng.random(len(q)) < 0.1
    lost[np.flatnonzero(neutral)[:5]] = True
    p_nan = p.copy()
    p_nan[lost, rng.integers(0, 3, lost.sum())] = np.nan
    a, info_a = calibrate_pdl(q, p_nan, labels, directions, neutral, return_info=True)
    keep = ~lost
    b, info_b = calibrate_pdl(q[keep], p[keep], labels[keep], directions, neutral[keep], return_info=True)
    _assert_same_params(a, b)
    assert info_a["rmse_mm"] == pytest.approx(info_b["rmse_mm"], rel=1e-12)
    assert_array_equal(info_a["n_samples"], info_b["n_samples"])


def test_inputs_not_modified(noisy_sweep):
    q, p, labels, neutral, directions = noisy_sweep
    p = p.copy()
    p[::17] = np.nan
    args = (q.copy(), p.copy(), labels.copy(), directions.copy(), neutral.copy())
    params = calibrate_pdl(*args)
    for before, after in zip((q, p, labels, directions, neutral), args):
        assert_array_equal(before, after)
    q_eval = q.copy()
    pdl_tip(q_eval, params)
    assert_array_equal(q_eval, q)


def test_info_contents(noisy_sweep):
    q, p, labels, neutral, directions = noisy_sweep
    _, info = calibrate_pdl(q, p, labels, directions, neutral, return_info=True)
    assert set(info) >= {"cost", "rmse_mm", "ray_rmse_mm", "n_iter", "ray_n_iter", "converged"}
    assert info["ray_rmse_mm"].shape == (8,)
    n = info["n_samples"].sum()
    assert info["rmse_mm"] == pytest.approx(np.sqrt(2.0 * info["cost"] / n))
    assert info["rmse_mm"] == pytest.approx(0.5 * np.sqrt(3.0), rel=0.1)  # noise 0.5 mm per axis
    assert isinstance(info["n_iter"], int) and isinstance(info["converged"], bool)


def test_ray_with_too_few_references_is_named(noisy_sweep):
    q, p, labels, neutral, directions = noisy_sweep
    p = p.copy()
    ray = int(np.argmin(np.abs(directions - np.deg2rad(45.0))))
    rows = np.flatnonzero(labels == ray)
    p[rows[5:]] = np.nan  # five finite samples left
    with pytest.raises(ValueError, match=r"ray at 45\.0 deg has 5 .*at least 6"):
        calibrate_pdl(q, p, labels, directions, neutral)
    p[rows[:5]] = np.nan
    with pytest.raises(ValueError, match=r"ray at 45\.0 deg has 0 "):
        calibrate_pdl(q, p, labels, directions, neutral)


@pytest.mark.parametrize(
    "change, match",
    [
        (lambda a: {**a, "q": a["q"][:, :1]}, r"q must have shape \(n_samples, 2\)"),
        (lambda a: {**a, "p": a["p"][:-1]}, r"p must have shape"),
        (lambda a: {**a, "p": np.where(np.arange(len(a["p"]))[:, None] == 3, np.inf, a["p"])}, r"\+-inf"),
        (lambda a: {**a, "labels": a["labels"].astype(float)}, r"labels must be integers"),
        (lambda a: {**a, "labels": np.where(a["labels"] == 0, 8, a["labels"])}, r"labels must be -1 or a ray"),
        (lambda a: {**a, "neutral": a["neutral"].astype(int)}, r"neutral must be booleans"),
        (lambda a: {**a, "neutral": np.zeros_like(a["neutral"])}, r"No neutral row"),
        (lambda a: {**a, "directions": a["directions"][::-1]}, r"strictly increasing"),
        (lambda a: {**a, "directions": a["directions"] + np.pi}, r"\[-pi, pi\)"),
    ],
    ids=["q-shape", "p-shape", "p-inf", "labels-float", "labels-range", "neutral-int",
         "no-neutral", "directions-order", "directions-range"],
)
def test_errors_name_the_problem(noisy_sweep, change, match):
    q, p, labels, neutral, directions = noisy_sweep
    args = change({"q": q, "p": p, "labels": labels, "directions": directions, "neutral": neutral})
    with pytest.raises(ValueError, match=match):
        calibrate_pdl(args["q"], args["p"], args["labels"], args["directions"], args["neutral"])


def test_pdl_tip_rejects_bad_q(params):
    with pytest.raises(ValueError, match=r"q must have shape"):
        pdl_tip(np.zeros(2), params)
    with pytest.raises(ValueError, match=r"q must be finite; rows \[1\]"):
        pdl_tip(np.array([[0.0, 0.0], [np.nan, 1.0]]), params)


# ---------------------------------------------------------------------------
# simulated sweeps
# ---------------------------------------------------------------------------
def _simulated_sweep(seed):
    X = simulate_run(random_state=seed).X
    sweep = X[X["phase"] == "sweep"]
    return sweep[["q1", "q2"]].to_numpy(), sweep[["ref_x", "ref_y", "ref_z"]].to_numpy()


@pytest.fixture(scope="module", params=[0, 1])
def simulated(request):
    return _simulated_sweep(request.param)


def _spread(p):
    """RMS distance (mm) of the finite reference positions from their mean."""
    p = p[np.isfinite(p).all(axis=1)]
    return np.sqrt(np.mean(np.sum((p - p.mean(axis=0)) ** 2, axis=1)))


def test_simulated_sweep_rmse(simulated):
    q, p = simulated
    directions = _directions(0.0)  # commanded by the protocol, about q = 0
    labels, neutral = _labels(q, np.zeros(2), directions)
    params, info = calibrate_pdl(q, p, labels, directions, neutral, return_info=True)
    rmse = _rmse(pdl_tip(q, params), p)
    # tracker noise plus the hysteresis between outward and return strokes,
    # which a static backbone cannot follow: still most of the motion explained
    assert rmse < 0.45 * _spread(p)
    assert info["rmse_mm"] < 0.45 * _spread(p)  # over the ray samples only
    # each ray's coefficients are a least-squares minimum: no small change of
    # them lowers the sweep error
    rng = np.random.default_rng(0)
    for _ in range(20):
        coef = params.coef + rng.normal(0.0, 1e-4, params.coef.shape) * np.abs(params.coef).clip(1e-3)
        trial = dataclasses.replace(params, coef=coef)
        assert _rmse(pdl_tip(q, trial), p) >= rmse * (1.0 - 1e-7)
    assert info["converged"]
    assert np.all(np.isfinite(params.coef))


def test_simulated_sweep_with_find_rays(simulated):
    sweep = pytest.importorskip("skcath.sweep")
    if not hasattr(sweep, "find_rays"):
        pytest.skip("skcath.sweep.find_rays is not available")
    q, p = simulated
    rays = sweep.find_rays(q, n_rays=8)
    params, info = calibrate_pdl(
        q, p, rays.labels, rays.directions, rays.neutral, q_neutral=rays.q_neutral, return_info=True
    )
    assert rays.directions.shape == (8,)
    assert _rmse(pdl_tip(q, params), p) < 0.45 * _spread(p)
    assert info["converged"]
