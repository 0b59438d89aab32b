"""Streaming tip estimation: one motor sample in, one tip position out.

:class:`OnlineEstimator` wraps a fitted pipeline (a backbone, optionally
followed by a residual learner). ``start`` calibrates the backbone on one
run's sweep and encodes the sweep context, exactly as ``Pipeline.predict``
does for that run; ``step`` then estimates the tip from one motor sample at
a time, carrying the recurrent state between calls. The step
(:func:`skcath.online._kernels.step`) runs as Python with numpy calls
(:mod:`skcath.online._fast`) or, when numba is installed, compiled
(:mod:`skcath.online._jit`).
"""

from __future__ import annotations

import copy
import math
import warnings
from numbers import Real

import numpy as np
from sklearn.base import BaseEstimator, _fit_context
from sklearn.exceptions import NotFittedError
from sklearn.utils._param_validation import HasMethods, Interval, StrOptions, validate_params
from sklearn.utils.validation import check_is_fitted

from .. import _format as fmt
from .._rate import RATE_TOLERANCE, TICK_TOLERANCE, run_at_rate
from .._sweep_end import N_SWEEP_ATTR, naming_n_sweep
from ..backbones import (
    BACKBONE_COLUMNS,
    PCCParams,
    PolynomialParams,
    play_kernel,
    play_operator,
)
from ..exceptions import PipelineChangedWarning
from ..frames import _sweep_frame
from ..residuals._context import sweep_context
from ..sweep import _find_rays
from ._fast import BackboneStep, NumpyStep
from ._model_view import ModelView
from ._pi_stream import kept_angles, pi_step_of, start_hysteresis
from ._pipeline import STEP_BACKBONES, check_online_pipeline
from ._sample import as_real, real_sample
from ._sweep import calibrate, check_sweep
from ._weights import fitted_fingerprint, step_weights

__all__ = ["OnlineEstimator", "calibrate_sweep"]


@validate_params(
    {"backbone": list(STEP_BACKBONES), "sweep": "no_validation"},
    prefer_skip_nested_validation=True,
)
def calibrate_sweep(backbone, sweep):
    """Calibrate a backbone on the sweep rows of one run, as its ``predict`` does.

    Parameters
    ----------
    backbone : PCCBackbone, PDLBackbone or PolynomialBackbone
        A fitted backbone (its sweep and solver parameters are used).
    sweep : pandas.DataFrame
        The sweep rows of one run in the long format.

    Returns
    -------
    params : PCCParams, PDLParams or PolynomialParams
        Calibrated parameters of the run.
    nominal : ndarray of shape (n_sweep, 3)
        Nominal tip of every sweep row (mm).

    See Also
    --------
    skcath.backbones.PDLBackbone.calibrate : the calibrations of every run of recordings.
    """
    check_is_fitted(backbone)
    params, nominal, _ = calibrate(backbone, check_sweep(sweep))
    return params, nominal


def _step_class(engine):
    """The step's class for ``engine``: the numba engine's where it applies, else the numpy one."""
    if engine == "numpy":
        return NumpyStep
    try:  # numba is optional: its engine is imported when it is asked for
        from . import _jit
    except ImportError as exc:
        if engine == "numba":
            raise ImportError(
                'engine="numba" needs numba, which could not be imported '
                f"({exc}); install it with pip install \"skcath[fast]\" (or pip install "
                'numba), or use engine="numpy" or engine="auto".'
            ) from exc
        return NumpyStep
    return _jit.JitStep


def _step_inputs(residual, rotation, context):
    """What the step reads of the residual: folded weights, clip bound, torque features.

    Taken from the pipeline once, by :meth:`OnlineEstimator.start`; the
    estimator keeps them (and pickles them), so that refitting the pipeline
    afterwards does not change a started estimator. ``(None, inf, False)``
    without a learned residual.
    """
    if residual is None:
        return None, math.inf, False
    clip = math.inf if residual.clip is None else float(residual.clip)
    return step_weights(residual, rotation, context), clip, residual.use_torque


def _without_reference(X):
    """``X`` with its reference tip replaced by NaN columns: what a sweep without the tracker holds."""
    return X.drop(columns=list(fmt.REFERENCE_COLUMNS), errors="ignore").assign(
        **{c: np.nan for c in fmt.REFERENCE_COLUMNS}
    )


def _kept_nominal(params, q):
    """Nominal tip (mm) of a kept calibration at the (played) motor angles ``q`` (deg), as the step evaluates it."""
    backbone = BackboneStep(params)
    return np.array([backbone(q1, q2) for q1, q2 in q.tolist()], dtype=np.float64).reshape(-1, 3)


def _motors(channels):
    """The motor angles ``q1 .. qN`` among the channels of a recording."""
    return [c for c in channels if fmt.channel_index(c)[0] == "q"]


def _motor_range(q, q_neutral, q_margin):
    """Sweep amplitude and largest accepted distance (deg) of the motor angles from neutral."""
    amplitude = float(np.hypot.reduce(q - q_neutral, axis=1).max())
    return amplitude, (math.inf if q_margin is None else (1.0 + q_margin) * amplitude)


