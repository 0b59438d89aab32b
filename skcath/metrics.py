"""Tip-error metrics with equal run weights, and scorers for model selection.

The paper reports the mean per-run 3-D RMSE over the motion rows: each run's
RMSE is computed over its own motion samples, then runs are averaged with
equal weights, so long and short runs count the same.

The other functions describe the errors further, always run by run: the
distribution of the tip error (:func:`error_cdf`), the RMSE in bins of the
motor magnitude or of the time since the start of the motion
(:func:`run_bin_rmse` and its two shortcuts), and the paired comparison of
two methods with a cluster bootstrap interval (:func:`paired_reduction`).
See ``docs/evaluation.rst``.
"""

import numbers

import numpy as np
import pandas as pd
from sklearn.utils import Bunch, check_random_state

from . import _format as fmt
from ._runs import run_codes
from ._validation_columns import (
    _check_columns_present,
    _check_finite,
    _check_frame,
    _column_as_float,
    motor_columns,
)
from ._validation_runs import CUT_RUN_HINT, _phase_masks
from ._validation_target import _target_frame_in_order, check_target

__all__ = [
    "per_run_rmse",
    "mean_per_run_rmse",
    "run_rmse_scorer",
    "make_run_rmse_scorer",
    "error_cdf",
    "motor_magnitude",
    "motion_time",
    "run_bin_rmse",
    "rmse_by_motor_magnitude",
    "rmse_over_time",
    "paired_reduction",
]


def _tip_errors(y_true, y_pred, n_rows):
    """Euclidean tip error (mm) per row; NaN where the reference is missing."""
    y_true = check_target(y_true, n_rows)
    if isinstance(y_pred, pd.DataFrame):
        y_pred = _target_frame_in_order(y_pred, "y_pred")
    y_pred = np.asarray(y_pred, dtype=float)
    if y_pred.shape != (n_rows, 3):
        raise ValueError(f"y_pred must have shape ({n_rows}, 3) to match X; got {y_pred.shape}.")
    if not np.isfinite(y_pred).all():
        raise ValueError("y_pred contains NaN or infinite values; a prediction is expected for every row.")
    return np.linalg.norm(y_pred - y_true, axis=1)


def _check_phase(phase):
    if phase not in (None, *fmt.PHASES):
        raise ValueError(f"phase must be one of {fmt.PHASES} or None; got {phase!r}.")


def _scored_errors(y_true, y_pred, X, phase):
    """Tip error (mm), run code and scored-row mask of every row.

    A row is scored when it is in ``phase`` (any phase for None) and its
    reference ``y_true`` is finite.
    """
    if not isinstance(X, pd.DataFrame) or fmt.RUN not in X.columns:
        raise ValueError("X must be a long-format DataFrame with a 'run' column (see docs/data_format.rst).")
    _check_phase(phase)
    err = _tip_errors(y_true, y_pred, len(X))
    codes, runs = run_codes(X)
    keep = np.isfinite(err)
    if phase is not None:
        if fmt.PHASE not in X.columns:
            raise ValueError("X has no 'phase' column; pass phase=None to score all rows.")
        keep &= X[fmt.PHASE].to_numpy() == phase
    return err, codes, runs, keep


# Parameter entries shared by the docstrings of the distribution and binned
# metrics; ``{name}`` in a docstring decorated with ``_fill_doc`` stands for
# the entry ``name`` (indented for a function docstring).
_SHARED_DOCS = {
    "tip_params": """y_true : array-like of shape (n_samples, 3)
        Measured tip positions (mm), NaN rows allowed (not scored). The
        columns of a DataFrame are matched by name (``p_x, p_y, p_z``).
    y_pred : array-like of shape (n_samples, 3)
        Estimated tip positions (mm), columns as ``y_true``.""",
    "X_run_phase": """X : pandas.DataFrame
        The recordings (long format); only the ``run`` and ``phase`` columns
        are used.""",
}


