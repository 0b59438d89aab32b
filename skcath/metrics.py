"""Tip-error metrics with equal run weights, and scorers for model selection.

The paper reports the mean per-run 3-D RMSE over the motion rows: each run's
RMSE is computed over its own motion samples, then runs are averaged with
equal weights, so long and short runs count the same.
"""

import numpy as np
import pandas as pd

from . import _format as fmt
from ._validation import check_target, run_codes

__all__ = ["per_run_rmse", "mean_per_run_rmse", "run_rmse_scorer", "make_run_rmse_scorer"]


def _tip_errors(y_true, y_pred, n_rows):
    """Euclidean tip error (mm) per row; NaN where the reference is missing."""
    y_true = check_target(y_true, n_rows)
    y_pred = np.asarray(y_pred, dtype=float)
    if y_pred.shape != (n_rows, 3):
        raise ValueError(f"y_pred must have shape ({n_rows}, 3) to match X; got {y_pred.shape}.")
    if not np.isfinite(y_pred).all():
        raise ValueError("y_pred contains NaN or infinite values; a prediction is expected for every row.")
    return np.linalg.norm(y_pred - y_true, axis=1)


def per_run_rmse(y_true, y_pred, X, *, phase=fmt.MOTION):
    """3-D tip RMSE of each run.

    .. math::

        \\mathrm{RMSE}_j = \\sqrt{\\frac{1}{|T_j|} \\sum_{t \\in T_j}
        \\lVert \\hat p_{j,t} - p_{j,t} \\rVert_2^2}

    over the rows ``T_j`` of run ``j`` in the given phase whose reference
    ``y_true`` is finite (tracker dropouts are left out, never imputed).

    Parameters
    ----------
    y_true : array-like of shape (n_samples, 3)
        Measured tip positions (mm), NaN rows allowed.
    y_pred : array-like of shape (n_samples, 3)
        Estimated tip positions (mm).
    X : pandas.DataFrame
        The recordings (long format, ``docs/data_format.rst``); only the
        ``run`` and ``phase`` columns are used.
    phase : {"motion", "sweep"} or None, default="motion"
        Rows to score; None scores all rows.

    Returns
    -------
    rmse : pandas.Series
        RMSE (mm) indexed by run id, in order of first appearance; NaN for a
        run with no scored row.
    """
    if not isinstance(X, pd.DataFrame) or fmt.RUN not in X.columns:
        raise ValueError("X must be a long-format DataFrame with a 'run' column (see docs/data_format.rst).")
    if phase not in (None, *fmt.PHASES):
        raise ValueError(f"phase must be one of {fmt.PHASES} or None; got {phase!r}.")
    err = _tip_errors(y_true, y_pred, len(X))
    codes, runs = run_codes(X)
    keep = np.isfinite(err)
    if phase is not None:
        if fmt.PHASE not in X.columns:
            raise ValueError("X has no 'phase' column; pass phase=None to score all rows.")
        keep &= (X[fmt.PHASE].to_numpy() == phase)
    sums = np.bincount(codes[keep], weights=err[keep] ** 2, minlength=len(runs))
    counts = np.bincount(codes[keep], minlength=len(runs))
    with np.errstate(invalid="ignore", divide="ignore"):
        rmse = np.sqrt(sums / counts)
    return pd.Series(rmse, index=pd.Index(runs, name=fmt.RUN), name="rmse_mm")


def mean_per_run_rmse(y_true, y_pred, X, *, phase=fmt.MOTION):
    """Mean per-run 3-D RMSE (mm) with equal run weights (the paper's metric).

    Parameters are those of :func:`per_run_rmse`; runs without a scored row
    are left out of the mean.

    Returns
    -------
    rmse : float
    """
    per_run = per_run_rmse(y_true, y_pred, X, phase=phase)
    if per_run.isna().all():
        raise ValueError(f"no run has a scored row (phase={phase!r} with a finite y_true).")
    return float(per_run.mean())


class _RunRMSEScorer:
    """Picklable scorer: negated mean per-run RMSE of ``estimator.predict(X)``."""

    def __init__(self, phase):
        self.phase = phase

    def __call__(self, estimator, X, y):
        return -mean_per_run_rmse(y, estimator.predict(X), X, phase=self.phase)

    def __repr__(self):
        return f"make_run_rmse_scorer(phase={self.phase!r})"


def make_run_rmse_scorer(*, phase=fmt.MOTION):
    """Scorer ``scorer(estimator, X, y)`` for cross_validate and GridSearchCV.

    Returns the NEGATED mean per-run RMSE (greater is better, as scikit-learn
    expects), computed on ``estimator.predict(X)``.

    Parameters
    ----------
    phase : {"motion", "sweep"} or None, default="motion"
        Rows to score.

    Returns
    -------
    scorer : callable
    """
    if phase not in (None, *fmt.PHASES):
        raise ValueError(f"phase must be one of {fmt.PHASES} or None; got {phase!r}.")
    return _RunRMSEScorer(phase)


#: Negated mean per-run RMSE over motion rows, for ``scoring=`` arguments.
run_rmse_scorer = make_run_rmse_scorer()
