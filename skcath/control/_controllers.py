"""Controllers that turn a fitted tip model into motor commands: feedforward and resolved-rate feedback."""

from __future__ import annotations

import math
import warnings
from collections import deque
from numbers import Integral, Real

import numpy as np
from sklearn.base import BaseEstimator
from sklearn.exceptions import NotFittedError
from sklearn.utils._param_validation import HasMethods, Interval, StrOptions

from .. import _format as fmt
from ..online import OnlineEstimator
from ..online._sweep import check_sweep
from ._compiled import EPS_DEG, SOLVE_TOL_DEG, CompiledStep
from ._hysteresis import hysteresis_inverse
from ._limits import MotorLimits, UnreachableTargetWarning, check_target, rate_limited, read_obs
from ._model import ModelInverse, damped_solve
from ._modes import MODE_FEEDFORWARD, MODE_INTERNAL_MODEL, MODE_RESOLVED_RATE
from ._preview import check_upcoming, lead, plan

__all__ = ["FeedbackController", "FeedforwardController"]


def _limits_box(motor_limits, q_sweep):
    """Bounds (low, high) of every motor (deg): given, or the sweep's range."""
    n = q_sweep.shape[1]
    if motor_limits is None:
        return q_sweep.min(axis=0), q_sweep.max(axis=0)
    box = np.asarray(motor_limits, dtype=float)
    if box.shape == (2,):
        box = np.tile(box, (n, 1))
    if box.shape != (n, 2) or not np.all(np.isfinite(box)) or np.any(box[:, 0] >= box[:, 1]):
        raise ValueError(
            f"motor_limits must be (low, high) in deg, or one such row per motor (shape ({n}, 2)), "
            f"finite with low < high; got {np.asarray(motor_limits).tolist()}."
        )
    return box[:, 0], box[:, 1]


#: Points per motor of the grid of commands whose backbone tips seed the inverse, by motor count.
GRID_POINTS = {1: 61, 2: 25, 3: 11}
#: How much closer (mm^2, squared distance) a grid tip must be to restart the inverse from it.
GRID_MARGIN_MM = 0.25


def _seed_grid(view, limits):
    """Effective angles on a grid over the motor limits (deg) and the backbone's tips there (mm)."""
    n = view.n_motors
    axes = [np.linspace(lo, hi, GRID_POINTS[min(n, 3)]) for lo, hi in zip(limits.low, limits.high)]
    z = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, n)
    z = z[[limits.contains(row) for row in z]]
    tips = np.array([view.backbone(*row) for row in z.tolist()], dtype=float).reshape(-1, 3)
    return z, tips


def _warn_unreachable(target, tip, miss, reach_tol_mm, stacklevel):
    """Warn that ``target`` lies ``miss`` (mm) from the nearest reachable model tip ``tip``."""
    warnings.warn(
        f"target {np.round(target, 2).tolist()} mm lies {miss:.1f} mm from the nearest tip the "
        f"model reaches within the motor limits ({np.round(tip, 2).tolist()} mm), more than "
        f"reach_tol_mm={reach_tol_mm}; steering to that tip.",
        UnreachableTargetWarning, stacklevel=stacklevel + 1,
    )


