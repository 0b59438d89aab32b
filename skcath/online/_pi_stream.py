"""The Prandtl-Ishlinskii hysteresis of a backbone (``hysteresis="pi"``) in the streaming step.

``start`` takes the run's identified :class:`~skcath.backbones.PrandtlIshlinskii`
(:func:`calibrate_pi`, as the backbone's ``calibrate`` identifies it on the
sweep) and its state after the sweep (:func:`kept_angles`: the sweep's
motor angles through the model from rest at its first row,
:meth:`~skcath.backbones.PrandtlIshlinskii.forward` as ``predict`` runs the
run's rows, with its final state). :class:`PIStep` holds what the packed step reads: the
packed parameters, the dead band up and down of each motor, the state after
the sweep and the step's nominal time step. :func:`pi_angles` is the part of
:func:`~skcath.online._kernels.step` that runs it: one
:func:`~skcath.backbones.pi_step` per motor, with the time since the previous
step (``f[F_DT]``) for the creep.

The time step: a sample given with its time ``t`` steps the creep by the
time since the previous sample, as ``predict`` does with the rows' times; a
sample without one by the stream's nominal step, the model's step
``1 / rate_hz_`` (the stream is then at the model's rate), or without a
learned residual the sweep's median time step.
"""

from __future__ import annotations

import math

import numpy as np

from .. import _format as fmt
from .._kernel import compiled_as
from ..backbones import (
    PCCBackbone,
    PDLBackbone,
    PrandtlIshlinskii,
    pi_step,
    play_operator,
    polynomial_tip,
)
from ..backbones._backbone import _calibrate_run, _check_two
from ._layout import F_DT, M_ANGLES, M_N_MOTORS, M_PI_BANDS, M_PI_STATE, M_PI_THETA

__all__ = [
    "PIStep",
    "calibrate_pi",
    "kept_angles",
    "pi_angles",
    "pi_spec",
    "pi_step_of",
    "start_hysteresis",
    "sweep_period",
]


def _pi_angles_compiled(meta, f, sample):
    n = meta[M_N_MOTORS]
    angles = meta[M_ANGLES]
    bands = meta[M_PI_BANDS]
    at = meta[M_PI_STATE]
    theta = f[meta[M_PI_THETA] : bands]
    size = int(theta[0]) + 2
    dt = f[F_DT]
    for j in range(n):
        f[angles + j] = pi_step(theta, f, at + j * size, sample[j], dt, f[bands + j],
                                f[bands + n + j])


@compiled_as(_pi_angles_compiled)
def pi_angles(meta, f, sample):
    """The effective angles (deg) of the sample's motor angles into ``f[meta[M_ANGLES]:]``.

    One :func:`~skcath.backbones.pi_step` per motor on the packed PI of
    ``f`` (``meta[M_PI_THETA]``, ``meta[M_PI_BANDS]``, ``meta[M_PI_STATE]``),
    its state updated in place, with the time step ``f[F_DT]`` (s).
    Compiled code steps on ``f`` itself; Python reads the parameters, the
    dead bands and the state as one list (Python reads a list's items
    faster than an array's, and computes on floats as on float64: the same
    numbers) and writes the state back.
    """
    n = meta[M_N_MOTORS]
    first = meta[M_PI_THETA]
    bands = meta[M_PI_BANDS] - first
    at = meta[M_PI_STATE]
    size = int(f[first]) + 2
    end = at + n * size
    pi = f[first:end].tolist()  # the packed parameters first: pi_step reads them from index 0
    dt = float(f[F_DT])
    angles = meta[M_ANGLES]
    at -= first
    for j in range(n):
        f[angles + j] = pi_step(pi, pi, at + j * size, sample[j], dt, pi[bands + j], pi[bands + n + j])
    f[meta[M_PI_STATE]:end] = pi[at:]


def pi_spec(model):
    """The parameters of a :class:`~skcath.backbones.PrandtlIshlinskii` as plain data (a dict)."""
    return {"thresholds": np.array(model.thresholds), "weights": np.array(model.weights),
            "dead_band": float(model.dead_band), "asymmetry": np.array(model.asymmetry),
            "creep_gain": float(model.creep_gain), "creep_tau_s": float(model.creep_tau_s)}


