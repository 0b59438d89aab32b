"""The long-format columns of a recording, derived from a table's own columns.

:func:`recording_from_table` turns a table in file column names (read from a
file, or assembled from streams or a bag) into ``(X, y)``: it finds the file
column of every skcath name, then derives the ids, the time, the phase, the
motor and torque channels, the validity of every row, the target (tip in the
base frame, from raw sensor poses or from ``p_*`` columns) and the reference
tip, and checks the result with :func:`skcath.check_recordings`. How the
columns are mapped is set by :class:`~skcath.io._options.ReadingOptions`.
"""

from dataclasses import dataclass
from pathlib import PurePath

import numpy as np
import pandas as pd
from pandas.api import types as pdt

from .._format import (
    ID_COLUMNS, MOTION, MOTOR_PREFIX, PHASE, PHASES, REFERENCE_COLUMNS, RUN, SENSOR_POSE_COLUMNS,
    SWEEP, TARGET_NAMES, TIME, TORQUE_PREFIX, channel_index, motor_names, torque_names,
)
from .._runs import run_codes, run_steps
from .._sweep_end import N_SWEEP_ATTR, find_sweep_end
from .._validation import check_recordings
from ..frames import tip_in_base_frame
from ._options import AUTO_SWEEP, SINGLE_NAMES

__all__ = ["VALID_STRINGS", "recording_from_table"]

#: Status strings (compared after stripping and lower-casing) that mark a
#: sample as valid in a ``valid`` column of strings; any other string is invalid.
VALID_STRINGS = frozenset({"ok", "valid", "true", "yes"})


# ---------------------------------------------------------------------------
# the source table and its columns
# ---------------------------------------------------------------------------
def _found(frame):
    """``"file columns: [...]"``: the columns of ``frame``, for the end of a message."""
    return f"file columns: {[str(c) for c in frame.columns]}"


