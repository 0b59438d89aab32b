"""Renewing a backbone's calibration from a sweep of the motors alone.

After a shaft change the backbone calibrated on the tracked sweep is stale,
and a new sweep recorded without the tracker gives the motor angles and
torques of the new configuration but no tip. :class:`MotorRecalibration`
learns, on tracked recordings of other catheters, how the calibration
changes when the sweep's torque loops change, and predicts the tip along a
motor-only re-sweep from the kept calibration:

.. math::

    \\hat p(q) = g_\\text{old}(q) + R_\\text{old}^\\top\\, \\Delta(q), \\qquad
    \\Delta = W\\, \\big(f(\\text{re-sweep}) - f(\\text{sweep})\\big),

where :math:`g_\\text{old}` is the kept calibration, :math:`f` the sweep's
torque model (the coefficients and residual scales of
:class:`~skcath.online.ShaftChangeDetector` fitted on it), :math:`R_\\text{old}`
the sweep frame of the kept calibration (:func:`~skcath.frames.sweep_frame`,
which makes the change independent of how the base sensor is mounted), and
:math:`\\Delta` the change of the calibration's tip on a polar grid of motor
angles about the neutral angles (``n_directions`` directions at
``n_radii`` magnitudes up to the sweep amplitude, and the neutral point),
interpolated between the grid points. :math:`W` is a ridge regression fitted
on every ordered pair of runs of one catheter in the training recordings,
without an intercept (the same torque loops predict the same calibration).
The backbone is then calibrated on the re-sweep with :math:`\\hat p` as its
reference tip.
"""

from __future__ import annotations

import math
from numbers import Integral, Real

import numpy as np
import pandas as pd
from sklearn.base import BaseEstimator, _fit_context, clone
from sklearn.linear_model import Ridge
from sklearn.preprocessing import StandardScaler
from sklearn.utils._param_validation import HasMethods, Interval, StrOptions
from sklearn.utils.validation import check_is_fitted

from .. import _format as fmt
from .._runs import run_codes, run_positions
from .._validation import check_recordings
from ..backbones import (
    PCCParams,
    PDLBackbone,
    PDLParams,
    PolynomialParams,
    pcc_tip,
    pdl_tip,
    polynomial_tip,
)
from ..frames import sweep_frame
from ._change import ShaftChangeDetector
from ._estimator import _motor_range, _neutral_angles

#: Ridge penalties tried with ``alpha="auto"``, one catheter held out at a time.
ALPHAS = tuple(float(a) for a in np.logspace(0, 5, 11))

_TIPS = {PDLParams: pdl_tip, PCCParams: pcc_tip, PolynomialParams: polynomial_tip}


def _tip(params, q):
    """Nominal tip (mm) of a calibration at the motor angles ``q`` (deg), shape (n, 3)."""
    return _TIPS[type(params)](np.asarray(q, dtype=np.float64), params)


def _scaler():
    """Scales of the feature changes; no centring, so that no change predicts no change."""
    return StandardScaler(with_mean=False)


def _ridge(alpha):
    """The regression of the grid change on the scaled feature change, through the origin."""
    return Ridge(alpha=alpha, fit_intercept=False)


def polar_grid(q_neutral, amplitude, n_directions, n_radii):
    """Motor angles of the grid: the neutral point, then each magnitude's directions.

    Parameters
    ----------
    q_neutral : array-like of shape (2,)
        Centre of the grid (deg).
    amplitude : float
        Largest magnitude (deg); the magnitudes are ``amplitude * k / n_radii``.
    n_directions, n_radii : int
        Directions (from 0, evenly spaced) and magnitudes.

    Returns
    -------
    q : ndarray of shape (1 + n_radii * n_directions, 2)
        Motor angles (deg).
    """
    psi = 2.0 * np.pi * np.arange(n_directions) / n_directions
    unit = np.column_stack([np.cos(psi), np.sin(psi)])
    rings = [amplitude * (k + 1) / n_radii * unit for k in range(n_radii)]
    return np.asarray(q_neutral, dtype=float) + np.concatenate([np.zeros((1, 2)), *rings])


