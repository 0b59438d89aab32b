"""Backbone estimators: per-run calibration on the run's own sweep.

A backbone ``g_xi(q)`` is calibrated separately for every recording from that
recording's initial sweep rows (motor angles and reference tip positions),
then evaluated on all rows of the recording. Nothing is learned across runs:
``fit`` only validates the input and records its columns, and the calibration
happens in ``calibrate`` (and in ``transform`` / ``predict``, which use it),
where each run's sweep is part of the input; it returns the calibrations and
leaves the estimator unchanged. Reference values on motion rows are never
read.
"""

from numbers import Integral, Real

import numpy as np
import pandas as pd
from joblib import Parallel, delayed
from sklearn.base import BaseEstimator, RegressorMixin, TransformerMixin, _fit_context
from sklearn.utils import Bunch
from sklearn.utils._param_validation import Interval, StrOptions
from sklearn.utils.validation import check_is_fitted

from .. import _format as fmt
from .._base import RecordingsMixin
from .._runs import run_codes, run_positions
from .._validation import check_recordings, motor_columns
from .._sweep_end import N_SWEEP_ATTR, naming_n_sweep
from ..sweep import _check_sweep_references, _find_rays
from ._hysteresis import identify_play_width, play_operator
from ._pi import PrandtlIshlinskii, SweepProblem
from ._pi_sweep import identify_sweep_pi, strided_reference
from ._pcc import calibrate_pcc, pcc_tip
from ._pdl import calibrate_pdl, pdl_tip
from ._pdl_batch import _calibrate_pdl_batch

__all__ = ["BACKBONE_COLUMNS", "PCCBackbone", "PDLBackbone", "check_two_motors"]

#: Columns that ``transform`` appends: the nominal tip position (mm, base frame).
BACKBONE_COLUMNS = ("b_x", "b_y", "b_z")


# The Parameters and Attributes sections shared by both backbones, placed
# into their class docstrings (f-strings) at the indentation of a section
# header, with the calibration's unit ("calibration" or "ray") formatted in.
_PARAMETERS_AND_ATTRIBUTES = """Parameters
    ----------
    n_rays : int, default=8
        Number of rays of the initial sweep (at least 3); a sweep with
        another number of rays is rejected.
    ray_spacing_deg : float, default=None
        Angle between neighbouring directions of the sweep layout (degrees);
        None means ``360 / n_rays`` (evenly spaced rays). Give the spacing of
        the full layout when the sweep keeps only some of its rays, e.g.
        ``n_rays=4, ray_spacing_deg=45`` for 4 of 8 rays
        (:func:`skcath.sweep.reduce_sweep`); see
        :func:`skcath.sweep.find_rays`.
    max_iter : int, default=100
        Largest number of Gauss-Newton steps per {}.
    hysteresis : {{None, "play", "pi"}}, default=None
        None: the backbone reads the motor angles as they are. ``"pi"``: a
        Prandtl-Ishlinskii hysteresis with dead band
        (:class:`PrandtlIshlinskii`), its loop half-width and softness
        identified on each run's sweep by the backbone's own calibration
        RMSE (``calibrate`` returns the models in
        ``hysteresis`` and their parameters in the table's ``pi_*``
        columns; ``max_play_deg`` is its largest threshold; see
        ``docs/backbones.rst``). ``"play"``:
        the motor angles of each run pass through a symmetric play operator
        (backlash, :func:`play_operator`) before the backbone, its half-width
        identified on the run's own sweep (the width whose calibration on
        the played sweep angles has the lowest sweep RMSE; the rays are
        found from the angles as they are). See
        :func:`identify_play_width` for the search and ``docs/backbones.rst``
        for its cost (about 20 calibrations per run).
    max_play_deg : float, default=20.0
        Largest half-width of the play searched (deg), in (0, 180]; used
        with ``hysteresis="play"`` and ``"pi"`` only.
    n_jobs : int, default=None
        Runs calibrated in parallel (joblib); None means 1.

    Attributes
    ----------
    feature_names_in_ : ndarray of str
        Columns of ``X`` seen in ``fit``.
    n_features_in_ : int
        Number of columns of ``X`` seen in ``fit``. The calibrations of the
        runs of ``X`` are returned by :meth:`calibrate`, not kept."""


def check_two_motors(X, owner):
    """Raise unless the recordings ``X`` have two motors, ``q1`` and ``q2``.

    The geometric backbones model a catheter bent by two motors (two
    bending planes); recordings of another number of motors get an error
    that names it and points to :class:`PolynomialBackbone`.
    """
    _check_two(motor_columns(X)[0], owner)


