"""Damped Gauss-Newton (Levenberg-Marquardt) least squares for small problems.

The calibrations of skcath have a few to a few dozen parameters and a few
thousand residuals; the Jacobian is formed analytically by the model, so one
iteration is a handful of small matrix products and a p x p solve.
"""

import math
from dataclasses import dataclass
from numbers import Integral, Real

import numpy as np
from sklearn.utils._param_validation import Interval, validate_params

__all__ = ["LMResult", "levenberg_marquardt"]


@dataclass(frozen=True)
class LMResult:
    """Outcome of :func:`levenberg_marquardt`.

    Attributes
    ----------
    x : ndarray of shape (p,)
        Parameters at the lowest cost found.
    cost : float
        ``0.5 * sum(r**2)`` at ``x``.
    n_iter : int
        Number of Jacobian evaluations.
    converged : bool
        Whether a stopping tolerance was met before ``max_iter``.
    """

    x: np.ndarray
    cost: float
    n_iter: int
    converged: bool


@validate_params(
    {
        "fun": [callable],
        "x0": ["array-like"],
        "max_iter": [Interval(Integral, 1, None, closed="left")],
        "ftol": [Interval(Real, 0, None, closed="left")],
        "xtol": [Interval(Real, 0, None, closed="left")],
        "damping": [Interval(Real, 0, None, closed="neither")],
        "retract": [callable, None],
    },
    prefer_skip_nested_validation=True,
)
def levenberg_marquardt(
    fun,
    x0,
    *,
    max_iter=100,
    ftol=1e-12,
    xtol=1e-12,
    damping=1e-3,
    retract=None,
):
    """Minimise ``0.5 ||r(x)||^2`` by damped Gauss-Newton steps.

    Each iteration solves ``(J^T J + lambda diag(J^T J)) dx = -J^T r``
    (Marquardt's scaling) and accepts the step if the cost decreases, then
    shrinks ``lambda``; otherwise it grows ``lambda`` and tries again.

    Parameters
    ----------
    fun : callable
        ``fun(x, jac=True) -> (r, J)`` with ``r`` of shape (m,) and ``J`` of
        shape (m, p); ``fun(x, jac=False) -> r``.
    x0 : ndarray of shape (p,)
        Initial parameters.
    max_iter : int
        Largest number of accepted steps.
    ftol : float
        Stop when an accepted step lowers the cost by less than ``ftol``
        times the cost.
    xtol : float
        Stop when the step is smaller than ``xtol * (xtol + ||x||)``.
    damping : float
        Initial ``lambda``.
    retract : callable, optional
        ``retract(x, dx) -> x_new`` for parameters on a manifold (e.g. a
        rotation updated multiplicatively); default ``x + dx``.

    Returns
    -------
    result : LMResult
    """
    retract = retract or (lambda x, dx: x + dx)
    x = np.asarray(x0, dtype=float).copy()
    r, J = fun(x, jac=True)
    cost = 0.5 * float(r @ r)
    if not np.isfinite(cost):
        raise ValueError("the residuals are not finite at the initial parameters.")
    lam = damping
    n_iter = 1
    converged = False
    for it in range(max_iter):
        g = J.T @ r
        A = J.T @ J
        diag = np.maximum(np.diag(A), 1e-12 * max(1.0, np.max(np.diag(A))))
        while True:
            try:
                dx = np.linalg.solve(A + lam * np.diag(diag), -g)
            except np.linalg.LinAlgError:
                lam *= 10.0
                if lam > 1e16:  # no usable step: x is as good as it gets
                    return LMResult(x, cost, n_iter, True)
                continue
            x_new = retract(x, dx)
            r_new = fun(x_new, jac=False)
            cost_new = 0.5 * float(r_new @ r_new)
            if np.isfinite(cost_new) and cost_new <= cost:
                break
            lam *= 4.0
            if lam > 1e16:  # no descent step at any damping: a minimum
                return LMResult(x, cost, n_iter, True)
        small_step = np.linalg.norm(dx) <= xtol * (xtol + np.linalg.norm(x))
        small_gain = cost - cost_new <= ftol * cost
        x, cost = x_new, cost_new
        lam = max(lam / 3.0, 1e-12)
        if small_step or small_gain or cost == 0.0:
            converged = True
            break
        if it == max_iter - 1:
            break
        r, J = fun(x, jac=True)
        n_iter += 1
    return LMResult(x, cost, n_iter, converged)


def _norm(v):
    """``np.linalg.norm`` of a float vector, as it computes it (``sqrt(v . v)``), for one call."""
    return math.sqrt(v.dot(v))