class _Controller(BaseEstimator):
    """What the controllers share: start on a sweep, read a sample, aim, issue a command within limits."""

    _parameter_constraints: dict = {
        "pipeline": [HasMethods(["predict"])],
        "motor_limits": ["array-like", None],
        "rate_limit": [Interval(Real, 0, None, closed="neither"), None],
        "reach_tol_mm": [Interval(Real, 0, None, closed="left")],
        "max_iter": [Interval(Integral, 1, None, closed="left")],
        "damping": [Interval(Real, 0, None, closed="left")],
        "latency": [Interval(Integral, 0, None, closed="left")],
        "engine": [StrOptions({"auto", "numba", "numpy"})],
        "preview": [Interval(Integral, 0, None, closed="left")],
    }

    def start(self, sweep):
        """Calibrate the model on the run's sweep, as :meth:`OnlineEstimator.start` does.

        Parameters
        ----------
        sweep : pandas.DataFrame
            The sweep rows (``phase == "sweep"``) of the run, with the tracked tip.

        Returns
        -------
        self
            Ready for :meth:`step`; the first command moves from the last sweep sample.
        """
        self._validate_params()
        X = check_sweep(sweep).X
        est = OnlineEstimator(self.pipeline, engine=self.engine).start(X)
        n = len(est.q_neutral_)
        q = X[list(est.channels_[:n])].to_numpy(dtype=float)
        low, high = _limits_box(self.motor_limits, q)
        self.limits_ = MotorLimits(low, high, est.q_neutral_, est.q_limit_)
        t = X[fmt.TIME].to_numpy(dtype=float)
        self.dt_ = float(np.median(np.diff(t))) if len(t) > 1 else 0.1
        self.estimator_ = est
        self._view = est._model_view()
        self.inverse_ = hysteresis_inverse(est, self._dead_band())
        self.model_ = ModelInverse(self._view, self.limits_.project, eps_deg=EPS_DEG)
        self._grid_z, self._grid_tips = _seed_grid(self._view, self.limits_)
        self.command_ = self.limits_.project(q[-1])
        self._z_solution = self.command_.copy()
        self._torques = tuple(float(v) for v in est._last_sweep[n:])
        self.aimed_ = self.estimate_ = None
        self.n_unreachable_ = 0
        self._unreachable = None  # (target, tip, miss) of the step under way, warned of at its end
        self._limited = False
        self._ahead = []  # (target, effective angles) of the samples after this one, solved as they came in view
        self._issued = deque([self.command_.copy()] * self.latency, maxlen=max(self.latency, 1))
        self._reset_feedback()
        self._compiled = CompiledStep(self, self._mode(), GRID_MARGIN_MM) if est.engine_ == "numba" else None
        return self

    def _mode(self):
        """The controller of the compiled step: :data:`~skcath.control._modes.MODE_FEEDFORWARD`, ..."""
        return MODE_FEEDFORWARD

    def _step_compiled(self, target, obs, need_tracker, ahead):
        """The step on the numba engine: the observation read and the estimator stepped, then one compiled call.

        ``ahead``: the targets of the next samples (k, 3) (mm) for the preview, or None.
        """
        sample, t, tip = read_obs(obs, self.estimator_.channels_, need_tracker)
        self.estimate_ = self.estimator_.step(*sample, t=t)
        step = self._compiled
        miss = math.sqrt(step(target, self.estimate_ if tip is None else tip, sample, ahead))
        self.aimed_ = step.aimed.copy()
        self.command_ = step.command.copy()
        self._limited = step.limited
        if self._mode() != MODE_FEEDFORWARD:
            self.correction_ = step.correction.copy()
        self._unreachable = None
        if miss > self.reach_tol_mm:
            self.n_unreachable_ += 1
            self._unreachable = (target - step.correction, self.aimed_, miss)
        return step.command.copy()

    def _warn_if_unreachable(self):
        """Warn of the step's target if it was out of reach: the step's last act, its state complete."""
        unreachable, self._unreachable = self._unreachable, None
        if unreachable is not None:
            _warn_unreachable(*unreachable, self.reach_tol_mm, stacklevel=3)

    def _reset_feedback(self):
        """Feedback state set by :meth:`start`; none for the feedforward."""

    def _dead_band(self):
        """Smallest reversal of an effective angle the hysteresis inverse makes (deg); none for the feedforward."""
        return 0.0

    def _check_started(self):
        if not hasattr(self, "estimator_"):
            raise NotFittedError(
                f"This {type(self).__name__} has not been started; call start(sweep) with the "
                "sweep rows of the run before step."
            )

    def _observe(self, obs, need_tracker=False):
        """Step the model with the measured sample; the estimate (mm) and the tracker's tip or None.

        Then the model is advanced, on a copy of its state, by the commands
        still pending (``latency``), with the sample's torques.
        """
        sample, t, tip = read_obs(obs, self.estimator_.channels_, need_tracker)
        est = self.estimator_
        self.estimate_ = est.step(*sample, t=t).copy()
        n = len(est.q_neutral_)
        self._torques = sample[n:]
        pending = list(self._issued)[-self.latency:] if self.latency else []
        self._effective = np.array(pending[-1] if pending else sample[:n], dtype=float)
        self.model_.begin([(*q.tolist(), *self._torques) for q in pending])
        if self.inverse_.kind != "none":  # the effective angles after the pending commands
            self._effective = self._view.effective.copy()
        return self.estimate_, tip

    def _effective_state(self):
        """Effective angles (deg) the next command moves from: through the hysteresis, or commanded without."""
        return self._effective

    def _solve(self, target, z0):
        return self.model_.solve(target, z0, self._torques, max_iter=self.max_iter, tol_deg=SOLVE_TOL_DEG,
                                 damping=self.damping)

    def _nearest(self, target, z0):
        """Solve the model for ``target`` from ``z0``: effective angles, the nearest model tip and its Jacobian.

        Again from the nearest backbone tip of the seed grid when one of
        those lies closer to the target than the tip found (a local minimum,
        e.g. in a dead zone of the backbone).
        """
        z, tip, J = self._solve(target, z0)
        d = target - tip
        miss2 = float(d @ d)
        if miss2 > GRID_MARGIN_MM:  # else no grid tip can be closer by the margin
            d2 = np.sum((self._grid_tips - target) ** 2, axis=1)
            best = int(np.argmin(d2))
            if d2[best] + GRID_MARGIN_MM < miss2:
                z2, tip2, J2 = self._solve(target, self._grid_z[best])
                if np.sum((target - tip2) ** 2) < miss2:
                    z, tip, J = z2, tip2, J2
        return z, tip, J

    def _aim(self, target):
        """Solve the model for ``target`` from the previous solution (:meth:`_nearest`); the step's aim."""
        z, tip, J = self._nearest(target, self._z_solution)
        self._z_solution = z
        d = target - tip
        miss = math.sqrt(float(d @ d))
        self._unreachable = None
        if miss > self.reach_tol_mm:  # warned of once the step is complete
            self.n_unreachable_ += 1
            self._unreachable = (target, tip, miss)
        self.aimed_ = tip
        return z, tip, J

    def _upcoming(self, upcoming):
        """The checked ``upcoming`` targets within the preview (k, 3), or None: no preview this step."""
        if upcoming is None or self.preview == 0:
            self._ahead = []
            if self._compiled is not None:
                self._compiled.forget_ahead()
            return None
        ahead = check_upcoming(upcoming, self.preview)
        return ahead if len(ahead) else None

    def _angles_ahead(self, target, ahead, correction):
        """Wanted effective angles (deg) of the samples ahead, each target solved once as it comes in view.

        ``ahead`` (k, 3): the targets of the next samples (mm); the model is
        solved for ``target - correction`` from the solution of the sample
        before, with this sample's model state, and the solution is kept
        while the same target stays in view. A target ahead equal to this
        sample's ``target`` (a target held, as a reach target is) takes this
        sample's solution.
        """
        kept, now = self._ahead[1:], target.tolist()
        out = np.empty((len(ahead), len(self.command_)))
        z = self._z_solution
        for i, key in enumerate(ahead.tolist()):
            if i < len(kept) and kept[i][0] == key:
                z = self._z_solution if key == now else kept[i][1]
                kept[i] = (key, z)
            else:
                del kept[i:]
                z = self._z_solution if key == now else self._nearest(np.array(key) - correction, z)[0]
                kept.append((key, z))
            out[i] = z
        self._ahead = kept
        return out

    def _issue(self, z_wanted, z_ahead=None):
        """The command (deg) for the wanted effective angles: inverted hysteresis, preview, motor and rate limits.

        ``z_ahead`` (k, n_motors): the wanted effective angles of the next
        samples (deg), or None: without them the command is the inverse's.
        """
        q = self.inverse_.command(self.limits_.project(z_wanted), self._effective_state(), self.command_)
        q_limited = self.limits_.project(q)
        limited = q_limited.tolist() != q.tolist()
        if z_ahead is not None:
            u = plan(self.inverse_, np.vstack([z_wanted, z_ahead]), self._effective_state(), self.command_,
                     self.limits_.project)
            step = math.inf if self.rate_limit is None else self.rate_limit * self.dt_
            q_led = self.limits_.project(lead(u, step))
            limited = limited or q_led.tolist() != q_limited.tolist()  # its aim is not the command's
            q_limited = q_led
        if self.rate_limit is not None:
            q_limited, slowed = rate_limited(q_limited, self.command_, self.rate_limit * self.dt_)
            limited = limited or slowed
        self._limited = limited
        self.command_ = q_limited
        self._issued.append(q_limited)
        return q_limited.copy()


