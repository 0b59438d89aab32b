"""Which quaternion order the raw sensor poses fit, told by the neutral tip across runs.

At the neutral pose of its sweep (motor angles at their smallest) a catheter's
tip lies in the same direction from the base, expressed in the base frame B,
in every run of that catheter, whatever shaft setting the run has and however
the base sensor happens to be turned in the tracker volume. The four numbers
of a quaternion read in the other component order give another rotation, one
that is not a fixed change of frame (the permutation of the components is an
improper map of the 4-vectors): when the base sensor turns between runs, the
neutral tip read through it points a different way in every run. The order
whose neutral tip directions spread least across the runs of each catheter is
the one the data fit.

The data can tell the orders apart only when the base sensor turns between the
runs of a catheter: with one run per catheter, or a base that keeps the same
orientation in every run, both orders give the same spread. The decision takes
no tuned threshold: an order fits when its spread is at least
:data:`MIN_SPREAD_RATIO` times smaller than the other's; otherwise the data
cannot tell.
"""

from dataclasses import dataclass

import numpy as np
import pandas as pd

from ._format import CATHETER, PHASE, QUAT_ORDERS, RUN, SWEEP
from ._validation import factorize_ids, motor_columns, to_array

__all__ = [
    "MIN_SPREAD_RATIO",
    "NEUTRAL_TOLERANCE_DEG",
    "QuatOrderFit",
    "fit_quat_order",
    "neutral_rows",
]

#: Smallest ratio between the two orders' spreads for the data to tell which
#: order fits; below it (e.g. a base that does not turn between runs, where the
#: ratio is 1) the data cannot tell.
MIN_SPREAD_RATIO = 3.0

#: Sweep rows whose largest absolute motor angle is within this many degrees of
#: the run's smallest on the sweep are the run's neutral rows.
NEUTRAL_TOLERANCE_DEG = 0.5

# Quaternions with a norm below this are left out (no orientation).
_MIN_QUAT_NORM = 1e-12


def neutral_rows(X):
    """Mask of the neutral rows of every run's sweep.

    The neutral rows of a run are its sweep rows whose largest absolute motor
    angle is within :data:`NEUTRAL_TOLERANCE_DEG` degrees of the smallest one
    on that run's sweep (the sweep starts and passes through the neutral pose,
    all motor angles zero).

    Parameters
    ----------
    X : pandas.DataFrame
        Recordings in the long format; the ``run``, ``phase`` and motor-angle
        columns ``q1 .. qN`` (degrees) are used.

    Returns
    -------
    mask : ndarray of bool, shape (n_rows,)
        True on the neutral rows. A run without sweep rows has none.

    Raises
    ------
    TypeError
        If ``X`` is not a DataFrame.
    ValueError
        If a needed column is missing.
    """
    if not isinstance(X, pd.DataFrame):
        raise TypeError(f"X must be a pandas DataFrame of recordings; got {type(X).__name__}.")
    missing = [c for c in (RUN, PHASE) if c not in X.columns]
    if missing:
        raise ValueError(f"X needs the column(s) {missing} to find the neutral rows.")
    motors, _ = motor_columns(X)
    codes, runs = factorize_ids(X, RUN)
    sweep = (X[PHASE] == SWEEP).to_numpy(dtype=bool)
    angle = np.abs(X[list(motors)].to_numpy(dtype=np.float64)).max(axis=1)
    angle = np.where(sweep, angle, np.inf)
    smallest = np.full(len(runs), np.inf)
    np.minimum.at(smallest, codes, angle)
    return sweep & (angle <= smallest[codes] + NEUTRAL_TOLERANCE_DEG)


