"""Checks of the long recording format and of the arguments that carry it.

Every estimator and transformer of the package validates its input through
:func:`check_recordings`, so that a malformed recording fails early with a
message that names the offending column, run and row, instead of failing deep
inside numpy, pandas or torch. This module only checks and converts values to
their canonical dtypes; assigning rows to runs and converting between the long
format and per-run arrays is the job of :mod:`skcath._runs`, which builds on
these checks.

The checks live in three modules below this one, each re-exported here:
:mod:`skcath._validation_columns` (the frame, its columns, ids and numbers,
and plain arguments), :mod:`skcath._validation_runs` (what spans the rows of
a run: its ids, phases, time axis and sampling) and
:mod:`skcath._validation_target` (the target ``y``).

All checks are vectorised (``pd.factorize`` for the ids, ``np.diff`` over rows
sorted by run for the time axis, one sort by run and value for the per-run
medians): the cost is linear in the number of rows, up to these sorts, with no
Python loop over rows or runs on valid input.

The format itself is described in ``docs/data_format.rst``; the column names
live in :mod:`skcath._format`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd
from sklearn.utils._param_validation import validate_params

from ._format import (
    CATHETER, ID_COLUMNS, MOTOR_COLUMNS, PHASE, REFERENCE_COLUMNS, RUN, SETTING, TIME,
    TORQUE_COLUMNS, channel_index,
)
from ._validation_columns import (
    _DOCS,
    MAX_ABS_VALUE,
    _channel_columns,
    _check_columns_present,
    _check_finite,
    _check_frame,
    _check_magnitude,
    _column_as_float,
    _where,
    check_quat_order,
    check_tip_offset,
    factorize_ids,
    motor_columns,
    to_array,
)
from ._validation_runs import (
    CUT_RUN_HINT,
    MAX_GAP_FRACTION,
    _check_motion_sampling,
    _check_phase_order,
    _check_run_ids_unique,
    _check_time_order,
    _phase_masks,
    check_sweeps,
)
from ._validation_target import REFERENCE_TOLERANCE_MM, _check_target_matches_reference, check_target

__all__ = [
    "CUT_RUN_HINT",
    "FINITE_COLUMNS",
    "MAX_ABS_VALUE",
    "MAX_GAP_FRACTION",
    "NUMERIC_COLUMNS",
    "REFERENCE_TOLERANCE_MM",
    "check_quat_order",
    "check_recordings",
    "check_sweeps",
    "check_target",
    "check_tip_offset",
    "factorize_ids",
    "motor_columns",
    "to_array",
]

#: Numeric channels that must be finite on every row: time (s), motor angles
#: (degrees) and drive torques (here those of the default two motors; every
#: ``qk`` and ``tauk`` of a recording is checked the same way).
FINITE_COLUMNS = (TIME, *MOTOR_COLUMNS, *TORQUE_COLUMNS)
#: All numeric channels of the default format. The reference tip columns (mm)
#: may be NaN (absent on motion rows, tracker dropouts on sweep rows) but never
#: +-inf.
NUMERIC_COLUMNS = (*FINITE_COLUMNS, *REFERENCE_COLUMNS)


# ---------------------------------------------------------------------------
# main entry point
# ---------------------------------------------------------------------------
@validate_params(
    {
        "X": "no_validation",
        "y": "no_validation",
        "columns": [str, "array-like"],
        "require_sweep": ["boolean"],
        "copy": ["boolean"],
    },
    prefer_skip_nested_validation=True,
)
def check_recordings(
    X,
    y=None,
    *,
    columns: Sequence[str] | str = "auto",
    require_sweep: bool = True,
    copy: bool = True,
) -> tuple[pd.DataFrame, np.ndarray | None]:
    """Validate recordings in the long format and return checked copies.

    Parameters
    ----------
    X : pandas.DataFrame
        One row per time sample, with the columns of ``docs/data_format.rst``:
        ids ``catheter``, ``setting``, ``run``; time ``t`` (s); ``phase``
        (``"sweep"`` then ``"motion"`` in every run); motor angles ``q1``,
        ``q2`` (degrees), or ``q1 .. qN`` for ``N`` motors (:func:`motor_columns`);
        drive torques ``tau1``, ``tau2`` (``tau1 .. tauN``, or none); reference tip
        ``ref_x``, ``ref_y``, ``ref_z`` (mm, base frame; NaN allowed). Rows of
        different runs may be interleaved; within a run, rows must be in time
        order.
    y : array-like or pandas.DataFrame of shape (n_rows, 3), optional
        Tip position in the base frame (mm), matched to ``X`` by row position.
        NaN rows (tracker dropouts) are allowed and kept. The columns of a
        DataFrame are matched by name (``p_x, p_y, p_z`` in any order), or
        taken by position when unnamed (labels ``0, 1, 2``). On sweep rows it
        must agree with ``ref_*`` (see Raises).
    columns : "auto", str or sequence of str, default="auto"
        Columns that must be present. ``"auto"`` means those of the format:
        the ids, ``t``, ``phase``, the reference tip and the motor and
        torque columns of ``X`` (:func:`motor_columns`); for the default
        two-motor recordings with torques, ``REQUIRED_COLUMNS``. Another
        string names one column. The ``run`` column is always required.
        The checks of the known columns (ids, numeric channels, ``phase``) run
        for those listed here; other listed columns are only checked for
        presence. Columns of ``X`` not listed are passed through unchecked.
    require_sweep : bool, default True
        Require every run to contain at least one sweep row (needs ``phase``
        in ``columns``). Sweep rows must precede motion rows in any case.
        False accepts runs whose rows are all ``"motion"`` (a rig without a
        sweep phase); the estimators that read no sweep check with False.
    copy : bool, default True
        Return a deep copy of ``X``. With False, the returned frame may share
        unconverted column data with ``X`` (pandas copy-on-write still keeps
        ``X`` unchanged when the result is modified).

    Returns
    -------
    X_checked : pandas.DataFrame
        A new frame with the same columns, index and row order as ``X``; the
        numeric channels among ``columns`` are float64.
    y_checked : ndarray of shape (n_rows, 3), dtype float64, or None
        A copy of ``y``, or None when ``y`` is None.

    Raises
    ------
    TypeError
        If ``X`` is not a pandas DataFrame.
    sklearn.utils._param_validation.InvalidParameterError
        If ``columns`` is not a name or a sequence of names, or
        ``require_sweep`` or ``copy`` is not a bool.
    ValueError
        On any violation of the format; the message names the column and,
        where it applies, the run id and row label. This includes finite
        values larger than :data:`MAX_ABS_VALUE` (``1e12``) in magnitude;
        a run whose ``y`` and ``ref_*`` are more than
        :data:`REFERENCE_TOLERANCE_MM` (1 mm) apart in the median over its
        sweep rows (units or a row shift); and a run with at least 20 motion
        rows of which more than :data:`MAX_GAP_FRACTION` (5 %) of the time
        steps exceed 1.5 times the median step (rows missing, as in a fold
        that cuts runs).

    Notes
    -----
    The inputs are never modified. The checks are vectorised; on 1.25 million
    rows in 204 runs they take a fraction of a second.
    """
    _check_frame(X)
    if isinstance(columns, str) and columns == "auto":
        motors, torques = _channel_columns(X)
        columns = (*ID_COLUMNS, TIME, PHASE, *motors, *torques, *REFERENCE_COLUMNS)
    elif isinstance(columns, str):
        columns = (columns,)
    required = list(dict.fromkeys([*columns, RUN]))
    _check_columns_present(X, required)

    codes, runs = factorize_ids(X, RUN)
    for column in (CATHETER, SETTING):
        if column in required:
            _check_run_ids_unique(X, codes, runs, column)

    converted: dict[str, np.ndarray] = {}
    channels = [c for c in required if channel_index(c) is not None]
    for column in (TIME, *channels, *REFERENCE_COLUMNS):
        if column in required:
            values = _column_as_float(X, column)
            _check_finite(X, column, values, allow_nan=column in REFERENCE_COLUMNS)
            _check_magnitude(
                values,
                f"Column {column!r}",
                lambda position: f"at {_where(X, position)}",
                f"physical values in the units of {_DOCS} (degrees, s, mm)",
            )
            converted[column] = values

    if PHASE not in required and require_sweep:
        raise ValueError(
            f"require_sweep=True needs the {PHASE!r} column; add it to `columns` "
            "or pass require_sweep=False."
        )
    if PHASE in required or TIME in required:
        # rows of every run together, in row order: the order the run is checked in
        order = np.argsort(codes, kind="stable")
    if PHASE in required:
        sweep, motion = _phase_masks(X)
        _check_phase_order(X, sweep, codes, runs, order, require_sweep=require_sweep)
    if TIME in required:
        _check_time_order(X, converted[TIME], codes, runs, order)
        if PHASE in required:
            _check_motion_sampling(converted[TIME], motion, codes, runs, order)

    y_checked = None if y is None else check_target(y, len(X))
    if y_checked is not None and PHASE in required and set(REFERENCE_COLUMNS) <= set(required):
        ref = np.column_stack([converted[c] for c in REFERENCE_COLUMNS])
        _check_target_matches_reference(y_checked, ref, sweep, codes, runs)

    X_checked = X.copy(deep=copy)
    for column, values in converted.items():
        if X_checked[column].dtype != np.float64:
            X_checked[column] = values
    return X_checked, y_checked