def _check_two(motors, owner):
    """:func:`check_two_motors` of the motor columns ``motors`` of checked recordings."""
    if len(motors) != 2:
        raise ValueError(
            f"{owner} models a catheter with two bending motors (q1, q2), but the "
            f"recordings have {len(motors)} motor(s) ({', '.join(motors)}). Use "
            "PolynomialBackbone, which takes any number of motors, as the backbone."
        )


def _calibrate_run(backbone, run, q, ref, sweep, given=None, t=None):
    """Calibrate one run on its sweep rows and evaluate it on all its rows.

    ``given`` is ``(n_sweep, t)`` when the run's sweep rows are the first
    ``n_sweep`` rows given when it was read (``t``: the times of its rows,
    s), so that a sweep error names ``n_sweep`` and the sweep end found from
    the motor angles.

    Returns the nominal tips, the parameters, the solver's summary and the
    half-width of the play (deg; 0 without hysteresis), or with
    ``hysteresis="pi"`` the :class:`PrandtlIshlinskii` model (``t``, the
    times of the run's rows in s, is then needed).
    """
    q_sweep, ref_sweep = q[sweep], ref[sweep]
    with naming_n_sweep(given, q, run):
        rays = _find_rays(
            q_sweep, n_rays=backbone.n_rays, run=run,
            # absent from backbones pickled before the parameter existed
            ray_spacing_deg=getattr(backbone, "ray_spacing_deg", None),
        )
        _check_sweep_references(ref_sweep, rays, run=run)
    if getattr(backbone, "hysteresis", None) is None:
        params, info = backbone._calibrate(q_sweep, ref_sweep, rays, q_sweep)
        return backbone._evaluate(q, params), params, info, 0.0
    if backbone.hysteresis == "pi":
        # the sweep rows come first, so the run's effective angles continue the sweep's
        problem = SweepProblem(
            [(q_sweep, t[sweep])], ref_sweep,
            lambda z: backbone._calibrate(z, ref_sweep, rays, q_sweep),
            backbone._evaluate,
        )
        # trials read evenly strided sweep rows; the rays stay those of all the rows
        few = strided_reference(ref_sweep)
        model, params, info = identify_sweep_pi(
            problem, max_play_deg=backbone.max_play_deg, n_motors=q.shape[1],
            where=f"run {run!r}", search=lambda z: backbone._calibrate(z, few, rays, q_sweep),
            search_many=lambda zs: backbone._calibrate_many(zs, few, rays, q_sweep),
        )
        return backbone._evaluate(model.forward(q, t), params), params, info, model
    fits = {}

    def sweep_rmse(width):
        played = play_operator(q_sweep, width)
        fits[float(width)] = backbone._calibrate(played, ref_sweep, rays, q_sweep)
        return fits[float(width)][1]["rmse_mm"]

    def grid_rmse(widths):  # the grid's calibrations at once, with the numbers of sweep_rmse
        played = [play_operator(q_sweep, width) for width in widths]
        fits.update(zip(widths, backbone._calibrate_many(played, ref_sweep, rays, q_sweep)))
        return [fits[width][1]["rmse_mm"] for width in widths]

    width = identify_play_width(sweep_rmse, backbone.max_play_deg, grid_rmse)
    params, info = fits[width]
    # the sweep rows come first, so the run's played angles continue the sweep's
    return backbone._evaluate(play_operator(q, width), params), params, info, width


