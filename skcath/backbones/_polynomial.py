"""A memoryless polynomial of the motor angles as a backbone.

The nominal tip ``b = P(q)`` is a least-squares polynomial of the motor
angles: the angles are standardised, expanded into all monomials up to a
degree and mapped linearly to the three tip coordinates (mm). It needs no
model of the catheter's geometry, so it serves where the geometric
backbones do not apply (a probe whose sweep is not the paper's 8-ray sweep,
one motor, motor positions in encoder counts) and as the memoryless
baseline of a residual learner.

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

from math import comb
from numbers import Integral

import numpy as np
from sklearn.base import BaseEstimator, RegressorMixin, TransformerMixin, _fit_context
from sklearn.linear_model import LinearRegression
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import PolynomialFeatures, StandardScaler
from sklearn.utils._param_validation import Interval, StrOptions
from sklearn.utils.validation import check_is_fitted, validate_data

from .. import _format as fmt
from .._base import RecordingsMixin
from .._runs import run_codes, run_positions
from .._validation import check_recordings
from ._backbone import BACKBONE_COLUMNS

__all__ = ["PolynomialBackbone"]


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

    The motor angles ``q`` (the columns ``skcath.MOTOR_COLUMNS``) are
    standardised, expanded into all monomials of total degree up to
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

    Attributes
    ----------
    feature_names_in_ : ndarray of str
        The column names of the recordings given to ``fit``, in order;
        ``transform`` requires the same and appends ``b_x, b_y, b_z``.
    n_features_in_ : int
        How many columns those recordings had.
    polynomial_ : sklearn.pipeline.Pipeline or None
        With ``calibration="fit"``: the fitted polynomial
        (``StandardScaler``, ``PolynomialFeatures``, ``LinearRegression``)
        that maps the motor angles to the tip (mm). None with
        ``calibration="sweep"``, where every run has its own.

    See Also
    --------
    PDLBackbone : per-direction geometric backbone calibrated on the sweep.

    Notes
    -----
    ``predict`` and ``transform`` read only the motor angles of motion rows
    (and, with ``calibration="sweep"``, the reference tip of sweep rows);
    they never change the fitted estimator. A run calibrated on its sweep
    needs more sweep rows with a finite reference than the polynomial has
    coefficients per coordinate. ``docs/real_data.rst`` uses
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
    }

    def __init__(self, degree=3, *, calibration="sweep"):
        self.degree = degree
        self.calibration = calibration

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
        self._record_columns(X)
        self.polynomial_ = None
        if not by_sweep:
            q = X[list(fmt.MOTOR_COLUMNS)].to_numpy(dtype=np.float64)
            keep = _finite_rows(y)
            self._check_enough_rows(int(keep.sum()), "the training recordings")
            self.polynomial_ = _fit_polynomial(q[keep], y[keep], self.degree)
        return self

    def _check_enough_rows(self, n_rows, where):
        """Raise unless ``n_rows`` rows with a finite target can determine the polynomial."""
        n_coef = comb(len(fmt.MOTOR_COLUMNS) + self.degree, self.degree)
        if n_rows <= self.degree or n_rows < n_coef:
            raise ValueError(
                f"PolynomialBackbone(degree={self.degree}) has {n_coef} coefficients per "
                f"coordinate but {where} have {n_rows} rows with a finite tip position; "
                "lower the degree or give more rows."
            )

    def _sweep_polynomials(self, X, q):
        """Nominal tip of every row, each run's polynomial fitted on its own sweep rows."""
        _, runs = run_codes(X)
        ref = X[list(fmt.REFERENCE_COLUMNS)].to_numpy(dtype=np.float64)
        sweep = (X[fmt.PHASE] == fmt.SWEEP).to_numpy()
        nominal = np.empty((len(X), 3))
        for run, pos in zip(runs, run_positions(X)):
            rows = pos[sweep[pos] & _finite_rows(ref[pos])]
            self._check_enough_rows(len(rows), f"the sweep rows of run {run!r}")
            polynomial = _fit_polynomial(q[rows], ref[rows], self.degree)
            nominal[pos] = polynomial.predict(q[pos])
        return nominal

    def _nominal(self, X):
        """The checked recordings and the nominal tip of every row (mm)."""
        check_is_fitted(self)
        X, _ = check_recordings(X, require_sweep=self.calibration == "sweep")
        q = X[list(fmt.MOTOR_COLUMNS)].to_numpy(dtype=np.float64)
        if self.polynomial_ is None:
            return X, self._sweep_polynomials(X, q)
        return X, self.polynomial_.predict(q)

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