@dataclass(frozen=True, eq=False)
class _Source:
    """A source table with the file column of every skcath name found in it.

    Made by :meth:`find`; every helper below reads the table through it.

    Attributes
    ----------
    frame : pandas.DataFrame
        Source table, in file column names (never modified).
    columns : dict of str to str
        skcath name -> file column, for every skcath name found.
    scale : mapping of str to float
        Factors applied to the numeric columns read.
    label : str
        Name of the source, starting every message.
    """

    frame: pd.DataFrame
    columns: dict
    scale: object
    label: str

    @classmethod
    def find(cls, frame, mapping, scale, label):
        """Find the file column of every skcath name present in ``frame``.

        Parameters
        ----------
        frame : pandas.DataFrame
            Source table.
        mapping : mapping of str to str
            Explicit skcath name -> file column mapping (the ``columns``
            option); other skcath names are looked up under their own name.
        scale : mapping of str to float
            Factors of the numeric columns (the ``scale`` option).
        label : str
            Name of the source, for messages.

        Raises
        ------
        ValueError
            If an explicitly mapped column is not in the table, or ``scale``
            has a factor for a column that is not read.
        """
        present = set(frame.columns)
        columns = {}
        channels = [c for c in (*mapping, *frame.columns) if channel_index(c) is not None]
        for name in dict.fromkeys((*SINGLE_NAMES, *channels)):
            if name in mapping:
                file_column = mapping[name]
                if file_column not in present:
                    raise ValueError(
                        f"{label}: columns maps {name!r} to the file column "
                        f"{file_column!r}, which the file does not have; "
                        f"{_found(frame)}."
                    )
                columns[name] = file_column
            elif name in present:
                columns[name] = name
        for name in scale:
            if name not in columns:
                raise ValueError(
                    f"{label}: scale has a factor for {name!r}, which is not read "
                    f"from the file (the file has no such column after mapping); "
                    f"{_found(frame)}."
                )
        return cls(frame, columns, scale, label)

    def __contains__(self, name):
        return name in self.columns

    def __len__(self):
        return len(self.frame)

    @property
    def found(self):
        """``"file columns: [...]"``, the columns of the table, for messages."""
        return _found(self.frame)

    def describe(self, name):
        """Describe a skcath column and its file column for error messages."""
        file_column = self.columns.get(name)
        if file_column is None or file_column == name:
            return f"column {name!r}"
        return f"file column {file_column!r} (skcath column {name!r})"

    def raw(self, name):
        """The file column of skcath column ``name``, index ``range(n_rows)``."""
        return self.frame[self.columns[name]].reset_index(drop=True)

    def numeric(self, name):
        """Read skcath column ``name`` as float64, times its ``scale`` factor.

        Returns
        -------
        values : ndarray of shape (n_rows,), dtype float64
            A new array; empty cells are NaN.

        Raises
        ------
        ValueError
            If the column holds values that are not numbers.
        """
        series = self.frame[self.columns[name]]
        if isinstance(series, pd.DataFrame):
            raise ValueError(
                f"{self.label}: the file has several columns named {self.columns[name]!r}; "
                "column names must be unique."
            )
        if pdt.is_bool_dtype(series.dtype) or pdt.is_datetime64_any_dtype(series.dtype):
            raise ValueError(
                f"{self.label}: {self.describe(name)} must hold numbers; got dtype "
                f"{series.dtype}."
            )
        factor = self.scale.get(name, 1.0)
        if pdt.is_numeric_dtype(series.dtype) and not pdt.is_complex_dtype(series.dtype):
            return series.to_numpy(dtype=np.float64, na_value=np.nan, copy=True) * factor
        parsed = pd.to_numeric(series, errors="coerce")
        values = parsed.to_numpy(dtype=np.float64, na_value=np.nan, copy=True)
        bad = np.flatnonzero(np.isnan(values) & series.notna().to_numpy(dtype=bool))
        if bad.size:
            raise ValueError(
                f"{self.label}: {self.describe(name)} must hold numbers; "
                f"{bad.size} value(s) are not numeric, first {series.iloc[bad[0]]!r} "
                f"at row {int(bad[0])}."
            )
        return values * factor

    def stack(self, names):
        """Numeric columns ``names`` side by side, shape ``(n_rows, len(names))``."""
        return np.column_stack([self.numeric(name) for name in names])


def _clean_text(series):
    """Strip and lower-case the text cells of a column; booleans become text.

    Parameters
    ----------
    series : pandas.Series
        Column of the file.

    Returns
    -------
    cleaned : pandas.Series of object
        Stripped lower-case strings where the cell holds text, ``"true"`` /
        ``"false"`` for booleans (a column of booleans with empty cells is read
        from CSV as objects), None elsewhere.
    """

    def clean(value):
        if isinstance(value, str):
            return value.strip().lower()
        if isinstance(value, (bool, np.bool_)):
            return "true" if value else "false"
        return None

    return series.astype(object).map(clean).reset_index(drop=True)


# ---------------------------------------------------------------------------
# the long-format columns, each from the file or from the options
# ---------------------------------------------------------------------------
def _id_values(source, given, default_run):
    """Id columns: from the file, or broadcast from the options.

    Parameters
    ----------
    source : _Source
        Source table.
    given : dict
        ``{"catheter": ..., "setting": ..., "run": ...}`` given as options.
    default_run : str
        Run id used when neither the file nor ``run`` gives one.

    Returns
    -------
    ids : dict of str to pandas.Series
        One series per id column, index ``range(n_rows)``.

    Raises
    ------
    ValueError
        If an id is given both in the file and as an option, is missing, or
        the file column has empty cells.
    """
    ids = {}
    for name in ID_COLUMNS:
        value = given[name]
        if name in source:
            if value is not None:
                raise ValueError(
                    f"{source.label}: {name}={value!r} was given, but the file already "
                    f"has {source.describe(name)}; give one or the other."
                )
            series = source.raw(name)
            empty = np.flatnonzero(series.isna().to_numpy(dtype=bool))
            if empty.size:
                raise ValueError(
                    f"{source.label}: {source.describe(name)} has {empty.size} empty "
                    f"cell(s), first at row {int(empty[0])}; every row needs an id."
                )
            ids[name] = series
            continue
        if value is None and name == RUN:
            value = default_run
        if value is None:
            raise ValueError(
                f"{source.label}: the file has no {name!r} column; pass {name}=... to "
                f"read_recording or map the file column with columns={{{name!r}: ...}}; "
                f"{source.found}."
            )
        ids[name] = pd.Series([value] * len(source))
    return ids