class _BaseBackbone(RecordingsMixin, TransformerMixin, RegressorMixin, BaseEstimator):
    """Shared machinery of the geometric backbones (not for direct use)."""

    _parameter_constraints: dict = {
        "n_rays": [Interval(Integral, 3, None, closed="left")],
        "ray_spacing_deg": [None, Interval(Real, 0, 360, closed="right")],
        "max_iter": [Interval(Integral, 1, None, closed="left")],
        "hysteresis": [None, StrOptions({"play", "pi"})],
        "max_play_deg": [Interval(Real, 0, 180, closed="right")],
        "n_jobs": [None, Integral],
    }

    def __init__(self, *, n_rays=8, ray_spacing_deg=None, max_iter=100, hysteresis=None,
                 max_play_deg=20.0, n_jobs=None):
        self.n_rays = n_rays
        self.ray_spacing_deg = ray_spacing_deg
        self.max_iter = max_iter
        self.hysteresis = hysteresis
        self.max_play_deg = max_play_deg
        self.n_jobs = n_jobs

    @_fit_context(prefer_skip_nested_validation=True)
    def fit(self, X, y=None):
        """Validate the recordings; a backbone has nothing to learn across runs.

        Parameters
        ----------
        X : pandas.DataFrame
            Recordings in the long format (``docs/data_format.rst``).
        y : array-like of shape (n_samples, 3), optional
            Tip positions (mm); validated if given, otherwise unused.

        Returns
        -------
        self : object
        """
        X, _ = check_recordings(X, y)
        check_two_motors(X, type(self).__name__)
        self._record_columns(X)
        return self

    def calibrate(self, X):
        """Calibrate every run of ``X`` on its own sweep; the estimator is left unchanged.

        What ``predict`` and ``transform`` do for each run, with the
        calibrations themselves returned.

        Parameters
        ----------
        X : pandas.DataFrame
            Recordings in the long format; every run needs its sweep rows
            with reference tip positions.

        Returns
        -------
        calibration : sklearn.utils.Bunch
            ``table``: a pandas.DataFrame indexed by run id, in order of
            first appearance, with the fitted parameters (the keys of the
            parameters' ``to_dict``), the sweep RMSE ``rmse_mm`` (mm), the
            number of solver iterations ``n_iter``, whether the solver
            converged (``converged``) and the half-width of the play
            ``play_width_deg`` (deg, 0 without hysteresis); ``params``: a
            dict run id -> parameters (:class:`PCCParams` or
            :class:`PDLParams`, usable with :func:`pcc_tip` /
            :func:`pdl_tip`); ``play_widths``: a dict run id -> half-width
            of the play (deg); ``nominal``: the nominal tip position of every
            row, ndarray of shape (n_samples, 3) (mm). With
            ``hysteresis="play"`` a run's nominal tips are its parameters
            evaluated on its played angles,
            ``pdl_tip(play_operator(q, play_widths[run]), params[run])``
            with ``q`` the motor angles of all its rows (sweep, then
            motion). With ``hysteresis="pi"`` also ``hysteresis``: a dict
            run id -> :class:`PrandtlIshlinskii`, whose parameters are the
            table's ``pi_*`` columns, and the nominal tips are
            ``pdl_tip(hysteresis[run].forward(q, t), params[run])``.
        """
        check_is_fitted(self)
        X, _ = check_recordings(X)
        return self._calibrate_checked(X)

    def _calibrate_checked(self, X):
        """:meth:`calibrate` on recordings already checked."""
        check_two_motors(X, type(self).__name__)
        _, runs = run_codes(X)
        positions = run_positions(X)
        q = X[list(fmt.MOTOR_COLUMNS)].to_numpy()
        ref = X[list(fmt.REFERENCE_COLUMNS)].to_numpy()
        sweep = (X[fmt.PHASE] == fmt.SWEEP).to_numpy()
        t = X[fmt.TIME].to_numpy()
        given = X.attrs.get(N_SWEEP_ATTR, {})
        results = Parallel(n_jobs=self.n_jobs)(
            delayed(_calibrate_run)(
                self, run, q[pos], ref[pos], sweep[pos],
                (given[run], t[pos]) if run in given else None, t[pos],
            )
            for run, pos in zip(runs, positions)
        )
        nominal = np.empty((len(X), 3))
        records, params, widths, models = [], {}, {}, {}
        for run, pos, (tip, par, info, width) in zip(runs, positions, results):
            nominal[pos] = tip
            params[run] = par
            hysteresis = {}
            if isinstance(width, PrandtlIshlinskii):
                models[run], width, hysteresis = width, 0.0, width.to_dict()
            widths[run] = width
            records.append({fmt.RUN: run, **par.to_dict(), "play_width_deg": width,
                            **hysteresis, **_summary(info)})
        table = pd.DataFrame.from_records(records).set_index(fmt.RUN)
        out = Bunch(table=table, params=params, play_widths=widths, nominal=nominal)
        if self.hysteresis == "pi":
            out.hysteresis = models
        return out

    def _calibrate_sweep(self, run, motors, q, ref, given=None):
        """:meth:`calibrate` of one run given by its sweep rows alone, from their checked arrays.

        ``motors`` are the motor columns, ``q`` (n, 2) the motor angles (deg)
        and ``ref`` (n, 3) the reference tip (mm) of the rows, float64;
        ``given`` as for :func:`_calibrate_run`. Returns the nominal tip of
        every row (mm), the parameters and the half-width of the play (deg).
        """
        _check_two(motors, type(self).__name__)
        tip, params, _, width = _calibrate_run(self, run, q, ref, np.ones(len(q), dtype=bool), given)
        return tip, params, width

    def predict(self, X):
        """Nominal tip position of every row, each run calibrated on its own sweep.

        Parameters
        ----------
        X : pandas.DataFrame
            Recordings in the long format, as for :meth:`calibrate`.

        Returns
        -------
        b : ndarray of shape (n_samples, 3)
            Nominal tip position ``g_xi(q)`` in the base frame (mm).
        """
        return self.calibrate(X).nominal

    def transform(self, X):
        """Append the nominal tip position ``b_x, b_y, b_z`` (mm) to the recordings.

        Parameters
        ----------
        X : pandas.DataFrame
            Recordings in the long format.

        Returns
        -------
        Xt : pandas.DataFrame
            A copy of ``X`` with the columns ``b_x``, ``b_y``, ``b_z``.
        """
        check_is_fitted(self)
        if isinstance(X, pd.DataFrame) and list(X.columns) != list(self.feature_names_in_):
            raise ValueError(
                "X must have the columns seen in fit, in the same order (transform returns "
                f"them followed by {list(BACKBONE_COLUMNS)}); fit saw "
                f"{list(self.feature_names_in_)}, got {list(X.columns)}."
            )
        X, _ = check_recordings(X)
        nominal = self._calibrate_checked(X).nominal
        Xt = X.copy()
        for k, name in enumerate(BACKBONE_COLUMNS):
            Xt[name] = nominal[:, k]
        return Xt

    def get_feature_names_out(self, input_features=None):
        """Input column names followed by those of ``b_x``, ``b_y``, ``b_z`` not among them."""
        check_is_fitted(self)
        names = list(self.feature_names_in_)
        return np.asarray([*names, *(c for c in BACKBONE_COLUMNS if c not in names)], dtype=object)