def _sweep_at_rate(residual, X, sweep, nominal):
    """The sweep brought to the residual's rate, or None if it is at that rate already.

    ``X`` holds the rows of the checked sweep ``sweep`` (a
    :class:`~skcath.online._sweep.CheckedSweep`), ``nominal`` the backbone's
    tip on them (mm). Returns the rotation ``R_SB`` of the resampled sweep
    (``frame="sweep"``, else None), its frame (for the context), its last
    sample (the values of the sweep's channels) and its number of ticks, as
    ``predict`` sees the run.
    """
    rate = getattr(residual, "rate_hz_", None)
    at_rate = run_at_rate(X.assign(**dict(zip(BACKBONE_COLUMNS, nominal.T))), sweep.run, sweep.t,
                          rate, type(residual).__name__)
    if at_rate is None:
        return None
    Xr = at_rate.X
    q = Xr[list(sweep.motors)].to_numpy(dtype=np.float64)
    rotation = None
    if residual.frame == "sweep":
        rotation = _sweep_frame(q, Xr[list(BACKBONE_COLUMNS)].to_numpy(dtype=np.float64), sweep.run)
    last = Xr[list(sweep.channels)].to_numpy(dtype=np.float64)[-1]
    return rotation, Xr, tuple(float(v) for v in last), len(Xr)


def _neutral_angles(params):
    """Neutral motor angles (deg) of a calibration: for a polynomial, the centre of its angles."""
    if isinstance(params, PolynomialParams):
        return np.array(params.mean, dtype=float)
    return np.array(params.q0 if isinstance(params, PCCParams) else params.q_neutral, dtype=float)



