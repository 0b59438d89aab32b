"""Align a motor log and a tracker log recorded with their own clocks and rates.

:func:`align_streams` attaches to every motor sample the tracker sample
nearest in time (within a tolerance) with :func:`pandas.merge_asof`, after
shifting the tracker clock by a constant latency, and reports how many motor
samples found no tracker sample. :func:`read_streams` does the same from two
files and returns the long format ``(X, y)``; it refuses clocks that count in
different units and alignments that leave most motor samples unmatched
(:func:`check_alignment`).
"""

import math
import numbers
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from pandas.api import types as pdt
from sklearn.utils._param_validation import Interval, validate_params

from ._convert import recording_from_table
from ._options import ReadingOptions
from ._quat import check_read_quat_order
from ._recording import CSV_SUFFIXES, file_kind, read_table

__all__ = ["AlignmentReport", "align_streams", "check_alignment", "read_streams"]

_DIRECTIONS = ("nearest", "backward", "forward")
#: Default of ``max_unmatched``: the largest fraction of motor samples left
#: without a tracker sample before a reader refuses the alignment.
MAX_UNMATCHED = 0.9
#: Two clocks whose spans differ by a power of 1000 within this factor are
#: taken to count in different units (s, ms, us, ns).
_UNIT_FACTOR = 3.0


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
        Value subtracted from the tracker times (converted by
        ``tracker_time_scale``) before matching, in the unit of the motor
        time: the latency, or the difference of the first timestamps with
        ``latency="start"``.
    tolerance : float
        Largest time difference accepted for a match (unit of the motor
        time).
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
        "tracker_time_scale": "no_validation",
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
    tracker_time_scale=None,
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
        (unit of the motor time column, e.g. s). Motor samples without a
        tracker sample this close get NaN tracker columns.
    on : str, default="t"
        Time column of ``motors``.
    tracker_on : str, default=None
        Time column of ``tracker``; defaults to ``on``.
    latency : float or "start", default=0.0
        Constant offset of the tracker clock (unit of the motor time): a
        tracker sample stamped ``s`` is matched as if taken at
        ``s * tracker_time_scale - latency`` on the motor clock (e.g. the
        tracker's transport delay). ``"start"`` uses the difference of the
        first timestamps of the two streams, for clocks with unrelated
        origins that started together.
    direction : {"nearest", "backward", "forward"}, default="nearest"
        Which tracker sample to take (see :func:`pandas.merge_asof`):
        nearest in time, the last one at or before, or the first one at or
        after the motor sample.
    sort : bool, default=False
        Sort a stream that is not in time order instead of raising.
    tracker_time_scale : float, default=None
        Factor that converts the tracker time to the unit of the motor time,
        e.g. ``1e-3`` for a tracker clock in ms and motors in s. None: both
        clocks count in the same unit (factor 1).

    Returns
    -------
    aligned : pandas.DataFrame
        The motor columns (sorted by time), then the tracker columns, then
        ``tracker_time``: the tracker timestamp matched (tracker clock and
        unit, NaN where none). Index ``range(n_motor)``. Inputs are not modified.
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
        or ``tracker_time_scale`` is not positive; on an unknown
        ``direction`` or a bad ``latency``;
        if the streams share a column name other than the time column.

    Examples
    --------
    ::

        aligned, report = align_streams(motors, tracker, tolerance=0.02)
        print(report.n_unmatched, report.fraction_unmatched)
    """
    tolerance = _check_positive(tolerance, "tolerance")
    factor = 1.0
    if tracker_time_scale is not None:
        factor = _check_positive(tracker_time_scale, "tracker_time_scale")
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
        float(tracker[tracker_on].iloc[0] * factor - motors[on].iloc[0])
        if isinstance(latency, str)
        else float(latency)
    )
    right = tracker.rename(columns={tracker_on: "tracker_time"})
    right["__skcath_key"] = right["tracker_time"] * factor - offset
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


def _unit_power(motor_span, tracker_span):
    """How many powers of ten (a multiple of 3) the tracker span exceeds the motor span by.

    Returns
    -------
    power : int
        ``3``, ``6``, ``9`` (or negative) when the ratio of the spans is
        within a factor :data:`_UNIT_FACTOR` of that power of ten: clocks
        counting in different units (s, ms, us, ns). ``0`` otherwise, or when
        a span is zero.
    """
    if not (motor_span > 0 and tracker_span > 0):
        return 0
    decades = math.log10(tracker_span / motor_span)
    power = 3 * round(decades / 3)
    return power if power and abs(decades - power) <= math.log10(_UNIT_FACTOR) else 0


def check_alignment(report, motor_times, tracker_times, *, label, max_unmatched, check_units):
    """Refuse clocks in different units and alignments that match too few motor samples.

    Parameters
    ----------
    report : AlignmentReport
        Report of :func:`align_streams`.
    motor_times, tracker_times : array-like of float
        Time columns of the two streams, the tracker's already converted to
        the unit of the motor time (by ``tracker_time_scale``).
    label : str
        Start of the messages (the streams' or the bag's name).
    max_unmatched : float
        Largest accepted ``report.fraction_unmatched``.
    check_units : bool
        Check that the spans of the two clocks do not differ by a power of
        1000 (see :func:`_unit_power`).

    Raises
    ------
    ValueError
        If the clocks seem to count in different units (the message gives
        both spans and the ``tracker_time_scale`` that converts them), or
        more than ``max_unmatched`` of the motor samples found no tracker
        sample (the message gives the fraction, both clocks' ranges and what
        to check).
    """
    m0, m1 = float(np.min(motor_times)), float(np.max(motor_times))
    t0, t1 = float(np.min(tracker_times)), float(np.max(tracker_times))
    power = _unit_power(m1 - m0, t1 - t0) if check_units else 0
    if power:
        unit = {3: "ms", 6: "us", 9: "ns"}[abs(power)]
        if power > 0:
            fix = (
                f"as when the tracker counts in {unit} and the motors in s. Pass "
                f"tracker_time_scale={10.0 ** -power:g}, the factor that converts the tracker "
                "time to the unit of the motor time, or convert the tracker time column "
                "before reading"
            )
        else:
            fix = (
                f"as when the motors count in {unit} and the tracker in s. The motor time "
                "becomes t and must be in seconds: convert the motor time column before "
                f"reading (or pass scale={{'t': {10.0 ** power:g}}} and tracker_time_scale="
                f"{10.0 ** -power:g}, with tolerance and latency in {unit})"
            )
        raise ValueError(
            f"{label}: the two clocks count in different units: the motor clock spans "
            f"{m1 - m0:.6g} ({m0:.6g} to {m1:.6g}) and the tracker clock {t1 - t0:.6g} "
            f"({t0:.6g} to {t1:.6g}), {(t1 - t0) / (m1 - m0):.3g} times as long, {fix}; "
            "tracker_time_scale=1.0 states that both clocks count in one unit."
        )
    if report.fraction_unmatched > max_unmatched:
        raise ValueError(
            f"{label}: {report.n_unmatched} of the {report.n_motor} motor samples "
            f"({100 * report.fraction_unmatched:.1f} %) found no tracker sample within "
            f"tolerance={report.tolerance:g}, more than max_unmatched={max_unmatched:g}. The "
            f"motor samples run from {m0:.6g} to {m1:.6g}, the tracker samples (shifted by "
            f"the offset {report.offset:.6g}) from {t0 - report.offset:.6g} to "
            f"{t1 - report.offset:.6g}. Check the latency (latency='start' for clocks with "
            "other origins), the time units (tracker_time_scale) and the tolerance, or "
            "pass a larger max_unmatched to accept the alignment."
        )


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


@validate_params(
    {
        "motors": "no_validation",
        "tracker": "no_validation",
        "max_unmatched": [Interval(numbers.Real, 0, 1, closed="both")],
        "quat_check": ["boolean"],
    },
    prefer_skip_nested_validation=True,
)
def read_streams(
    motors, tracker, *, tolerance, on="t", tracker_on=None, latency=0.0, direction="nearest",
    sort=False, tracker_time_scale=None, max_unmatched=MAX_UNMATCHED, quat_check=True,
    **read_kwargs,
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
    tracker_time_scale : float, default=None
        Factor that converts the tracker time to seconds, the unit of the
        motor time (``1e-3`` for a tracker clock in ms); see
        :func:`align_streams`. None: both clocks count in seconds, which is
        checked: clocks whose spans differ by a factor near 1000, 1e6 or 1e9
        (within a factor 3) are refused as counting in different units.
        Giving a factor (1.0 included) skips that check.
    max_unmatched : float in [0, 1], default=0.9
        Largest fraction of the motor samples allowed to find no tracker
        sample within ``tolerance``; above it the streams are refused as not
        aligned (wrong latency, units or tolerance). Motor samples unmatched
        by design, e.g. a tracker at 40 Hz and motors at 100 Hz with a
        tolerance under half a tracker period (about 60 % unmatched), stay
        below the default; 1.0 accepts any alignment.
    quat_check : bool, default=True
        When the motor log holds several runs of a catheter and the target
        is computed from raw sensor poses, check the quaternion order
        against the data as :func:`skcath.io.read_recording` does (a
        ValueError names the order that fits). One run cannot tell the
        orders apart, so streams of one run pass. False skips the check.
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
    sklearn.utils._param_validation.InvalidParameterError
        If ``max_unmatched`` is not a number in [0, 1].
    ValueError
        As :func:`align_streams` and :func:`skcath.io.read_recording`, and
        when the two clocks count in different units or more than
        ``max_unmatched`` of the motor samples found no tracker sample (see
        :func:`check_alignment`). With ``quat_check``, also when the base
        quaternions of streams of several runs fit the other order.
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
        tracker_time_scale=tracker_time_scale,
    )
    name = "aligned streams" if stem is None else f"{stem} (aligned streams)"
    factor = 1.0 if tracker_time_scale is None else tracker_time_scale
    check_alignment(
        report,
        motor_frame[on].to_numpy(dtype=np.float64),
        tracker_frame[tracker_on or on].to_numpy(dtype=np.float64) * factor,
        label=name,
        max_unmatched=max_unmatched,
        check_units=tracker_time_scale is None,
    )
    X, y, poses = recording_from_table(aligned, name, stem or "streams", options, with_poses=True)
    if quat_check:
        check_read_quat_order(X, poses, {**read_kwargs, "columns": columns})
    return X, y, report