def _fill_doc(func):
    """Decorator: replace the ``{name}`` placeholders of ``func``'s docstring with ``_SHARED_DOCS``."""
    if func.__doc__:  # None under python -OO
        for name, text in _SHARED_DOCS.items():
            func.__doc__ = func.__doc__.replace("{" + name + "}", text)
    return func


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
        Measured tip positions (mm), NaN rows allowed. The columns of a
        DataFrame are matched by name (``p_x, p_y, p_z`` in any order);
        unnamed columns and arrays by position.
    y_pred : array-like of shape (n_samples, 3)
        Estimated tip positions (mm), columns as ``y_true``.
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
    err, codes, runs, keep = _scored_errors(y_true, y_pred, X, phase)
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
        raise ValueError(
            f"no run has a scored row (phase={phase!r} with a finite y_true). " + CUT_RUN_HINT
        )
    return float(per_run.mean())


def _check_whole_runs(X):
    """Raise if some runs of the scored recordings have sweep rows and others none (a cut run).

    Recordings of a rig without a sweep phase, where no run has a sweep row,
    are scored as they are.
    """
    _check_frame(X, caller="run_rmse_scorer")
    _check_columns_present(X, (fmt.RUN, fmt.PHASE))
    codes, runs = run_codes(X)
    sweep, _ = _phase_masks(X)
    no_sweep = np.flatnonzero(np.bincount(codes[sweep], minlength=len(runs)) == 0)
    if 0 < no_sweep.size < len(runs):
        raise ValueError(
            f"The scored recordings hold {no_sweep.size} run(s) without {fmt.SWEEP!r} rows, "
            f"first {runs[no_sweep[0]]!r}, beside runs with them; every run of these "
            "recordings starts with its calibration sweep, which a held-out run needs at "
            "test time. " + CUT_RUN_HINT
        )


class _RunRMSEScorer:
    """Picklable scorer: negated mean per-run RMSE of ``estimator.predict(X)``.

    The runs of ``X`` must be whole (each with its sweep rows): a run without
    them beside runs with them is a fold that cut the run, and is refused
    before ``predict``. Recordings without any sweep row (a rig without a
    sweep phase) are scored as they are.
    """

    def __init__(self, phase):
        self.phase = phase

    def __call__(self, estimator, X, y):
        _check_whole_runs(X)
        return -mean_per_run_rmse(y, estimator.predict(X), X, phase=self.phase)

    def __repr__(self):
        return f"make_run_rmse_scorer(phase={self.phase!r})"


def make_run_rmse_scorer(*, phase=fmt.MOTION):
    """Scorer ``scorer(estimator, X, y)`` for cross_validate and GridSearchCV.

    Returns the NEGATED mean per-run RMSE (greater is better, as scikit-learn
    expects), computed on ``estimator.predict(X)``. ``X`` must hold whole runs:
    a run without its sweep rows, which a cross-validation split that cuts
    runs (such as ``KFold``) leaves, is a ValueError naming the fix, unless
    no run of ``X`` has sweep rows (recordings of a rig without a sweep
    phase, where a cut run cannot be told from a whole one: split them by
    run, as the splitters of :mod:`skcath.model_selection` do).

    Parameters
    ----------
    phase : {"motion", "sweep"} or None, default="motion"
        Rows to score.

    Returns
    -------
    scorer : callable
    """
    _check_phase(phase)
    return _RunRMSEScorer(phase)


#: Negated mean per-run RMSE over motion rows, for ``scoring=`` arguments.
run_rmse_scorer = make_run_rmse_scorer()