def _time_values(source, codes, rate_hz):
    """Time (s): from the file, or sample index within the run / ``rate_hz``.

    Parameters
    ----------
    source : _Source
        Source table.
    codes : ndarray of int, shape (n_rows,)
        Run code of every row (:func:`skcath._runs.run_codes`).
    rate_hz : float or None
        Sampling rate (Hz).

    Returns
    -------
    t : ndarray of shape (n_rows,)
        Time in seconds.

    Raises
    ------
    ValueError
        If the file has a time column and ``rate_hz`` is given, or neither.
    """
    if TIME in source:
        if rate_hz is not None:
            raise ValueError(
                f"{source.label}: rate_hz was given, but the file already has "
                f"{source.describe(TIME)}; give one or the other."
            )
        return source.numeric(TIME)
    if rate_hz is None:
        raise ValueError(
            f"{source.label}: the file has no time column {TIME!r}; pass rate_hz "
            f"(sampling rate, Hz) or map the time column with columns={{{TIME!r}: ...}}; "
            f"{source.found}."
        )
    return run_steps(codes) / float(rate_hz)


def _phase_values(source, codes, runs, phase, n_sweep):
    """Phase of every row: from the file, ``phase`` or ``n_sweep``.

    Parameters
    ----------
    source : _Source
        Source table.
    codes, runs : ndarray
        Run code of every row and the run ids it indexes, as returned by
        :func:`skcath._runs.run_codes`.
    phase : {"sweep", "motion"} or None
        Phase of every row.
    n_sweep : int or None
        Number of sweep samples at the start of each run.

    Returns
    -------
    phases : ndarray of shape (n_rows,), dtype object
        ``"sweep"`` or ``"motion"``.

    Raises
    ------
    ValueError
        On conflicting or missing phase information, unknown phase strings,
        or a run shorter than ``n_sweep``.
    """
    label = source.label
    if PHASE in source:
        if phase is not None or n_sweep is not None:
            given = "phase" if phase is not None else "n_sweep"
            raise ValueError(
                f"{label}: {given} was given, but the file already has "
                f"{source.describe(PHASE)}; give one or the other."
            )
        raw = source.raw(PHASE)
        cleaned = _clean_text(raw)
        bad = np.flatnonzero(~cleaned.isin(PHASES).to_numpy(dtype=bool))
        if bad.size:
            raise ValueError(
                f"{label}: {source.describe(PHASE)} must hold {list(PHASES)}; "
                f"first other value {raw.iloc[bad[0]]!r} at row {int(bad[0])}."
            )
        return cleaned.to_numpy(dtype=object)
    if phase is not None:
        return np.array([phase] * len(source), dtype=object)
    if n_sweep is None:
        raise ValueError(
            f"{label}: the file has no {PHASE!r} column; pass n_sweep (the first "
            f"n_sweep samples of each run are the sweep), phase={SWEEP!r} or "
            f"phase={MOTION!r}, or map the column with columns={{{PHASE!r}: ...}}; "
            f"{source.found}."
        )
    sizes = np.bincount(codes, minlength=len(runs))
    short = np.flatnonzero(sizes < n_sweep)
    if short.size:
        k = int(short[0])
        raise ValueError(
            f"{label}: n_sweep={n_sweep} but run {runs[k]!r} has only "
            f"{int(sizes[k])} samples; n_sweep must not exceed the length of a run."
        )
    return np.where(run_steps(codes, len(runs)) < n_sweep, SWEEP, MOTION).astype(object)


