r"""A richer hysteresis of the motor transmission: Prandtl-Ishlinskii with dead band and creep.

For each motor the motor angle :math:`q` (deg) passes through three stages
before the backbone reads it as the effective angle :math:`v` (deg):

1. **Dead band** (tendon slack): an asymmetric play of half-widths
   :math:`d_+ = d (1 + a)` on the way up and :math:`d_- = d (1 - a)` on the
   way down,

   .. math::

       b_t = \min\bigl(\max(b_{t-1},\; q_t - d_+),\; q_t + d_-\bigr),

   so after a reversal nothing moves until the slack is taken up. The
   asymmetry :math:`a \in [-0.9, 0.9]` (one per motor) is the difference in
   slack of the two tendons of a pair.
2. **Prandtl-Ishlinskii superposition** (friction distributed along the
   sheath): a weighted sum of symmetric plays of :math:`b` with thresholds
   :math:`g_k` on a fixed grid and weights :math:`w_k \ge 0`,
   :math:`\sum_k w_k = 1`,

   .. math::

       z_{k,t} = \min\bigl(\max(z_{k,t-1},\; b_t - g_k),\; b_t + g_k\bigr),
       \qquad y_t = \sum_k w_k z_{k,t}.

   Stretches of tendon slip after different travels, so the loop widens with
   the amplitude of the motion, the property a single play lacks.
3. **Creep** (visco-elastic tendon): a first-order lag :math:`c` of
   :math:`y` with time constant :math:`\tau` (s, from the run's times
   :math:`t`) and gain :math:`\kappa \in [0, 0.5]`,

   .. math::

       c_t = c_{t-1} + (y_t - c_{t-1}) (1 - e^{-(t_t - t_{t-1}) / \tau}),
       \qquad v_t = \frac{y_t - \kappa c_t}{1 - \kappa},

   so after a move the effective angle overshoots by :math:`\kappa/(1-\kappa)`
   of the move and relaxes to :math:`y` with :math:`\tau`; at rest
   :math:`v = y`.

All states start at the first motor angle (:math:`b_0 = z_{k,0} = c_0 =
q_0`, so :math:`v_0 = q_0`). The single play of half-width :math:`r` is the
case :math:`d = r, a = 0, w = (1, 0, \dots), \kappa = 0`, and with
:math:`d = 0` and all weight on :math:`g_0 = 0`, :math:`v = q`.

The **inverse** (the motor angle that gives a wanted effective angle, for
feedforward) runs the stages backwards, each exactly: the creep's one-step
inverse is closed form,
:math:`y_t = \bigl((1-\kappa) v_t + \kappa e^{-\Delta t/\tau} c_{t-1}\bigr)
/ (1 - \kappa (1 - e^{-\Delta t/\tau}))`; the inverse of the PI part is
again a PI operator, with thresholds and weights in closed form from the
forward ones (:meth:`PrandtlIshlinskii.inverse_terms`); the dead band's
inverse adds the band in the direction of motion (:math:`q = b + d_+` while
:math:`b` rises, :math:`q = b - d_-` while it falls, and holds :math:`q`
while :math:`b` does). ``forward(inverse(v)) == v`` for any ``v``;
``inverse(forward(q)) == q`` where the dead band is zero (the dead band
forgets where the motor is within the slack).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from .._kernel import compiled, kernel
from ._hysteresis import identify_play_width

__all__ = [
    "PI_GRID_FRACTIONS",
    "PrandtlIshlinskii",
    "identify_pi",
    "pi_inverse_step",
    "pi_step",
]

#: Thresholds of the PI plays as fractions of ``max_play_deg``: 0 (the
#: motor angle itself) and a geometric grid up to ``max_play_deg``.
PI_GRID_FRACTIONS = (0.0, 0.125, 0.354, 1.0)
#: Largest number of sweep rows whose residuals the hysteresis fit reads (evenly strided).
MAX_FIT_ROWS = 1000
#: Bounds of the asymmetry of the dead band, of the creep gain and of the creep time constant (s).
ASYMMETRY_MAX = 0.9
CREEP_GAIN_MAX = 0.5
CREEP_TAU_S = (0.5, 100.0)
#: Rows with a finite reference needed per identified parameter.
ROWS_PER_PARAMETER = 20
#: Alternations of the hysteresis fit (backbone fixed) and the backbone's calibration.
N_ROUNDS = 3
#: Evaluations of the residuals allowed per parameter in one hysteresis fit.
MAX_NFEV_PER_PARAMETER = 10


@kernel
def pi_step(theta, state, at, q, dt, up, down):
    """One step of the forward hysteresis of one motor: the effective angle (deg).

    Parameters
    ----------
    theta : ndarray
        :meth:`PrandtlIshlinskii.pack`: ``[K, kappa, tau, g_0..g_{K-1}, w_0..w_{K-1}]``.
    state : ndarray
        States of all motors, updated in place; this motor's are
        ``state[at:at + K + 2]``: dead band ``b``, plays ``z_k``, creep ``c`` (deg).
    at : int
        Offset of this motor's states.
    q : float
        Motor angle of this sample (deg).
    dt : float
        Time since the previous sample (s), ``>= 0``.
    up, down : float
        Dead band on the way up and down (deg), ``>= 0``.

    Returns
    -------
    v : float
        Effective angle (deg).
    """
    k = int(theta[0])
    kappa = theta[1]
    b = min(max(state[at], q - up), q + down)
    state[at] = b
    y = 0.0
    for i in range(k):
        g = theta[3 + i]
        z = min(max(state[at + 1 + i], b - g), b + g)
        state[at + 1 + i] = z
        y += theta[3 + k + i] * z
    c = state[at + 1 + k]
    c += (y - c) * (1.0 - math.exp(-dt / theta[2]))
    state[at + 1 + k] = c
    return (y - kappa * c) / (1.0 - kappa)


@kernel
def pi_inverse_step(theta, state, at, v, dt, up, down):
    """One step of the inverse hysteresis of one motor: the motor angle (deg).

    Parameters
    ----------
    theta : ndarray
        :meth:`PrandtlIshlinskii.pack_inverse`: ``[K, kappa, tau, r_0..r_{K-1}, u_0..u_{K-1}]``,
        the thresholds and weights of the inverse PI.
    state : ndarray
        States of all motors, updated in place; this motor's are
        ``state[at:at + K + 3]``: creep ``c``, inverse plays, dead band
        output ``b`` and motor angle ``q`` of the previous sample (deg).
    at : int
        Offset of this motor's states.
    v : float
        Wanted effective angle of this sample (deg).
    dt : float
        Time since the previous sample (s), ``>= 0``.
    up, down : float
        Dead band on the way up and down (deg), including the thresholds
        of leading plays without weight.

    Returns
    -------
    q : float
        Motor angle (deg).
    """
    k = int(theta[0])
    kappa = theta[1]
    keep = math.exp(-dt / theta[2])
    c = state[at]
    y = ((1.0 - kappa) * v + kappa * keep * c) / (1.0 - kappa * (1.0 - keep))
    state[at] = c + (y - c) * (1.0 - keep)
    b = 0.0
    for i in range(k):
        r = theta[3 + i]
        z = min(max(state[at + 1 + i], y - r), y + r)
        state[at + 1 + i] = z
        b += theta[3 + k + i] * z
    b_prev = state[at + 1 + k]
    # a change within rounding (the inverse PI's weights sum to 1 up to it) is no move
    tol = 1e-12 * (1.0 + abs(b))
    if b > b_prev + tol:
        q = b + up
    elif b < b_prev - tol:
        q = b - down
    else:
        b = b_prev
        q = min(max(state[at + 2 + k], b - down), b + up)
    state[at + 1 + k] = b
    state[at + 2 + k] = q
    return q


@kernel
def _rest_state(x0, n_state):
    """States of all motors at rest at the first row's angles ``x0``."""
    m = x0.shape[0]
    state = np.empty(m * n_state)
    for j in range(m):
        for i in range(n_state):
            state[j * n_state + i] = x0[j]
    return state


