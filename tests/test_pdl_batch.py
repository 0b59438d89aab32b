"""The rays of the PDL calibration solved together: exactly the steps of the single solver.

Also the width grids' calibrations (several played sweeps) solved in one batch, and the play's
and the PI's searches of a backbone with the grid batched against the grid calibrated in turn.
"""

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from skcath.backbones import PDLBackbone, _pdl, identify_play_width, play_operator
from skcath.backbones._lm import (
    _batched_levenberg_marquardt,
    _solve_steps,
    levenberg_marquardt,
)
from skcath.backbones._pdl import calibrate_pdl
from skcath.backbones._pdl_batch import _calibrate_pdl_batch
from skcath.datasets import simulate_run
from skcath.sweep import find_rays


def _assert_identical(a, b):
    (params_a, info_a), (params_b, info_b) = a, b
    for name in ("coef", "p0", "basis", "q_neutral", "directions"):
        assert_array_equal(getattr(params_a, name), getattr(params_b, name), strict=True)
    assert params_a.rho0 == params_b.rho0
    assert info_a.keys() == info_b.keys()
    for key in info_a:
        assert_array_equal(info_a[key], info_b[key], strict=True)


@pytest.fixture(scope="module", params=[0, 3])
def sweep(request):
    """A simulated hysteretic sweep, its rays found from the motor angles, rows of it lost."""
    X = simulate_run(random_state=request.param).X
    X = X[X["phase"] == "sweep"]
    q, p = X[["q1", "q2"]].to_numpy(), X[["ref_x", "ref_y", "ref_z"]].to_numpy().copy()
    rays = find_rays(q, n_rays=8)
    rng = np.random.default_rng(request.param)
    p[rng.random(len(p)) < 0.3] = np.nan  # rays of different lengths
    return q, p, rays


@pytest.mark.parametrize("max_iter", [8, 50])
def test_rays_together_equal_rays_one_by_one(sweep, max_iter):
    q, p, rays = sweep
    args = (q, p, rays.labels, rays.directions, rays.neutral)
    options = {"q_neutral": rays.q_neutral, "max_iter": max_iter, "return_info": True}
    together = calibrate_pdl(*args, **options)
    one_by_one = calibrate_pdl(*args, solver=levenberg_marquardt, **options)
    _assert_identical(together, one_by_one)
    # the rays stop after different numbers of steps; with 8, some at max_iter
    assert len(np.unique(together[1]["ray_n_iter"])) > 1
    assert together[1]["converged"] == (max_iter == 50)


def test_rays_together_from_perturbed_starts(sweep, monkeypatch):
    q, p, rays = sweep
    rng = np.random.default_rng(7)
    initial = _pdl._initial_ray_coef
    shifts = rng.uniform(-0.3, 0.3, (8, 6))
    calls = []

    def perturbed(*args):  # ray k of each calibration gets shifts[k]
        calls.append(None)
        return initial(*args) * (1.0 + shifts[(len(calls) - 1) % 8])

    monkeypatch.setattr(_pdl, "_initial_ray_coef", perturbed)
    args = (q, p, rays.labels, rays.directions, rays.neutral)
    together = calibrate_pdl(*args, q_neutral=rays.q_neutral, return_info=True)
    one_by_one = calibrate_pdl(*args, q_neutral=rays.q_neutral, return_info=True, solver=levenberg_marquardt)
    _assert_identical(together, one_by_one)


class _Exponentials:
    """Problems ``y_i ~ a exp(b t_i) + c`` of different sizes, for both solvers."""

    def __init__(self, sizes, rng):
        self.t = [np.linspace(0.0, 2.0, n) for n in sizes]
        self.y = [1.5 * np.exp(-0.7 * t) + 0.2 + rng.normal(0.0, 0.01, len(t)) for t in self.t]
        self.last = None

    def one(self, k):
        def fun(x, jac=True):
            r, J = self._eval(k, x)
            return (r, J) if jac else r

        return fun

    def _eval(self, k, x):
        t = self.t[k]
        e = np.exp(x[1] * t)
        return x[0] * e + x[2] - self.y[k], np.column_stack([e, x[0] * t * e, np.ones_like(t)])

    def residuals(self, ids, x):
        self.last = {k: self._eval(k, row) for k, row in zip(ids, x)}
        return [self.last[k][0] for k in ids]

    def jacobians(self, ids):
        return [self.last[k][1] for k in ids]