# ---------------------------------------------------------------------------
# error distribution, binned errors and paired comparisons
# ---------------------------------------------------------------------------
def _real_vector(values, name, *, allow_nan=False, allow_inf=False):
    """1-D float array from a scalar or array-like; raise naming ``name``."""
    if isinstance(values, (pd.Series, pd.Index)) and pd.api.types.is_numeric_dtype(values.dtype):
        if not pd.api.types.is_bool_dtype(values.dtype):
            values = values.to_numpy(dtype=np.float64, na_value=np.nan)  # nullable dtypes
    elif isinstance(values, (pd.DataFrame, pd.Series)):
        values = values.to_numpy()
    try:
        array = np.asarray(values)
    except (TypeError, ValueError) as exc:  # ragged input
        raise ValueError(f"{name} must be a 1-D array of real numbers; converting it failed: {exc}") from None
    if array.dtype.kind == "b" or array.dtype.kind not in "fiuO":
        raise ValueError(f"{name} must hold real numbers; got dtype {array.dtype}.")
    try:
        array = array.astype(np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must hold real numbers; some values do not convert to float.") from None
    array = np.atleast_1d(array)
    if array.ndim != 1:
        raise ValueError(f"{name} must be 1-D; got shape {array.shape}.")
    for flag, test, what in ((allow_nan, np.isnan, "NaN"), (allow_inf, np.isinf, "+-inf")):
        bad = test(array)
        if not flag and bad.any():
            raise ValueError(
                f"{name} contains {int(bad.sum())} {what} value(s); first at position "
                f"{int(np.flatnonzero(bad)[0])}."
            )
    return array


@_fill_doc
def error_cdf(y_true, y_pred, X, thresholds, *, phase=fmt.MOTION):
    """Fraction of samples whose 3-D tip error is at most each threshold.

    The fraction is computed within each run and then averaged over runs with
    equal weights:

    .. math::

        F(\\delta) = \\frac{1}{J} \\sum_{j=1}^{J} \\frac{1}{|T_j|}
        \\sum_{t \\in T_j} \\mathbf{1}\\bigl[\\lVert \\hat p_{j,t} - p_{j,t}
        \\rVert_2 \\le \\delta\\bigr],

    over the ``J`` runs with at least one scored row; ``T_j`` are the rows of
    run ``j`` in the given phase whose reference ``y_true`` is finite.

    Parameters
    ----------
    {tip_params}
    {X_run_phase}
    thresholds : float or array-like of shape (n_thresholds,)
        Error thresholds (mm), in any order; NaN is not allowed.
    phase : {"motion", "sweep"} or None, default="motion"
        Rows to score; None scores all rows.

    Returns
    -------
    fraction : pandas.Series
        Values in [0, 1] named ``"fraction"``, indexed by the thresholds (mm,
        index name ``"threshold_mm"``) in the order given.

    Raises
    ------
    ValueError
        If no run has a scored row, or on malformed input.

    Examples
    --------
    >>> import numpy as np, pandas as pd
    >>> from skcath.metrics import error_cdf
    >>> X = pd.DataFrame({"run": ["a", "a", "b"], "phase": "motion"})
    >>> y_true = np.zeros((3, 3))
    >>> y_pred = np.array([[1.0, 0, 0], [6.0, 0, 0], [2.0, 0, 0]])
    >>> error_cdf(y_true, y_pred, X, [5.0]).tolist()  # (1/2 + 1/1) / 2
    [0.75]
    """
    _check_phase(phase)
    thresholds = _real_vector(thresholds, "thresholds", allow_inf=True)
    err, codes, runs, keep = _scored_errors(y_true, y_pred, X, phase)
    scored_codes = codes[keep]
    scored_err = err[keep]
    counts = np.bincount(scored_codes, minlength=len(runs))
    if not counts.any():
        raise ValueError(f"no run has a scored row (phase={phase!r} with a finite y_true).")
    order = np.lexsort((scored_err, scored_codes))
    sorted_err = scored_err[order]
    bounds = np.concatenate(([0], np.cumsum(counts)))
    fractions = []
    for k in np.flatnonzero(counts):
        errors = sorted_err[bounds[k] : bounds[k + 1]]
        fractions.append(np.searchsorted(errors, thresholds, side="right") / errors.size)
    mean = np.mean(fractions, axis=0)
    return pd.Series(mean, index=pd.Index(thresholds, name="threshold_mm"), name="fraction")


def motor_magnitude(X):
    """Magnitude of the bending-motor command of every row.

    .. math::

        m_t = \\sqrt{q_{1,t}^2 + \\dots + q_{N,t}^2}

    Parameters
    ----------
    X : pandas.DataFrame
        The recordings (long format); only the motor angle columns ``q1 ..
        qN`` (degrees, :func:`skcath.motor_columns`) are used.

    Returns
    -------
    magnitude : ndarray of shape (n_samples,)
        Euclidean norm of the motor angles (degrees), one value per row of
        ``X``.

    Examples
    --------
    >>> import pandas as pd
    >>> from skcath.metrics import motor_magnitude
    >>> motor_magnitude(pd.DataFrame({"q1": [3.0, 0.0], "q2": [4.0, -2.0]}))
    array([5., 2.])
    """
    _check_frame(X, caller="motor_magnitude")
    motors, _ = motor_columns(X)
    q = []
    for column in motors:
        values = _column_as_float(X, column)
        _check_finite(X, column, values, allow_nan=False)
        q.append(values)
    return np.hypot.reduce(q, axis=0)


def motion_time(X):
    """Time since the start of the motion phase of each row's run.

    .. math::

        s_{j,t} = t - t_j^{0}, \\qquad t_j^{0} = \\min \\{t : \\text{row of run } j
        \\text{ in the motion phase}\\}

    Parameters
    ----------
    X : pandas.DataFrame
        The recordings (long format); the ``run``, ``t`` (s) and ``phase``
        columns are used.

    Returns
    -------
    time : ndarray of shape (n_samples,)
        Seconds since the run's first motion sample on motion rows (0 on that
        sample); NaN on sweep rows.

    Examples
    --------
    >>> import pandas as pd
    >>> from skcath.metrics import motion_time
    >>> X = pd.DataFrame({"run": ["a", "a", "a"], "t": [5.0, 5.1, 5.3],
    ...                   "phase": ["sweep", "motion", "motion"]})
    >>> motion_time(X).round(6)
    array([nan, 0. , 0.2])
    """
    _check_frame(X, caller="motion_time")
    _check_columns_present(X, (fmt.RUN, fmt.TIME, fmt.PHASE))
    t = _column_as_float(X, fmt.TIME)
    _check_finite(X, fmt.TIME, t, allow_nan=False)
    codes, runs = run_codes(X)
    _, motion = _phase_masks(X)
    start = np.full(len(runs), np.inf)
    np.minimum.at(start, codes[motion], t[motion])
    out = np.full(len(X), np.nan)
    out[motion] = t[motion] - start[codes[motion]]
    return out


def _check_edges(bins):
    """Bin edges as a strictly increasing finite float array with >= 2 entries."""
    edges = _real_vector(bins, "bins")
    if edges.size < 2:
        raise ValueError(f"bins must hold at least 2 edges (one bin); got {edges.size}.")
    steps = np.diff(edges)
    if not (steps > 0).all():
        i = int(np.flatnonzero(steps <= 0)[0])
        raise ValueError(
            f"bins must be strictly increasing; edge {i + 1} ({edges[i + 1]!r}) does "
            f"not exceed edge {i} ({edges[i]!r})."
        )
    return edges


@_fill_doc
def run_bin_rmse(y_true, y_pred, X, values, bins, *, phase=fmt.MOTION):
    """3-D tip RMSE of each run within bins of a per-row quantity.

    Row ``t`` of run ``j`` falls in bin ``b`` when
    :math:`e_b \\le v_t < e_{b+1}`; for every run and every bin holding at
    least one scored row,

    .. math::

        \\mathrm{RMSE}_{j,b} = \\sqrt{\\frac{1}{|T_{j,b}|} \\sum_{t \\in T_{j,b}}
        \\lVert \\hat p_{j,t} - p_{j,t} \\rVert_2^2}.

    Averaging ``rmse_mm`` over runs for each bin gives the error as a
    function of the quantity with equal run weights.

    Parameters
    ----------
    {tip_params}
    {X_run_phase}
    values : array-like of shape (n_samples,)
        The quantity to bin by, one value per row of ``X`` (e.g.
        :func:`motor_magnitude` or :func:`motion_time`). Rows with NaN or
        values outside ``[bins[0], bins[-1])`` are not scored.
    bins : array-like of shape (n_bins + 1,)
        Strictly increasing, finite bin edges, in the unit of ``values``.
        Bins are closed on the left and open on the right.
    phase : {"motion", "sweep"} or None, default="motion"
        Rows to score; None scores all rows.

    Returns
    -------
    table : pandas.DataFrame
        One row per (run, non-empty bin), runs in order of first appearance
        and bins in increasing order, with the columns ``run``, ``bin_left``,
        ``bin_right`` (unit of ``values``), ``n_samples`` (scored rows) and
        ``rmse_mm``.

    Examples
    --------
    >>> import numpy as np, pandas as pd
    >>> from skcath.metrics import run_bin_rmse
    >>> X = pd.DataFrame({"run": ["a", "a", "a"], "phase": "motion"})
    >>> y_pred = np.array([[3.0, 0, 0], [4.0, 0, 0], [1.0, 0, 0]])
    >>> table = run_bin_rmse(np.zeros((3, 3)), y_pred, X, [0.0, 5.0, 12.0], [0, 10, 20])
    >>> table[["bin_left", "n_samples", "rmse_mm"]].round(4).to_numpy().tolist()
    [[0.0, 2.0, 3.5355], [10.0, 1.0, 1.0]]
    """
    _check_phase(phase)
    edges = _check_edges(bins)
    values = _real_vector(values, "values", allow_nan=True, allow_inf=True)
    if isinstance(X, pd.DataFrame) and values.size != len(X):
        raise ValueError(f"values must have one entry per row of X ({len(X)}); got {values.size}.")
    err, codes, runs, keep = _scored_errors(y_true, y_pred, X, phase)
    n_bins = edges.size - 1
    which = np.searchsorted(edges, values, side="right") - 1
    keep &= (which >= 0) & (which < n_bins)  # NaN sorts past the last edge
    key = codes[keep] * n_bins + which[keep]
    sums = np.bincount(key, weights=err[keep] ** 2, minlength=len(runs) * n_bins)
    counts = np.bincount(key, minlength=len(runs) * n_bins)
    cells = np.flatnonzero(counts)
    run_of, bin_of = np.divmod(cells, n_bins)
    return pd.DataFrame(
        {
            fmt.RUN: pd.Series(runs[run_of], dtype=object).infer_objects(),
            "bin_left": edges[bin_of],
            "bin_right": edges[bin_of + 1],
            "n_samples": counts[cells].astype(np.int64),
            "rmse_mm": np.sqrt(sums[cells] / counts[cells]),
        }
    )


def _check_width(width):
    if (
        isinstance(width, bool)
        or not isinstance(width, (numbers.Real, np.floating, np.integer))
        or not np.isfinite(width)
        or width <= 0
    ):
        raise ValueError(f"width must be a positive finite number (bin width); got {width!r}.")
    return float(width)


def _regular_edges(values, width, name):
    """Edges 0, width, 2 width, ... up to past the largest finite value."""
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        raise ValueError(f"no row has a finite {name}.")
    top = max(float(finite.max()), 0.0)
    n_bins = int(np.floor(top / width)) + 1
    edges = width * np.arange(n_bins + 1, dtype=np.float64)
    if edges[-1] <= top:  # rounding in top / width
        edges = np.append(edges, edges[-1] + width)
    return edges


@_fill_doc
def rmse_by_motor_magnitude(y_true, y_pred, X, *, width=10.0, phase=fmt.MOTION):
    """Per-run 3-D tip RMSE in bins of the motor magnitude.

    :func:`run_bin_rmse` with ``values=motor_magnitude(X)`` and the edges
    ``0, width, 2 width, ...`` up to past the largest magnitude of ``X``.

    Parameters
    ----------
    {tip_params}
    X : pandas.DataFrame
        The recordings (long format); the ``run``, ``phase``, ``q1`` and
        ``q2`` columns are used.
    width : float, default=10.0
        Bin width (degrees of motor magnitude).
    phase : {"motion", "sweep"} or None, default="motion"
        Rows to score; None scores all rows.

    Returns
    -------
    table : pandas.DataFrame
        As :func:`run_bin_rmse`; ``bin_left`` and ``bin_right`` in degrees.

    See Also
    --------
    motor_magnitude, run_bin_rmse
    """
    _check_phase(phase)
    width = _check_width(width)
    magnitude = motor_magnitude(X)
    edges = _regular_edges(magnitude, width, "motor magnitude")
    return run_bin_rmse(y_true, y_pred, X, magnitude, edges, phase=phase)


@_fill_doc
def rmse_over_time(y_true, y_pred, X, *, width=10.0):
    """Per-run 3-D tip RMSE in bins of time since the start of the motion.

    :func:`run_bin_rmse` over the motion rows with ``values=motion_time(X)``
    and the edges ``0, width, 2 width, ...`` up to past the longest motion
    phase of ``X``.

    Parameters
    ----------
    {tip_params}
    X : pandas.DataFrame
        The recordings (long format); the ``run``, ``t`` (s) and ``phase``
        columns are used.
    width : float, default=10.0
        Bin width (s).

    Returns
    -------
    table : pandas.DataFrame
        As :func:`run_bin_rmse`; ``bin_left`` and ``bin_right`` in seconds
        since the start of the motion.

    See Also
    --------
    motion_time, run_bin_rmse
    """
    width = _check_width(width)
    elapsed = motion_time(X)
    edges = _regular_edges(elapsed, width, "motion time (X has no motion rows)")
    return run_bin_rmse(y_true, y_pred, X, elapsed, edges, phase=fmt.MOTION)


# ---------------------------------------------------------------------------
# paired comparison of two methods
# ---------------------------------------------------------------------------
def _check_unique_index(series, name):
    if not series.index.is_unique:
        duplicated = series.index[series.index.duplicated()].unique()
        raise ValueError(
            f"{name} is a Series with duplicated index label(s) {list(duplicated[:5])}; "
            "one value per run is expected."
        )


def _align(series, index, name, reference):
    """``series`` reordered on ``index``; raise unless both have the same labels."""
    _check_unique_index(series, name)
    if series.index.equals(index):
        return series
    only_here = series.index.difference(index)
    only_there = index.difference(series.index)
    if len(only_here) or len(only_there):
        raise ValueError(
            f"{name} and {reference} are Series with different index labels (runs): "
            f"{len(only_here)} label(s) only in {name} (e.g. {list(only_here[:3])}), "
            f"{len(only_there)} only in {reference} (e.g. {list(only_there[:3])}). "
            "Both must hold one value for each of the same runs."
        )
    return series.reindex(index)


def paired_reduction(
    baseline, candidate, clusters, *, n_bootstrap=2000, confidence=0.95, random_state=None
):
    """Mean per-run error reduction of a candidate over a baseline, with a cluster bootstrap interval.

    With per-run errors :math:`b_j` (baseline) and :math:`c_j` (candidate)
    of the same ``n`` runs and the differences :math:`d_j = b_j - c_j`,

    .. math::

        \\bar d = \\frac{1}{n} \\sum_{j=1}^{n} d_j, \\qquad
        \\bar d_{\\%} = 100 \\, \\frac{\\bar d}{\\frac{1}{n} \\sum_j b_j}.

    The interval is a percentile interval of a cluster bootstrap: the ``K``
    clusters (e.g. the (catheter, setting) pairs whose repeats share a shaft
    configuration) are drawn ``K`` times with replacement, and the statistic
    is the mean of :math:`d_j` over all runs of the drawn clusters, each run
    weighted equally (a cluster drawn twice counts twice):

    .. math::

        \\bar d^{*} = \\frac{\\sum_{k} m_k D_k}{\\sum_k m_k n_k},

    with :math:`m_k` the number of times cluster ``k`` is drawn, :math:`D_k`
    the sum of its differences and :math:`n_k` its number of runs.

    Parameters
    ----------
    baseline : array-like or pandas.Series of shape (n_runs,)
        Per-run error of the reference method (mm), e.g. the output of
        :func:`per_run_rmse`.
    candidate : array-like or pandas.Series of shape (n_runs,)
        Per-run error of the method compared (mm), same runs. When both
        ``baseline`` and ``candidate`` are Series, they are matched by index
        label (which must be the same set of unique labels); otherwise by
        position.
    clusters : array-like or pandas.Series of shape (n_runs,)
        Cluster label of every run (hashable, no missing value). A Series is
        matched to a Series ``baseline`` (or ``candidate``) by index label;
        otherwise by position.
    n_bootstrap : int, default=2000
        Number of bootstrap resamples.
    confidence : float, default=0.95
        Coverage of the interval, in (0, 1).
    random_state : int, RandomState instance or None, default=None
        Seed of the resampling; the same int gives the same interval.

    Returns
    -------
    result : sklearn.utils.Bunch
        With the keys

        - ``reduction_mm`` (float): :math:`\\bar d`, in mm; positive when the
          candidate is better;
        - ``reduction_pct`` (float): :math:`\\bar d_{\\%}`, in percent of the
          baseline's mean error;
        - ``ci_low_mm``, ``ci_high_mm`` (float): bounds of the bootstrap
          interval of :math:`\\bar d` (mm);
        - ``fraction_improved`` (float): fraction of runs with
          :math:`c_j < b_j`;
        - ``n_runs`` (int), ``n_clusters`` (int): runs and clusters used.

    Raises
    ------
    ValueError
        On mismatched lengths or index labels, +-inf errors, missing cluster
        labels, fewer than 2 clusters, or bad ``n_bootstrap`` / ``confidence``.

    Notes
    -----
    Runs where either error is NaN (no scored row, see :func:`per_run_rmse`)
    are left out, and a cluster left without runs is dropped. The resamples
    are drawn in blocks as integer arrays, so 2000 resamples of a few hundred
    runs take milliseconds.

    Examples
    --------
    >>> from skcath.metrics import paired_reduction
    >>> res = paired_reduction([8.0, 6.0, 7.0, 9.0], [4.0, 3.0, 4.0, 4.0],
    ...                        ["S01", "S01", "S02", "S02"], random_state=0)
    >>> res.reduction_mm, res.reduction_pct, res.fraction_improved
    (3.75, 50.0, 1.0)
    """
    if isinstance(n_bootstrap, bool) or not isinstance(n_bootstrap, numbers.Integral) or n_bootstrap < 1:
        raise ValueError(f"n_bootstrap must be a positive integer; got {n_bootstrap!r}.")
    if (
        isinstance(confidence, bool)
        or not isinstance(confidence, numbers.Real)
        or not 0.0 < confidence < 1.0
    ):
        raise ValueError(f"confidence must be a number strictly between 0 and 1; got {confidence!r}.")
    base, cand, codes = _paired_runs(baseline, candidate, clusters)
    n_clusters = int(codes.max()) + 1 if codes.size else 0
    if n_clusters < 2:
        raise ValueError(
            f"a cluster bootstrap needs runs in at least 2 clusters; got {base.size} "
            f"run(s) with finite errors in {n_clusters} cluster(s)."
        )

    diff = base - cand
    reduction = float(diff.mean())
    mean_base = float(base.mean())
    with np.errstate(invalid="ignore", divide="ignore"):
        reduction_pct = float(np.float64(100.0) * reduction / mean_base)
    stats = _cluster_bootstrap(diff, codes, n_clusters, n_bootstrap, check_random_state(random_state))
    tail = (1.0 - confidence) / 2.0
    low, high = np.quantile(stats, [tail, 1.0 - tail])
    return Bunch(
        reduction_mm=reduction,
        reduction_pct=reduction_pct,
        ci_low_mm=float(low),
        ci_high_mm=float(high),
        fraction_improved=float(np.mean(cand < base)),
        n_runs=int(base.size),
        n_clusters=n_clusters,
    )


def _paired_runs(baseline, candidate, clusters):
    """Per-run errors of both methods and cluster codes (0, 1, ...) of the runs where both are finite.

    Series are matched by index label (see :func:`paired_reduction`), other
    inputs by position.
    """
    for name, value in (("baseline", baseline), ("candidate", candidate), ("clusters", clusters)):
        if isinstance(value, pd.DataFrame):
            raise TypeError(f"{name} must be 1-D (one value per run); got a DataFrame.")
    index = None
    if isinstance(baseline, pd.Series):
        _check_unique_index(baseline, "baseline")
        index = baseline.index
        if isinstance(candidate, pd.Series):
            candidate = _align(candidate, index, "candidate", "baseline")
    elif isinstance(candidate, pd.Series):
        _check_unique_index(candidate, "candidate")
        index = candidate.index
    if isinstance(clusters, pd.Series) and index is not None:
        clusters = _align(clusters, index, "clusters", "the per-run errors")

    base = _real_vector(baseline, "baseline", allow_nan=True)
    cand = _real_vector(candidate, "candidate", allow_nan=True)
    labels = _cluster_labels(clusters)
    if not base.size == cand.size == labels.size:
        raise ValueError(
            "baseline, candidate and clusters must have one entry per run; got "
            f"lengths {base.size}, {cand.size} and {labels.size}."
        )
    codes = _cluster_codes(labels)
    used = np.isfinite(base) & np.isfinite(cand)
    codes, _ = pd.factorize(codes[used], sort=False)
    return base[used], cand[used], np.asarray(codes, dtype=np.intp)


def _cluster_labels(clusters):
    """The cluster labels as a 1-D object array."""
    if isinstance(clusters, pd.Series):
        labels = clusters.to_numpy(dtype=object)
    else:
        labels = np.asarray(clusters, dtype=object)
        if labels.ndim == 0:
            labels = labels.reshape(1)
    if labels.ndim != 1:
        raise ValueError(f"clusters must be 1-D (one label per run); got shape {labels.shape}.")
    return labels


def _cluster_codes(labels):
    """Code of every run's cluster label, in order of first appearance; raise on a missing label."""
    try:
        codes, _ = pd.factorize(labels, sort=False, use_na_sentinel=True)
    except TypeError as exc:
        raise ValueError(f"clusters must hold hashable labels; factorizing them failed: {exc}") from None
    if (codes < 0).any():
        first = int(np.flatnonzero(codes < 0)[0])
        raise ValueError(
            f"clusters contains {int((codes < 0).sum())} missing label(s) (NaN/None); "
            f"first at position {first}. Every run needs a cluster."
        )
    return codes


def _cluster_bootstrap(diff, codes, n_clusters, n_bootstrap, rng):
    """Mean difference over the runs of ``n_bootstrap`` resamples of the clusters.

    Each resample draws the clusters with replacement and weights every run
    of a drawn cluster equally; the draws come in blocks as integer arrays.
    """
    sums = np.bincount(codes, weights=diff, minlength=n_clusters)
    sizes = np.bincount(codes, minlength=n_clusters).astype(np.float64)
    stats = np.empty(n_bootstrap)
    block = max(1, (1 << 20) // n_clusters)  # about 8 MB of draws at a time
    for start in range(0, n_bootstrap, block):
        stop = min(start + block, n_bootstrap)
        draws = rng.randint(0, n_clusters, size=(stop - start, n_clusters))
        stats[start:stop] = sums[draws].sum(axis=1) / sizes[draws].sum(axis=1)
    return stats
