"""Online detection of a shaft change from the motor angles and torques.

A shaft setting fixes the capstan wrap of the tendons, the motor offsets and
the dead zone of the tendon pairs, so it fixes the relation between a motor's
angle, its direction of motion and its drive torque. :class:`ShaftChangeDetector`
fits that relation on a run's own calibration sweep (a small least-squares
torque model), then follows the normalised torque residual during motion with
a two-sided CUSUM per motor and raises an alarm when the residual drifts away
from zero for longer than noise and model error explain: the shaft has been
repositioned since the sweep, and the sweep-calibrated models no longer hold.
"""

import math
from numbers import Integral, Real

import numpy as np
import pandas as pd
from sklearn.base import BaseEstimator, _fit_context
from sklearn.exceptions import NotFittedError
from sklearn.utils import Bunch
from sklearn.utils._param_validation import Interval, StrOptions, validate_parameter_constraints

from .. import _format as fmt
from ._detector_rate import check_detector_rate
from ._sample import CHANNELS, real_sample

__all__ = ["ShaftChangeDetector"]

#: Torque models: with a direction-of-motion (hysteresis) term, or static.
MODELS = ("hysteresis", "static")


def _play(x, z, width):
    """Play operator over the sequence ``x`` from the state ``z``.

    Returns the direction state ``h = (x - z) / width`` in [-1, 1] of every
    sample (+1 after moving up by at least ``2 width``, -1 after moving down)
    and the final state. Plain Python floats, so that one sample at a time
    gives the same numbers as a whole run.
    """
    h = []
    for xk in x:
        z = min(max(z, xk - width), xk + width)
        h.append((xk - z) / width)
    return h, z


def _cusum(z, s, drift, threshold):
    """Two-sided CUSUM of both axes over residuals ``z`` (list of pairs).

    ``s`` holds the four one-sided sums (up and down for each axis); each
    sample adds ``+z - drift`` or ``-z - drift`` and clips at zero. When the
    largest sum exceeds ``threshold`` an alarm is raised and the sums restart
    at zero. Returns the per-sample statistic (largest sum, before a
    restart), the alarm flags and the final sums.
    """
    up1, dn1, up2, dn2 = s
    stat, alarm = [], []
    for z1, z2 in z:
        up1 = max(0.0, up1 + z1 - drift)
        dn1 = max(0.0, dn1 - z1 - drift)
        up2 = max(0.0, up2 + z2 - drift)
        dn2 = max(0.0, dn2 - z2 - drift)
        g = max(up1, dn1, up2, dn2)
        stat.append(g)
        raised = g > threshold
        alarm.append(raised)
        if raised:
            up1 = dn1 = up2 = dn2 = 0.0
    return stat, alarm, [up1, dn1, up2, dn2]


