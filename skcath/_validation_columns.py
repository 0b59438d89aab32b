"""Checks of the columns of recordings and of plain arguments.

The lowest layer of the checks of :func:`skcath.check_recordings`: the
messages' helpers (a value, a row, a list of items as the messages name
them), plain arguments (arrays, ``quat_order``, ``tip_offset``), the frame
and its columns (presence, the motor and torque channels), the id columns
and the numeric columns (conversion to float64, finiteness, magnitude).
The checks that span the rows of a run are in
:mod:`skcath._validation_runs`, those of the target in
:mod:`skcath._validation_target`.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np
import pandas as pd
from pandas.api import types as pdt

from ._format import (
    MOTOR_PREFIX, QUAT_ORDERS, REQUIRED_COLUMNS, RUN, TORQUE_PREFIX, channel_index, motor_names,
    torque_names,
)

__all__ = [
    "MAX_ABS_VALUE",
    "check_quat_order",
    "check_tip_offset",
    "factorize_ids",
    "motor_columns",
    "to_array",
]

#: Largest magnitude accepted in any numeric channel. Larger finite values are
#: logger fill values (1e30, 3.4e38, ...) or a unit far off, never a physical
#: angle (degrees), torque, time (s) or position (mm); they would also overflow
#: the float32 arithmetic of the residual networks.
MAX_ABS_VALUE = 1e12

_DOCS = "docs/data_format.rst"
# How many offending values or runs an error message lists before "... and N more".
_MAX_LISTED = 10


# ---------------------------------------------------------------------------
# message helpers
# ---------------------------------------------------------------------------
def _list_items(items: Sequence, limit: int = _MAX_LISTED) -> str:
    """Format ``items`` as a comma-separated list of reprs, truncated after ``limit``."""
    items = list(items)
    shown = ", ".join(repr(_plain(item)) for item in items[:limit])
    if len(items) > limit:
        shown += f", ... and {len(items) - limit} more"
    return shown


def _plain(value):
    """Turn numpy scalars into plain Python objects so that reprs read naturally."""
    return value.item() if isinstance(value, np.generic) else value


def _where(X: pd.DataFrame, position: int) -> str:
    """Describe row ``position`` of ``X`` by its run id and index label."""
    label = _plain(X.index[position])
    if RUN in X.columns and isinstance(X.columns.get_loc(RUN), int):
        run = _plain(X[RUN].iloc[position])
        return f"run {run!r}, row label {label!r} (position {position})"
    return f"row label {label!r} (position {position})"


# ---------------------------------------------------------------------------
# plain arguments
# ---------------------------------------------------------------------------
def to_array(values, description: str, *, dtype=None, copy: bool = False) -> np.ndarray:
    """``values`` as an ndarray, or a ValueError that says what was expected.

    Parameters
    ----------
    values : array-like
        Input given by the caller; never modified.
    description : str
        What was expected, starting the message, e.g. ``"y must be
        array-like of shape (n_rows, 3)"``.
    dtype : numpy dtype, default=None
        Dtype of the result; None keeps the one numpy infers.
    copy : bool, default=False
        Return a new array even when ``values`` already is an array of
        ``dtype``.

    Returns
    -------
    array : ndarray

    Raises
    ------
    ValueError
        If numpy cannot convert ``values``; the message starts with
        ``description``.
    """
    try:
        if copy:
            return np.array(values, dtype=dtype, copy=True)
        return np.asarray(values, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{description}; converting it failed: {exc}") from None


def check_quat_order(quat_order) -> str:
    """Return ``quat_order`` if it is one of :data:`skcath.frames.QUAT_ORDERS`.

    Parameters
    ----------
    quat_order : object
        Value given by the caller.

    Returns
    -------
    quat_order : str
        The validated order.

    Raises
    ------
    ValueError
        If ``quat_order`` is not ``"wxyz"`` or ``"xyzw"``.
    """
    if not isinstance(quat_order, str) or quat_order not in QUAT_ORDERS:
        raise ValueError(
            f"quat_order must be one of {QUAT_ORDERS} ('wxyz' = scalar first, "
            f"'xyzw' = scalar last); got {quat_order!r}."
        )
    return quat_order


def check_tip_offset(tip_offset) -> np.ndarray:
    """Validate ``tip_offset`` as three finite numbers (mm).

    Parameters
    ----------
    tip_offset : array-like of shape (3,)
        Offset of the tip from the tip sensor, in the tip sensor frame (mm).

    Returns
    -------
    offset : ndarray of shape (3,)
        A float copy.

    Raises
    ------
    ValueError
        If it is not three finite numbers.
    """
    offset = to_array(
        tip_offset, "tip_offset must be a numeric array of shape (3,)", dtype=np.float64, copy=True
    )
    if offset.shape != (3,) or not np.isfinite(offset).all():
        raise ValueError(
            f"tip_offset must be three finite numbers (mm, tip sensor frame); got {tip_offset!r}."
        )
    return offset


# ---------------------------------------------------------------------------
# frame-level checks
# ---------------------------------------------------------------------------
def _check_frame(X, caller: str = "check_recordings", allow_empty: bool = False) -> None:
    """Raise unless ``X`` is a DataFrame (non-empty unless ``allow_empty``)."""
    if not isinstance(X, pd.DataFrame):
        raise TypeError(
            f"{caller} expects the long recording format: a pandas DataFrame with "
            f"one row per time sample and the columns {list(REQUIRED_COLUMNS)} (motors "
            "q1 .. qN, torques tau1 .. tauN or none); "
            f"got {type(X).__module__}.{type(X).__qualname__}. See {_DOCS}."
        )
    if len(X) == 0 and not allow_empty:
        raise ValueError(
            f"{caller} got an empty DataFrame (0 rows); at least one run with "
            f"samples is required. See {_DOCS}."
        )


def _check_columns_present(X: pd.DataFrame, required: Iterable[str]) -> None:
    """Raise if any required column is missing or appears more than once."""
    required = list(dict.fromkeys(required))
    missing = [c for c in required if c not in X.columns]
    if missing:
        channels = [c for c in missing if channel_index(c) is not None]
        hint = (
            f" A recording of N motors has the motor angles {MOTOR_PREFIX}1 .. "
            f"{MOTOR_PREFIX}N without a gap and the torques {TORQUE_PREFIX}1 .. "
            f"{TORQUE_PREFIX}N or no torque column; N is the largest k of the columns "
            f"{MOTOR_PREFIX}k and {TORQUE_PREFIX}k."
            if channels else ""
        )
        raise ValueError(
            f"The recordings are missing the column(s) {missing}. Expected columns: "
            f"{required}; got {[_plain(c) for c in X.columns]}.{hint} See {_DOCS}."
        )
    duplicated = X.columns[X.columns.duplicated()]
    clashing = [c for c in required if c in set(duplicated)]
    if clashing:
        raise ValueError(
            f"The recordings contain the column(s) {clashing} more than once; "
            "each column name must be unique."
        )


def _channel_columns(X: pd.DataFrame) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """The motor and torque columns ``X`` must have, read from its column names.

    ``N`` is the largest ``k`` of a column ``qk`` or ``tauk`` (1 when there is
    none, so that ``q1`` is missing); the motors are ``q1 .. qN``, the torques
    ``tau1 .. tauN`` when ``X`` has any ``tauk`` column, else none. Whether
    they are all present is left to :func:`_check_columns_present`.
    """
    found = {}
    for column in X.columns:
        index = channel_index(column)
        if index is not None:
            found.setdefault(index[0], set()).add(index[1])
    n_motors = max(max(found.get(MOTOR_PREFIX, {1})), max(found.get(TORQUE_PREFIX, {1})))
    torques = torque_names(n_motors) if TORQUE_PREFIX in found else ()
    return motor_names(n_motors), torques


def motor_columns(X) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """The motor-angle and drive-torque columns of recordings in the long format.

    A recording of ``N >= 1`` motors has the motor angles ``q1 .. qN``
    (degrees) and either the drive torques ``tau1 .. tauN`` or no torque
    column at all; ``N`` is read from the column names. See
    ``docs/data_format.rst``.

    Parameters
    ----------
    X : pandas.DataFrame
        Recordings in the long format; only the column names are read.

    Returns
    -------
    motors : tuple of str
        ``("q1", ..., "qN")``; ``len(motors)`` is the number of motors.
    torques : tuple of str
        ``("tau1", ..., "tauN")``, or ``()`` for recordings without torques.

    Raises
    ------
    TypeError
        If ``X`` is not a DataFrame.
    ValueError
        If a motor column is missing below the largest ``qk`` or ``tauk``
        (``q1, q3`` without ``q2``), some but not all torques are present,
        or a channel column appears twice; the message names the missing
        columns and the columns found.

    Examples
    --------
    >>> import pandas as pd
    >>> from skcath import motor_columns
    >>> motor_columns(pd.DataFrame(columns=["run", "q1", "q2", "q3"]))
    (('q1', 'q2', 'q3'), ())
    """
    _check_frame(X, caller="motor_columns", allow_empty=True)
    motors, torques = _channel_columns(X)
    _check_columns_present(X, (*motors, *torques))
    return motors, torques


def _factorize(X: pd.DataFrame, column: str, expected: str) -> tuple[np.ndarray, np.ndarray]:
    """Integer codes (order of first appearance, -1 for missing) and unique values.

    Parameters
    ----------
    X : pandas.DataFrame
        Recordings.
    column : str
        Column to factorize.
    expected : str
        What the column must hold, completing "Column ... must ..." in the
        message raised when the values cannot be factorized.

    Raises
    ------
    ValueError
        If the column holds unhashable objects.
    """
    try:
        codes, uniques = pd.factorize(X[column], sort=False, use_na_sentinel=True)
    except TypeError as exc:
        raise ValueError(
            f"Column {column!r} must {expected}; factorizing it failed: {exc}"
        ) from None
    return np.asarray(codes, dtype=np.intp), np.asarray(uniques, dtype=object)


def factorize_ids(X: pd.DataFrame, column: str) -> tuple[np.ndarray, np.ndarray]:
    """Integer codes (order of first appearance) and unique values of an id column.

    Raises
    ------
    ValueError
        If the column contains missing values or unhashable objects.
    """
    codes, uniques = _factorize(X, column, "hold hashable ids (strings or integers)")
    missing = np.flatnonzero(codes < 0)
    if missing.size:
        first = int(missing[0])
        raise ValueError(
            f"Column {column!r} contains {missing.size} missing id(s) (NaN/None); "
            f"first at row label {_plain(X.index[first])!r} (position {first}). "
            "Every row needs a catheter, setting and run id."
        )
    return codes, uniques


def _column_as_float(X: pd.DataFrame, column: str) -> np.ndarray:
    """Return column ``column`` of ``X`` as a float64 array (missing values as NaN).

    Numeric dtypes (including nullable ``Int64``/``Float64``) are cast directly;
    object, string and categorical columns are parsed with ``pd.to_numeric``.
    The returned array may share memory with ``X`` and must not be modified.

    Raises
    ------
    ValueError
        If the column holds booleans, complex numbers, dates, or values that do
        not convert to numbers; the message names the first offending run/row.
    """
    series = X[column]
    dtype = series.dtype
    unsupported = (
        pdt.is_bool_dtype(dtype)
        or pdt.is_complex_dtype(dtype)
        or pdt.is_datetime64_any_dtype(dtype)
        or pdt.is_timedelta64_dtype(dtype)
        or isinstance(dtype, (pd.PeriodDtype, pd.IntervalDtype))
    )
    if unsupported:
        raise ValueError(
            f"Column {column!r} must hold real numbers (float or int), got dtype "
            f"{dtype}. See {_DOCS} for the unit of each channel."
        )
    if pdt.is_numeric_dtype(dtype):
        return series.to_numpy(dtype=np.float64, na_value=np.nan)

    parsed = pd.to_numeric(series, errors="coerce")
    if pdt.is_bool_dtype(parsed.dtype) or pdt.is_complex_dtype(parsed.dtype):
        raise ValueError(
            f"Column {column!r} must hold real numbers, got {parsed.dtype} values "
            f"(dtype {dtype}). See {_DOCS}."
        )
    values = parsed.to_numpy(dtype=np.float64, na_value=np.nan)
    bad = np.isnan(values) & ~series.isna().to_numpy(dtype=bool)
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        raise ValueError(
            f"Column {column!r} must be numeric, but {int(bad.sum())} value(s) do "
            f"not convert to numbers; first {_plain(series.iloc[first])!r} at "
            f"{_where(X, first)}."
        )
    return values


def _check_finite(
    X: pd.DataFrame, column: str, values: np.ndarray, *, allow_nan: bool
) -> None:
    """Raise if ``values`` contains +-inf (or NaN unless ``allow_nan``)."""
    bad = np.isinf(values) if allow_nan else ~np.isfinite(values)
    if not bad.any():
        return
    first = int(np.flatnonzero(bad)[0])
    kind = "NaN" if np.isnan(values[first]) else repr(_plain(values[first]))
    allowed = (
        "NaN (tracker dropout) is allowed but +-inf is not"
        if allow_nan
        else "every value must be finite"
    )
    raise ValueError(
        f"Column {column!r} contains {int(bad.sum())} non-finite value(s) "
        f"({allowed}); first {kind} at "
        f"{_where(X, first)}."
    )


def _check_magnitude(values: np.ndarray, name: str, locate, expected: str) -> None:
    """Raise if finite ``values`` exceed :data:`MAX_ABS_VALUE` in magnitude.

    Parameters
    ----------
    values : ndarray
        Values of a recording column (1-D) or of the target (2-D).
    name : str
        What holds the values, starting the message (``"Column 'q1'"``, ``"y"``).
    locate : callable
        Called with the index of the first offending value (one integer per
        dimension of ``values``); returns where it is, e.g. ``"at row position 3"``.
    expected : str
        The values expected, with their units.
    """
    with np.errstate(invalid="ignore"):
        bad = np.abs(values) > MAX_ABS_VALUE
    if not bad.any():
        return
    first = tuple(int(i) for i in np.argwhere(bad)[0])
    raise ValueError(
        f"{name} contains {int(bad.sum())} value(s) larger than "
        f"{MAX_ABS_VALUE:g} in magnitude; first {_plain(values[first])!r} "
        f"{locate(*first)}. Expected {expected}; is it a logger fill value or a "
        "unit mix-up?"
    )