def calibrate_pi(backbone, sweep):
    """A backbone with ``hysteresis="pi"`` calibrated on a checked sweep, as its ``calibrate`` does.

    Returns the run's parameters, the nominal tip of every sweep row (mm)
    and the :class:`~skcath.backbones.PrandtlIshlinskii` identified for the
    run (the one ``fit`` identified, for a polynomial with
    ``calibration="fit"``).
    """
    if isinstance(backbone, (PCCBackbone, PDLBackbone)):
        _check_two(sweep.motors, type(backbone).__name__)
        tip, params, _, model = _calibrate_run(
            backbone, sweep.run, sweep.q, _reference(sweep), np.ones(len(sweep.q), dtype=bool),
            None, sweep.t)
        return params, tip, model
    backbone._check_motors(sweep.motors)
    _, _, fitted, models = backbone._run_params(sweep.X, sweep.q)
    params, model = fitted[0], models[0]
    return params, polynomial_tip(model.forward(sweep.q, sweep.t), params), model


def _reference(sweep):
    """The reference tip of the sweep's rows (n, 3), mm."""
    return np.ascontiguousarray(sweep.X[list(fmt.REFERENCE_COLUMNS)].to_numpy(dtype=np.float64))


class PIStep:
    """The run's PI as the packed step reads it.

    Parameters
    ----------
    spec : dict
        :func:`pi_spec` of the model.
    start : sequence of float
        Its state after the sweep (``K + 2`` per motor, deg).
    period : float
        Time step (s) of a sample given without its time.

    Attributes
    ----------
    model : PrandtlIshlinskii
    theta : ndarray
        ``model.pack()``.
    bands : ndarray of shape (2 N,)
        Dead band up (``N``), then down (``N``), deg.
    start : ndarray
    period : float
    """

    def __init__(self, spec, start, period):
        self.model = PrandtlIshlinskii(**spec)
        self.theta = self.model.pack()
        self.bands = np.concatenate(self.model._bands())
        self.start = np.array(start, dtype=np.float64)
        self.period = float(period)

    def step(self, state, q, dt):
        """Effective angles (tuple, deg) of one sample ``q`` (deg), ``state`` updated in place."""
        n = len(q)
        size = int(self.theta[0]) + 2
        return tuple(pi_step(self.theta, state, j * size, float(q[j]), dt, self.bands[j],
                             self.bands[n + j]) for j in range(n))


def sweep_period(t, rate_hz):
    """The nominal time step (s): the model's ``1 / rate_hz``, else the sweep's median step."""
    if rate_hz is not None:
        return 1.0 / float(rate_hz)
    steps = np.diff(t)
    return float(np.median(steps)) if steps.size else math.inf


# ---------------------------------------------------------------------------
# the estimator's side: what start, resweep, reset and a timed step do with the PI
# ---------------------------------------------------------------------------
def start_hysteresis(est, hysteresis, q, t):
    """Keep the run's hysteresis on ``est``: the play's half-width (returned) or the PI.

    With a :class:`~skcath.backbones.PrandtlIshlinskii` (returns 0.0): its
    parameters (``_pi_spec``) and its state after the sweep's motor angles
    ``q`` at times ``t`` (``_pi_start``, ``_sweep_period``, see
    :func:`kept_angles`). Otherwise ``hysteresis`` is the play's half-width.
    """
    if not isinstance(hysteresis, PrandtlIshlinskii):
        est._pi_spec = None
        return float(hysteresis)
    est._pi_spec = pi_spec(hysteresis)
    kept_angles(est, q, t)
    return 0.0


def kept_angles(est, q, t):
    """The angles the backbone reads over a sweep ``q`` (deg) at times ``t`` (s), through the kept hysteresis.

    The kept play (or none) as :func:`~skcath.backbones.play_operator`; the
    kept PI from rest at the first row, whose state after the last row
    becomes the one the motion starts from (``_pi_start``), and the
    sweep's median time step ``_sweep_period``.
    """
    spec = getattr(est, "_pi_spec", None)
    if spec is None:
        return play_operator(q, getattr(est, "play_width_", 0.0))
    z, state = PrandtlIshlinskii(**spec).forward(q, t, return_state=True)
    est._pi_start = state
    est._sweep_period = sweep_period(t, None)
    return z


def pi_step_of(est):
    """The :class:`PIStep` of a started estimator, or None without the PI."""
    spec = getattr(est, "_pi_spec", None)
    if spec is None:
        return None
    rate = getattr(est, "rate_hz_", None)
    return PIStep(spec, est._pi_start, 1.0 / rate if rate else est._sweep_period)