def interpolate_polar(values, q, q_neutral, amplitude, n_directions, n_radii):
    """Values on the grid of :func:`polar_grid`, interpolated at the motor angles ``q``.

    Linear in the magnitude (held beyond the amplitude) and in the direction
    (periodic).

    Parameters
    ----------
    values : ndarray of shape (1 + n_radii * n_directions, d)
        Values at the grid points, in the grid's order.
    q : ndarray of shape (n, 2)
        Motor angles (deg).
    q_neutral, amplitude, n_directions, n_radii
        As for :func:`polar_grid`.

    Returns
    -------
    out : ndarray of shape (n, d)
    """
    d = np.asarray(q, dtype=float) - q_neutral
    rho = np.clip(np.hypot(d[:, 0], d[:, 1]) / amplitude * n_radii, 0.0, float(n_radii))
    psi = np.mod(np.arctan2(d[:, 1], d[:, 0]), 2.0 * np.pi) / (2.0 * np.pi) * n_directions
    ring = np.minimum(np.floor(rho).astype(int), n_radii - 1)  # lower ring, 0 = the neutral point
    w_rho = rho - ring
    j0 = np.floor(psi).astype(int) % n_directions
    j1 = (j0 + 1) % n_directions
    w_psi = (psi - np.floor(psi))[:, None]

    def on_ring(k):  # values on the rings k >= 1 at the directions psi
        base = 1 + (k - 1) * n_directions
        return (1.0 - w_psi) * values[base + j0] + w_psi * values[base + j1]

    inner = np.where((ring == 0)[:, None], values[0], on_ring(np.maximum(ring, 1)))
    outer = on_ring(ring + 1)
    return (1.0 - w_rho)[:, None] * inner + w_rho[:, None] * outer