class OnlineEstimator(BaseEstimator):
    """Streaming tip estimator: one motor sample in, one tip position out.

    Wraps a fitted pipeline of a backbone and a residual learner. :meth:`start`
    calibrates the backbone on one run's sweep and encodes the sweep context
    once; :meth:`step` then returns the tip position for one motor sample
    ``(q1, q2, tau1, tau2)`` (for ``N`` motors ``(q1 .. qN, tau1 .. tauN)``,
    the torques only when the recordings have them), carrying the recurrent
    state from call to call.
    Stepping through the motion samples of a run after ``start`` on its sweep
    reproduces ``pipeline.predict`` on the motion rows of that run (see
    *Notes* for the tolerance). After a shaft change, :meth:`resweep`
    re-encodes the context from a new sweep of the motors alone, keeping the
    backbone's calibration or renewing it with a
    :class:`~skcath.online.MotorRecalibration`; the attributes of the sweep (``run_``,
    ``rotation_``, ``context_``, ``q_neutral_``, ``q_amplitude_``,
    ``q_limit_``) are then those of the new sweep.

    Parameters
    ----------
    pipeline : sklearn.pipeline.Pipeline
        Fitted ``Pipeline([("backbone", PCCBackbone() | PDLBackbone() |
        PolynomialBackbone()), ("residual", NoResidual() | MLPResidual() |
        GRUResidual())])``; the residual step may be left out. Any number of
        motors with :class:`~skcath.backbones.PolynomialBackbone`; PCC and
        PDL have two. It is read, never modified.
        :meth:`start` takes what the step needs from it (the backbone's
        calibration on the sweep, the sweep context, the network's weights
        folded with the run's constants) and keeps it: a started estimator
        does not follow a later refit of the pipeline, and neither does its
        pickled copy. :meth:`reset` and unpickling warn with
        :class:`~skcath.exceptions.PipelineChangedWarning` when the pipeline
        has been refit or its parameters set since :meth:`start`; call
        :meth:`start` again to step the pipeline as it is. A network trained
        on a GPU is read into CPU arrays.
    dtype : {"float64", "float32"}, default="float64"
        Precision of the residual network's arithmetic on the step path.
        ``"float64"`` evaluates the fitted (float32) weights without
        rounding; ``"float32"`` is faster for large networks and rounds as
        the trained network does. The backbone is always evaluated in
        float64.
    on_invalid : {"raise", "hold"}, default="raise"
        What :meth:`step` does with a sample that has a non-finite value
        (NaN, inf) or motor angles out of range (see ``q_margin``).
        ``"raise"``: raise ``ValueError`` naming the channel and leave the
        state unchanged, so that the caller may skip the sample and go on.
        ``"hold"``: replace each non-finite channel, and both motor angles
        if they are out of range, by its last accepted value (the last
        sweep sample before the first step), step with that, and count the
        sample in ``n_held_``. A NaN never reaches the tip estimate.
        "Both motor angles" means all of them for ``N`` motors.
    q_margin : float or None, default=0.25
        Motor angles are out of range when their distance from the neutral
        motor angles of the sweep exceeds ``1 + q_margin`` times the sweep
        amplitude, the largest such distance among the sweep samples (the
        backbone is calibrated within the amplitude and extrapolates
        beyond). None accepts any finite angle.
    detector : object or None, default=None
        Optional change detector with ``start(sweep)`` (returning the
        started detector) and ``step(*sample) -> bool`` (``step(q1, q2, tau1,
        tau2)`` for the default catheter, as
        :class:`~skcath.online.ShaftChangeDetector`). A copy of
        it, ``detector_``, is started by :meth:`start` with the same sweep
        and stepped by :meth:`step` with the same (accepted) sample; its last
        answer is ``shaft_changed_``. The object passed is never changed.
    engine : {"auto", "numba", "numpy"}, default="auto"
        What evaluates a step after the input checks: the one step function
        (backbone, features, network, clip; :mod:`skcath.online._kernels`),
        compiled or run as Python. ``"numba"``: compiled
        (:mod:`skcath.online._jit`), which needs the optional dependency numba
        (``pip install "skcath[fast]"``); it is compiled once per machine and
        dtype (numba's cache, several seconds) and loaded by :meth:`start`.
        ``"numpy"``: run as Python, its vector operations as numpy calls, a
        dozen or so per step, slower (``docs/deploying.rst`` gives measured
        times). ``"auto"``: numba when it can be imported, else numpy. Both
        engines give the same tips up to rounding (see *Notes*).

    Attributes
    ----------
    run_ : str
        Run id of the sweep given to :meth:`start`.
    channels_ : tuple of str
        The channels :meth:`step` takes, in order: the motor angles ``q1 ..
        qN`` of the sweep's recordings, then their torques ``tau1 .. tauN``
        if they have them.
    backbone_params_ : PCCParams, PDLParams or PolynomialParams
        The backbone's calibration on the sweep.
    play_width_ : float
        Half-width of the play in front of the backbone (deg), identified
        on the sweep by a backbone with ``hysteresis="play"``; 0 otherwise.
    play_state_ : ndarray of shape (n_motors,)
        Played motor angles of the last step (deg), which the backbone
        reads: right after :meth:`start` or :meth:`reset`, those of the last
        sweep sample (:func:`~skcath.backbones.play_operator` on the sweep).
        With a half-width of 0 the step skips the play (the backbone reads
        the motor angles as they are) and this stays as :meth:`start` set it.
    hysteresis_ : PrandtlIshlinskii or None
        With a backbone of ``hysteresis="pi"``: the run's Prandtl-Ishlinskii
        hysteresis, identified on the sweep as the backbone's ``calibrate``
        does, which the step runs in front of the backbone (``play_width_``
        is then 0); None otherwise.
    hysteresis_state_ : ndarray of shape (n_motors * (K + 2),) or None
        State of ``hysteresis_`` after the last step (deg; per motor the
        dead band's output, the ``K`` plays and the creep, as
        :func:`~skcath.backbones.pi_step`): right after :meth:`start` or
        :meth:`reset`, its state at the end of the sweep, run from rest at
        the sweep's first row. None without it.
    rotation_ : ndarray of shape (3, 3) or None
        ``R_SB`` of the sweep (residual learners with ``frame="sweep"``), else None.
    context_ : ndarray of shape (context_size,) or None
        The sweep context ``z``, or None (no residual or no context).
    q_neutral_ : ndarray of shape (n_motors,)
        Neutral motor angles of the sweep (deg), as found by the backbone's
        calibration; for a polynomial backbone the centre of the motor angles
        it was fitted on.
    q_amplitude_ : float
        Sweep amplitude: the largest distance of a sweep sample's motor
        angles from ``q_neutral_`` (deg).
    q_limit_ : float
        Largest accepted distance of the motor angles from ``q_neutral_``
        (deg); inf when ``q_margin`` is None.
    n_steps_ : int
        Samples stepped since :meth:`start` or :meth:`reset`.
    n_held_ : int
        Of those, samples that had a value replaced (``on_invalid="hold"``).
    nominal_ : ndarray of shape (3,)
        Nominal (backbone) tip of the last step (mm).
    engine_ : {"numba", "numpy"}
        The engine in use since :meth:`start`.
    compile_seconds_ : float
        Time :meth:`start` spent compiling the step, or loading it from
        numba's cache (s); 0 on the numpy engine.
    detector_ : object
        The started copy of ``detector`` (only with a detector).
    shaft_changed_ : bool
        Last answer of ``detector_`` (only with a detector).
    rate_hz_ : float or None
        Rate of the residual learner (Hz, its ``rate_hz_``), at which the
        model steps; None without a learned residual.
    resampled_ : bool
        Whether the stream is stepped at the model's ticks rather than once
        per sample: from :meth:`start` on when the sweep is at another rate
        than ``rate_hz_`` (or uneven), or from the first sample given with a
        time ``t`` whose time step is not within 10 % of the model's step.

    See Also
    --------
    skcath.online.export : the residual's stepping network as ONNX or TorchScript.

    Notes
    -----
    The backbone's evaluation and the step features are computed as in
    ``predict``. With ``dtype="float64"`` the step matches ``predict`` of the
    same pipeline run in float64 (``residual.module_.double()``) to 1e-9 mm;
    against the float32 ``predict`` (as fitted) the difference is that
    prediction's own float32 rounding, about 1e-6 mm for the default GRU
    (``docs/deploying.rst`` gives the measured values; the tests check
    1e-4 mm). For :class:`NoResidual` and the backbone alone the match is
    exact to 1e-9 mm. The first step after :meth:`start` or :meth:`reset`
    takes its motor differences from the last sweep sample, as ``predict``
    does for the first motion row.

    **Streams at another rate.** The residual learner counts time in
    samples at its rate ``rate_hz_``. A sweep at another rate (or uneven)
    is brought to that rate as ``predict`` brings the run: the context and
    the sweep frame are those of the sweep resampled onto the ticks
    ``t_0 + k / rate_hz_`` from its first sample (``docs/residuals.rst``,
    *Sample rates*), and :meth:`step` then needs the time ``t`` of every
    sample. The model steps whenever the stream's time reaches its next
    tick, on the sample interpolated linearly between the previous sample
    and this one at the tick (a sample spanning several ticks steps it
    several times). Every sample returns the backbone's tip at the sample
    itself plus the residual of the latest tick, held until the next tick
    (0 before the first motion tick). ``predict`` interpolates the residual
    between the ticks around a row instead, and takes the backbone's tip at
    a tick from the rows around it where the step evaluates the backbone at
    the interpolated angles. On rows that fall on a tick, the two agree as
    at the model's rate (for a backbone without play; the play in the step
    moves at the ticks, in ``predict`` at every row); between ticks they
    differ by at most the residual's change within one tick
    (``docs/deploying.rst``, *Streams at another rate*). A stream whose sweep is at the model's rate,
    given ``t``, is stepped once per sample until a time step leaves the
    10 % tolerance; from then on it is stepped at the ticks, counted from
    the last sample (``predict`` resamples such a run as a whole).

    The two engines run the same step on the same folded weights; they
    differ in the order of the additions within a matrix-vector product and
    in the compiled step evaluating the gates' and the head's nonlinearities
    with exponentials of its own. In float64 both match the float64
    ``predict`` to 1e-9 mm; in float32 they agree to float32 rounding (the
    tests check 1e-5 mm).

    Examples
    --------
    >>> est = OnlineEstimator(pipe).start(X_run[X_run["phase"] == "sweep"])  # doctest: +SKIP
    >>> tip = est.step(q1, q2, tau1, tau2)  # (3,) mm  # doctest: +SKIP
    >>> est.channels_  # doctest: +SKIP
    ('q1', 'q2', 'tau1', 'tau2')
    """

    _parameter_constraints: dict = {
        "pipeline": [HasMethods(["predict"])],
        "dtype": [StrOptions({"float64", "float32"})],
        "on_invalid": [StrOptions({"raise", "hold"})],
        "q_margin": [Interval(Real, 0, None, closed="left"), None],
        "detector": [HasMethods(["start", "step"]), None],
        "engine": [StrOptions({"auto", "numba", "numpy"})],
    }

    def __init__(self, pipeline, *, dtype="float64", on_invalid="raise", q_margin=0.25,
                 detector=None, engine="auto"):
        self.pipeline = pipeline
        self.dtype = dtype
        self.on_invalid = on_invalid
        self.q_margin = q_margin
        self.detector = detector
        self.engine = engine

    # ------------------------------------------------------------------ set-up
    def start(self, sweep):
        """Calibrate on the sweep of one run and encode its context.

        Parameters
        ----------
        sweep : pandas.DataFrame
            The sweep rows (``phase == "sweep"``) of one run in the long
            format, with the reference tip ``ref_x, ref_y, ref_z`` (mm).

        Returns
        -------
        self : OnlineEstimator
            Ready for :meth:`step`, with a zero recurrent state.
        """
        self._started = False  # until this start has succeeded
        return self._start(sweep)

    @_fit_context(prefer_skip_nested_validation=True)
    def _start(self, sweep):
        """:meth:`start` once the parameters are validated."""
        step_class = _step_class(self.engine)
        backbone, residual = check_online_pipeline(self.pipeline)
        self._fingerprint = fitted_fingerprint(backbone, residual)
        sweep = check_sweep(sweep)  # the sweep's rows are checked here, once
        X, motors, torques, q, tau = sweep.X, sweep.motors, sweep.torques, sweep.q, sweep.tau
        if residual is not None:  # its checks of the motors and torques, before any work
            residual._check_torques(motors, torques)
            residual._check_motor_count(motors)
        self.backbone_params_, nominal, hysteresis = calibrate(backbone, sweep)
        self.play_width_ = start_hysteresis(self, hysteresis, q, sweep.t)
        self.run_ = sweep.run
        self.channels_ = sweep.channels
        self._calibration_sweep = X[[*fmt.ID_COLUMNS, fmt.TIME, fmt.PHASE, *motors, *torques]]
        played = play_operator(q, self.play_width_) if self.play_width_ > 0 else q
        self._play_start = tuple(float(v) for v in played[-1])
        self.rotation_ = None
        self.context_ = None
        self._start_clock(X, residual, q, tau)
        if residual is not None:
            self._encode_sweep(residual, sweep, nominal)
        self.q_neutral_ = _neutral_angles(self.backbone_params_)
        self.q_amplitude_, self.q_limit_ = _motor_range(q, self.q_neutral_, self.q_margin)
        self._qn = tuple(float(v) for v in self.q_neutral_)
        self._limit2 = self.q_limit_ * self.q_limit_
        self._step_inputs = _step_inputs(residual, self.rotation_, self.context_)
        self._pack(step_class)
        if self.detector is not None:
            # a copy: the parameter stays as given, and two estimators never share state
            self.detector_ = copy.deepcopy(self.detector).start(X)
            self.shaft_changed_ = False
        self._started = True
        return self.reset()

    def _start_clock(self, X, residual, q, tau):
        """The stream's clock: the model's rate, the sweep's end, stepping per sample."""
        self.rate_hz_ = None if residual is None else getattr(residual, "rate_hz_", None)
        self.resampled_ = False
        self._last_sweep = (*(float(v) for v in q[-1]), *(float(v) for v in tau[-1]))
        t = X[fmt.TIME].to_numpy(dtype=np.float64)
        self._sweep_end = (float(t[-1]), self._last_sweep)
        self._tick0 = float(t[0])
        self._n_sweep_ticks = 0

    def _encode_sweep(self, residual, sweep, nominal):
        """The sweep frame ``rotation_`` and context ``context_`` of a checked sweep, at the model's rate.

        ``nominal`` is the backbone's tip on the sweep's rows (mm). A sweep at
        another rate than the residual's is brought to it first, as
        ``predict`` brings the run (``resampled_``).
        """
        resampled = _sweep_at_rate(residual, sweep.X, sweep, nominal)
        if resampled is None:
            if residual.frame == "sweep":
                self.rotation_ = _sweep_frame(sweep.q, nominal, sweep.run)
            if residual.use_context:
                self.context_ = sweep_context(residual, sweep.X, len(sweep.motors), self.dtype)
            return
        self.rotation_, Xr, self._last_sweep, self._n_sweep_ticks = resampled
        self.resampled_ = True
        if residual.use_context:
            self.context_ = sweep_context(residual, Xr, len(sweep.motors), self.dtype)

    def _pack(self, step_class):
        """The step's packed arrays from what :meth:`start` took from the pipeline.

        The backbone's calibration and the folded weights, clip and features
        of the residual (``_step_inputs``, see :func:`_step_inputs`);
        ``step_class`` is the engine's (:class:`~skcath.online._fast.NumpyStep`
        or :class:`~skcath.online._jit.JitStep`). Sets ``nominal_``,
        ``engine_`` and ``compile_seconds_``; the recurrent state is zero.
        """
        weights, clip, use_torque = self._step_inputs
        # without a play (also when pickled before the play existed) the angles pass as they are
        backbone = BackboneStep(self.backbone_params_, getattr(self, "play_width_", 0.0),
                                getattr(self, "_play_start", None), pi_step_of(self))
        n_channels = self._n_channels = len(self._channels())
        self._packed = step_class(backbone, weights, clip, use_torque, self.dtype, n_channels,
                                  self._qn, self._limit2)
        self._backbone = backbone
        self._call = self._packed.call
        self._last = self._packed.last  # updated by every step
        self.nominal_ = self._packed.nominal
        self.play_state_ = self._packed.play
        self._pi, self._dt = backbone.pi, self._packed.dt
        self.hysteresis_ = None if backbone.pi is None else backbone.pi.model
        self.hysteresis_state_ = self._packed.pi_state
        self.engine_ = self._packed.engine
        self.compile_seconds_ = self._packed.compile_seconds

    # ------------------------------------------------------------ re-sweep
    def resweep(self, sweep, recalibration=None):
        """Re-encode the run's context from a sweep without the tracker; keep or renew the calibration.

        After the shaft has been repositioned (for example when the detector
        raises ``shaft_changed_``), a new sweep recorded with the motors
        alone, the tracker off, renews what depends on the sweep's motor
        angles and torques, and keeps the backbone's calibration of the
        tracked sweep given to :meth:`start`:

        * the sweep context ``context_`` is encoded from the new sweep;
        * the sweep frame ``rotation_`` is that of the *kept* calibration
          (and play) evaluated on the new sweep's motor angles;
        * the neutral motor angles ``q_neutral_`` are found on the new sweep
          (:func:`skcath.sweep.find_rays`, with the backbone's ``n_rays``),
          and ``q_amplitude_`` and ``q_limit_`` follow;
        * the detector, if any, is started again on the new sweep
          (``shaft_changed_`` is False);
        * with a backbone of ``hysteresis="play"``, the play keeps its
          half-width ``play_width_`` and starts the motion from its state at
          the end of the new sweep (the new sweep's motor angles through the
          kept play); with ``hysteresis="pi"`` likewise the kept
          ``hysteresis_``, run from rest at the new sweep's first row;
        * ``backbone_params_`` stays as it is, and the recurrent state
          restarts at zero (as after :meth:`reset`, from the last sample of
          the new sweep).

        The reference tip is never read. A tracked re-sweep calibrates the
        backbone again as well: call :meth:`start` with it instead.

        With a fitted ``recalibration``
        (:class:`~skcath.online.MotorRecalibration`), the calibration is
        renewed from the motors as well: the tip along the new sweep is
        predicted from the kept calibration and the change of the sweep's
        torque loops (``recalibration.recalibrate``), and the estimator is
        started on that predicted tracked sweep, as :meth:`start` does
        (new calibration, context, sweep frame, motor range and detector).
        It needs the torques ``tau1``, ``tau2`` of a two-motor catheter.

        Parameters
        ----------
        sweep : pandas.DataFrame
            The sweep rows (``phase == "sweep"``) of one run in the long
            format, the same rays as the sweep of :meth:`start`. The
            reference columns ``ref_x``, ``ref_y``, ``ref_z`` may be absent
            or NaN.
        recalibration : MotorRecalibration or None, default=None
            A fitted recalibration to renew the backbone's calibration with;
            None keeps the calibration.

        Returns
        -------
        self : OnlineEstimator
            Ready for :meth:`step`, with a zero recurrent state.

        Raises
        ------
        sklearn.exceptions.NotFittedError
            Before :meth:`start`.
        ValueError
            If the pipeline has been refit or its parameters set since
            :meth:`start` (its residual would not match the kept
            calibration), or the sweep is not the sweep of one run (for a
            sweep read with ``n_sweep``, the error names it). The
            estimator is then left as it was.

        Notes
        -----
        The parameters of the estimator are validated again and used as they
        are now, as by :meth:`start`. ``docs/shaft_change.rst`` (*Recovering
        without the tracker*) measures how much of a shaft change's error a
        motor-only re-sweep removes on the simulated benchmark, against a
        tracked one.
        """
        self._check_started()
        if recalibration is not None:
            return self._recalibrate(sweep, recalibration)
        return self._resweep(sweep)

    def _recalibrate(self, sweep, recalibration):
        """:meth:`resweep` with a recalibration: start on the re-sweep with the predicted tip."""
        if not hasattr(recalibration, "recalibrate"):
            raise TypeError(
                "recalibration must be a fitted MotorRecalibration (with a recalibrate method); "
                f"got {type(recalibration).__name__}."
            )
        check_is_fitted(recalibration)
        if self._pipeline_changed():
            raise ValueError(
                "resweep renews the calibration from the one taken at start(), but the pipeline "
                "has been refit or its parameters set since start(). Call start(sweep) with a "
                "tracked sweep."
            )
        kept = getattr(self, "_calibration_sweep", None)
        channels = self._channels()
        if kept is None or channels != (*fmt.MOTOR_COLUMNS, *fmt.TORQUE_COLUMNS):
            raise ValueError(
                "resweep(recalibration=...) reads the torque loops of two motors, q1, q2 with "
                f"tau1, tau2, on the sweep given to start(); this estimator has {', '.join(channels)}"
                + ("" if kept is not None else ", and was started or pickled without its sweep")
                + ". Call start(sweep) with a tracked sweep."
            )
        X = check_sweep(sweep, columns=(*fmt.ID_COLUMNS, fmt.TIME, fmt.PHASE, *channels)).X
        predicted = recalibration.recalibrate(kept, _without_reference(X), params=self.backbone_params_)
        return self.start(predicted)

    @_fit_context(prefer_skip_nested_validation=True)
    def _resweep(self, sweep):
        """:meth:`resweep` once the parameters are validated; changes nothing until the sweep is read."""
        step_class = _step_class(self.engine)
        if self._pipeline_changed():
            raise ValueError(
                "resweep encodes the new sweep with the pipeline's residual learner and keeps "
                "the calibration taken at start(), but the pipeline has been refit or its "
                "parameters set since start(). Call start(sweep) with a tracked sweep."
            )
        backbone, residual = check_online_pipeline(self.pipeline)
        channels = self._channels()
        motors = _motors(channels)
        if len(motors) != 2:
            raise ValueError(
                f"resweep finds the rays of a two-motor sweep; this estimator was started on "
                f"{len(motors)} motor(s) ({', '.join(motors)}). Call start(sweep) with a tracked "
                "sweep instead."
            )
        sweep = check_sweep(sweep, columns=(*fmt.ID_COLUMNS, fmt.TIME, fmt.PHASE, *channels))
        run = sweep.run
        if sweep.channels != channels:
            raise ValueError(
                f"the re-sweep has the channels {', '.join(sweep.channels)}, but the "
                f"sweep given to start() had {', '.join(channels)}; resweep needs the same "
                "motor and torque columns."
            )
        X = _without_reference(sweep.X)
        q = X[motors].to_numpy(dtype=np.float64)
        tau = X[[c for c in channels if c not in motors]].to_numpy(dtype=np.float64)
        given = sweep.X.attrs.get(N_SWEEP_ATTR, {})  # the n_sweep it was read with
        with naming_n_sweep((given[run], sweep.t) if run in given else None, q, run):
            rays = _find_rays(
                q, n_rays=backbone.n_rays,
                ray_spacing_deg=getattr(backbone, "ray_spacing_deg", None), run=run,
            )
        # the kept play or PI (none before the play existed, e.g. unpickled) over the new sweep
        played = kept_angles(self, q, sweep.t)
        nominal = _kept_nominal(self.backbone_params_, played)
        rotation = context = at_rate = None
        if residual is not None:
            # a sweep at another rate than the model's is brought to it, as in start
            at_rate = _sweep_at_rate(residual, X, sweep, nominal)
            if at_rate is not None:
                rotation, Xr, _, _ = at_rate
            elif residual.frame == "sweep":
                rotation = _sweep_frame(q, nominal, run)
            if residual.use_context:
                context = sweep_context(residual, X if at_rate is None else Xr, len(motors), self.dtype)
        detector = None if self.detector is None else copy.deepcopy(self.detector).start(X)

        self.run_, self.rotation_, self.context_ = run, rotation, context
        self.q_neutral_ = np.array(rays.q_neutral, dtype=float)
        self.q_amplitude_, self.q_limit_ = _motor_range(q, self.q_neutral_, self.q_margin)
        self._start_clock(X, residual, q, tau)
        if at_rate is not None:
            _, _, self._last_sweep, self._n_sweep_ticks = at_rate
            self.resampled_ = True
        self._play_start = tuple(float(v) for v in played[-1])
        self._qn = tuple(float(v) for v in self.q_neutral_)
        self._limit2 = self.q_limit_ * self.q_limit_
        self._step_inputs = _step_inputs(residual, rotation, context)
        self._pack(step_class)
        if detector is not None:
            self.detector_, self.shaft_changed_ = detector, False
        return self.reset()

    def _channels(self):
        """``channels_``; two motors with torques for an estimator pickled before it existed."""
        return getattr(self, "channels_", (*fmt.MOTOR_COLUMNS, *fmt.TORQUE_COLUMNS))

    # ------------------------------------------------------------ pickling
    # The packed arrays are viewed by the estimator (the hidden state, the
    # last sample, the nominal tip), which pickle would turn into detached
    # copies. A pickle therefore holds the calibration, the folded weights
    # taken at start and the running state, and loading packs the step again
    # from those (not from the pipeline, which may have been refit since)
    # and restores the state.
    _RUNTIME = ("_packed", "_call", "_last", "nominal_", "play_state_", "_backbone", "_out",
                "_pi", "_dt", "hysteresis_", "hysteresis_state_")

    def __getstate__(self):
        state = {k: v for k, v in super().__getstate__().items() if k not in self._RUNTIME}
        if self._started:
            state["_running"] = {
                "hidden": [np.array(h) for h in self._packed.hidden],
                "last": [float(v) for v in self._last],
                "nominal": np.array(self.nominal_),
                "play": [float(v) for v in self.play_state_],
            }
            if self._pi is not None:
                state["_running"]["pi"] = np.array(self.hysteresis_state_)
        return state

    def __setstate__(self, state):
        state = dict(state)
        running = state.pop("_running", None)
        super().__setstate__(state)
        if running is None:
            return
        if not hasattr(self, "_step_inputs"):  # pickled before the weights were kept
            _, residual = check_online_pipeline(self.pipeline)
            self._step_inputs = _step_inputs(residual, self.rotation_, self.context_)
        # engine="auto" takes numba if it can be imported where the pickle is loaded
        self._pack(_step_class(self.engine))
        for h, saved in zip(self._packed.hidden, running["hidden"], strict=True):
            h[:] = saved
        self._last[:] = running["last"]
        self.nominal_[:] = running["nominal"]
        if "play" in running:  # pickled before the play existed: no play, nothing to restore
            self.play_state_[:] = running["play"]
        if "pi" in running:
            self.hysteresis_state_[:] = running["pi"]
        self._warn_if_pipeline_changed("was unpickled")

    def reset(self):
        """Start a new motion sequence: zero recurrent state, as right after :meth:`start`.

        The first step after ``reset`` takes its motor differences from the
        last sweep sample, as ``predict`` does for the first motion row.
        The detector, if any, is not reset. The estimator goes on stepping
        the pipeline as it was at :meth:`start`; if the pipeline has been
        refit or its parameters set since, ``reset`` warns with
        :class:`~skcath.exceptions.PipelineChangedWarning`.

        Returns
        -------
        self : OnlineEstimator
        """
        self._check_started()
        self._warn_if_pipeline_changed("was reset")
        self._packed.reset(self._last_sweep)
        self.n_steps_ = 0
        self.n_held_ = 0
        self._ticking = self.resampled_ = getattr(self, "_n_sweep_ticks", 0) > 0
        self._t_prev, self._x_prev = getattr(self, "_sweep_end", (None, None))
        self._tick = getattr(self, "_n_sweep_ticks", 0)
        self._residual_last = np.zeros(3)
        self._sample_play = getattr(self, "_play_start", None) or (0.0,) * len(self._qn)
        self._t_step = self._t_prev  # when the packed step last stepped (the PI's creep)
        self._sample_pi = None if self._pi is None else self._pi.start.copy()
        return self

    def _pipeline_changed(self):
        """Whether the pipeline no longer is the one :meth:`start` took its step from."""
        fingerprint = getattr(self, "_fingerprint", None)
        if fingerprint is None:  # pickled before fingerprints were kept
            return False
        try:
            return fitted_fingerprint(*check_online_pipeline(self.pipeline)) != fingerprint
        except (TypeError, ValueError, AttributeError):  # no longer a fitted pipeline
            return True

    def _warn_if_pipeline_changed(self, event):
        """Warn when the pipeline no longer is the one :meth:`start` took its step from."""
        if self._pipeline_changed():
            warnings.warn(
                f"This OnlineEstimator {event}, but its pipeline has been refit or its "
                "parameters set since start(): the estimator steps the pipeline as it was "
                "at start (its calibration, sweep context and weights), not the pipeline "
                "it holds now. Call start(sweep) again to step the pipeline as it is.",
                PipelineChangedWarning,
                stacklevel=3,
            )

    def _check_started(self):
        if not self._started:
            raise NotFittedError(
                "This OnlineEstimator has not been started; call start(sweep) with the "
                "sweep rows of the run before step or reset."
            )

    # ------------------------------------------------------------------ step
    _started = False
    _ticking = False  # stepping at the model's ticks (another rate, uneven times)
    _out = None  # the last out array checked by step

    def _accept(self, sample):
        """The sample to step with after the bad-input policy (a tuple of floats)."""
        channels = self._channels()
        n = len(self._qn)
        bad = [name for name, v in zip(channels, sample) if not math.isfinite(v)]
        if not bad:
            distance = math.sqrt(self._distance2(sample))
            if distance * distance <= self._limit2:
                return sample
        if self.on_invalid == "raise":
            if bad:
                values = ", ".join(
                    f"{name}={v!r}{' deg' if k < n else ''}"
                    for k, (name, v) in enumerate(zip(channels, sample))
                )
                raise ValueError(
                    f"step got a non-finite value for {', '.join(bad)} ({values}); pass "
                    "finite samples or use on_invalid='hold'."
                )
            raise ValueError(
                f"step got motor angles out of range: ({', '.join(channels[:n])}) = "
                f"({', '.join(repr(v) for v in sample[:n])}) deg lies {distance:.1f} deg from "
                f"the neutral angles ({', '.join(f'{v:.2f}' for v in self._qn)}) deg of the "
                f"sweep; at most {self.q_limit_:.1f} deg (1 + q_margin times the sweep "
                "amplitude) is accepted. Increase q_margin or use on_invalid='hold'."
            )
        held = list(sample)
        for k, name in enumerate(channels):
            if name in bad:
                held[k] = float(self._last[k])
        if not self._distance2(held) <= self._limit2:
            held[:n] = [float(v) for v in self._last[:n]]
        self.n_held_ += 1
        return tuple(held)

    def _distance2(self, sample):
        """Squared distance of the sample's motor angles from the neutral angles (deg^2)."""
        total = 0.0
        for v, neutral in zip(sample, self._qn):
            d = v - neutral
            total += d * d
        return total

    def step(self, *sample, t=None, out=None):
        """Tip position for one motor sample.

        Parameters
        ----------
        *sample : float
            The channels of the recordings, in the order of ``channels_``:
            the motor angles ``q1 .. qN`` (deg), then the drive torques
            ``tau1 .. tauN`` (N mm in the simulator; the units of the
            training data) when the recordings have them. For the default
            catheter ``step(q1, q2, tau1, tau2)``. Each channel must be a
            real number (``int``, ``float``, a numpy integer or floating
            scalar); ``bool``, strings, bytes, ``Decimal`` and complex
            numbers raise ``TypeError``, as in
            :meth:`ShaftChangeDetector.step`.
        t : float or None, default=None
            Time of the sample (s), on the clock of the sweep's ``t``,
            increasing. None steps the model once per sample, as for a
            stream at the model's rate. With ``t``, the model steps at its
            own rate ``rate_hz_``: once per sample while every time step is
            within 10 % of the model's step, and otherwise at its ticks (see
            *Notes*). Needed once the stream is ``resampled_``; ignored for
            a pipeline without a learned residual (the backbone has no time
            scale), except with ``hysteresis="pi"``, whose creep then steps
            by the time since the previous sample (without ``t``, by the
            sweep's median time step, or at the model's rate by its step).
        out : ndarray of shape (3,), dtype float64, optional
            Written in place and returned; without it a new array is
            returned. Passing ``out`` keeps the loop free of allocations.

        Returns
        -------
        tip : ndarray of shape (3,)
            Estimated tip position in the base frame (mm).
        """
        if not self._started:
            self._check_started()
        # floats pass as they are; anything else is checked to be a real number
        for v in sample:
            if type(v) is not float:
                sample = real_sample(sample, self._channels())
                break
        if len(sample) != self._n_channels:
            sample = real_sample(sample, self._channels())  # raises: a wrong count
        if t is not None or self._ticking:
            t = self._check_time(t)
        given = None  # a strided out, filled from a contiguous one at the end
        if out is None:
            out = np.empty(3)
        elif out is not self._out or not out.flags.writeable:  # _out: the last out that passed
            if not (type(out) is np.ndarray and out.shape == (3,) and out.dtype == np.float64
                    and out.flags.writeable):
                raise ValueError(
                    "out must be a writeable float64 array of shape (3,); got "
                    f"{type(out).__name__} {getattr(out, 'shape', '')} "
                    f"{getattr(out, 'dtype', '')}."
                )
            if out.flags.c_contiguous:
                self._out = out
            else:  # the compiled step writes contiguous arrays
                given, out = out, np.empty(3)
        if t is None:
            # the step checks the sample (finite, in range) and refuses a bad one untouched
            if not self._call(out, sample, True):
                sample = self._accept(sample)
                self._call(out, sample, False)
        else:
            total = sum(sample)
            # NaN or inf in any channel makes the sum NaN or inf, which fails the test
            if not (total - total == 0.0 and self._distance2(sample) <= self._limit2):
                sample = self._accept(sample)
            self._timed_step(sample, t, out)
        self.n_steps_ += 1
        if self.detector is not None:
            self.shaft_changed_ = bool(self.detector_.step(*sample))
        if given is not None:
            given[:] = out
            return given
        return out

    # ------------------------------------------------------------ the model's rate
    def _check_time(self, t):
        """The time of a sample as a float, checked; None where the model has no rate."""
        if getattr(self, "rate_hz_", None) is None:  # also: pickled before rates were kept
            if t is None or getattr(self, "_pi", None) is None:
                return None  # without the PI's creep the backbone has no time scale
        if t is None:
            raise ValueError(
                f"This stream is stepped at the model's rate of {self.rate_hz_:.4g} Hz (its "
                "sweep, or an earlier sample, is at another rate or uneven), so every sample "
                "needs its time: pass step(..., t=seconds)."
            )
        t = as_real(t, "t")
        if not (math.isfinite(t) and t > self._t_prev):
            raise ValueError(
                f"step got t={t!r} s; the times of a stream must be finite and increase, and "
                f"the previous sample was at t={self._t_prev!r} s (the sweep's clock)."
            )
        return t

    def _timed_step(self, sample, t, out):
        """:meth:`step` of a sample with its time: once per sample, or at the model's ticks."""
        call = self._call
        rate = self.rate_hz_
        dt = self._dt  # the PI's time step, None without it
        if rate is None:  # the PI without a learned residual: its creep by the sample's time
            self._step_after(call, out, sample, t - self._t_prev)
            self._t_prev = self._t_step = t
            return
        if not self._ticking:
            if abs((t - self._t_prev) * rate - 1.0) <= RATE_TOLERANCE:
                if dt is None:
                    call(out, sample, False)
                else:
                    self._step_after(call, out, sample, t - self._t_prev)
                self._residual_last = out - self.nominal_
                self._t_prev = self._t_step = t
                return
            # from here on at the ticks, counted from the last sample stepped
            self._ticking = self.resampled_ = True
            self._tick0, self._tick = self._t_prev, 1
            self._x_prev = tuple(float(v) for v in self._last)
            self._sample_play = tuple(float(v) for v in self.play_state_)
            if dt is not None:
                self._sample_pi = np.array(self.hysteresis_state_)
        t_prev, x_prev = self._t_prev, self._x_prev
        reach = t + TICK_TOLERANCE / rate
        tick = self._tick0 + self._tick / rate
        while tick <= reach:
            a = min(max((tick - t_prev) / (t - t_prev), 0.0), 1.0)
            at = tuple(p + a * (c - p) for p, c in zip(x_prev, sample))
            if dt is None:
                call(out, at, False)
            else:
                self._step_after(call, out, at, max(tick - self._t_step, 0.0))
                self._t_step = tick
            self._residual_last = out - self.nominal_
            self._tick += 1
            tick = self._tick0 + self._tick / rate
        out[:] = self._nominal_at(sample[: len(self._qn)], t - t_prev)
        self._t_prev, self._x_prev = t, sample
        out += self._residual_last

    def _model_view(self):
        """Look-ahead evaluations of the started step for a controller: a :class:`~skcath.online._model_view.ModelView`."""
        self._check_started()
        return ModelView(self._packed, self._backbone)

    def _step_after(self, call, out, sample, dt):
        """The packed step of ``sample`` with the PI's creep stepped by ``dt`` (s), then its nominal step again."""
        self._dt[0] = dt
        call(out, sample, False)
        self._dt[0] = self._pi.period

    def _nominal_at(self, q, dt):
        """The backbone's tip (mm) at one sample's motor angles, ``dt`` (s) after the previous sample.

        Its play, or its PI, is stepped at every sample.
        """
        if self._dt is not None:
            return self._backbone(*self._pi.step(self._sample_pi, q, dt))
        width = getattr(self, "play_width_", 0.0)
        if width > 0.0:
            q = tuple(play_kernel(z, v, width) for z, v in zip(self._sample_play, q))
            self._sample_play = q
        return self._backbone(*q)
