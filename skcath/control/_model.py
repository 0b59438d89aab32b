"""The model's own step evaluated at candidate commands, and its inverse by Gauss-Newton.

:class:`ModelInverse` evaluates a started :class:`~skcath.online.OnlineEstimator`
through its look-ahead view (:class:`~skcath.online._model_view.ModelView`):
the tip the model predicts for the next sample at candidate effective motor
angles, from the estimator's present state (advanced by the commands not
observed yet), the hysteresis in front of the backbone skipped, so that the
angles evaluated are the effective angles the backbone reads; the hysteresis
is inverted afterwards (:mod:`skcath.control._hysteresis`). This is the
numpy engine's inverse and the reference of the compiled step
(:mod:`skcath.control._jit`).
"""

from __future__ import annotations

import numpy as np

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
    view : ModelView
        The look-ahead view of a started estimator (``estimator._model_view()``).
    project : callable
        ``project(z) -> z``: the effective angles brought within the motor limits (deg).
    eps_deg : float
        Step of the finite differences (deg).
    """

    def __init__(self, view, project, eps_deg):
        self.view = view
        self.project = project
        self.eps = float(eps_deg)
        self.n_motors = view.n_motors

    def begin(self, pending):
        """Advance the state by the commanded samples not observed yet; evaluations start from there.

        ``pending`` holds those samples (tuples of the channels), oldest
        first, stepped with the hysteresis in front of the backbone. The
        estimator's own state is kept aside and restored by :meth:`end`.
        """
        self.view.advance(pending)

    def end(self):
        """Give the estimator back the state it had before :meth:`begin`."""
        self.view.restore()

    def tip(self, z, torques, out):
        """Model tip (mm) of the next sample at effective angles ``z`` (deg), into ``out``."""
        return self.view.tip(z, torques, out)

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