def _at_neutral(q, ref, rays):
    """Sweep samples at the neutral motor position, whose tips give ``p0`` (PDL).

    The neutral band of :func:`find_rays` (3 % of the amplitude) also holds the
    first and last samples of every move, whose tips are already displaced;
    averaging them would bias the neutral tip. Keep the band samples within
    ``4 sigma`` of the neutral motor angles, ``sigma`` the encoder noise from
    sixth differences of ``q`` (zero on smooth moves, ``sqrt(924) sigma`` on
    white noise), and at least ``1e-9`` of the amplitude; fall back to the
    band if none of them has a finite reference.
    """
    d6 = np.abs(np.diff(q, n=6, axis=0))
    sigma = 1.4826 * float(np.median(d6, axis=0).max()) / np.sqrt(924.0) if len(d6) else 0.0
    rho, _ = rays.polar(q)
    at = rays.neutral & (rho <= max(4.0 * sigma, 1e-9 * rays.amplitude))
    if not (at & np.isfinite(ref).all(axis=1)).any():
        return rays.neutral
    return at


def _summary(info):
    return {key: info[key] for key in ("rmse_mm", "n_iter", "converged") if key in info}


class PCCBackbone(_BaseBackbone):
    __doc__ = f"""Piecewise-constant-curvature backbone calibrated on each run's sweep.

    Paper eqs. 3-4: with the bending coordinates

    .. math::

        u = C \\frac{{q - q_0}}{{S_m}} + u_0, \\qquad \\alpha = \\lVert u \\rVert_2,

    the nominal tip position in the base frame is

    .. math::

        g(q) = L R_g \\begin{{bmatrix}} u_1 (1 - \\cos\\alpha)/\\alpha^2 \\\\
        u_2 (1 - \\cos\\alpha)/\\alpha^2 \\\\ \\sin\\alpha / \\alpha \\end{{bmatrix}},

    with the continuous limits at :math:`\\alpha = 0`. For every run, ``q0``
    is the neutral motor position and ``S_m`` the amplitude of its sweep
    (degrees); ``C`` (2x2), ``u0`` (rad), ``L`` (mm) and the tilt of ``R_g``
    are fitted to the run's sweep samples and their reference tip positions by
    damped Gauss-Newton (Levenberg-Marquardt) least squares
    (:func:`calibrate_pcc`). The roll of ``R_g`` about its z axis is absorbed
    by ``C``.

    {_PARAMETERS_AND_ATTRIBUTES.format("calibration")}

    See Also
    --------
    PDLBackbone : per-direction backbone, usually more accurate.

    Notes
    -----
    The data format is described in ``docs/data_format.rst``. Each run must
    start with its sweep rows, whose reference columns ``ref_x``, ``ref_y``,
    ``ref_z`` are the calibration targets; motion rows are predicted from the
    motor angles alone. The model has two motors, ``q1`` and ``q2``; for
    recordings of another number of motors use :class:`PolynomialBackbone`.

    Examples
    --------
    >>> from skcath.backbones import PCCBackbone
    >>> from skcath.datasets import make_benchmark
    >>> data = make_benchmark(n_catheters=1, n_runs=1)  # doctest: +SKIP
    >>> b = PCCBackbone().fit(data.X).predict(data.X)  # doctest: +SKIP
    >>> from skcath.metrics import mean_per_run_rmse
    >>> mean_per_run_rmse(data.y, b, data.X)  # doctest: +SKIP
    """

    def _calibrate_many(self, qs, ref, rays, q_raw):
        return [self._calibrate(q, ref, rays, q_raw) for q in qs]

    def _calibrate(self, q, ref, rays, q_raw):
        return calibrate_pcc(
            q, ref, q0=rays.q_neutral, S_m=rays.amplitude, max_iter=self.max_iter, return_info=True
        )

    def _evaluate(self, q, params):
        return pcc_tip(q, params)


