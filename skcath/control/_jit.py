"""The model's inverse compiled by numba: the solve of :class:`~skcath.control._model.ModelInverse`.

Imported only for an estimator on the numba engine (it imports numba). The
solve runs the estimator's compiled step (:data:`skcath.online._jit.step_kernel`)
at candidate angles, restoring its state after each evaluation, exactly as
:meth:`ModelInverse.solve <skcath.control._model.ModelInverse.solve>` does in
Python, with the same steps and the same acceptance rule.
"""

from __future__ import annotations

import math

import numpy as np

from .._kernel import compiled
from ..online._jit import step_kernel
from ..online._layout import F_PLAY_WIDTH

__all__ = ["solve_kernel"]


def _tip(meta, a64, anet, w32, f0, buf0, z, torques, sample, out):
    """Model tip (mm) of the next sample at effective angles ``z``, into ``out``; the state restored.

    ``a64`` holds the step's ``f`` first and ``anet`` its ``buf`` first
    (:class:`~skcath.online._jit.JitStep`): ``f0`` and ``buf0`` are their saved states.
    """
    n = z.shape[0]
    for j in range(n):
        sample[j] = z[j]
    for j in range(torques.shape[0]):
        sample[n + j] = torques[j]
    a64[F_PLAY_WIDTH] = 0.0
    step_kernel(meta, a64, anet, w32, out, sample, False)
    a64[: f0.shape[0]] = f0
    anet[: buf0.shape[0]] = buf0


def _project(z, low, high, neutral, radius):
    """``z`` (deg) into the box, then radially into the disk, in place."""
    r2 = 0.0
    for j in range(z.shape[0]):
        z[j] = min(max(z[j], low[j]), high[j])
        r2 += (z[j] - neutral[j]) ** 2
    r = math.sqrt(r2)
    if r > radius:
        for j in range(z.shape[0]):
            z[j] = neutral[j] + (z[j] - neutral[j]) * (radius / r)


def _damped_step(J, r, mu, dz, A, b):
    """``dz = (J^T J + mu^2 I)^-1 J^T r`` by Gaussian elimination with partial pivoting."""
    n = dz.shape[0]
    for i in range(n):
        b[i] = 0.0
        for k in range(3):
            b[i] += J[k, i] * r[k]
        for j in range(n):
            s = 0.0
            for k in range(3):
                s += J[k, i] * J[k, j]
            A[i, j] = s + (mu * mu if i == j else 0.0)
    for c in range(n):
        p = c
        for i in range(c + 1, n):
            if abs(A[i, c]) > abs(A[p, c]):
                p = i
        for j in range(n):
            A[c, j], A[p, j] = A[p, j], A[c, j]
        b[c], b[p] = b[p], b[c]
        for i in range(c + 1, n):
            m = A[i, c] / A[c, c]
            for j in range(c, n):
                A[i, j] -= m * A[c, j]
            b[i] -= m * b[c]
    for i in range(n - 1, -1, -1):
        s = b[i]
        for j in range(i + 1, n):
            s -= A[i, j] * dz[j]
        dz[i] = s / A[i, i]


def _solve(arrays, f0, buf0, target, z, torques, limits, settings, tip, J):
    """The Levenberg-Marquardt solve; ``z``, ``tip`` and ``J`` are written in place."""
    meta, a64, anet, w32 = arrays
    low, high, neutral, radius = limits
    eps, max_iter, tol, damping = settings
    n = z.shape[0]
    sample = np.empty(n + torques.shape[0])
    trial_tip, r, dz, z_new = np.empty(3), np.empty(3), np.empty(n), np.empty(n)
    A, b = np.empty((n, n)), np.empty(n)
    _project(z, low, high, neutral, radius)
    _tip(meta, a64, anet, w32, f0, buf0, z, torques, sample, tip)
    cost = 0.0
    for k in range(3):
        r[k] = target[k] - tip[k]
        cost += r[k] * r[k]
    _jacobian(arrays, f0, buf0, z, torques, eps, tip, J, sample, trial_tip)
    mu = max(damping, 1e-6)
    for _ in range(int(max_iter)):
        _damped_step(J, r, mu, dz, A, b)
        moved = 0.0
        for j in range(n):
            z_new[j] = z[j] + dz[j]
        _project(z_new, low, high, neutral, radius)
        for j in range(n):
            moved = max(moved, abs(z_new[j] - z[j]))
        if moved < tol:
            break
        _tip(meta, a64, anet, w32, f0, buf0, z_new, torques, sample, trial_tip)
        cost_new = 0.0
        for k in range(3):
            cost_new += (target[k] - trial_tip[k]) ** 2
        if cost_new < cost:
            cost, mu = cost_new, mu / 3.0
            for j in range(n):
                z[j] = z_new[j]
            for k in range(3):
                tip[k] = trial_tip[k]
                r[k] = target[k] - tip[k]
            _jacobian(arrays, f0, buf0, z, torques, eps, tip, J, sample, trial_tip)
        else:
            mu *= 4.0


def _jacobian(arrays, f0, buf0, z, torques, eps, tip, J, sample, out):
    """Forward-difference Jacobian (mm/deg) at ``z``, whose tip is ``tip``, into ``J``."""
    meta, a64, anet, w32 = arrays
    for j in range(z.shape[0]):
        z[j] += eps
        _tip(meta, a64, anet, w32, f0, buf0, z, torques, sample, out)
        z[j] -= eps
        for k in range(3):
            J[k, j] = (out[k] - tip[k]) / eps


_helpers = {}


def solve_kernel():
    """The compiled solve (loaded from numba's cache when a previous process compiled it)."""
    if not _helpers:
        g = globals()
        for name in ("_tip", "_project", "_damped_step", "_jacobian"):
            g[name] = compiled(g[name])  # the solve calls them compiled
        _helpers["solve"] = compiled(_solve)
    return _helpers["solve"]