@dataclass(frozen=True)
class QuatOrderFit:
    """How well each quaternion order fits the neutral tip across runs.

    Attributes
    ----------
    spread : dict of str to float
        For each order of :data:`skcath.frames.QUAT_ORDERS`: root mean square,
        over the runs of the catheters with at least two runs, of the angle
        (degrees) between a run's neutral tip direction in the base frame and
        its catheter's mean direction.
    ratio : float
        Larger spread over smaller spread (1 when they are equal, NaN when no
        catheter has two runs).
    fitting : str or None
        The order whose spread is at least :data:`MIN_SPREAD_RATIO` times
        smaller than the other's; None when the data cannot tell.
    n_runs : int
        Runs that entered the spreads.
    catheters : pandas.DataFrame
        One row per catheter: ``catheter``, ``n_runs`` and ``spread_<order>``
        for each order (degrees; NaN for a catheter with fewer than two runs).
    """

    spread: dict
    ratio: float
    fitting: object
    n_runs: int
    catheters: pd.DataFrame


def _poses(values, name, width, n):
    """A new float array of shape ``(n, width)``, or a ValueError naming ``name``."""
    array = to_array(
        values, f"{name} must be a numeric array of shape (n, {width})", dtype=np.float64, copy=True
    )
    if array.shape != (n, width):
        raise ValueError(
            f"{name} must have shape ({n}, {width}), one row per row of X; got {array.shape}."
        )
    return array


def _run_directions(vectors, codes, n_runs):
    """Unit direction of every run's median neutral tip; NaN rows for a run without finite rows."""
    directions = np.full((n_runs, 3), np.nan)
    for code in np.unique(codes):
        median = np.median(vectors[codes == code], axis=0)
        norm = np.linalg.norm(median)
        if norm > 0:
            directions[code] = median / norm
    return directions


def _spread_terms(directions, run_catheter, n_catheters):
    """Squared angles (degrees^2) of each run to its catheter's mean direction, per catheter."""
    terms = {}
    for k in range(n_catheters):
        mine = directions[(run_catheter == k) & np.isfinite(directions).all(axis=1)]
        if mine.shape[0] < 2:
            continue
        mean = mine.mean(axis=0)
        mean /= np.linalg.norm(mean)
        terms[k] = np.degrees(np.arccos(np.clip(mine @ mean, -1.0, 1.0))) ** 2
    return terms


def fit_quat_order(X, tip_position, base_position, base_orientation):
    """Find the quaternion order that the raw sensor poses fit.

    For each order of :data:`skcath.frames.QUAT_ORDERS`, the tip sensor
    position is expressed in the base frame,
    :math:`p = R_{WB}^{\\top} (p_{WT} - p_{WB})`, on the neutral rows of every
    run's sweep (:func:`neutral_rows`); a run's neutral tip direction is the
    direction of the median of these positions. The spread of an order is the
    root mean square angle between each run's direction and the mean
    direction of its catheter. The right order keeps the direction of a
    catheter's neutral tip (within what the shaft settings change); the wrong
    one scatters it as soon as the base sensor turns between runs.

    Parameters
    ----------
    X : pandas.DataFrame
        Recordings in the long format; the ``catheter``, ``run``, ``phase``
        and motor-angle columns are used. Only its neutral rows count, so
        ``X`` may hold just those.
    tip_position : array-like of shape (n_rows, 3)
        Tip sensor position in the tracker frame (mm), one row per row of
        ``X``.
    base_position : array-like of shape (n_rows, 3)
        Base sensor position in the tracker frame (mm).
    base_orientation : array-like of shape (n_rows, 4)
        Base sensor orientation: the four stored quaternion components, in
        the order the file holds them. Rows with a non-finite value or a zero
        norm are left out.

    Returns
    -------
    fit : QuatOrderFit
        The spread of each order, their ratio, the order that fits (None when
        the data cannot tell) and the spreads per catheter.

    Raises
    ------
    TypeError
        If ``X`` is not a DataFrame.
    ValueError
        If ``X`` lacks a needed column or has a missing id, or an array does
        not have one row per row of ``X``.

    Notes
    -----
    The data cannot tell the orders apart when no catheter has two runs, or
    when the base sensor has the same orientation in every run (both orders
    then give the same spread). The inputs are never modified.

    Examples
    --------
    >>> from skcath.datasets import make_benchmark
    >>> from skcath.frames import fit_quat_order
    >>> data = make_benchmark()  # 4 catheters x 17 settings x 3 runs
    >>> s = data.sensors
    >>> fit = fit_quat_order(data.X, s[["tip_px", "tip_py", "tip_pz"]],
    ...                      s[["base_px", "base_py", "base_pz"]],
    ...                      s[["base_qw", "base_qx", "base_qy", "base_qz"]])
    >>> fit.fitting
    'wxyz'
    """
    mask = neutral_rows(X)
    if CATHETER not in X.columns:
        raise ValueError(f"X needs the column {CATHETER!r} to compare the runs of each catheter.")
    n = len(X)
    tip = _poses(tip_position, "tip_position", 3, n)[mask]
    base = _poses(base_position, "base_position", 3, n)[mask]
    quats = _poses(base_orientation, "base_orientation", 4, n)[mask]
    norms = np.linalg.norm(quats, axis=1)
    keep = np.isfinite(tip).all(axis=1) & np.isfinite(base).all(axis=1)
    keep &= np.isfinite(norms) & (norms > _MIN_QUAT_NORM)
    neutral = X.loc[mask].iloc[np.flatnonzero(keep)]
    return _decide(*_spreads(neutral, tip[keep], base[keep], quats[keep]))


