"""A memoryless polynomial of the motor angles as a backbone.

The nominal tip ``b = P(q)`` is a least-squares polynomial of the motor
angles ``q = (q1, ..., qN)``: the angles are standardised, expanded into all
monomials up to a degree and mapped linearly to the three tip coordinates
(mm). It needs no model of the catheter's geometry, so it serves where the
geometric backbones do not apply (any number of motors, a probe whose sweep
is not the paper's 8-ray sweep, motor positions in encoder counts) and as
the memoryless baseline of a residual learner. A fitted polynomial is a
:class:`PolynomialParams`; :func:`polynomial_kernel` evaluates it at one
sample (the streaming step runs it too), :func:`polynomial_tip` on every
row.

Two ways to fit it:

* ``calibration="sweep"``: like the geometric backbones, every run is
  calibrated on its own sweep rows (motor angles to the reference tip
  ``ref_x, ref_y, ref_z``) in ``predict`` / ``transform``; ``fit`` only
  validates the recordings.
* ``calibration="fit"``: one polynomial is fitted in ``fit`` on every row of
  the training recordings with a finite target ``y`` (sweep and motion) and
  applied unchanged to every run, for recordings without a sweep that can
  identify the polynomial.
"""

from __future__ import annotations

from dataclasses import dataclass
from math import comb
from numbers import Integral, Real

import numpy as np
import pandas as pd
from sklearn.base import BaseEstimator, RegressorMixin, TransformerMixin, _fit_context
from sklearn.linear_model import LinearRegression
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import PolynomialFeatures, StandardScaler
from sklearn.utils import Bunch
from sklearn.utils._param_validation import Interval, StrOptions
from sklearn.utils.validation import check_is_fitted, validate_data

from .. import _format as fmt
from .._base import RecordingsMixin
from .._kernel import compiled, kernel
from .._runs import run_codes, run_positions
from .._validation import check_recordings, motor_columns
from ._backbone import BACKBONE_COLUMNS
from ._pi import SweepProblem, identify_pi

__all__ = ["PolynomialBackbone", "PolynomialParams", "polynomial_kernel", "polynomial_tip"]


@dataclass(frozen=True)
class PolynomialParams:
    """A fitted polynomial ``b = P(q)`` of the angles of ``n_motors`` motors.

    .. math::

        P(q) = c_0 + \\sum_\\alpha c_\\alpha\\, \\bar q^{\\alpha},
        \\qquad \\bar q = (q - \\mu_q) / \\sigma_q.

    Attributes
    ----------
    mean : ndarray of shape (n_motors,)
        Centre :math:`\\mu_q` of the standardisation (deg): the mean of
        the motor angles the polynomial was fitted on.
    scale : ndarray of shape (n_motors,)
        Scale :math:`\\sigma_q` (deg); 1 for a motor that did not move.
    powers : ndarray of int, shape (n_terms, n_motors)
        Exponent of every motor in every monomial :math:`\\bar q^\\alpha`.
    coef : ndarray of shape (n_terms, 3)
        Coefficients :math:`c_\\alpha` of every monomial (mm).
    intercept : ndarray of shape (3,)
        :math:`c_0` (mm).
    """

    mean: np.ndarray
    scale: np.ndarray
    powers: np.ndarray
    coef: np.ndarray
    intercept: np.ndarray

    def __post_init__(self):
        for name in ("mean", "scale", "powers", "coef", "intercept"):
            value = np.array(getattr(self, name), dtype=np.int64 if name == "powers" else float)
            value.setflags(write=False)  # read-only copies, as the other parameter classes
            object.__setattr__(self, name, value)

    @classmethod
    def from_polynomial(cls, polynomial):
        """The parameters of a fitted ``StandardScaler, PolynomialFeatures, LinearRegression`` pipeline."""
        scaler, features, linear = (step for _, step in polynomial.steps)
        return cls(mean=scaler.mean_, scale=scaler.scale_, powers=features.powers_,
                   coef=linear.coef_.T, intercept=linear.intercept_)

    @property
    def n_motors(self):
        """Number of motors the polynomial takes."""
        return self.mean.shape[0]

    def to_dict(self):
        """Summary for a calibration table: motors, degree and number of monomials."""
        return {"n_motors": self.n_motors, "degree": int(self.powers.sum(axis=1).max()),
                "n_terms": self.powers.shape[0]}

    def pack(self):
        """The parameters as one float64 vector, the layout :func:`polynomial_kernel` reads.

        ``[n_motors, n_terms, mean, scale, powers (term by term), coef
        (term by term, 3 each), intercept]``.
        """
        n, m = self.n_motors, self.powers.shape[0]
        return np.concatenate([[n, m], self.mean, self.scale, self.powers.ravel(),
                               self.coef.ravel(), self.intercept]).astype(np.float64)