_COMMON_PARAMETERS = """
    pipeline : sklearn.pipeline.Pipeline
        Fitted pipeline of a backbone and, optionally, a residual, as
        :class:`~skcath.online.OnlineEstimator` takes it. Read, never modified.
        A pipeline of a PCC or PDL backbone alone gives the backbone's inverse.
    motor_limits : array-like of shape (2,) or (n_motors, 2), default=None
        Lowest and highest motor angle (deg), for every motor or one row per
        motor. None: the range of each motor angle over the sweep. Commands
        are also kept within the motor angles the estimator accepts (the
        sweep's amplitude around the neutral angles, plus its ``q_margin``).
    rate_limit : float or None, default=None
        Largest motor speed (deg/s): no command differs from the previous
        one by more than ``rate_limit * dt_`` on any motor, ``dt_`` being the
        sweep's median sample interval. None: no rate limit.
    reach_tol_mm : float, default=2.0
        A target whose nearest reachable model tip is farther than this (mm)
        warns with :class:`UnreachableTargetWarning`; the controller steers to
        that nearest tip (``aimed_``) either way.
    max_iter : int, default=8
        Most Gauss-Newton steps of the model's inverse per sample.
    damping : float, default=0.05
        Damping of the least-squares steps (mm/deg).
    latency : int, default=1
        Commands issued whose samples the observations do not show yet: the
        model is advanced by these (with the last torques) before it is
        inverted, and feedback compares the estimate with the tip aimed at
        ``latency + 1`` steps before. 1 for
        :class:`~skcath.datasets.SimulatedCatheter`, whose record of a sample
        is complete only once the next command is known; 0 where the
        observation is the sample that the previous command produced.
    preview : int, default=0
        Samples of path preview: at most this many of the targets ahead
        that :meth:`step` is given (``upcoming``) are solved for (each once,
        as it comes in view, from the solution of the one before) and
        turned into the commands they want through the hysteresis inverse;
        where those jump (a reversal, which crosses the play) faster than
        ``rate_limit`` allows, the crossing starts early, so that it is half
        made at the reversal. Commands stay within the motor and rate
        limits. 0: no preview, ``upcoming`` is not read. The preview runs on
        either engine: on numba inside the compiled step, with the numpy
        engine's commands (within 1e-6 deg).
    engine : {"auto", "numba", "numpy"}, default="auto"
        Engine of the model's step (:class:`~skcath.online.OnlineEstimator`).
"""