def _rows_of(step, n_extra):
    """A loop running the stepping kernel ``step`` on every row of ``x`` (n, m) from rest at the first row.

    ``step`` is :func:`pi_step` or :func:`pi_inverse_step`; each motor has
    ``K + n_extra`` states (``K = theta[0]`` plays). The loop writes the
    output of every row into ``out`` (n, m) and returns the states after
    the last row (``m * (K + n_extra)``), where ``step`` continues the run.
    """

    def rows(theta, up, down, x, t, out):
        n_state = int(theta[0]) + n_extra
        state = _rest_state(x[0], n_state)
        for r in range(x.shape[0]):
            dt = t[r] - t[r - 1] if r > 0 else 0.0
            for j in range(x.shape[1]):
                out[r, j] = step(theta, state, j * n_state, x[r, j], dt, up[j], down[j])
        return state

    rows.__doc__ = (f":func:`{step.__name__}` on every row of ``x`` (n, m) from rest at the first row; "
                    "the states after the last row.")
    return rows


#: Forward rows: creep, plays and dead band output per motor (K + 2 states).
_forward_rows = _rows_of(pi_step, 2)
#: Inverse rows: creep, inverse plays, dead band output and motor angle (K + 3 states).
_inverse_rows = _rows_of(pi_inverse_step, 3)