class ShaftChangeDetector(BaseEstimator):
    """Online detector of a shaft repositioned since the calibration sweep.

    ``start`` fits, on one run's sweep, a torque model of each motor: the
    drive torque ``tau_i`` (N mm) as a piecewise-linear function of the motor
    angle ``q_i`` (deg), plus the same function times the direction state
    ``h_i`` in [-1, 1] of a play operator of width ``play_width`` on ``q_i``
    (the capstan friction makes the torque higher while pulling than while
    releasing), plus the load of the other motor ``|q_j|`` and ``|q_j| h_i``.
    During motion, ``step`` normalises each motor's residual by its standard
    deviation on the sweep, ``z_i = (tau_i - tau_hat_i) / s_i``, and updates
    a two-sided CUSUM per motor::

        G+_i = max(0, G+_i + z_i - drift),   G-_i = max(0, G-_i - z_i - drift),

    with the statistic ``G = max_i max(G+_i, G-_i)``. An alarm is raised when
    ``G > threshold``; the sums then restart at zero, so later alarms count
    again. See ``docs/shaft_change.rst`` for the physics and the measured
    detection delays and false-alarm rates.

    Parameters are validated in ``start``. ``threshold`` and ``drift`` may be
    changed with ``set_params`` after ``start`` (``detect`` checks them
    again); the others take effect at the next ``start``.

    Parameters
    ----------
    threshold : float, default=130.0
        Alarm threshold on the CUSUM statistic (dimensionless, in units of
        the sweep residual's standard deviation times samples). Larger: fewer
        false alarms, longer delays. The default was chosen on catheter
        ``C1`` of the simulated benchmark (``benchmarks/bench_shaft_change.py``)
        at 10 Hz. The statistic adds one term per sample, so ``threshold``
        and ``drift`` are per-sample values: ``start`` warns
        (:class:`~skcath.exceptions.SampleRateWarning`) when either keeps
        its default at a rate more than 10 % from 10 Hz.
    drift : float, default=1.5
        Allowance subtracted from each normalised residual (dimensionless):
        a persistent residual smaller than ``drift`` standard deviations is
        never flagged. Motion residuals of an unchanged shaft have a standard
        deviation of about 1.6 sweep standard deviations on the simulated
        benchmark (faster motion than on the sweep), so smaller values raise
        false alarms.
    warm_up_s : float, default=0.0
        Time after ``start`` during which the statistic is not updated (s);
        the torque model's direction state still follows the motors.
    rate_hz : float, default=10.0
        Sampling rate of the samples given to ``step`` (Hz); converts
        ``warm_up_s`` to samples and sample counts to seconds. ``start``
        warns when the sweep's times ``t`` (if given) are at a rate more
        than 10 % from it.
    model : {"hysteresis", "static"}, default="hysteresis"
        Torque model: with the direction-of-motion terms, or a function of
        the motor angles only.
    play_width : float, default=3.0
        Half-width of the play operator that gives the direction state (deg).
    n_knots : int, default=13
        Knots of the piecewise-linear function of the motor angle, evenly
        spaced over the sweep's range of each motor.

    Attributes
    ----------
    coef_ : ndarray of shape (2, n_features)
        Coefficients of the torque model of each motor (N mm per feature).
    scale_ : ndarray of shape (2,)
        Standard deviation of each motor's torque residual on the sweep (N mm).
    knots_ : ndarray of shape (2, n_knots)
        Knots of the piecewise-linear functions of ``q1`` and ``q2`` (deg).
    n_sweep_ : int
        Number of sweep samples the model was fitted on.
    statistic_ : float
        CUSUM statistic ``G`` at the last sample (when that sample raised an
        alarm, the value before the restart).
    residual_ : ndarray of shape (2,)
        Normalised torque residuals ``z`` of the last sample.
    alarm_ : bool
        Whether an alarm has been raised since ``start`` or ``reset``.
    alarm_index_ : int or None
        Index of the sample (0 = first sample after ``start``) of the first
        alarm; None before one.
    alarm_time_ : float or None
        Time of the first alarm after ``start`` (s), ``alarm_index_ /
        rate_hz``; None before one.
    n_alarms_ : int
        Number of alarms since ``start`` or ``reset``.
    n_steps_ : int
        Number of samples given to ``step`` since ``start`` or ``reset``.

    Examples
    --------
    >>> from skcath.datasets import simulate_run
    >>> from skcath.online import ShaftChangeDetector
    >>> run = simulate_run(random_state=0, setting="S01", setting_after="S09")
    >>> X = run.X
    >>> detector = ShaftChangeDetector().start(X[X["phase"] == "sweep"])
    >>> motion = X[X["phase"] == "motion"]
    >>> for q1, q2, tau1, tau2 in motion[["q1", "q2", "tau1", "tau2"]].to_numpy():
    ...     if detector.step(q1, q2, tau1, tau2):
    ...         break
    >>> detector.alarm_
    True
    """

    _parameter_constraints: dict = {
        "threshold": [Interval(Real, 0, None, closed="neither")],
        "drift": [Interval(Real, 0, None, closed="left")],
        "warm_up_s": [Interval(Real, 0, None, closed="left")],
        "rate_hz": [Interval(Real, 0, None, closed="neither")],
        "model": [StrOptions(set(MODELS))],
        "play_width": [Interval(Real, 0, None, closed="neither")],
        "n_knots": [Interval(Integral, 2, None, closed="left")],
    }

    def __init__(
        self,
        threshold=130.0,
        drift=1.5,
        *,
        warm_up_s=0.0,
        rate_hz=10.0,
        model="hysteresis",
        play_width=3.0,
        n_knots=13,
    ):
        self.threshold = threshold
        self.drift = drift
        self.warm_up_s = warm_up_s
        self.rate_hz = rate_hz
        self.model = model
        self.play_width = play_width
        self.n_knots = n_knots

    # ------------------------------------------------------------------ model
    def _design(self, axis, x, other, h):
        """Features of the torque model of one motor (vectorised over samples).

        ``x`` and ``other`` are the angles of this motor and of the other one
        (deg), ``h`` the direction state of this motor; all 1-D arrays.
        """
        knots = self.knots_[axis]
        x = np.clip(x, knots[0], knots[-1])
        hat = np.maximum(0.0, 1.0 - np.abs(x[:, None] - knots) / self._spacing[axis])
        load = np.abs(other)[:, None]
        if self._model == "static":
            return np.hstack([hat, load])
        h = h[:, None]
        return np.hstack([hat, hat * h, load, load * h])

    def _predict(self, axis, features):
        """Torque of one motor from its features, summed in a fixed order.

        The sum runs feature by feature, so that one sample gives the same
        number as a whole run.
        """
        coef = self.coef_[axis]
        out = features[:, 0] * coef[0]
        for j in range(1, len(coef)):
            out = out + features[:, j] * coef[j]
        return out

    def _residuals(self, q, tau, h1, h2):
        """Normalised torque residuals of samples, shape (n, 2)."""
        z = np.empty((len(q), 2))
        for axis, h in enumerate((h1, h2)):
            features = self._design(axis, q[:, axis], q[:, 1 - axis], np.asarray(h, dtype=float))
            z[:, axis] = (tau[:, axis] - self._predict(axis, features)) / self.scale_[axis]
        return z

    # ------------------------------------------------------------------ input
    @staticmethod
    def _check_signals(q, tau):
        """Motor angles and torques as float arrays of shape (n, 2), finite."""
        out = []
        for name, value, cols in (("q", q, fmt.MOTOR_COLUMNS), ("tau", tau, fmt.TORQUE_COLUMNS)):
            arr = np.array(value, dtype=float)  # a copy: inputs are never modified
            if arr.ndim != 2 or arr.shape[1] != 2:
                raise ValueError(
                    f"{name} must have shape (n_samples, 2) ({', '.join(cols)}); got {arr.shape}."
                )
            bad = ~np.isfinite(arr)
            if bad.any():
                row, col = np.argwhere(bad)[0]
                raise ValueError(
                    f"{name} has a non-finite value ({arr[row, col]}) in column {cols[col]!r} "
                    f"at row {row}; the detector needs finite motor angles and torques."
                )
            out.append(arr)
        if len(out[0]) != len(out[1]):
            raise ValueError(
                f"q and tau must have the same number of rows; got {len(out[0])} and {len(out[1])}."
            )
        return out

    def _check_started(self):
        if not hasattr(self, "coef_"):
            raise NotFittedError(
                f"This {type(self).__name__} has not been started: call start(sweep) with the "
                "run's calibration sweep before step or detect."
            )

    # ------------------------------------------------------------------ API
    @_fit_context(prefer_skip_nested_validation=True)
    def start(self, sweep):
        """Fit the torque model on a run's calibration sweep and reset the statistic.

        Parameters
        ----------
        sweep : pandas.DataFrame
            The sweep of one run, in time order, with the columns ``q1``,
            ``q2`` (deg), ``tau1``, ``tau2`` (N mm). When a ``phase``
            column is present, only its ``"sweep"`` rows are used; when a
            ``run`` column is present, it must hold a single run. The sweep
            should exercise each motor out and back over its range (the
            8-ray sweep of the protocol does).

        Returns
        -------
        self : ShaftChangeDetector
            Started detector, ready for ``step`` or ``detect``.
        """
        if not isinstance(sweep, pd.DataFrame):
            raise TypeError(f"sweep must be a pandas DataFrame; got {type(sweep).__name__}.")
        columns = [*fmt.MOTOR_COLUMNS, *fmt.TORQUE_COLUMNS]
        missing = [c for c in columns if c not in sweep.columns]
        if missing:
            raise ValueError(f"sweep is missing the column(s) {missing}; expected {columns}.")
        if fmt.RUN in sweep.columns and sweep[fmt.RUN].nunique() > 1:
            raise ValueError(
                f"sweep must hold one run; its {fmt.RUN!r} column has {sweep[fmt.RUN].nunique()} runs."
            )
        if fmt.PHASE in sweep.columns:
            sweep = sweep[(sweep[fmt.PHASE] == fmt.SWEEP).to_numpy()]
        check_detector_rate(self, sweep)
        q, tau = self._check_signals(sweep[list(fmt.MOTOR_COLUMNS)], sweep[list(fmt.TORQUE_COLUMNS)])
        n_features = 2 * self.n_knots + 2 if self.model == "hysteresis" else self.n_knots + 1
        if len(q) < 4 * n_features:
            raise ValueError(
                f"sweep has {len(q)} rows; the {self.model!r} torque model with n_knots={self.n_knots} "
                f"needs at least {4 * n_features}."
            )
        low, high = q.min(axis=0), q.max(axis=0)
        if np.any(high - low <= 0):
            raise ValueError("sweep must move both motors: q1 and q2 each need a range > 0 deg.")
        # the model's shape is fixed here; threshold and drift may change later
        self._model, self._play_width = self.model, float(self.play_width)
        self.knots_ = np.linspace(low, high, self.n_knots).T
        self._spacing = (high - low) / (self.n_knots - 1)
        self.n_sweep_ = len(q)

        coef, scale, state = [], [], []
        for axis in range(2):
            h, z_end = _play(q[:, axis].tolist(), float(q[0, axis]), self._play_width)
            features = self._design(axis, q[:, axis], q[:, 1 - axis], np.asarray(h))
            beta, *_ = np.linalg.lstsq(features, tau[:, axis], rcond=None)
            r = tau[:, axis] - features @ beta
            coef.append(beta)
            scale.append(float(np.sqrt(np.sum(r**2) / max(1, len(r) - features.shape[1]))))
            state.append(z_end)
        if min(scale) <= 0:
            raise ValueError(
                "the torque model fits the sweep exactly; the torques carry no noise to normalise by."
            )
        self.coef_ = np.array(coef)
        self.scale_ = np.array(scale)
        self._play_start = tuple(state)
        self._n_warm_up = int(np.ceil(self.warm_up_s * self.rate_hz - 1e-9))
        self.reset()
        return self

    def reset(self):
        """Restart the statistic and the alarm, keeping the torque model.

        The direction state of the motors returns to where the sweep left it,
        as right after ``start``.

        Returns
        -------
        self : ShaftChangeDetector
        """
        self._check_started()
        self._play_state = list(self._play_start)
        self._sums = [0.0, 0.0, 0.0, 0.0]
        self.statistic_ = 0.0
        self.residual_ = np.zeros(2)
        self.alarm_ = False
        self.alarm_index_ = None
        self.alarm_time_ = None
        self.n_alarms_ = 0
        self.n_steps_ = 0
        return self

    def step(self, q1, q2, tau1, tau2):
        """Take one sample and tell whether it raises an alarm.

        Parameters
        ----------
        q1, q2 : float
            Motor angles (deg).
        tau1, tau2 : float
            Drive torques (N mm). Each channel must be a finite real number
            (``int``, ``float``, a numpy integer or floating scalar): ``bool``,
            strings, bytes, ``Decimal`` and complex numbers raise
            ``TypeError``, as in :meth:`OnlineEstimator.step`.

        Returns
        -------
        alarm : bool
            True when the statistic exceeds ``threshold`` at this sample (it
            then restarts at zero); ``alarm_`` stays True from the first
            alarm until ``reset``.
        """
        self._check_started()
        sample = real_sample((q1, q2, tau1, tau2))
        for name, value in zip(CHANNELS, sample):
            if not math.isfinite(value):
                raise ValueError(f"{name} must be finite; got {value!r}.")
        q1, q2, tau1, tau2 = sample
        q = np.array([[q1, q2]], dtype=float)
        tau = np.array([[tau1, tau2]], dtype=float)
        h = []
        for axis in range(2):
            hk, self._play_state[axis] = _play([float(q[0, axis])], self._play_state[axis], self._play_width)
            h.append(hk)
        z = self._residuals(q, tau, *h)
        self.residual_ = z[0]
        raised = False
        if self.n_steps_ >= self._n_warm_up:
            stat, alarm, self._sums = _cusum(z.tolist(), self._sums, float(self.drift), float(self.threshold))
            self.statistic_ = stat[0]
            raised = alarm[0]
            if raised:
                self._record_alarm(self.n_steps_)
        self.n_steps_ += 1
        return raised

    def _record_alarm(self, index):
        self.n_alarms_ += 1
        if not self.alarm_:
            self.alarm_ = True
            self.alarm_index_ = index
            self.alarm_time_ = index / self.rate_hz

    def detect(self, q, tau):
        """Run the detector over a whole stretch of samples at once.

        Starts from the state right after ``start`` (as after ``reset``) and
        leaves the online state of ``step`` untouched. Gives the same
        numbers as calling ``step`` on each sample in turn after ``reset``.

        Parameters
        ----------
        q : array-like of shape (n_samples, 2)
            Motor angles ``q1``, ``q2`` (deg), in time order, starting right
            after the sweep given to ``start``.
        tau : array-like of shape (n_samples, 2)
            Drive torques ``tau1``, ``tau2`` (N mm).

        Returns
        -------
        result : sklearn.utils.Bunch
            ``statistic`` (n_samples,): the CUSUM statistic ``G`` at each
            sample, before the restart that follows an alarm;
            ``residual`` (n_samples, 2): the normalised torque residuals;
            ``alarms`` : ndarray of int, the samples that raised an alarm;
            ``first_alarm`` : int, the first of them, -1 when none.
        """
        self._check_started()
        q, tau = self._check_signals(q, tau)
        validate_parameter_constraints(
            {key: self._parameter_constraints[key] for key in ("threshold", "drift")},
            {"threshold": self.threshold, "drift": self.drift},
            caller_name=type(self).__name__,
        )
        h = [_play(q[:, axis].tolist(), self._play_start[axis], self._play_width)[0] for axis in range(2)]
        z = self._residuals(q, tau, *h)
        n_skip = min(self._n_warm_up, len(q))
        stat, alarm, _ = _cusum(z[n_skip:].tolist(), [0.0] * 4, float(self.drift), float(self.threshold))
        statistic = np.concatenate([np.zeros(n_skip), np.asarray(stat, dtype=float)])
        alarms = n_skip + np.flatnonzero(np.asarray(alarm, dtype=bool))
        return Bunch(
            statistic=statistic,
            residual=z,
            alarms=alarms,
            first_alarm=int(alarms[0]) if len(alarms) else -1,
        )