def _detected_phases(label, codes, runs, t, values):
    """Phase of every row, the sweep of each run found from its motor angles.

    Parameters
    ----------
    label : str
        File name, for messages.
    codes, runs : ndarray
        Run code of every row and the run ids it indexes.
    t : ndarray of shape (n_rows,)
        Time of every row (s).
    values : dict
        Channel name -> values of every row; the motor angles ``q1 .. qN``
        are used.

    Raises
    ------
    ValueError
        Starting with ``label`` and naming the run, when the start of a run
        is not a sweep (:func:`skcath.sweep.find_sweep_end`).
    """
    q = np.column_stack([values[c] for c in values if c.startswith(MOTOR_PREFIX)])
    phases = np.full(len(codes), MOTION, dtype=object)
    for k, run in enumerate(runs):
        rows = np.flatnonzero(codes == k)
        try:
            end = find_sweep_end(q[rows], t[rows], run=run)
        except ValueError as exc:
            raise ValueError(f"{label}: n_sweep={AUTO_SWEEP!r}: {exc}") from None
        phases[rows[: end.n_sweep]] = SWEEP
    return phases


def _channel(source, constants, name):
    """A motor or torque channel: from the file or from ``constants``.

    Parameters
    ----------
    source : _Source
        Source table.
    constants : mapping of str to float
        Constant channels.
    name : str
        skcath name.

    Returns
    -------
    values : ndarray of shape (n_rows,), dtype float64

    Raises
    ------
    ValueError
        If the channel is both in the file and in ``constants``, or in neither.
    """
    if name in source:
        if name in constants:
            raise ValueError(
                f"{source.label}: constants sets {name!r}, but the file already has "
                f"{source.describe(name)}; give one or the other."
            )
        return source.numeric(name)
    if name in constants:
        return np.full(len(source), constants[name], dtype=np.float64)
    no_torque = (
        ", or pass torques=False for a rig without torque sensing"
        if channel_index(name)[0] == TORQUE_PREFIX else ""
    )
    raise ValueError(
        f"{source.label}: the file has no {name!r} column; map it with "
        f"columns={{{name!r}: ...}} or set it with constants={{{name!r}: value}}{no_torque}; "
        f"{source.found}."
    )


def _channel_names(source, options):
    """The motor and torque channels of the recording read: ``q1 .. qN`` and ``tau1 .. tauN``.

    ``N`` is the largest ``k`` of a channel ``qk`` or ``tauk`` found in the
    file or set by ``constants`` (1 when there is none); every channel up to
    ``N`` is then needed, from the file or from ``constants``. Without
    torques (``options.torques`` False) no ``tauk`` counts.
    """
    indices = [channel_index(c) for c in (*source.columns, *options.constants)]
    kinds = (MOTOR_PREFIX, TORQUE_PREFIX) if options.torques else (MOTOR_PREFIX,)
    n_motors = 1
    for index in indices:
        if index is not None and index[0] in kinds:
            n_motors = max(n_motors, index[1])
    torques = torque_names(n_motors) if options.torques else ()
    return (*motor_names(n_motors), *torques)