_COMMON_ATTRIBUTES = """
    estimator_ : OnlineEstimator
        The started estimator, stepped with every observation.
    limits_ : MotorLimits
        The motor limits in force.
    dt_ : float
        Sample interval the rate limit applies to (s).
    command_ : ndarray of shape (n_motors,)
        Last command (deg); after :meth:`start`, the last sweep sample's angles.
    estimate_ : ndarray of shape (3,)
        The model's tip estimate for the last observation (mm).
    aimed_ : ndarray of shape (3,)
        The model tip nearest the last target (mm; for the feedback, the wanted tip): the target itself when reachable.
    n_unreachable_ : int
        Targets farther than ``reach_tol_mm`` from every reachable model tip.
"""

_STEP_DOC = """Motor command for the next sample.

        Parameters
        ----------
        target : array-like of shape (3,)
            Wanted tip (mm, base frame); finite.
        obs : mapping, pandas.Series or sequence of float
            The sample just measured: ``q1 .. qN`` (deg), ``tau1 .. tauN``
            when the recordings have torques, optionally ``t`` (s), and the
            tracker's ``x, y, z`` (mm) when closing on the tracker. A sequence
            holds the channels in the order of ``estimator_.channels_``
            (then ``x, y, z``): the fast path.
        upcoming : array-like of shape (k, 3), default=None
            Targets of the next ``k`` samples (mm, base frame; finite), the
            first the target of the sample after this one: a planned path.
            Read with ``preview > 0`` (its first ``preview`` rows); None or
            ``k = 0``: nothing ahead is known (e.g. a reach target whose
            successor is not known yet).

        Returns
        -------
        command : ndarray of shape (n_motors,)
            Motor angles to command (deg), within the motor and rate limits.

        Warns
        -----
        UnreachableTargetWarning
            When the target lies farther than ``reach_tol_mm`` from every
            reachable model tip. The warning is the step's last act, issued
            once the step is complete: the estimator has taken the sample,
            the command is issued (``command_``, steering to ``aimed_``) and
            ``n_unreachable_`` counts the target. Where warnings are errors
            (``warnings.simplefilter("error")``) the step raises it in place
            of returning the command, and the controller's state is that of
            the completed step, as when the warning is not an error: the
            command to send is ``command_``, and the next step continues
            from it.
        """