class PDLBackbone(_BaseBackbone):
    __doc__ = f"""Per-direction backbone (PDL) calibrated on each run's sweep.

    Paper eq. 5: along each sweep ray of direction :math:`\\psi`, with
    :math:`\\rho = \\lVert q - q_n \\rVert_2` (degrees),

    .. math::

        \\gamma(\\rho) = a_\\gamma \\rho + b_\\gamma \\rho^2, \\quad
        d(\\rho) = a_d \\rho + b_d \\rho^2, \\quad
        \\varphi(\\rho) = \\varphi_0 + s_\\varphi (\\rho - \\rho_0),

    where :math:`\\gamma` is twice the inclination of the tip vector from the
    neutral tip direction, :math:`d` the distance from the neutral tip (mm)
    and :math:`\\varphi` the azimuth of the tip vector. Coefficients are
    interpolated linearly in :math:`\\psi` between neighbouring rays, with
    periodic continuation and azimuth unwrapping; the tip is the point along
    the tip direction at distance :math:`d` from the neutral tip. Per ray, the
    coefficients are initialised by linear least squares and refined by
    damped Gauss-Newton on the 3-D residuals (:func:`calibrate_pdl`).

    {_PARAMETERS_AND_ATTRIBUTES.format("ray")}

    See Also
    --------
    PCCBackbone : constant-curvature backbone.

    Notes
    -----
    The data format is described in ``docs/data_format.rst``. The model has
    two motors, ``q1`` and ``q2``; for recordings of another number of
    motors use :class:`PolynomialBackbone`.

    Examples
    --------
    >>> from sklearn.pipeline import Pipeline
    >>> from skcath.backbones import PDLBackbone
    >>> from skcath.datasets import make_benchmark
    >>> data = make_benchmark(n_catheters=1, n_runs=1)  # doctest: +SKIP
    >>> pipe = Pipeline([("backbone", PDLBackbone())]).fit(data.X)  # doctest: +SKIP
    >>> pipe.transform(data.X)[["b_x", "b_y", "b_z"]].shape  # doctest: +SKIP
    >>> calibration = pipe["backbone"].calibrate(data.X)  # doctest: +SKIP
    >>> calibration.table[["rmse_mm", "n_iter", "converged"]]  # doctest: +SKIP
    """

    def _calibrate(self, q, ref, rays, q_raw):
        # the neutral rows are found from the motor angles as they are, as the rays
        return calibrate_pdl(
            q, ref, rays.labels, rays.directions, _at_neutral(q_raw, ref, rays),
            q_neutral=rays.q_neutral, max_iter=self.max_iter, return_info=True,
        )

    def _calibrate_many(self, qs, ref, rays, q_raw):
        # the calibrations of the angles qs, all their rays solved together
        return _calibrate_pdl_batch(
            qs, ref, rays.labels, rays.directions, _at_neutral(q_raw, ref, rays),
            q_neutral=rays.q_neutral, max_iter=self.max_iter,
        )

    def _evaluate(self, q, params):
        return pdl_tip(q, params)