class MotorRecalibration(BaseEstimator):
    """Predict the tip along a sweep of the motors alone, from a tracked sweep of the same catheter.

    A shaft change makes the backbone's calibration stale. This estimator
    learns, on tracked recordings of several shaft settings of other
    catheters, how a calibration changes with the sweep's torque loops, and
    turns a motor-only re-sweep into a tracked one with a predicted
    reference tip (module docstring for the model), on which the backbone
    can be calibrated again. :meth:`OnlineEstimator.resweep
    <skcath.online.OnlineEstimator.resweep>` uses it with
    ``recalibration=``.

    Parameters
    ----------
    backbone : estimator or None, default=None
        The backbone whose calibrations the training sweeps give
        (``calibrate``): :class:`~skcath.backbones.PDLBackbone` when None.
    detector : ShaftChangeDetector or None, default=None
        Its torque model (``n_knots``, ``play_width``, ``model``) gives the
        sweep features; ``ShaftChangeDetector()`` when None.
    alpha : float or "auto", default="auto"
        Ridge penalty on the standardised feature changes. ``"auto"``
        chooses among :data:`ALPHAS` by holding out one group (catheter) at
        a time, which needs at least two groups.
    n_directions : int, default=8
        Directions of the grid on which the calibration's change is learned.
    n_radii : int, default=3
        Magnitudes of the grid, evenly spaced up to the sweep amplitude.

    Attributes
    ----------
    alpha_ : float
        The ridge penalty used.
    cv_rmse_ : dict or None
        With ``alpha="auto"``: penalty -> RMS error (mm) of the predicted
        tip changes on the grid, one group held out at a time.
    change_rmse_ : float
        RMS change (mm) of the calibration's tip on the grid over the
        training pairs: the error of keeping the old calibration.
    n_pairs_ : int
        Ordered pairs of runs of one group the regression was fitted on.
    scaler_ : sklearn.preprocessing.StandardScaler
    ridge_ : sklearn.linear_model.Ridge
        The fitted regression from the feature change to the grid change
        (mm, in the old sweep frame).

    See Also
    --------
    skcath.online.OnlineEstimator.resweep : a re-sweep with or without a recalibration.

    Notes
    -----
    ``docs/shaft_change.rst`` (*Recovering without the tracker*) measures it
    on the simulated benchmark with a held-out catheter.
    """

    _parameter_constraints: dict = {
        "backbone": [HasMethods(["fit", "calibrate"]), None],
        "detector": [HasMethods(["start"]), None],
        "alpha": [Interval(Real, 0, None, closed="neither"), StrOptions({"auto"})],
        "n_directions": [Interval(Integral, 3, None, closed="left")],
        "n_radii": [Interval(Integral, 1, None, closed="left")],
    }

    def __init__(self, backbone=None, *, detector=None, alpha="auto", n_directions=8, n_radii=3):
        self.backbone = backbone
        self.detector = detector
        self.alpha = alpha
        self.n_directions = n_directions
        self.n_radii = n_radii

    # ---------------------------------------------------------------- pieces
    def _features(self, sweep):
        """The torque model of a sweep: coefficients and residual scales, flattened."""
        detector = ShaftChangeDetector() if self.detector is None else clone(self.detector)
        detector.start(sweep)
        return np.concatenate([detector.coef_.ravel(), detector.scale_])

    def _grid(self, params, q_sweep):
        """The grid of a calibration and its sweep's angles: centre, amplitude, angles, tips, sweep frame."""
        centre = _neutral_angles(params)
        amplitude = _motor_range(q_sweep, centre, None)[0]
        grid = polar_grid(centre, amplitude, self.n_directions, self.n_radii)
        tips = _tip(params, grid)
        return centre, amplitude, grid, tips, sweep_frame(grid, tips)

    def _runs(self, X):
        """Per run of ``X``: sweep motor angles, calibration and sweep features."""
        backbone = PDLBackbone() if self.backbone is None else clone(self.backbone)
        sweeps = X[(X[fmt.PHASE] == fmt.SWEEP).to_numpy()]
        calibration = backbone.fit(sweeps).calibrate(sweeps)
        _, runs = run_codes(sweeps)
        out = {}
        for run, pos in zip(runs, run_positions(sweeps)):
            rows = sweeps.iloc[pos]
            q = rows[list(fmt.MOTOR_COLUMNS)].to_numpy(dtype=np.float64)
            out[run] = (q, calibration.params[run], self._features(rows))
        return out

    # ------------------------------------------------------------------- API
    @_fit_context(prefer_skip_nested_validation=True)
    def fit(self, X, y=None, groups=None):
        """Learn the calibration's change from the sweeps of tracked recordings.

        Parameters
        ----------
        X : pandas.DataFrame
            Recordings in the long format with their tracked sweeps
            (``ref_x, ref_y, ref_z``), several shaft settings of each
            catheter; only the sweep rows are read.
        y : None
            Unused.
        groups : array-like of shape (n_samples,), optional
            Which rows belong to one catheter: pairs are formed within a
            group. The ``catheter`` column when None.

        Returns
        -------
        self : MotorRecalibration
        """
        X, _ = check_recordings(X)
        groups = self._groups(X, groups)
        runs = self._runs(X)
        run_group = pd.Series(np.asarray(groups), index=X.index).groupby(X[fmt.RUN].astype(str).to_numpy()).first()
        features, changes, pair_groups = [], [], []
        for group in pd.unique(run_group.to_numpy()):
            members = [r for r in runs if run_group[str(r)] == group]
            for a in members:
                _, _, grid, old, rotation = self._grid(runs[a][1], runs[a][0])  # once per old run
                for b in members:
                    if a != b:
                        features.append(runs[b][2] - runs[a][2])
                        # the change of the calibration on the old grid, in the old sweep frame (mm)
                        changes.append(((_tip(runs[b][1], grid) - old) @ rotation.T).ravel())
                        pair_groups.append(group)
        if not features:
            raise ValueError("fit needs at least two runs of one group (catheter) to form a pair.")
        F, Y, G = np.array(features), np.array(changes), np.array(pair_groups)
        self.alpha_, self.cv_rmse_ = self._choose_alpha(F, Y, G)
        self.scaler_ = _scaler().fit(F)
        self.ridge_ = _ridge(self.alpha_).fit(self.scaler_.transform(F), Y)
        self.change_rmse_ = float(np.sqrt(np.mean(Y**2) * 3))
        self.n_pairs_ = len(F)
        return self

    @staticmethod
    def _groups(X, groups):
        if groups is None:  # the recordings always have the column
            return X[fmt.CATHETER].astype(str).to_numpy()
        groups = np.asarray(groups)
        if groups.shape != (len(X),):
            raise ValueError(f"groups must have one value per row of X ({len(X)}); got shape {groups.shape}.")
        return groups

    def _choose_alpha(self, F, Y, G):
        """The penalty, and the held-out-group RMS error (mm) of each one tried."""
        if self.alpha != "auto":
            return float(self.alpha), None
        labels = np.unique(G)
        if len(labels) < 2:
            raise ValueError(
                'alpha="auto" holds out one catheter at a time and needs at least two groups; '
                f"got {len(labels)}. Give alpha as a number."
            )
        scores = {}
        for alpha in ALPHAS:
            sq = 0.0
            for label in labels:
                held = G == label
                scaler = _scaler().fit(F[~held])
                model = _ridge(alpha).fit(scaler.transform(F[~held]), Y[~held])
                sq += float(np.sum((model.predict(scaler.transform(F[held])) - Y[held]) ** 2))
            scores[alpha] = math.sqrt(sq / Y.size * 3)
        return min(scores, key=scores.get), scores

    def predict_change(self, params, sweep, resweep):
        """The predicted change of the calibration's tip at the re-sweep's motor angles (mm, base frame).

        Parameters
        ----------
        params : PCCParams, PDLParams or PolynomialParams
            The kept calibration, from ``sweep``.
        sweep, resweep : pandas.DataFrame
            The sweep rows of the kept calibration's run and of the re-sweep,
            with the motor angles and torques (the reference tip is not read).

        Returns
        -------
        change : ndarray of shape (n_resweep, 3)
        """
        check_is_fitted(self)
        q_old = sweep[list(fmt.MOTOR_COLUMNS)].to_numpy(dtype=np.float64)
        q_new = resweep[list(fmt.MOTOR_COLUMNS)].to_numpy(dtype=np.float64)
        centre, amplitude, _, _, rotation = self._grid(params, q_old)
        df = self._features(resweep) - self._features(sweep)
        delta = self.ridge_.predict(self.scaler_.transform(df[None]))[0].reshape(-1, 3) @ rotation
        return interpolate_polar(delta, q_new, centre, amplitude, self.n_directions, self.n_radii)

    def recalibrate(self, sweep, resweep, params=None):
        """A copy of the motor-only re-sweep with the predicted reference tip.

        Parameters
        ----------
        sweep : pandas.DataFrame
            The tracked sweep rows of one run (the old configuration).
        resweep : pandas.DataFrame
            The sweep rows of the re-sweep of the motors alone; its
            reference columns, if any, are not read.
        params : PCCParams, PDLParams or PolynomialParams, optional
            The calibration kept from ``sweep``; calibrated on ``sweep``
            with ``backbone`` when None.

        Returns
        -------
        resweep : pandas.DataFrame
            A copy of ``resweep`` whose ``ref_x, ref_y, ref_z`` (mm) are the
            kept calibration's tip plus the predicted change: a tracked
            re-sweep to calibrate the backbone on.
        """
        check_is_fitted(self)
        if params is None:
            backbone = PDLBackbone() if self.backbone is None else clone(self.backbone)
            checked, _ = check_recordings(sweep)
            calibration = backbone.fit(checked).calibrate(checked)
            params = next(iter(calibration.params.values()))
        q_new = resweep[list(fmt.MOTOR_COLUMNS)].to_numpy(dtype=np.float64)
        tip = _tip(params, q_new) + self.predict_change(params, sweep, resweep)
        return resweep.assign(**{c: tip[:, k] for k, c in enumerate(fmt.REFERENCE_COLUMNS)})