def test_batched_solver_equals_the_single_solver():
    problems = _Exponentials([5, 12, 40, 7], np.random.default_rng(0))
    x0 = np.array([[1.0, -0.1, 0.0], [3.0, -2.0, 1.0], [0.5, 0.5, 0.0], [1.5, -0.7, 0.2]])
    together = _batched_levenberg_marquardt(problems, x0, max_iter=30, ftol=1e-10)
    for k, result in enumerate(together):
        alone = levenberg_marquardt(problems.one(k), x0[k], max_iter=30, ftol=1e-10)
        assert_array_equal(result.x, alone.x, strict=True)
        assert (result.cost, result.n_iter, result.converged) == (alone.cost, alone.n_iter, alone.converged)
    assert len({result.n_iter for result in together}) > 1
    assert_array_equal(x0[0], [1.0, -0.1, 0.0])  # the start is not modified


def test_batched_solver_rejects_non_finite_start():
    problems = _Exponentials([5, 6], np.random.default_rng(1))
    with pytest.raises(ValueError, match="not finite at the initial parameters"):
        _batched_levenberg_marquardt(problems, np.array([[1.0, 0.0, 0.0], [np.nan, 0.0, 0.0]]))


def test_singular_system_is_solved_alone_with_growing_damping():
    A = np.stack([np.zeros((2, 2)), np.array([[2.0, 0.5], [0.5, 1.0]])])
    scale = np.stack([np.zeros((2, 2)), np.diag([2.0, 1.0])])
    g = np.array([[1.0, 1.0], [0.3, -0.2]])
    lam = np.array([1e-3, 1e-3])
    steps, ok = _solve_steps(A, scale, g, lam, [0, 1])
    assert_array_equal(ok, [False, True])
    assert lam[0] > 1e16 and lam[1] == 1e-3
    assert_array_equal(steps[1], np.linalg.solve(A[1] + 1e-3 * scale[1], -g[1]))


# ---------------------------------------------------------------------------
# the width grids' calibrations in one batch
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("max_iter", [8, 100])
def test_grid_batch_equals_each_calibration_alone(sweep, max_iter):
    q, p, rays = sweep
    qs = [play_operator(q, width) for width in (0.0, 2.0, 7.5, 14.0, 20.0)]
    args = (p, rays.labels, rays.directions, rays.neutral)
    batch = _calibrate_pdl_batch(qs, *args, q_neutral=rays.q_neutral, max_iter=max_iter)
    alone = [calibrate_pdl(z, *args, q_neutral=rays.q_neutral, max_iter=max_iter, return_info=True)
             for z in qs]
    assert len(batch) == len(qs)
    for a, b in zip(batch, alone):
        _assert_identical(a, b)
    # the widths' own rho0 (half their largest rho) differ: each ray kept its calibration's
    assert len({params.rho0 for params, _ in batch}) == len(qs)
    assert _calibrate_pdl_batch([], *args) == []


def _one_by_one(self, qs, ref, rays, q_raw):
    return [self._calibrate(q, ref, rays, q_raw) for q in qs]


@pytest.mark.parametrize("hysteresis", ["play", "pi"])
def test_batched_grid_equals_the_sequential_grid(hysteresis, monkeypatch):
    X = simulate_run(random_state=3).X
    batched = PDLBackbone(hysteresis=hysteresis).fit(X).calibrate(X)
    monkeypatch.setattr(PDLBackbone, "_calibrate_many", _one_by_one)
    sequential = PDLBackbone(hysteresis=hysteresis).fit(X).calibrate(X)
    assert batched.table.equals(sequential.table)
    assert_array_equal(batched.nominal, sequential.nominal, strict=True)
    assert batched.play_widths == sequential.play_widths
    (run,) = batched.params
    _assert_identical((batched.params[run], {}), (sequential.params[run], {}))


def test_grid_callable_is_asked_for_the_grid():
    asked = []

    def cost(w):
        return (w - 7.3) ** 2

    def grid(widths):
        asked.append(list(widths))
        return [cost(w) for w in widths]

    assert identify_play_width(cost, 20.0, grid) == identify_play_width(cost, 20.0)
    assert asked == [[2.0 * k for k in range(11)]]
    with pytest.raises(ValueError, match="grid_rmse must return one RMSE"):
        identify_play_width(cost, 20.0, lambda widths: [0.0])