def _solve_steps(A, scale, g, lam, ids):
    """Damped steps ``dx`` (rows) of the problems ``ids``, and which of them have one.

    Several problems: one stacked solve of ``(A + lam scale) dx = -g``,
    ``scale`` the diagonal matrix of Marquardt's scaling. One problem, or a
    singular system (the stacked solve raises): each system solved on its
    own, growing its ``lam`` tenfold until it solves, as
    :func:`levenberg_marquardt` does. ``lam`` is updated in place.

    Returns
    -------
    steps : ndarray of shape (len(ids), p)
    ok : ndarray of bool or None
        Which problems have a usable step; None when all have one.
    """
    if len(ids) > 1:
        try:
            M = A[ids] + lam[ids][:, None, None] * scale[ids]
            return np.linalg.solve(M, -g[ids][:, :, None])[:, :, 0], None
        except np.linalg.LinAlgError:
            pass
    steps, ok = np.empty((len(ids), A.shape[1])), None
    for i, k in enumerate(ids):
        while True:
            try:
                steps[i] = np.linalg.solve(A[k] + lam[k] * scale[k], -g[k])
                break
            except np.linalg.LinAlgError:
                lam[k] *= 10.0
                if lam[k] > 1e16:  # no usable step: x is as good as it gets
                    ok = np.ones(len(ids), dtype=bool) if ok is None else ok
                    ok[i] = False
                    break
    return steps, ok


class _BatchState:
    """Per-problem state of :func:`_batched_levenberg_marquardt`: normal equations, damping, counts."""

    def __init__(self, x, cost, residuals, jacobians, damping):
        n, p = x.shape
        self.x, self.cost = x, cost
        self.g, self.A, self.scale = np.empty((n, p)), np.empty((n, p, p)), np.empty((n, p, p))
        self.lam = np.full(n, float(damping))
        self.n_iter, self.it = [1] * n, [0] * n
        self.results = [None] * n
        self.linearise(range(n), residuals, jacobians)

    def linearise(self, ids, residuals, jacobians):
        """``J^T r``, ``J^T J`` and Marquardt's scaling (a diagonal matrix) of the problems ``ids``.

        Formed as :func:`levenberg_marquardt` forms them.
        """
        for k, r, J in zip(ids, residuals, jacobians):
            self.g[k] = J.T @ r
            self.A[k] = A = J.T @ J
            d = A.diagonal()
            self.scale[k] = np.diag(np.maximum(d, 1e-12 * max(1.0, d.max())))

    def finish(self, k, converged):
        """Record the result of problem ``k`` at its current parameters."""
        self.results[k] = LMResult(self.x[k].copy(), self.cost[k], self.n_iter[k], converged)


def _batched_levenberg_marquardt(problem, x0, *, max_iter=100, ftol=1e-12, xtol=1e-12, damping=1e-3):
    """:func:`levenberg_marquardt` on independent problems at once, step for step.

    Every problem takes exactly the steps (and gets exactly the result) of
    :func:`levenberg_marquardt` on it alone, without ``retract``: its
    reductions and its solve are those of the single solver; only the
    evaluations of the residuals are shared between the problems, so that
    their per-call cost is paid once per round of trial steps.

    Parameters
    ----------
    problem : object
        ``problem.residuals(ids, x) -> list`` of the residual vectors of the
        problems ``ids`` (list of int, increasing) at the rows of ``x`` (one
        row per id), and ``problem.jacobians(ids) -> list`` of their
        Jacobians at the parameters of the last ``residuals`` call, whose ids
        contain ``ids``.
    x0 : ndarray of shape (n_problems, p)
        Initial parameters.
    max_iter, ftol, xtol, damping
        As in :func:`levenberg_marquardt`.

    Returns
    -------
    results : list of LMResult
        One per problem.
    """
    x = np.array(x0, dtype=float, copy=True)
    pending = list(range(len(x)))
    residuals = problem.residuals(pending, x)
    cost = [0.5 * float(r @ r) for r in residuals]
    if not all(math.isfinite(c) for c in cost):
        raise ValueError("the residuals are not finite at the initial parameters.")
    state = _BatchState(x, cost, residuals, problem.jacobians(pending), damping)
    while pending:
        steps, ok = _solve_steps(state.A, state.scale, state.g, state.lam, pending)
        trial = pending
        if ok is not None:
            for k in np.asarray(pending)[~ok]:
                state.finish(k, True)
            trial, steps = [k for k, usable in zip(pending, ok) if usable], steps[ok]
        x_new = x[trial] + steps
        pending, going, accepted = [], [], []
        for k, dx, x_k, r_new in zip(trial, steps, x_new, problem.residuals(trial, x_new) if trial else []):
            cost_new = 0.5 * float(r_new @ r_new)
            if not (math.isfinite(cost_new) and cost_new <= cost[k]):
                state.lam[k] *= 4.0
                if state.lam[k] > 1e16:  # no descent step at any damping: a minimum
                    state.finish(k, True)
                else:
                    pending.append(k)
                continue
            small_step = _norm(dx) <= xtol * (xtol + _norm(x[k]))
            small_gain = cost[k] - cost_new <= ftol * cost[k]
            x[k], cost[k] = x_k, cost_new
            state.lam[k] = max(state.lam[k] / 3.0, 1e-12)
            if small_step or small_gain or cost_new == 0.0:
                state.finish(k, True)
            elif state.it[k] == max_iter - 1:
                state.finish(k, False)
            else:
                going.append(k)
                accepted.append(r_new)
        if going:
            state.linearise(going, accepted, problem.jacobians(going))
            for k in going:
                state.n_iter[k] += 1
                state.it[k] += 1
        pending = sorted(pending + going)
    return state.results
