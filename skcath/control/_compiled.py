"""The controller's compiled step as the controllers call it: its arrays, built once at start.

:class:`CompiledStep` lays out a started controller's parameters and state
in the arrays of :func:`~skcath.control._jit.control_step` and calls it once
per sample; the controllers use it on the numba engine
(:mod:`skcath.control._controllers`), the Python methods otherwise.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["CompiledStep"]

#: Step of the finite differences of the model's Jacobian (deg) and the solve's tolerance (deg).
EPS_DEG = SOLVE_TOL_DEG = 1e-3


def _pi_arrays(inverse):
    """What the compiled step reads of a :class:`~skcath.control._hysteresis.PIInverse` (placeholders for another).

    ``(link, theta, forward, dt, up, down)``; ``forward`` and ``dt`` are the
    stream's own arrays (views of its state), read at every step.
    """
    if inverse.kind != "pi":
        return tuple(np.zeros(1) for _ in range(6))
    link, theta, up, down = (np.ascontiguousarray(a, dtype=np.float64)
                             for a in (inverse.link, inverse.theta, inverse.up, inverse.down))
    return link, theta, inverse.state, inverse.dt, up, down


def _pi_forward(inverse):
    """What the compiled preview reads of a PI's forward step, in one array: ``pack()``, then its dead band up and down.

    A placeholder for another inverse.
    """
    if inverse.kind != "pi":
        return np.zeros(1)
    n = np.size(inverse.state) // (inverse.model.thresholds.size + 2)
    up, down = (np.broadcast_to(band, (n,)) for band in inverse.model._bands())
    return np.concatenate([inverse.model.pack(), up, down]).astype(np.float64)


class CompiledStep:
    """The compiled step of one started controller.

    Parameters
    ----------
    controller : FeedforwardController or FeedbackController
        Started (its ``limits_``, ``dt_``, ``command_``, look-ahead view and seed grid set).
    mode : int
        :data:`~skcath.control._modes.MODE_FEEDFORWARD`, ``MODE_INTERNAL_MODEL`` or ``MODE_RESOLVED_RATE``.
    margin : float
        How much closer (mm^2) a seed's tip must be to restart the solve from it.
    """

    def __init__(self, controller, mode, margin):
        from . import _jit

        self._jit = j = _jit
        view = controller._view
        n = view.n_motors
        size, at = j.layout(n)
        s = np.zeros(size)
        limits = controller.limits_
        rate = controller.rate_limit
        inverse = controller.inverse_
        kind = {"none": j.KIND_NONE, "play": j.KIND_PLAY, "pi": j.KIND_PI}[inverse.kind]
        s[[j.S_GAIN, j.S_DAMPING, j.S_EPS, j.S_TOL, j.S_MAX_ITER, j.S_MAX_STEP, j.S_WIDTH, j.S_BAND,
           j.S_RADIUS, j.S_MARGIN, j.S_MODE, j.S_LATENCY, j.S_KIND]] = (
            getattr(controller, "gain", 0.0), controller.damping, EPS_DEG, SOLVE_TOL_DEG, controller.max_iter,
            math.inf if rate is None else rate * controller.dt_, getattr(inverse, "width", 0.0),
            controller._dead_band(), limits.radius, margin, mode, controller.latency, kind)
        for b, values in ((j.B_LOW, limits.low), (j.B_HIGH, limits.high), (j.B_NEUTRAL, limits.neutral),
                          (j.B_COMMAND, controller.command_), (j.B_SOLUTION, controller.command_),
                          (j.B_WANTED, controller.command_)):
            s[at[b] : at[b] + n] = values
        issued = np.tile(controller.command_, (max(controller.latency, 1), 1))
        aims = np.zeros((controller.latency + 1, 4))  # no aim yet: nothing to compare with
        arrays = view.compiled()[0]
        self.state = s
        self.command = s[at[j.B_COMMAND] : at[j.B_COMMAND] + n]
        self.aimed = s[j.S_AIMED : j.S_AIMED + 3]
        self.correction = s[j.S_CORRECTION : j.S_CORRECTION + 3]
        window = np.zeros((max(controller.preview, 1), 3 + n))  # the targets in view and their solutions
        self._args = (arrays, s, issued, aims, controller._grid_z, controller._grid_tips, _pi_arrays(inverse),
                      _pi_forward(inverse), window)
        self._nothing_ahead = np.empty((0, 3))
        self._kernel = j.control_kernel()

    @property
    def limited(self):
        """Whether a motor or rate limit changed the last command."""
        return bool(self.state[self._jit.S_LIMITED])

    def forget_ahead(self):
        """Empty the preview's window: nothing ahead is known."""
        self.state[self._jit.S_N_AHEAD] = 0.0

    def __call__(self, target, measured, sample, ahead=None):
        """One step: the squared distance of the aimed tip from the (corrected) target (mm^2).

        ``target`` and ``measured`` (mm) are float arrays of shape (3,),
        ``sample`` the observed channels; the estimator has been stepped with them.
        ``ahead`` (k, 3): the targets of the next samples (mm) for the preview, or None.
        """
        ahead = self._nothing_ahead if ahead is None else np.ascontiguousarray(ahead, dtype=np.float64)
        return self._kernel(*self._args, target, measured, np.array(sample), ahead)