def _valid_rows(source, column, accepted):
    """Boolean mask of valid rows from a status column (all rows without one).

    Parameters
    ----------
    source : _Source
        Source table.
    column : str or None
        File column holding the status; None when every row is valid.
    accepted : list or None
        Values meaning valid; None for the default rules (see
        :func:`skcath.io.read_recording`).

    Returns
    -------
    valid : ndarray of bool, shape (n_rows,)

    Raises
    ------
    ValueError
        If the column is not in the file.
    """
    frame = source.frame
    if column is None:
        return np.ones(len(frame), dtype=bool)
    if column not in frame.columns:
        raise ValueError(
            f"{source.label}: valid names the status column {column!r}, which the file "
            f"does not have; {source.found}."
        )
    status = frame[column]
    present = status.notna().to_numpy(dtype=bool)
    if accepted is not None:
        return status.isin(accepted).to_numpy(dtype=bool) & present
    if pdt.is_bool_dtype(status.dtype):
        return status.to_numpy(dtype=bool, na_value=False)
    if pdt.is_numeric_dtype(status.dtype):
        return (status.to_numpy(dtype=np.float64, na_value=np.nan) == 0) & present
    return _clean_text(status).isin(VALID_STRINGS).to_numpy(dtype=bool) & present


def _target_values(source, tip_offset, invalid):
    """Tip position in the base frame (mm): from sensor poses or ``p_*`` columns.

    Parameters
    ----------
    source : _Source
        Source table.
    tip_offset : array-like of shape (3,) or None
        Offset of the tip from the tip sensor, tip sensor frame (mm).
    invalid : ndarray of bool
        Rows whose poses are masked before the computation.

    Returns
    -------
    y : ndarray of shape (n_rows, 3)
    poses : dict or None
        The masked sensor-pose arrays by group name (quaternions as ``w, x, y,
        z`` by name), and under ``"file_columns"`` the file columns read as
        ``base_qw .. base_qz``; None when ``y`` comes from ``p_*`` columns.

    Raises
    ------
    ValueError
        If neither the sensor poses nor the base-frame tip columns are complete.
    """
    groups = ["tip_position", "base_position", "base_orientation"]
    if tip_offset is not None:
        groups.append("tip_orientation")

    # quaternion components are assembled by name as (w, x, y, z)
    needed = [name for group in groups for name in SENSOR_POSE_COLUMNS[group]]
    missing_pose = [name for name in needed if name not in source]
    if not missing_pose:
        arrays = {}
        for group in groups:
            block = source.stack(SENSOR_POSE_COLUMNS[group])
            block[invalid] = np.nan
            arrays[group] = block
        quaternion = SENSOR_POSE_COLUMNS["base_orientation"]
        arrays["file_columns"] = [source.columns[name] for name in quaternion]
        try:
            y = tip_in_base_frame(
                arrays["tip_position"],
                arrays["base_position"],
                arrays["base_orientation"],
                quat_order="wxyz",
                tip_offset=tip_offset,
                tip_orientation=arrays.get("tip_orientation"),
            )
            return y, arrays
        except ValueError as exc:
            used = {g: [source.columns[n] for n in SENSOR_POSE_COLUMNS[g]] for g in groups}
            raise ValueError(
                f"{source.label}: cannot compute the tip in the base frame from the "
                f"sensor-pose file columns {used}: {exc}"
            ) from None

    missing_target = [name for name in TARGET_NAMES if name not in source]
    if tip_offset is not None:
        raise ValueError(
            f"{source.label}: tip_offset needs the sensor-pose columns, but the file "
            f"lacks {missing_pose}; map them with columns=... or drop tip_offset; "
            f"{source.found}."
        )
    if missing_target:
        raise ValueError(
            f"{source.label}: no target found. The file needs either the sensor-pose "
            f"columns (missing: {missing_pose}) or the base-frame tip columns "
            f"{list(TARGET_NAMES)} (missing: {missing_target}); map them with "
            f"columns=...; {source.found}."
        )
    y = source.stack(TARGET_NAMES)
    y[invalid] = np.nan
    return y, None


