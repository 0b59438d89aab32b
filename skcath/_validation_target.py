"""Checks of the tip-position target ``y`` of recordings.

Its shape and columns (``p_x, p_y, p_z`` by name or by position), its
values (numbers, no +-inf, no logger fill values) and, for
:func:`skcath.check_recordings`, its agreement with the reference tip on
the sweep rows of every run.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from pandas.api import types as pdt

from ._format import REFERENCE_COLUMNS, SWEEP, TARGET_NAMES
from ._medians import group_medians
from ._validation_columns import _check_magnitude, _list_items, _plain, to_array

__all__ = ["REFERENCE_TOLERANCE_MM", "check_target"]

#: Largest median distance (mm) between ``y`` and the reference tip ``ref_*``
#: over the sweep rows of a run where both are finite. Both hold the same
#: tracker measurement there (equal in the simulator and in what the readers
#: return); the tracker's position jitter is 0.1-0.2 mm, so even two separately
#: filtered copies of one measurement stay well below this. A unit mix-up (m
#: against mm) or a target shifted by some rows is tens of mm away.
REFERENCE_TOLERANCE_MM = 1.0


def _check_target_matches_reference(
    y: np.ndarray,
    ref: np.ndarray,
    sweep: np.ndarray,
    codes: np.ndarray,
    runs: np.ndarray,
) -> None:
    """Raise if ``y`` and ``ref_*`` disagree on the sweep rows of a run.

    The median distance over the sweep rows where both are finite must not
    exceed :data:`REFERENCE_TOLERANCE_MM`.
    """
    squared = np.zeros(len(y))
    for j in range(3):  # column by column: no copies of the (n_rows, 3) arrays
        squared += (y[:, j] - ref[:, j]) ** 2
    both = sweep & np.isfinite(squared)  # NaN in either is not compared
    if not both.any():
        return
    median = group_medians(np.sqrt(squared[both]), codes[both], len(runs))
    bad = np.flatnonzero(median > REFERENCE_TOLERANCE_MM)  # NaN (no row) compares False
    if not bad.size:
        return
    k = int(bad[0])
    rows = both & (codes == k)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.median(np.linalg.norm(y[rows], axis=1)) / np.median(
            np.linalg.norm(ref[rows], axis=1)
        )
    raise ValueError(
        f"y and the reference tip {list(REFERENCE_COLUMNS)} disagree on the {SWEEP!r} rows "
        f"of run {_plain(runs[k])!r}: their median distance is {median[k]:.3g} mm over "
        f"{int(rows.sum())} rows where both are finite, above the "
        f"{REFERENCE_TOLERANCE_MM:g} mm allowed (REFERENCE_TOLERANCE_MM; the tracker "
        "jitter is 0.1-0.2 mm). On sweep rows both hold the same tracker measurement. "
        f"Likely causes: different units (y is {ratio:.3g} times as far from the base "
        "frame's origin as ref_*; 0.001 or 1000 means metres against mm, both must be "
        "in mm), y shifted against the rows of X (it is matched by row position), or "
        f"columns in another order than {list(TARGET_NAMES)}. Runs affected: "
        f"{_list_items(runs[bad])}."
    )


# ---------------------------------------------------------------------------
# target
# ---------------------------------------------------------------------------
def check_target(y, n_rows: int) -> np.ndarray:
    """Validate the tip-position target and return it as a float64 copy.

    Parameters
    ----------
    y : array-like or pandas.DataFrame of shape (n_rows, 3)
        Tip position in the base frame (mm), columns ``p_x, p_y, p_z``. Rows
        are matched to the recordings by position, not by index label. The
        columns of a DataFrame are matched by name, in any order; unnamed
        columns (labels ``0, 1, 2``) and arrays are taken by position. NaN
        (tracker dropout) is allowed; +-inf is not.
    n_rows : int
        Number of rows of the recordings.

    Returns
    -------
    y : ndarray of shape (n_rows, 3), dtype float64
        A new array; NaN rows are kept (to be masked downstream).

    Raises
    ------
    ValueError
        If ``y`` is not of shape ``(n_rows, 3)``, is a DataFrame with column
        names other than ``p_x, p_y, p_z``, is not numeric, contains +-inf,
        or has a value larger than :data:`MAX_ABS_VALUE` in magnitude.
    """
    if isinstance(y, pd.Series):
        raise ValueError(
            f"y must have shape (n_rows, 3) with the tip position {list(TARGET_NAMES)} "
            "in mm; got a pandas Series (1-D)."
        )
    if isinstance(y, pd.DataFrame):
        y = _target_frame_in_order(y)
        values = np.column_stack(
            [_target_column_as_float(y.iloc[:, j], j) for j in range(3)]
        )
    else:
        values = to_array(y, "y must be array-like of shape (n_rows, 3)", copy=True)
        if values.ndim != 2 or values.shape[1] != 3:
            raise ValueError(
                f"y must have shape (n_rows, 3) with the tip position "
                f"{list(TARGET_NAMES)} in mm; got shape {values.shape}."
            )
        if values.dtype.kind in "fiu":
            values = values.astype(np.float64, copy=False)
        else:
            values = np.column_stack(
                [_target_column_as_float(pd.Series(values[:, j]), j) for j in range(3)]
            )
    if values.shape[0] != n_rows:
        raise ValueError(
            f"y has {values.shape[0]} rows but the recordings X have {n_rows}; "
            "y must have one tip position per row of X."
        )
    values = np.ascontiguousarray(values, dtype=np.float64)
    inf = np.isinf(values)
    if inf.any():
        row, col = (int(i) for i in np.argwhere(inf)[0])
        raise ValueError(
            f"y contains {int(inf.sum())} infinite value(s); first in column "
            f"{TARGET_NAMES[col]!r} at row position {row}. NaN marks a tracker "
            "dropout and is allowed, +-inf is not."
        )
    _check_magnitude(
        values,
        "y",
        lambda row, col: f"in column {TARGET_NAMES[col]!r} at row position {row}",
        "tip positions in mm",
    )
    return values


def _target_frame_in_order(y: pd.DataFrame, name: str = "y") -> pd.DataFrame:
    """The columns of a target frame in the order ``p_x, p_y, p_z``.

    Named columns are matched by name, whatever their order; unnamed columns
    (the labels ``0, 1, 2`` of a frame built from an array) are taken by
    position.

    Parameters
    ----------
    y : pandas.DataFrame of shape (n_rows, 3)
        Tip positions (mm); never modified.
    name : str, default="y"
        Name of the argument, starting the messages.

    Returns
    -------
    y : pandas.DataFrame
        ``y`` itself when its columns are unnamed or already in order,
        otherwise a new frame with the columns reordered.

    Raises
    ------
    ValueError
        If ``y`` does not have 3 columns, or has column names other than the
        target names :data:`skcath.TARGET_NAMES`.
    """
    found = [_plain(c) for c in y.columns]
    expected = list(TARGET_NAMES)
    if len(found) != 3:
        raise ValueError(
            f"{name} must have 3 columns (tip position {expected}, mm); got "
            f"a DataFrame with columns {found}."
        )
    if found == [0, 1, 2] or found == expected:
        return y
    if set(found) != set(expected):
        raise ValueError(
            f"{name} is a DataFrame with the columns {found}; its columns must be the "
            f"target names {expected} (in any order: they are matched by name) or "
            f"unnamed (labels 0, 1, 2: taken by position as {expected}). Rename them, e.g. "
            f"{name}.rename(columns={{...}}), or pass {name}.to_numpy() if they are in "
            f"the order {expected}."
        )
    return y[expected]


def _target_column_as_float(series: pd.Series, j: int) -> np.ndarray:
    """Column ``j`` of y as a float64 array; raise on non-numeric values."""
    name = TARGET_NAMES[j]
    dtype = series.dtype
    if pdt.is_bool_dtype(dtype) or pdt.is_complex_dtype(dtype) or not (
        pdt.is_numeric_dtype(dtype)
        or pdt.is_object_dtype(dtype)
        or pdt.is_string_dtype(dtype)
    ):
        raise ValueError(
            f"y column {j} ({name!r}) must hold real numbers (mm), got dtype {dtype}."
        )
    if pdt.is_numeric_dtype(dtype):
        return series.to_numpy(dtype=np.float64, na_value=np.nan)
    parsed = pd.to_numeric(series, errors="coerce")
    values = parsed.to_numpy(dtype=np.float64, na_value=np.nan)
    bad = np.isnan(values) & ~series.isna().to_numpy(dtype=bool)
    if pdt.is_bool_dtype(parsed.dtype) or bad.any():
        first = int(np.flatnonzero(bad)[0]) if bad.any() else 0
        raise ValueError(
            f"y column {j} ({name!r}) must be numeric (mm); value "
            f"{_plain(series.iloc[first])!r} at row position {first} is not a number."
        )
    return values