def _run_rows(rows, theta, up, down, x, t):
    """The outputs of a :func:`_rows_of` loop on ``x`` (n, m) at times ``t`` and its final states (None without rows)."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    t = np.ascontiguousarray(t, dtype=np.float64)
    out = np.empty_like(x)
    state = None
    if len(x):
        fast = compiled(rows)
        state = (fast or rows)(theta, np.asarray(up, float), np.asarray(down, float), x, t, out)
    return out, state


def _check_angles(x, t, name):
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 2:
        raise ValueError(f"{name} must have shape (n, n_motors) (deg); got {x.shape}.")
    t = np.asarray(t, dtype=np.float64)
    if t.shape != (x.shape[0],):
        raise ValueError(f"t must have shape ({x.shape[0]},) (times of the rows of {name}, s); "
                         f"got {t.shape}.")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(t))):
        raise ValueError(f"{name} and t must be finite.")
    if np.any(np.diff(t) < 0):
        raise ValueError("t must not decrease (times of the rows, s).")
    return x, t


@dataclass(frozen=True)
class PrandtlIshlinskii:
    r"""Prandtl-Ishlinskii hysteresis with a dead band and creep, per motor.

    The model of the module docstring (:mod:`skcath.backbones._pi`): dead
    band :math:`d` with asymmetry :math:`a_i` per motor, plays of thresholds
    ``thresholds`` and weights ``weights``, creep of gain ``creep_gain`` and
    time constant ``creep_tau_s``. :meth:`forward` maps motor angles to
    effective angles, :meth:`inverse` effective angles to motor angles; the
    stepping forms :meth:`initial_state` / :meth:`step` and
    :meth:`initial_inverse_state` / :meth:`inverse_step` take one sample at
    a time (state in, state out) for a controller.

    Attributes
    ----------
    thresholds : ndarray of shape (K,)
        Thresholds :math:`g_k` of the plays (deg), increasing, the first 0.
    weights : ndarray of shape (K,)
        Weights :math:`w_k \ge 0`, summing to 1.
    dead_band : float
        Half-width :math:`d` of the dead band (deg), ``>= 0``.
    asymmetry : ndarray of shape (n_motors,)
        :math:`a_i` in [-0.9, 0.9]: dead band :math:`d (1 + a_i)` up, :math:`d (1 - a_i)` down.
    creep_gain : float
        :math:`\kappa` in [0, 0.5].
    creep_tau_s : float
        :math:`\tau` (s), > 0.

    Examples
    --------
    >>> import numpy as np
    >>> from skcath.backbones import PrandtlIshlinskii
    >>> pi = PrandtlIshlinskii.play(1.5, n_motors=1)
    >>> pi.forward([[0.0], [3.0], [2.0]], t=[0.0, 0.1, 0.2]).ravel()
    array([0. , 1.5, 1.5])
    """

    thresholds: np.ndarray
    weights: np.ndarray
    dead_band: float = 0.0
    asymmetry: np.ndarray = field(default_factory=lambda: np.zeros(2))
    creep_gain: float = 0.0
    creep_tau_s: float = 10.0

    def __post_init__(self):
        g = np.array(self.thresholds, dtype=float)
        w = np.array(self.weights, dtype=float)
        a = np.array(self.asymmetry, dtype=float).reshape(-1)
        if g.ndim != 1 or g.shape != w.shape or g.size == 0:
            raise ValueError("thresholds and weights must be 1-D of the same length >= 1.")
        if not (g[0] == 0.0 and np.all(np.diff(g) > 0)):
            raise ValueError(f"thresholds must increase from 0 (deg); got {g}.")
        if np.any(w < 0) or not np.isclose(w.sum(), 1.0, rtol=0, atol=1e-9):
            raise ValueError(f"weights must be >= 0 and sum to 1; got {w}.")
        if not self.dead_band >= 0 or not math.isfinite(self.dead_band):
            raise ValueError(f"dead_band must be finite and >= 0 (deg); got {self.dead_band}.")
        if a.size == 0 or np.any(np.abs(a) > ASYMMETRY_MAX):
            raise ValueError(f"asymmetry must be in [-{ASYMMETRY_MAX}, {ASYMMETRY_MAX}]; got {a}.")
        if not 0.0 <= self.creep_gain <= CREEP_GAIN_MAX:
            raise ValueError(f"creep_gain must be in [0, {CREEP_GAIN_MAX}]; got {self.creep_gain}.")
        if not (self.creep_tau_s > 0 and math.isfinite(self.creep_tau_s)):
            raise ValueError(f"creep_tau_s must be finite and > 0 (s); got {self.creep_tau_s}.")
        for name, value in (("thresholds", g), ("weights", w), ("asymmetry", a)):
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        object.__setattr__(self, "dead_band", float(self.dead_band))
        object.__setattr__(self, "creep_gain", float(self.creep_gain))
        object.__setattr__(self, "creep_tau_s", float(self.creep_tau_s))

    @classmethod
    def play(cls, width, n_motors=2):
        """The single symmetric play of half-width ``width`` (deg) as a PI model."""
        return cls([0.0], [1.0], dead_band=width, asymmetry=np.zeros(n_motors))

    @classmethod
    def identity(cls, thresholds=(0.0,), n_motors=2):
        """No hysteresis: ``v = q``."""
        w = np.zeros(len(thresholds))
        w[0] = 1.0
        return cls(thresholds, w, asymmetry=np.zeros(n_motors))

    @property
    def n_motors(self):
        """Number of motors (the length of ``asymmetry``)."""
        return self.asymmetry.size

    def _bands(self, extra=0.0):
        return (self.dead_band * (1.0 + self.asymmetry) + extra,
                self.dead_band * (1.0 - self.asymmetry) + extra)

    def pack(self):
        """Flat parameters read by :func:`pi_step`: ``[K, kappa, tau, g..., w...]``."""
        k = self.thresholds.size
        return np.concatenate([[k, self.creep_gain, self.creep_tau_s], self.thresholds, self.weights])

    def inverse_terms(self):
        r"""Thresholds, weights and extra dead band (deg) of the inverse PI.

        Leading plays without weight act as more dead band: with :math:`f`
        the first term of positive weight, the forward PI is a dead band of
        :math:`g_f` followed by plays of thresholds :math:`h_k = g_k - g_f`,
        :math:`k \ge f`. The inverse of :math:`\sum_k w_k\,\mathrm{play}_{h_k}`
        is :math:`\sum_j \hat w_j\,\mathrm{play}_{\hat r_j}` with

        .. math::

            \hat r_j = \sum_{k \le j} w_k (h_j - h_k),\qquad
            \hat w_f = \frac{1}{w_f},\qquad
            \hat w_j = -\frac{w_j}{W_j W_{j-1}},\quad W_j = \sum_{k \le j} w_k.

        Returns
        -------
        thresholds, weights : ndarray of shape (K',)
            Of the inverse PI (deg; weights may be negative).
        extra : float
            Dead band added on both sides (deg).
        """
        active = np.flatnonzero(self.weights > 0)
        h = self.thresholds[active] - self.thresholds[active[0]]
        w = self.weights[active]
        cum = np.cumsum(w)
        r = np.array([np.sum(w[: j + 1] * (h[j] - h[: j + 1])) for j in range(h.size)])
        u = np.empty_like(w)
        u[0] = 1.0 / w[0]
        u[1:] = -w[1:] / (cum[1:] * cum[:-1])
        return r, u, float(self.thresholds[active[0]])

    def pack_inverse(self):
        """Flat parameters read by :func:`pi_inverse_step` and the dead band (up, down, deg)."""
        r, u, extra = self.inverse_terms()
        up, down = self._bands(extra)
        return np.concatenate([[r.size, self.creep_gain, self.creep_tau_s], r, u]), up, down

    def forward(self, q, t, *, return_state=False):
        """Effective angles of one run's motor angles ``q`` (n, n_motors; deg) at times ``t`` (s).

        From rest at the first row (:meth:`initial_state`). With
        ``return_state=True`` also the state after the last row, from which
        :meth:`step` continues the run (``K + 2`` per motor, deg; None
        without rows): ``(v, state)``.
        """
        q, t = _check_angles(q, t, "q")
        self._check_motors(q)
        up, down = self._bands()
        v, state = _run_rows(_forward_rows, self.pack(), up, down, q, t)
        return (v, state) if return_state else v

    def inverse(self, v, t):
        """Motor angles (deg) that give the effective angles ``v`` (n, n_motors; deg) at times ``t`` (s)."""
        v, t = _check_angles(v, t, "v")
        self._check_motors(v)
        theta, up, down = self.pack_inverse()
        return _run_rows(_inverse_rows, theta, up, down, v, t)[0]

    def _check_motors(self, x):
        if x.shape[1] != self.n_motors:
            raise ValueError(f"The hysteresis has {self.n_motors} motor(s); got angles of "
                             f"{x.shape[1]}.")

    def initial_state(self, q0):
        """Forward state at rest at motor angles ``q0`` (n_motors,; deg)."""
        q0 = np.asarray(q0, dtype=float).reshape(-1)
        return np.repeat(q0, self.thresholds.size + 2)

    def step(self, state, q, dt):
        """One sample forward: ``(new_state, v)``; ``state`` is not modified."""
        state = np.array(state, dtype=float)
        up, down = self._bands()
        n = self.thresholds.size + 2
        theta = self.pack()
        v = np.array([pi_step(theta, state, j * n, float(qj), float(dt), up[j], down[j])
                      for j, qj in enumerate(np.asarray(q, dtype=float).reshape(-1))])
        return state, v

    def initial_inverse_state(self, v0):
        """Inverse state at rest at effective angles ``v0`` (n_motors,; deg)."""
        v0 = np.asarray(v0, dtype=float).reshape(-1)
        return np.repeat(v0, self.inverse_terms()[0].size + 3)

    def inverse_step(self, state, v, dt):
        """One sample of the inverse: ``(new_state, q)``; ``state`` is not modified."""
        state = np.array(state, dtype=float)
        theta, up, down = self.pack_inverse()
        n = int(theta[0]) + 3
        q = np.array([pi_inverse_step(theta, state, j * n, float(vj), float(dt), up[j], down[j])
                      for j, vj in enumerate(np.asarray(v, dtype=float).reshape(-1))])
        return state, q

    def to_dict(self):
        """Parameters by name, for a calibration table (deg, s)."""
        out = {f"pi_w{k}": float(w) for k, w in enumerate(self.weights)}
        out.update({f"pi_g{k}_deg": float(g) for k, g in enumerate(self.thresholds)})
        out["pi_dead_band_deg"] = self.dead_band
        out.update({f"pi_asymmetry_{j + 1}": float(a) for j, a in enumerate(self.asymmetry)})
        out["pi_creep_gain"] = self.creep_gain
        out["pi_creep_tau_s"] = self.creep_tau_s
        return out


# ---------------------------------------------------------------------------
# identification
# ---------------------------------------------------------------------------
def _from_vector(x, grid, n_motors):
    """A model from the free vector ``[w..., d, kappa, log tau]`` (weights normalised).

    ``x`` holds the weights of the first thresholds of ``grid``; the others
    get 0. The asymmetry is not identified (0): the sweep's rays leave and
    return to the neutral angles found from the motor angles, with which a
    shift of the dead band is confounded.
    """
    k = x.size - 3
    w = np.zeros(grid.size)
    w[:k] = np.clip(x[:k], 0.0, None)
    w = w / w.sum() if w.sum() > 0 else np.eye(1, grid.size).ravel()
    return PrandtlIshlinskii(
        grid, w, dead_band=max(float(x[k]), 0.0),
        asymmetry=np.zeros(n_motors),
        creep_gain=float(np.clip(x[-2], 0.0, CREEP_GAIN_MAX)), creep_tau_s=float(np.exp(x[-1])),
    )


def _to_vector(model, k):
    return np.concatenate([model.weights[:k], [model.dead_band],
                           [model.creep_gain, math.log(model.creep_tau_s)]])


@dataclass
class SweepProblem:
    """What the identification reads: the runs' angles and times, targets and the backbone."""

    segments: list  # (q, t) of every run, in the order of ``target``'s rows
    target: np.ndarray  # (N, 3) mm; rows with NaN are skipped
    calibrate: object  # z (N, m) -> (params, info with "rmse_mm")
    evaluate: object  # (z, params) -> tips (N, 3), mm

    def effective(self, model):
        return np.concatenate([model.forward(q, t) for q, t in self.segments])


def _fallback(where, reason):
    warnings.warn(
        f"hysteresis='pi': {reason} for {where}, which is calibrated without "
        "hysteresis.", UserWarning, stacklevel=4,
    )


def _n_shown(problem, grid, where):
    """How many thresholds of ``grid`` the runs' motion can show, or 0 (with a warning) if too flat.

    A play of threshold ``g`` moves only after a reversal of more than ``2 g``.
    """
    amplitude = 0.5 * max(float(np.ptp(q, axis=0).max()) for q, _ in problem.segments)
    n = int(np.sum(2.0 * grid <= amplitude))
    if n < 2:
        _fallback(where, f"the motor angles move {amplitude:.3g} deg about their centre, too "
                       f"little to identify the plays (the smallest nonzero threshold, "
                       f"{grid[1]:.3g} deg, needs a reversal of twice that; lower max_play_deg)")
        return 0
    return n


def _fit_hysteresis(problem, params, x0, grid, n_motors, max_play_deg):
    """Bounded least squares over the hysteresis parameters, the backbone's parameters fixed."""
    finite = np.flatnonzero(np.isfinite(problem.target).all(axis=1))
    rows = finite[:: max(1, -(-finite.size // MAX_FIT_ROWS))]
    target = problem.target[rows]
    k = x0.size - 3

    def residuals(x):
        z = problem.effective(_from_vector(x, grid, n_motors))
        return (problem.evaluate(z[rows], params) - target).ravel()

    lower = np.concatenate([np.zeros(k + 1), [0.0, math.log(CREEP_TAU_S[0])]])
    upper = np.concatenate([np.full(k, 2.0), [0.5 * max_play_deg], [CREEP_GAIN_MAX,
                            math.log(CREEP_TAU_S[1])]])
    x0 = np.clip(x0, lower, upper)
    result = least_squares(residuals, x0, bounds=(lower, upper), method="trf",
                           diff_step=1e-3, max_nfev=MAX_NFEV_PER_PARAMETER * x0.size,
                           x_scale="jac")
    return _from_vector(result.x, grid, n_motors)


def identify_pi(problem, *, max_play_deg, n_motors, where="the rows"):
    """Identify the PI hysteresis and the backbone's calibration together.

    ``problem`` (:class:`SweepProblem`) holds the motor angles and times of
    the rows identified on (a run's sweep, or training runs), their
    reference tips and the backbone's ``calibrate`` and ``evaluate``.

    Warm start: the single play whose calibration fits best
    (:func:`~skcath.backbones.identify_play_width`, as ``hysteresis="play"``),
    written as a PI (dead band of the play's half-width, all weight on the
    first threshold). Then :data:`N_ROUNDS` times: the hysteresis
    parameters by bounded least squares (:func:`scipy.optimize.least_squares`
    on at most :data:`MAX_FIT_ROWS` evenly strided rows, the backbone's
    parameters fixed; weights >= 0 normalised to sum 1), and the backbone
    recalibrated on the new effective angles. Of no hysteresis, the play
    and the PI of every round, the one of the lowest calibration RMSE
    (``rmse_mm``, as the play's search) is kept if it beats no hysteresis by the Bayesian
    information criterion (``n log(SSE_0 / SSE) > p log n``, ``n`` the
    residuals, ``p = K + 2`` the hysteresis parameters), else no
    hysteresis: noise is never fitted.

    ``where`` names the rows in the warning of a fallback (e.g. ``"run 'R1'"``).

    Returns
    -------
    model : PrandtlIshlinskii
        The hysteresis (the identity where none was identified).
    params, info
        The backbone's calibration on the effective angles.
    """
    grid = np.asarray(PI_GRID_FRACTIONS) * max_play_deg
    n_finite = int(np.isfinite(problem.target).all(axis=1).sum())
    n_free = (grid.size - 1) + 1 + 2
    identity = PrandtlIshlinskii.identity(grid, n_motors=n_motors)
    fits = [(identity, *problem.calibrate(problem.effective(identity)))]
    n_shown = _n_shown(problem, grid, where)
    if not n_shown:
        return fits[0]
    if n_finite < ROWS_PER_PARAMETER * n_free:
        _fallback(where, f"{n_finite} rows with a finite reference are too few to identify "
                       f"{n_free} parameters (at least {ROWS_PER_PARAMETER * n_free})")
        return fits[0]
    played = {}

    def sweep_rmse(width):
        model = PrandtlIshlinskii(grid, np.eye(1, grid.size).ravel(), dead_band=width,
                                  asymmetry=np.zeros(n_motors))
        played[float(width)] = (model, *problem.calibrate(problem.effective(model)))
        return played[float(width)][2]["rmse_mm"]

    best = played[identify_play_width(sweep_rmse, max_play_deg)]
    fits.append(best)
    model, params = best[0], best[1]
    for _ in range(N_ROUNDS):
        model = _fit_hysteresis(problem, params, _to_vector(model, n_shown), grid, n_motors,
                                max_play_deg)
        params, info = problem.calibrate(problem.effective(model))
        fits.append((model, params, info))
    scores = [info["rmse_mm"] for _, _, info in fits]
    best = fits[int(np.argmin(scores))]
    n_obs = 3 * n_finite
    rmse0, rmse = scores[0], min(scores)
    if rmse0 == 0 or (rmse > 0 and n_obs * 2.0 * math.log(rmse0 / rmse) <= n_free * math.log(n_obs)):
        return fits[0]
    return best