def _reference_values(source, y, sweep, invalid):
    """Reference tip (mm): from the file, or the target on sweep rows.

    Parameters
    ----------
    source : _Source
        Source table.
    y : ndarray of shape (n_rows, 3)
        Target, already masked.
    sweep : ndarray of bool
        Sweep rows.
    invalid : ndarray of bool
        Rows to mask.

    Returns
    -------
    ref : ndarray of shape (n_rows, 3)

    Raises
    ------
    ValueError
        If the file has only some of the reference columns.
    """
    found = [name for name in REFERENCE_COLUMNS if name in source]
    if found and len(found) < len(REFERENCE_COLUMNS):
        missing = [name for name in REFERENCE_COLUMNS if name not in source]
        raise ValueError(
            f"{source.label}: the file has the reference column(s) {found} but not "
            f"{missing}; give all three or none (then they are taken from the "
            f"target on sweep rows); {source.found}."
        )
    if found:
        ref = source.stack(REFERENCE_COLUMNS)
    else:
        ref = np.where(sweep[:, None], y, np.nan)
    ref[invalid] = np.nan
    return ref


# ---------------------------------------------------------------------------
# the recording
# ---------------------------------------------------------------------------
def recording_from_table(frame, name, stem, options, *, with_poses=False):
    """Convert a table in file column names into ``(X, y)``.

    Shared by every reader of :mod:`skcath.io`; all but
    :func:`skcath.io.read_recording` first build such a table from their
    source (aligned streams, a bag).

    Parameters
    ----------
    frame : pandas.DataFrame
        Source table (not modified).
    name : str
        Name of the source, used at the start of error messages.
    stem : str
        Default run id.
    options : ReadingOptions
        Checked reading options.
    with_poses : bool, default=False
        Also return the raw sensor poses the target was computed from.

    Returns
    -------
    X : pandas.DataFrame
    y : ndarray of shape (n_rows, 3)
        As in :func:`skcath.io.read_recording`.
    poses : dict or None
        Only with ``with_poses``: the sensor-pose arrays by group name, one
        row per row of ``X`` (quaternions ``w, x, y, z`` by name), and the
        file columns read as the base quaternion under ``"file_columns"``;
        None when the target was read from ``p_*`` columns.

    Raises
    ------
    ValueError
        As in :func:`skcath.io.read_recording`; every message starts with
        ``name``.
    """
    label = PurePath(name.replace("/", "_")).name
    if len(frame) == 0:
        raise ValueError(f"{label}: the file has no rows; a recording needs samples.")
    source = _Source.find(frame, options.columns, options.scale, label)
    ids = _id_values(source, options.ids, stem)
    codes, runs = run_codes(pd.DataFrame(ids))
    invalid = ~_valid_rows(source, options.valid_column, options.valid_values)
    data = {**ids, TIME: _time_values(source, codes, options.rate_hz)}
    channels = _channel_names(source, options)
    values = {channel: _channel(source, options.constants, channel) for channel in channels}
    if options.n_sweep == AUTO_SWEEP and PHASE not in source:
        data[PHASE] = _detected_phases(label, codes, runs, data[TIME], values)
    else:
        data[PHASE] = _phase_values(source, codes, runs, options.phase, options.n_sweep)
    data.update(values)
    y, poses = _target_values(source, options.tip_offset, invalid)
    ref = _reference_values(source, y, data[PHASE] == SWEEP, invalid)
    data.update(zip(REFERENCE_COLUMNS, ref.T))
    order = [*ID_COLUMNS, TIME, PHASE, *channels, *REFERENCE_COLUMNS]
    X = pd.DataFrame(data, index=pd.RangeIndex(len(frame)), columns=order)
    try:
        X, y = check_recordings(X, y, require_sweep=options.require_sweep)
    except ValueError as exc:
        raise ValueError(f"{label}: the recording read is not valid: {exc}") from None
    if options.n_sweep not in (None, AUTO_SWEEP) and options.n_sweep > 0:
        # the sweep errors of the backbones name the n_sweep given (skcath.sweep)
        X.attrs[N_SWEEP_ATTR] = {run: int(options.n_sweep) for run in runs}
    return (X, y, poses) if with_poses else (X, y)
