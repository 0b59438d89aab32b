"""Align a motor log and a tracker log recorded with their own clocks and rates.

:func:`align_streams` attaches to every motor sample the tracker sample
nearest in time (within a tolerance) with :func:`pandas.merge_asof`, after
shifting the tracker clock by a constant latency, and reports how many motor
samples found no tracker sample. :func:`read_streams` does the same from two
files and returns the long format ``(X, y)``.
"""

import numbers
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from pandas.api import types as pdt
from sklearn.utils._param_validation import validate_params

from ._convert import recording_from_table
from ._options import ReadingOptions
from ._recording import CSV_SUFFIXES, file_kind, read_table

__all__ = ["AlignmentReport", "align_streams", "read_streams"]

_DIRECTIONS = ("nearest", "backward", "forward")


@dataclass(frozen=True)
class AlignmentReport:
    """What :func:`align_streams` matched and dropped.

    Attributes
    ----------
    n_motor : int
        Motor samples (rows of the aligned frame).
    n_tracker : int
        Tracker samples given.
    n_unmatched : int
        Motor samples with no tracker sample within the tolerance; their
        tracker columns are NaN (dropouts).
    fraction_unmatched : float
        ``n_unmatched / n_motor``.
    n_tracker_unused : int
        Tracker samples matched to no motor sample.
    offset : float
        Value subtracted from the tracker times before matching (time
        unit of the streams): the latency, or the difference of the first
        timestamps with ``latency="start"``.
    tolerance : float
        Largest time difference accepted for a match (time unit of the
        streams).
    """

    n_motor: int
    n_tracker: int
    n_unmatched: int
    fraction_unmatched: float
    n_tracker_unused: int
    offset: float
    tolerance: float


def _check_positive(value, name):
    """Return ``value`` as float if it is a positive finite real number."""
    ok = isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))
    if not ok or not np.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a positive finite number; got {value!r}.")
    return float(value)


def _times(frame, on, label, sort):
    """Validated time column of one stream, and the stream sorted by it.

    Parameters
    ----------
    frame : pandas.DataFrame
        Stream (not modified).
    on : str
        Time column.
    label : str
        ``"motors"`` or ``"tracker"``, for messages.
    sort : bool
        Sort an unsorted stream instead of raising.

    Returns
    -------
    frame : pandas.DataFrame
        A copy, sorted by time, index ``range(n)``.

    Raises
    ------
    ValueError
        If the column is missing, not numeric, has NaN or duplicated values,
        or decreases somewhere while ``sort`` is False.
    """
    if not isinstance(frame, pd.DataFrame):
        raise ValueError(f"{label} must be a pandas DataFrame; got {type(frame).__name__}.")
    if on not in frame.columns:
        raise ValueError(
            f"{label} has no time column {on!r}; columns: {list(frame.columns)}. "
            "Pass on=... (or tracker_on=...) to name it."
        )
    t = frame[on]
    if not pdt.is_numeric_dtype(t.dtype) or pdt.is_bool_dtype(t.dtype):
        raise ValueError(f"{label}[{on!r}] must hold numbers (time); got dtype {t.dtype}.")
    values = t.to_numpy(dtype=np.float64, na_value=np.nan)
    if len(values) == 0:
        raise ValueError(f"{label} has no rows.")
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        raise ValueError(
            f"{label}[{on!r}] must be finite; {bad.size} value(s) are not, first at row "
            f"{int(bad[0])}."
        )
    duplicated = pd.Series(values).duplicated()
    if duplicated.any():
        at = int(np.flatnonzero(duplicated.to_numpy())[0])
        raise ValueError(
            f"{label}[{on!r}] has duplicated timestamps (first {values[at]!r} at row "
            f"{at}); every sample needs its own time."
        )
    decreasing = np.flatnonzero(np.diff(values) < 0)
    if decreasing.size and not sort:
        at = int(decreasing[0]) + 1
        raise ValueError(
            f"{label}[{on!r}] is not increasing (row {at}: {values[at]!r} after "
            f"{values[at - 1]!r}); sort the stream by time or pass sort=True."
        )
    out = frame.copy()
    out[on] = values
    if decreasing.size:
        out = out.sort_values(on, kind="stable")
    return out.reset_index(drop=True)


