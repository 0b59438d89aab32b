"""Damped Gauss-Newton (Levenberg-Marquardt) least squares for small problems.

The calibrations of skcath have a few to a few dozen parameters and a few
thousand residuals; the Jacobian is formed analytically by the model, so one
iteration is a handful of small matrix products and a p x p solve.
"""

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
