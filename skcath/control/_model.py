"""The model's own step evaluated at candidate commands, and its inverse by Gauss-Newton.

:class:`ModelInverse` reads the packed step of a started
:class:`~skcath.online.OnlineEstimator` (the one function both engines run,
:func:`~skcath.online._kernels.step`) and evaluates it at candidate effective
motor angles from the estimator's present state, which it restores after
every evaluation: the tip the model predicts for the next sample. The play
in front of the backbone is bypassed there (its half-width set to 0 in the
copy), so that the angles evaluated are the effective angles the backbone
reads; the hysteresis is inverted afterwards (:mod:`skcath.control._hysteresis`).
"""

from __future__ import annotations

import numpy as np

from ..online._layout import F_PLAY_WIDTH

__all__ = ["ModelInverse", "damped_solve"]


def damped_solve(J, r, damping):
    """Damped least-squares step ``(J^T J + damping^2 I)^-1 J^T r``.

    Parameters
    ----------
    J : ndarray of shape (3, n_motors)
        Jacobian of the tip (mm/deg).
    r : ndarray of shape (3,)
        Tip error (mm).
    damping : float
        Damping ``lambda`` (mm/deg), ``>= 0``.

    Returns
    -------
    dz : ndarray of shape (n_motors,)
        Step of the effective angles (deg).
    """
    A = J.T @ J
    A.flat[:: A.shape[0] + 1] += damping * damping
    return np.linalg.solve(A, J.T @ r)


class ModelInverse:
    """Tip of the model's next step at candidate angles, its Jacobian and its inverse.

    Parameters
    ----------
    estimator : OnlineEstimator
        A started estimator; its state is read, and restored after every evaluation.
    project : callable
        ``project(z) -> z``: the effective angles brought within the motor limits (deg).
    eps_deg : float
        Step of the finite differences (deg).
    """

    def __init__(self, estimator, project, eps_deg, limits=None):
        self.estimator = estimator
        self.project = project
        self.eps = float(eps_deg)
        self._compiled = None
        if limits is not None and estimator.engine_ == "numba":
            from ._jit import solve_kernel

            self._compiled = solve_kernel()
            self._limits = (limits.low, limits.high, limits.neutral, limits.radius)
        packed = estimator._packed
        self._step = packed.call  # call(out, sample, check)
        # the compiled solve steps the engine's arrays as the estimator's step does
        self._arrays = (packed.meta, packed.a64, packed.anet, packed.w32) if self._compiled else None
        self._f, self._buf = packed.f, packed.buf
        self._f0, self._buf0 = packed.f.copy(), packed.buf.copy()
        self.n_motors = len(estimator.q_neutral_)
        self.n_evaluations = 0

    def begin(self, pending):
        """Advance the state by the commanded samples not observed yet; evaluations start from there.

        ``pending`` holds those samples (tuples of the channels), oldest
        first, stepped with the play in front of the backbone. The
        estimator's own state is kept aside and restored by :meth:`end`.
        """
        self._saved = (self._f.copy(), self._buf.copy())
        out = np.empty(3)
        for sample in pending:
            self._step(out, tuple(sample), False)
        np.copyto(self._f0, self._f)
        np.copyto(self._buf0, self._buf)

    def end(self):
        """Give the estimator back the state it had before :meth:`begin`."""
        np.copyto(self._f, self._saved[0])
        np.copyto(self._buf, self._saved[1])

    def tip(self, z, torques, out):
        """Model tip (mm) of the next sample at effective angles ``z`` (deg), into ``out``."""
        self._f[F_PLAY_WIDTH] = 0.0
        self._step(out, (*z.tolist(), *torques), False)
        np.copyto(self._f, self._f0)
        np.copyto(self._buf, self._buf0)
        self.n_evaluations += 1
        return out

    def jacobian(self, z, torques, tip):
        """Forward-difference Jacobian (3, n_motors) (mm/deg) at ``z``, whose tip is ``tip``."""
        J = np.empty((3, self.n_motors))
        out = np.empty(3)
        for j in range(self.n_motors):
            zj = z.copy()
            zj[j] += self.eps
            J[:, j] = (self.tip(zj, torques, out) - tip) / self.eps
        return J

    def solve(self, target, z0, torques, *, max_iter, tol_deg, damping):
        """Effective angles whose model tip is nearest ``target``, from ``z0``.

        Levenberg-Marquardt steps (damped least squares from ``damping``,
        projected onto the motor limits): a step that brings the tip closer
        is taken and the damping divided by 3, one that does not is refused
        and the damping multiplied by 4; until a step is below ``tol_deg`` or
        after ``max_iter`` trials.

        Returns
        -------
        z : ndarray of shape (n_motors,)
            Effective angles (deg), within the limits.
        tip : ndarray of shape (3,)
            Model tip at ``z`` (mm).
        J : ndarray of shape (3, n_motors)
            Jacobian at ``z`` (mm/deg).
        """
        if self._compiled is not None:
            z, tip, J = np.array(z0, dtype=float), np.empty(3), np.empty((3, self.n_motors))
            self._compiled(self._arrays, self._f0, self._buf0, np.asarray(target, dtype=float), z,
                           np.asarray(torques, dtype=float), self._limits,
                           (self.eps, float(max_iter), float(tol_deg), float(damping)), tip, J)
            return z, tip, J
        z = self.project(np.asarray(z0, dtype=float))
        tip = self.tip(z, torques, np.empty(3))
        cost = float(np.sum((target - tip) ** 2))
        J = self.jacobian(z, torques, tip)
        mu = max(float(damping), 1e-6)
        for _ in range(max_iter):
            z_new = self.project(z + damped_solve(J, target - tip, mu))
            moved = float(np.max(np.abs(z_new - z)))
            if moved < tol_deg:
                break
            tip_new = self.tip(z_new, torques, np.empty(3))
            cost_new = float(np.sum((target - tip_new) ** 2))
            if cost_new < cost:
                z, tip, cost, mu = z_new, tip_new, cost_new, mu / 3.0
                J = self.jacobian(z, torques, tip)
            else:
                mu *= 4.0
        return z, tip, J