@validate_params(
    {
        "motors": "no_validation",
        "tracker": "no_validation",
        "tolerance": "no_validation",
        "on": [str],
        "tracker_on": [str, None],
        "latency": "no_validation",
        "direction": "no_validation",
        "sort": ["boolean"],
    },
    prefer_skip_nested_validation=True,
)
def align_streams(
    motors,
    tracker,
    *,
    tolerance,
    on="t",
    tracker_on=None,
    latency=0.0,
    direction="nearest",
    sort=False,
):
    """Attach to every motor sample the matching tracker sample.

    Parameters
    ----------
    motors : pandas.DataFrame
        Motor log: a time column ``on`` and any channels (``q1, q2, tau1,
        tau2``, ...). Defines the rows of the result.
    tracker : pandas.DataFrame
        Tracker log: a time column ``tracker_on`` and the pose columns (e.g.
        ``tip_px ... base_qz`` from :func:`skcath.io.read_ndi_csv`). Its
        other columns must not share a name with a motor column.
    tolerance : float
        Largest time difference between a motor sample and its tracker sample
        (same unit as the time columns, e.g. s). Motor samples without a
        tracker sample this close get NaN tracker columns.
    on : str, default="t"
        Time column of ``motors``.
    tracker_on : str, default=None
        Time column of ``tracker``; defaults to ``on``.
    latency : float or "start", default=0.0
        Constant offset of the tracker clock: a tracker sample stamped ``s``
        is matched as if taken at ``s - latency`` on the motor clock (e.g. the
        tracker's transport delay). ``"start"`` uses the difference of the
        first timestamps of the two streams, for clocks with unrelated
        origins that started together.
    direction : {"nearest", "backward", "forward"}, default="nearest"
        Which tracker sample to take (see :func:`pandas.merge_asof`):
        nearest in time, the last one at or before, or the first one at or
        after the motor sample.
    sort : bool, default=False
        Sort a stream that is not in time order instead of raising.

    Returns
    -------
    aligned : pandas.DataFrame
        The motor columns (sorted by time), then the tracker columns, then
        ``tracker_time``: the tracker timestamp matched (tracker clock, NaN
        where none). Index ``range(n_motor)``. Inputs are not modified.
    report : AlignmentReport
        Matched and dropped samples, offset used.

    Raises
    ------
    sklearn.utils._param_validation.InvalidParameterError
        If ``on`` or ``tracker_on`` is not a column name (str) or ``sort``
        not a bool.
    ValueError
        If a time column is missing, not numeric, not finite, has duplicated
        values or is not increasing (with ``sort=False``); if ``tolerance``
        is not positive; on an unknown ``direction`` or a bad ``latency``;
        if the streams share a column name other than the time column.

    Examples
    --------
    ::

        aligned, report = align_streams(motors, tracker, tolerance=0.02)
        print(report.n_unmatched, report.fraction_unmatched)
    """
    tolerance = _check_positive(tolerance, "tolerance")
    tracker_on = on if tracker_on is None else tracker_on
    if direction not in _DIRECTIONS:
        raise ValueError(f"direction must be one of {list(_DIRECTIONS)}; got {direction!r}.")
    if not (isinstance(latency, str) and latency == "start"):
        ok = isinstance(latency, numbers.Real) and not isinstance(latency, (bool, np.bool_))
        if not ok or not np.isfinite(latency):
            raise ValueError(
                f"latency must be a finite number (time unit of the streams) or "
                f"'start'; got {latency!r}."
            )
    motors = _times(motors, on, "motors", sort)
    tracker = _times(tracker, tracker_on, "tracker", sort)
    shared = set(motors.columns) & (set(tracker.columns) - {tracker_on})
    if "tracker_time" in motors.columns or "tracker_time" in tracker.columns:
        shared.add("tracker_time")
    if shared:
        raise ValueError(
            f"motors and tracker share the column(s) {sorted(shared)}; rename them "
            "in one stream."
        )

    offset = (
        float(tracker[tracker_on].iloc[0] - motors[on].iloc[0])
        if isinstance(latency, str)
        else float(latency)
    )
    right = tracker.rename(columns={tracker_on: "tracker_time"})
    right["__skcath_key"] = right["tracker_time"] - offset
    right["__skcath_index"] = np.arange(len(right))
    left = motors.copy()
    left["__skcath_key"] = left[on]
    aligned = pd.merge_asof(
        left, right, on="__skcath_key", direction=direction, tolerance=tolerance
    )
    matched = aligned["__skcath_index"].notna().to_numpy()
    used = np.unique(aligned.loc[matched, "__skcath_index"].to_numpy(dtype=np.int64))
    aligned = aligned.drop(columns=["__skcath_key", "__skcath_index"])
    n_unmatched = int((~matched).sum())
    report = AlignmentReport(
        n_motor=len(motors),
        n_tracker=len(tracker),
        n_unmatched=n_unmatched,
        fraction_unmatched=n_unmatched / len(motors),
        n_tracker_unused=len(tracker) - len(used),
        offset=offset,
        tolerance=tolerance,
    )
    return aligned.reset_index(drop=True), report


