"""The rays of the PDL calibration solved together: exactly the steps of the single solver."""

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from skcath.backbones import _pdl
from skcath.backbones._lm import (
    _batched_levenberg_marquardt,
    _solve_steps,
    levenberg_marquardt,
)
from skcath.backbones._pdl import calibrate_pdl
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