@kernel
def polynomial_kernel(theta, q):
    """Tip ``(x, y, z)`` (mm) of a packed polynomial (:meth:`PolynomialParams.pack`).

    Parameters
    ----------
    theta : ndarray or list of float
        The packed parameters.
    q : ndarray of shape (n_motors,)
        Motor angles (deg).

    Returns
    -------
    x, y, z : float
        Tip position in the base frame (mm).
    """
    n = int(theta[0])
    m = int(theta[1])
    at_powers = 2 + 2 * n
    at_coef = at_powers + m * n
    at_intercept = at_coef + 3 * m
    x = theta[at_intercept]
    y = theta[at_intercept + 1]
    z = theta[at_intercept + 2]
    for t in range(m):
        v = 1.0
        for j in range(n):
            u = (q[j] - theta[2 + j]) / theta[2 + n + j]
            for _ in range(int(theta[at_powers + t * n + j])):
                v *= u
        c = at_coef + 3 * t
        x += theta[c] * v
        y += theta[c + 1] * v
        z += theta[c + 2] * v
    return x, y, z


def _polynomial_rows(theta, q, x, y, z):
    """Rows of :func:`polynomial_kernel`: ``(x[i], y[i], z[i]) = P(q[i])``."""
    for i in range(len(q)):
        x[i], y[i], z[i] = polynomial_kernel(theta, q[i])