def _stream_table(source, label):
    """A stream given as a DataFrame or a CSV/Parquet file.

    Parameters
    ----------
    source : pandas.DataFrame, str or path-like
        Stream.
    label : str
        ``"motors"`` or ``"tracker"``, for messages.

    Returns
    -------
    frame : pandas.DataFrame
    stem : str or None
        File name without suffix, None for a DataFrame.
    """
    if isinstance(source, pd.DataFrame):
        return source, None
    if isinstance(source, (str, Path)):
        path = Path(source)
        kind, stem = file_kind(path)
        if not path.is_file():
            raise ValueError(f"{label}: no such file {str(path)!r}.")
        return read_table(path, kind), stem
    raise ValueError(
        f"{label} must be a DataFrame or the path of a file ({', '.join(CSV_SUFFIXES)}, "
        f".parquet); got {type(source).__name__}."
    )


def read_streams(
    motors, tracker, *, tolerance, on="t", tracker_on=None, latency=0.0, direction="nearest",
    sort=False, **read_kwargs,
):
    """Read a motor log and a tracker log into the long format.

    The two streams are aligned with :func:`align_streams` (one row per
    motor sample), then converted like a file by
    :func:`skcath.io.read_recording`.

    Parameters
    ----------
    motors, tracker : pandas.DataFrame, str or path-like
        The two logs, as DataFrames or CSV / Parquet files. For example the
        tracker stream returned by :func:`skcath.io.read_ndi_csv`.
    tolerance, on, tracker_on, latency, direction, sort
        See :func:`align_streams`. The time column ``on`` must be in
        seconds, since it becomes the time ``t`` of the recording.
    **read_kwargs
        Options of :func:`skcath.io.read_recording` (``columns``,
        ``constants``, ``scale``, ``catheter``, ``setting``, ``run``,
        ``phase``, ``n_sweep``, ``valid``, ``quat_order``, ``tip_offset``)
        applied to the aligned table. ``run`` defaults to the motor file name
        without suffix (``"streams"`` for a DataFrame). ``rate_hz`` is not
        accepted: the motor clock gives the time.

    Returns
    -------
    X : pandas.DataFrame
        Long format, one row per motor sample.
    y : ndarray of shape (n_motor, 3)
        Tip in the base frame (mm); NaN rows for motor samples without a
        tracker sample within the tolerance, or tracker dropouts.
    report : AlignmentReport
        See :func:`align_streams`.

    Raises
    ------
    ValueError
        As :func:`align_streams` and :func:`skcath.io.read_recording`.
    """
    if "rate_hz" in read_kwargs:
        raise ValueError(
            "read_streams takes the time from the motor log; rate_hz is not accepted."
        )
    columns = dict(read_kwargs.pop("columns", None) or {})
    if on != "t" and "t" not in columns:
        columns["t"] = on
    options = ReadingOptions.from_kwargs(
        {**read_kwargs, "columns": columns or None}, "read_streams"
    )
    motor_frame, stem = _stream_table(motors, "motors")
    tracker_frame, _ = _stream_table(tracker, "tracker")
    aligned, report = align_streams(
        motor_frame,
        tracker_frame,
        tolerance=tolerance,
        on=on,
        tracker_on=tracker_on,
        latency=latency,
        direction=direction,
        sort=sort,
    )
    name = "aligned streams" if stem is None else f"{stem} (aligned streams)"
    X, y = recording_from_table(aligned, name, stem or "streams", options)
    return X, y, report