class FeedforwardController(_Controller):
    __doc__ = f"""Feedforward inverse of a fitted tip model: the command whose predicted tip is the target.

    At every sample the model's own streaming step, from its present state,
    is inverted by a few Gauss-Newton steps (finite-difference Jacobian,
    warm-started from the previous solution) for the effective motor angles
    whose predicted tip is the target; the inverse of the hysteresis in
    front of the backbone (for ``hysteresis="play"``: the wanted angle plus or
    minus the play's half-width in the direction of motion; for
    ``hysteresis="pi"``: one step of the Prandtl-Ishlinskii model's inverse
    from the stream's state) turns those into
    the motor command, which is then kept within the motor and rate limits.
    The measured sample only advances the model's state: the loop is open.

    Parameters
    ----------{_COMMON_PARAMETERS}
    Attributes
    ----------{_COMMON_ATTRIBUTES}
    See Also
    --------
    FeedbackController : the same inverse, closed on the estimate or the tracker.
    """

    def __init__(self, pipeline, *, motor_limits=None, rate_limit=None, reach_tol_mm=2.0,
                 max_iter=8, damping=0.05, latency=1, preview=0, engine="auto"):
        self.pipeline = pipeline
        self.motor_limits = motor_limits
        self.rate_limit = rate_limit
        self.reach_tol_mm = reach_tol_mm
        self.max_iter = max_iter
        self.damping = damping
        self.latency = latency
        self.preview = preview
        self.engine = engine

    def step(self, target, obs, upcoming=None):
        self._check_started()
        target = check_target(target)
        ahead = self._upcoming(upcoming)
        if self._compiled is not None:
            command = self._step_compiled(target, obs, False, ahead)
        else:
            self._observe(obs)
            try:
                z, _, _ = self._aim(target)
                command = self._issue(z, None if ahead is None else self._angles_ahead(target, ahead, 0.0))
            finally:
                self.model_.end()
        self._warn_if_unreachable()
        return command

    step.__doc__ = _STEP_DOC