def _spreads(neutral, tip, base, quats):
    """Spread of every order, pooled and per catheter, and the runs that entered them.

    Parameters
    ----------
    neutral : pandas.DataFrame
        The neutral rows with finite poses (``catheter`` and ``run`` used).
    tip, base : ndarray of shape (m, 3)
        Tip and base sensor positions in the tracker frame (mm).
    quats : ndarray of shape (m, 4)
        Base quaternions with a nonzero norm, components as stored.

    Returns
    -------
    spread : dict of str to float
    n_runs : int
    table : pandas.DataFrame
    """
    from .frames import tip_in_base_frame  # skcath.frames re-exports this module's API

    if len(neutral):
        codes, runs = factorize_ids(neutral, RUN)
        row_catheter, catheters = factorize_ids(neutral, CATHETER)
    else:
        codes, runs = np.zeros(0, dtype=np.intp), []
        row_catheter, catheters = np.zeros(0, dtype=np.intp), []
    cat_codes = row_catheter[np.unique(codes, return_index=True)[1]]
    table = pd.DataFrame({CATHETER: pd.Series(catheters, dtype=object)})
    table["n_runs"] = np.bincount(cat_codes, minlength=len(catheters))
    spread = {}
    for order in QUAT_ORDERS:
        vectors = tip_in_base_frame(tip, base, quats, quat_order=order)
        terms = _spread_terms(_run_directions(vectors, codes, len(runs)), cat_codes, len(catheters))
        column = np.full(len(catheters), np.nan)
        for k, squares in terms.items():
            column[k] = np.sqrt(squares.mean())
        table[f"spread_{order}"] = column
        pooled = np.concatenate(list(terms.values())) if terms else np.zeros(0)
        spread[order] = float(np.sqrt(pooled.mean())) if pooled.size else float("nan")
    n_used = int(table.loc[table[f"spread_{QUAT_ORDERS[0]}"].notna(), "n_runs"].sum())
    return spread, n_used, table


def _decide(spread, n_runs, table):
    """The ratio of the spreads and the order that fits, as a :class:`QuatOrderFit`."""
    low, high = sorted(spread.values())
    if n_runs == 0:
        ratio = float("nan")
    elif high == 0:
        ratio = 1.0
    else:
        ratio = float(high / low) if low > 0 else float("inf")
    fitting = None
    if ratio >= MIN_SPREAD_RATIO:
        fitting = min(spread, key=spread.get)
    return QuatOrderFit(spread=spread, ratio=ratio, fitting=fitting, n_runs=n_runs, catheters=table)