def polynomial_tip(q, params):
    """Tip position of a fitted polynomial at every row of ``q``.

    Every row is evaluated by :func:`polynomial_kernel`, in a loop compiled
    by numba where it is available and in Python otherwise.

    Parameters
    ----------
    q : array-like of shape (n, n_motors)
        Motor angles (deg).
    params : PolynomialParams
        The polynomial.

    Returns
    -------
    tip : ndarray of shape (n, 3)
        Tip positions in the base frame (mm).
    """
    q = np.ascontiguousarray(q, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != params.n_motors:
        raise ValueError(
            f"q must have shape (n, {params.n_motors}): the angles of the "
            f"{params.n_motors} motor(s) of the polynomial; got {q.shape}."
        )
    n = q.shape[0]
    fast = compiled(_polynomial_rows)
    if fast is not None:
        x, y, z = np.empty(n), np.empty(n), np.empty(n)
        fast(params.pack(), q, x, y, z)
    else:  # Python reads list items faster than array items
        x, y, z = [0.0] * n, [0.0] * n, [0.0] * n
        _polynomial_rows(params.pack().tolist(), q.tolist(), x, y, z)
    return np.column_stack([x, y, z])


def _fit_polynomial(q, tip, degree):
    """Least-squares polynomial ``tip = P(q)`` of standardised motor angles.

    Parameters
    ----------
    q : ndarray of shape (n, n_motors)
        Motor angles (any unit; standardised before the expansion).
    tip : ndarray of shape (n, 3)
        Tip positions (mm), all finite.
    degree : int
        Largest total degree of the monomials.

    Returns
    -------
    polynomial : sklearn.pipeline.Pipeline
        ``StandardScaler``, ``PolynomialFeatures(degree)``, ``LinearRegression``.
    """
    return make_pipeline(
        StandardScaler(), PolynomialFeatures(degree), LinearRegression()
    ).fit(q, tip)


def _finite_rows(tip):
    """Rows of ``tip`` (n, 3) whose three coordinates are finite."""
    return np.isfinite(tip).all(axis=1)


class PolynomialBackbone(RecordingsMixin, TransformerMixin, RegressorMixin, BaseEstimator):
    """Memoryless polynomial ``b = P(q)`` of the motor angles, fitted by least squares.

    The motor angles ``q = (q1, ..., qN)`` of any number of motors ``N``
    (:func:`skcath.motor_columns`) are standardised, expanded into all monomials of total degree up to
    ``degree`` and mapped linearly to the tip position (mm, base frame):

    .. math::

        P(q) = c_0 + \\sum_{1 \\le |\\alpha| \\le d} c_\\alpha\\, \\bar q^{\\alpha},
        \\qquad \\bar q = (q - \\mu_q) / \\sigma_q,

    with the coefficients :math:`c_\\alpha \\in \\mathbb{R}^3` from
    ordinary least squares (a motor that does not move has
    :math:`\\sigma_q = 1` and contributes nothing). Unlike
    :class:`PCCBackbone` and :class:`PDLBackbone` it has no geometric
    model and no memory: at one motor position it predicts one tip,
    whatever the direction of motion, so what it leaves over is the
    hysteresis a residual learner can learn.

    Parameters
    ----------
    degree : int, default=3
        Largest total degree ``d`` of the monomials (at least 1).
    calibration : {"sweep", "fit"}, default="sweep"
        ``"sweep"``: each run is calibrated on its own sweep rows (motor
        angles to the reference tip ``ref_x, ref_y, ref_z``) when it is
        predicted, as the geometric backbones are; ``fit`` only validates.
        ``"fit"``: one polynomial is fitted in ``fit`` on all rows of the
        training recordings whose target ``y`` is finite (sweep and motion
        rows; NaN rows, tracker dropouts, are skipped) and applied to every
        run; ``fit`` then needs ``y``.
    hysteresis : {None, "pi"}, default=None
        None: the polynomial reads the motor angles as they are. ``"pi"``:
        the motor angles of each run pass through a Prandtl-Ishlinskii
        hysteresis with dead band and creep
        (:class:`~skcath.backbones.PrandtlIshlinskii`) identified with the
        polynomial on the rows it is fitted on (each run's sweep, or with
        ``calibration="fit"`` the training rows, one model for all runs);
        see ``docs/backbones.rst``.
    max_play_deg : float, default=20.0
        Largest threshold of the hysteresis (in the unit of the motor
        columns); used with ``hysteresis="pi"`` only.

    Attributes
    ----------
    feature_names_in_ : ndarray of str
        The column names of the recordings given to ``fit``, in order;
        ``transform`` requires the same and appends ``b_x, b_y, b_z``.
    n_features_in_ : int
        How many columns those recordings had.
    n_motors_ : int
        Number of motors of those recordings. With ``calibration="fit"``,
        recordings of another number of motors are refused.
    polynomial_ : sklearn.pipeline.Pipeline or None
        With ``calibration="fit"``: the fitted polynomial
        (``StandardScaler``, ``PolynomialFeatures``, ``LinearRegression``)
        that maps the motor angles to the tip (mm). None with
        ``calibration="sweep"``, where every run has its own.
    hysteresis_ : PrandtlIshlinskii or None
        With ``calibration="fit"`` and ``hysteresis="pi"``: the hysteresis
        identified on the training rows; None otherwise.

    See Also
    --------
    PDLBackbone : per-direction geometric backbone calibrated on the sweep.

    Notes
    -----
    Both calibrations evaluate the fitted polynomial (:class:`PolynomialParams`,
    one per run, returned by :meth:`calibrate`) with :func:`polynomial_kernel`,
    the function the streaming step of :class:`skcath.online.OnlineEstimator`
    runs. ``predict`` and ``transform`` read only the motor angles of motion rows
    (and, with ``calibration="sweep"``, the reference tip of sweep rows);
    they never change the fitted estimator. A run calibrated on its sweep
    needs more sweep rows with a finite reference than the polynomial has
    coefficients per coordinate. ``docs/studies/real_data.rst`` uses
    ``calibration="fit"`` on recordings of a probe that has no 8-ray sweep.

    Examples
    --------
    >>> from skcath.backbones import PolynomialBackbone
    >>> from skcath.datasets import make_benchmark
    >>> data = make_benchmark(n_catheters=1, n_runs=1)  # doctest: +SKIP
    >>> b = PolynomialBackbone(degree=3).fit(data.X).predict(data.X)  # doctest: +SKIP
    >>> b.shape  # doctest: +SKIP
    (104486, 3)
    """

    _parameter_constraints: dict = {
        "degree": [Interval(Integral, 1, None, closed="left")],
        "calibration": [StrOptions({"sweep", "fit"})],
        "hysteresis": [None, StrOptions({"pi"})],
        "max_play_deg": [Interval(Real, 0, None, closed="neither")],
    }

    def __init__(self, degree=3, *, calibration="sweep", hysteresis=None, max_play_deg=20.0):
        self.degree = degree
        self.calibration = calibration
        self.hysteresis = hysteresis
        self.max_play_deg = max_play_deg

    @_fit_context(prefer_skip_nested_validation=True)
    def fit(self, X, y=None):
        """Validate the recordings; with ``calibration="fit"``, fit the polynomial.

        Parameters
        ----------
        X : pandas.DataFrame
            The training recordings, one row per sample (the long format of
            ``docs/data_format.rst``).
        y : array-like of shape (n_samples, 3), optional
            Measured tip positions (mm); needed with ``calibration="fit"``,
            where rows with a NaN coordinate are skipped.

        Returns
        -------
        self : object
        """
        by_sweep = self.calibration == "sweep"
        if not by_sweep and y is None:
            raise ValueError(
                "PolynomialBackbone(calibration='fit') fits the polynomial on the tip "
                "positions y, but y is None; pass fit(X, y), or use calibration='sweep' "
                "to calibrate every run on its own sweep."
            )
        X, y = check_recordings(X, y, require_sweep=by_sweep)
        motors, _ = motor_columns(X)
        self._record_columns(X)
        self.n_motors_ = len(motors)
        self.polynomial_ = None
        self.hysteresis_ = None
        if not by_sweep:
            q = X[list(motors)].to_numpy(dtype=np.float64)
            keep = _finite_rows(y)
            self._check_enough_rows(int(keep.sum()), len(motors), "the training recordings")
            if self.hysteresis == "pi":
                positions = run_positions(X)
                t = X[fmt.TIME].to_numpy(dtype=np.float64)
                self.hysteresis_, self.polynomial_ = self._identify(
                    [(q[pos], t[pos]) for pos in positions],
                    np.concatenate([y[pos] for pos in positions]), "the training recordings")
            else:
                self.polynomial_ = _fit_polynomial(q[keep], y[keep], self.degree)
        return self

    def _identify(self, segments, target, where):
        """The hysteresis and the polynomial fitted on the effective angles of ``segments``."""
        keep = _finite_rows(target)

        def calibrate(z):
            polynomial = _fit_polynomial(z[keep], target[keep], self.degree)
            error = np.sum((polynomial.predict(z[keep]) - target[keep]) ** 2, axis=1)
            return polynomial, {"rmse_mm": float(np.sqrt(error.mean()))}

        problem = SweepProblem(segments, target, calibrate, lambda z, p: p.predict(z))
        model, polynomial, _ = identify_pi(problem, max_play_deg=self.max_play_deg,
                                           n_motors=segments[0][0].shape[1], where=where)
        return model, polynomial

    def _check_enough_rows(self, n_rows, n_motors, where):
        """Raise unless ``n_rows`` rows with a finite target can determine the polynomial."""
        n_coef = comb(n_motors + self.degree, self.degree)
        if n_rows <= self.degree or n_rows < n_coef:
            raise ValueError(
                f"PolynomialBackbone(degree={self.degree}) of {n_motors} motor(s) has {n_coef} "
                f"coefficients per coordinate but {where} have {n_rows} rows with a finite "
                "tip position; lower the degree or give more rows."
            )

    def _run_params(self, X, q):
        """The polynomial of every run: fitted on its sweep rows, or the one of ``fit``."""
        _, runs = run_codes(X)
        positions = run_positions(X)
        if self.polynomial_ is not None:
            params = PolynomialParams.from_polynomial(self.polynomial_)
            model = getattr(self, "hysteresis_", None)
            return runs, positions, [params] * len(runs), [model] * len(runs)
        ref = X[list(fmt.REFERENCE_COLUMNS)].to_numpy(dtype=np.float64)
        sweep = (X[fmt.PHASE] == fmt.SWEEP).to_numpy()
        t = X[fmt.TIME].to_numpy(dtype=np.float64)
        fitted, models = [], []
        for run, pos in zip(runs, positions):
            on = pos[sweep[pos]]  # the sweep rows come first
            model = None
            if getattr(self, "hysteresis", None) == "pi":
                rows = on[_finite_rows(ref[on])]
                self._check_enough_rows(len(rows), q.shape[1], f"the sweep rows of run {run!r}")
                model, polynomial = self._identify([(q[on], t[on])], ref[on], f"run {run!r}")
                params = PolynomialParams.from_polynomial(polynomial)
            else:
                params = self._fit_run(run, q[on], ref[on])
            fitted.append(params)
            models.append(model)
        return runs, positions, fitted, models

    def _fit_run(self, run, q, ref):
        """The polynomial of run ``run`` fitted on its sweep rows: angles ``q`` (deg), reference ``ref`` (mm)."""
        rows = _finite_rows(ref)
        self._check_enough_rows(int(rows.sum()), q.shape[1], f"the sweep rows of run {run!r}")
        return PolynomialParams.from_polynomial(_fit_polynomial(q[rows], ref[rows], self.degree))

    def _check_motors(self, motors):
        """Raise unless the motor columns ``motors`` are as many as those of ``fit``."""
        if self.polynomial_ is not None and len(motors) != self.n_motors_:
            raise ValueError(
                f"This PolynomialBackbone was fitted on recordings of {self.n_motors_} "
                f"motor(s), but X has {len(motors)} ({', '.join(motors)})."
            )

    def _calibrate_sweep(self, run, motors, q, ref, given=None):
        """:meth:`calibrate` of one run given by its sweep rows alone, from their checked arrays.

        As :meth:`PDLBackbone._calibrate_sweep` (``given`` is not read):
        returns the nominal tip of every row (mm), the parameters and the
        half-width of the play, 0.
        """
        self._check_motors(motors)
        if self.polynomial_ is not None:
            params = PolynomialParams.from_polynomial(self.polynomial_)
        else:
            params = self._fit_run(run, q, ref)
        return polynomial_tip(q, params), params, 0.0

    def calibrate(self, X):
        """The polynomial of every run of ``X``; the estimator is left unchanged.

        What ``predict`` and ``transform`` do for each run, with the
        polynomials themselves returned: with ``calibration="sweep"`` each
        run's own, fitted on its sweep rows, with ``calibration="fit"`` the
        one fitted in ``fit`` for every run.

        Parameters
        ----------
        X : pandas.DataFrame
            Recordings in the long format (each run with its sweep rows and
            reference tip when ``calibration="sweep"``).

        Returns
        -------
        calibration : sklearn.utils.Bunch
            As :meth:`PDLBackbone.calibrate`: ``table`` (indexed by run id:
            ``n_motors``, ``degree``, ``n_terms``, the RMSE ``rmse_mm`` (mm)
            on the run's sweep rows with a finite reference, NaN without
            any, and ``play_width_deg``, always 0), ``params`` (run id ->
            :class:`PolynomialParams`), ``play_widths`` (run id -> 0.0) and
            ``nominal`` (ndarray of shape (n_samples, 3), mm).
        """
        check_is_fitted(self)
        X, _ = check_recordings(X, require_sweep=self.calibration == "sweep")
        return self._calibrate_checked(X)

    def _calibrate_checked(self, X):
        """:meth:`calibrate` on recordings already checked."""
        motors, _ = motor_columns(X)
        self._check_motors(motors)
        q = X[list(motors)].to_numpy(dtype=np.float64)
        ref = X[list(fmt.REFERENCE_COLUMNS)].to_numpy(dtype=np.float64)
        sweep = (X[fmt.PHASE] == fmt.SWEEP).to_numpy()
        t = X[fmt.TIME].to_numpy(dtype=np.float64)
        nominal = np.empty((len(X), 3))
        records, params, models = [], {}, {}
        for run, pos, par, model in zip(*self._run_params(X, q)):
            z = q[pos] if model is None else model.forward(q[pos], t[pos])
            nominal[pos] = polynomial_tip(z, par)
            params[run] = par
            rows = pos[sweep[pos] & _finite_rows(ref[pos])]
            error = np.sum((nominal[rows] - ref[rows]) ** 2, axis=1)
            rmse = float(np.sqrt(error.mean())) if rows.size else np.nan
            hysteresis = {} if model is None else model.to_dict()
            models[run] = model
            records.append({fmt.RUN: run, **par.to_dict(), "rmse_mm": rmse, "play_width_deg": 0.0,
                            **hysteresis})
        table = pd.DataFrame.from_records(records).set_index(fmt.RUN)
        out = Bunch(table=table, params=params, play_widths=dict.fromkeys(params, 0.0),
                    nominal=nominal)
        if getattr(self, "hysteresis", None) == "pi":
            out.hysteresis = models
        return out

    def _nominal(self, X):
        """The checked recordings and the nominal tip of every row (mm)."""
        check_is_fitted(self)
        X, _ = check_recordings(X, require_sweep=self.calibration == "sweep")
        return X, self._calibrate_checked(X).nominal

    def predict(self, X):
        """Nominal tip position ``P(q)`` of every row.

        Parameters
        ----------
        X : pandas.DataFrame
            Recordings in the long format; with ``calibration="sweep"`` every
            run needs its sweep rows with reference tip positions.

        Returns
        -------
        b : ndarray of shape (n_samples, 3)
            Nominal tip position in the base frame (mm).
        """
        return self._nominal(X)[1]

    def transform(self, X):
        """Append the nominal tip position ``b_x, b_y, b_z`` (mm) to the recordings.

        Parameters
        ----------
        X : pandas.DataFrame
            Recordings in the long format, with the columns seen in ``fit``.

        Returns
        -------
        Xt : pandas.DataFrame
            A copy of ``X`` with the columns ``b_x``, ``b_y``, ``b_z``.
        """
        X, nominal = self._nominal(X)
        # the output columns follow get_feature_names_out: same names, same order
        validate_data(self, X, reset=False, skip_check_array=True)
        return X.assign(**{name: nominal[:, k] for k, name in enumerate(BACKBONE_COLUMNS)})

    def get_feature_names_out(self, input_features=None):
        """Input column names followed by those of ``b_x``, ``b_y``, ``b_z`` not among them."""
        check_is_fitted(self)
        added = [name for name in BACKBONE_COLUMNS if name not in self.feature_names_in_]
        return np.concatenate([self.feature_names_in_, np.asarray(added, dtype=object)])