class FeedbackController(_Controller):
    __doc__ = f"""Feedback on the streamed tip estimate (or the tracker) through the model's inverse.

    With ``feedforward=True`` (default) the loop is an internal-model
    (Smith-predictor) loop on the wanted tip: every sample the model's
    error on the observed sample, ``d`` (the estimate, or the tracker's tip,
    minus the tip the model predicted for the command that sample shows,
    ``latency + 1`` steps before), is low-pass filtered into a tip
    correction, ``correction_ += gain * (d - correction_)``, and the model is
    solved as by :class:`FeedforwardController` for the wanted tip
    ``target - correction_``. As the prediction compared with the
    measurement is that of the command it measures, the loop's delay does
    not enter the loop; a wanted tip that moves smoothly goes through the
    hysteresis inverse, and a reversal of an effective angle smaller than
    ``dead_band`` is not made. The correction is not updated from a sample
    whose command was held at a motor or rate limit.

    With ``feedforward=False``, classical resolved rate: the tip error ``e``
    (the aimed tip minus the estimate, or minus the tracker's tip) moves the
    previous wanted angles by ``gain * (J^T J + damping^2 I)^-1 J^T e``,
    damped least squares on the model's Jacobian.

    Parameters
    ----------
    close_on : {{"estimate", "tracker"}}, default="estimate"
        Feedback on the model's estimate of the measured sample, or on the
        tracker's tip (``x, y, z`` of the observation): the latter needs the
        tracker and bounds what the estimate can give.
    feedforward : bool, default=True
        Whether the feedforward solution of the corrected wanted tip is the
        command (the internal-model loop), or the resolved-rate law moves the
        previous angles.
    gain : float, default=0.2
        Per sample: the weight of the newest model error in the tip
        correction (``feedforward=True``), or the fraction of the
        least-squares correction applied (``feedforward=False``); in (0, 1].
        Lower filters more of the measurement's noise and follows a change
        of the model's error more slowly (a time constant of about
        ``1 / gain`` samples).
    dead_band : float, default=1.0
        Smallest reversal of an effective angle (deg) the inverse of the
        play or of the Prandtl-Ishlinskii hysteresis makes; for a pipeline
        without either it has no effect. 0: every reversal.{_COMMON_PARAMETERS}
    Attributes
    ----------{_COMMON_ATTRIBUTES}    correction_ : ndarray of shape (3,)
        The filtered model error (mm) subtracted from the target, with
        ``feedforward=True``; zeros otherwise.

    See Also
    --------
    FeedforwardController : the open-loop inverse.
    """

    _parameter_constraints: dict = {
        **_Controller._parameter_constraints,
        "close_on": [StrOptions({"estimate", "tracker"})],
        "feedforward": ["boolean"],
        "gain": [Interval(Real, 0, 1, closed="right")],
        "dead_band": [Interval(Real, 0, None, closed="left")],
    }

    def __init__(self, pipeline, *, close_on="estimate", feedforward=True, gain=0.2, dead_band=1.0,
                 motor_limits=None, rate_limit=None, reach_tol_mm=2.0, max_iter=8, damping=0.05,
                 latency=1, preview=0, engine="auto"):
        self.pipeline = pipeline
        self.close_on = close_on
        self.feedforward = feedforward
        self.gain = gain
        self.dead_band = dead_band
        self.motor_limits = motor_limits
        self.rate_limit = rate_limit
        self.reach_tol_mm = reach_tol_mm
        self.max_iter = max_iter
        self.damping = damping
        self.latency = latency
        self.preview = preview
        self.engine = engine

    def _dead_band(self):
        return self.dead_band

    def _reset_feedback(self):
        self.correction_ = np.zeros(3)
        self._z_wanted = self.command_.copy()
        # (the tip the model predicted, whether the command was limited) of the commands not yet observed
        self._aims = deque([(None, True)] * (self.latency + 1), maxlen=self.latency + 1)

    def _mode(self):
        return MODE_INTERNAL_MODEL if self.feedforward else MODE_RESOLVED_RATE

    def step(self, target, obs, upcoming=None):
        self._check_started()
        target = check_target(target)
        ahead = self._upcoming(upcoming)
        if self._compiled is not None:
            command = self._step_compiled(target, obs, self.close_on == "tracker", ahead)
        else:
            aimed_before = self._aims[0]  # the aim of the command the observation shows
            estimate, tip = self._observe(obs, need_tracker=self.close_on == "tracker")
            try:
                command = self._feedback(target, aimed_before, estimate if tip is None else tip, ahead)
            finally:
                self.model_.end()
        self._warn_if_unreachable()
        return command

    step.__doc__ = _STEP_DOC

    def _feedback(self, target, aimed_before, measured, ahead=None):
        """The command from the model's solution and the error of the aim the observation shows.

        ``ahead``: the targets of the next samples (k, 3) (mm) or None; their
        wanted angles are corrected as this sample's are.
        """
        predicted, limited = aimed_before
        z_ahead = None
        if self.feedforward:
            if predicted is not None and not limited:
                self.correction_ = self.correction_ + self.gain * (measured - predicted - self.correction_)
            z, aimed, _ = self._aim(target - self.correction_)
            self._z_wanted = z
            if ahead is not None:
                z_ahead = self._angles_ahead(target, ahead, self.correction_)
        else:
            z_ff, aimed, J = self._aim(target)
            step = self.gain * damped_solve(J, aimed - measured, self.damping)
            self._z_wanted = self.limits_.project(self._z_wanted + step)
            if ahead is not None:  # moved by the feedback's offset from this sample's feedforward solution
                z_ahead = self._angles_ahead(target, ahead, 0.0) + (self._z_wanted - z_ff)
        command = self._issue(self._z_wanted, z_ahead)
        self._aims.append((aimed, self._limited))
        return command
