"""Read recordings exported by other tools into the long recording format.

:func:`read_recording` reads one CSV or Parquet file, renames its columns to
the skcath names, fills the channels the file lacks from arguments, computes
the target (tip position in the base frame, mm) from raw EM sensor poses when
needed, and returns ``(X, y)`` in the long format described in
``docs/data_format.rst``.

Column names used here (the "skcath names"):

- ids ``catheter``, ``setting``, ``run``; time ``t`` (s); ``phase``;
  motor angles ``q1``, ``q2`` (degrees); torques ``tau1``, ``tau2``;
  reference tip ``ref_x``, ``ref_y``, ``ref_z`` (mm, base frame);
- base-frame tip (target) ``p_x``, ``p_y``, ``p_z`` (mm);
- raw sensor poses in the tracker frame: ``tip_px``, ``tip_py``, ``tip_pz``,
  ``tip_qw``, ``tip_qx``, ``tip_qy``, ``tip_qz`` and the same with ``base_``
  (positions in mm, quaternions named by component).
"""

import inspect
import numbers
from pathlib import Path, PurePath

import numpy as np
import pandas as pd
from pandas.api import types as pdt

from .._format import (
    CATHETER,
    ID_COLUMNS,
    MOTION,
    MOTOR_COLUMNS,
    PHASE,
    PHASES,
    REFERENCE_COLUMNS,
    REQUIRED_COLUMNS,
    RUN,
    SENSOR_POSE_COLUMNS,
    SETTING,
    SWEEP,
    TARGET_NAMES,
    TIME,
    TORQUE_COLUMNS,
)
from .._validation import check_quat_order
from ..frames import tip_in_base_frame

__all__ = ["VALID_STRINGS", "read_recording"]

#: Status strings (compared after stripping and lower-casing) that mark a
#: sample as valid in a ``valid`` column of strings; any other string is invalid.
VALID_STRINGS = frozenset({"ok", "valid", "true", "yes"})

_POSE_NAMES = tuple(name for names in SENSOR_POSE_COLUMNS.values() for name in names)
_POSITION_GROUPS = ("tip_position", "base_position")
_ORIENTATION_GROUPS = ("tip_orientation", "base_orientation")
#: Names that ``columns`` may map, one file column each.
_SINGLE_NAMES = (*REQUIRED_COLUMNS, *TARGET_NAMES, *_POSE_NAMES)
#: Channels that ``constants`` may set.
_CONSTANT_NAMES = (*MOTOR_COLUMNS, *TORQUE_COLUMNS)
#: Numeric names that ``scale`` may rescale (quaternions are normalised anyway).
_SCALABLE_NAMES = (
    TIME,
    *MOTOR_COLUMNS,
    *TORQUE_COLUMNS,
    *REFERENCE_COLUMNS,
    *TARGET_NAMES,
    *(n for g in _POSITION_GROUPS for n in SENSOR_POSE_COLUMNS[g]),
)
_CSV_SUFFIXES = (".csv", ".csv.gz", ".csv.bz2", ".csv.xz", ".csv.zip")
_PARQUET_SUFFIXES = (".parquet",)


# ---------------------------------------------------------------------------
# argument checks (before the file is read)
# ---------------------------------------------------------------------------
def _file_kind(path):
    """Return ``("csv" | "parquet", stem)`` from the file name.

    Parameters
    ----------
    path : pathlib.Path
        File to read.

    Returns
    -------
    kind : str
        ``"csv"`` or ``"parquet"``.
    stem : str
        File name without the recognised suffix (the default run id).

    Raises
    ------
    ValueError
        If the suffix is not one of the supported ones.
    """
    name = path.name.lower()
    for kind, suffixes in (("csv", _CSV_SUFFIXES), ("parquet", _PARQUET_SUFFIXES)):
        for suffix in suffixes:
            if name.endswith(suffix) and len(name) > len(suffix):
                return kind, path.name[: -len(suffix)]
    raise ValueError(
        f"path must name a CSV ({', '.join(_CSV_SUFFIXES)}) or Parquet "
        f"({', '.join(_PARQUET_SUFFIXES)}) file; got {str(path)!r}."
    )


def _check_columns_arg(columns, quat_order):
    """Expand ``columns`` into a mapping skcath name -> file column name.

    Parameters
    ----------
    columns : mapping or None
        Keys: skcath names (see the module docstring) or the sensor groups
        ``tip_position``, ``base_position`` (3 file columns x, y, z) and
        ``tip_orientation``, ``base_orientation`` (4 file columns in the order
        ``quat_order``). Values: file column names.
    quat_order : {"wxyz", "xyzw"}
        Component order of the file columns listed for an orientation group.

    Returns
    -------
    mapping : dict of str to str
        Explicit mapping, one entry per skcath name.

    Raises
    ------
    ValueError
        If a key is unknown, a value is not a column name (or a sequence of
        3 or 4 names for a group), or a group and one of its components are
        both given.
    """
    if columns is None:
        return {}
    if not hasattr(columns, "items"):
        raise ValueError(
            f"columns must be a mapping from skcath column names to file column "
            f"names; got {type(columns).__name__}."
        )
    mapping = {}
    for key, value in columns.items():
        if key in SENSOR_POSE_COLUMNS:
            names = SENSOR_POSE_COLUMNS[key]
            if key in _ORIENTATION_GROUPS:
                prefix = key.split("_")[0]
                names = tuple(f"{prefix}_q{c}" for c in quat_order)
                expected = f"4 file column names in the order {quat_order!r}"
            else:
                expected = "3 file column names (x, y, z)"
            if (
                isinstance(value, str)
                or not hasattr(value, "__len__")
                or len(value) != len(names)
                or not all(isinstance(v, str) for v in value)
            ):
                raise ValueError(f"columns[{key!r}] must be {expected}; got {value!r}.")
            for name, file_column in zip(names, value):
                if name in columns:
                    raise ValueError(
                        f"columns maps both the group {key!r} and its component "
                        f"{name!r}; give one or the other."
                    )
                mapping[name] = file_column
        elif key in _SINGLE_NAMES:
            if not isinstance(value, str):
                raise ValueError(
                    f"columns[{key!r}] must be a file column name (str); got {value!r}."
                )
            mapping[key] = value
        else:
            raise ValueError(
                f"columns has the unknown key {key!r}; expected one of "
                f"{list(_SINGLE_NAMES)} or a sensor group {list(SENSOR_POSE_COLUMNS)}."
            )
    return mapping


def _check_number_map(values, name, allowed, *, finite, nonzero=False):
    """Validate a dict of skcath column -> real number (``constants``, ``scale``).

    Parameters
    ----------
    values : mapping or None
        Mapping given by the caller.
    name : str
        Parameter name used in error messages.
    allowed : tuple of str
        Keys that are accepted.
    finite : bool
        Require finite values.
    nonzero : bool, default=False
        Reject zero.

    Returns
    -------
    checked : dict of str to float
        A new dict.

    Raises
    ------
    ValueError
        On an unknown key or a value that is not an accepted real number.
    """
    if values is None:
        return {}
    if not hasattr(values, "items"):
        raise ValueError(
            f"{name} must be a mapping from skcath column names to numbers; "
            f"got {type(values).__name__}."
        )
    checked = {}
    for key, value in values.items():
        if key not in allowed:
            raise ValueError(
                f"{name} has the key {key!r}; expected one of {list(allowed)}."
            )
        ok = isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))
        if ok and finite:
            ok = bool(np.isfinite(value))
        if ok and nonzero:
            ok = value != 0
        if not ok:
            what = "a finite" if finite else "a"
            what += " nonzero" if nonzero else ""
            raise ValueError(f"{name}[{key!r}] must be {what} real number; got {value!r}.")
        checked[key] = float(value)
    return checked


def _expand_scale(scale):
    """Expand position groups in ``scale`` to their three components.

    Parameters
    ----------
    scale : mapping or None
        Factors by skcath name; ``tip_position`` / ``base_position`` stand
        for their three components.

    Returns
    -------
    scale : mapping or None
        Same factors keyed by component names only.
    """
    if scale is None or not hasattr(scale, "items"):
        return scale
    expanded = {}
    for key, value in scale.items():
        if key in _POSITION_GROUPS:
            for name in SENSOR_POSE_COLUMNS[key]:
                expanded[name] = value
        else:
            expanded[key] = value
    return expanded


def _check_id_arg(value, name):
    """Validate an id given as an argument (str or int, or None).

    Parameters
    ----------
    value : object
        Value given by the caller.
    name : str
        Parameter name.

    Returns
    -------
    value : str, int or None
        The value, unchanged.

    Raises
    ------
    ValueError
        If it is neither None, a string nor an integer.
    """
    if value is None or isinstance(value, str):
        return value
    if isinstance(value, numbers.Integral) and not isinstance(value, (bool, np.bool_)):
        return value
    raise ValueError(f"{name} must be a string or an integer id; got {value!r}.")


def _check_phase_args(phase, n_sweep):
    """Validate ``phase`` and ``n_sweep`` (at most one of them).

    Parameters
    ----------
    phase : {"sweep", "motion"} or None
        Phase of every row.
    n_sweep : int or None
        Number of sweep samples at the start of each run.

    Raises
    ------
    ValueError
        If both are given or either has an invalid value.
    """
    if phase is not None and n_sweep is not None:
        raise ValueError(
            "Give either phase (one phase for every row) or n_sweep (the first "
            "n_sweep samples of each run are the sweep), not both."
        )
    if phase is not None and phase not in PHASES:
        raise ValueError(f"phase must be one of {list(PHASES)}; got {phase!r}.")
    if n_sweep is not None and (
        not isinstance(n_sweep, numbers.Integral)
        or isinstance(n_sweep, (bool, np.bool_))
        or n_sweep < 0
    ):
        raise ValueError(f"n_sweep must be a non-negative integer; got {n_sweep!r}.")


def _check_rate(rate_hz):
    """Validate ``rate_hz`` (positive finite number or None).

    Parameters
    ----------
    rate_hz : float or None
        Sampling rate (Hz).

    Raises
    ------
    ValueError
        If it is not a positive finite real number.
    """
    if rate_hz is None:
        return
    ok = isinstance(rate_hz, numbers.Real) and not isinstance(rate_hz, (bool, np.bool_))
    if not ok or not np.isfinite(rate_hz) or rate_hz <= 0:
        raise ValueError(f"rate_hz must be a positive finite number (Hz); got {rate_hz!r}.")


def _check_valid_arg(valid):
    """Split ``valid`` into ``(column, accepted_values or None)``.

    Parameters
    ----------
    valid : str, tuple (str, values) or None
        Status column, optionally with the values that mean "valid".

    Returns
    -------
    column : str or None
        File column holding the status.
    accepted : list or None
        Values meaning valid, or None for the default rules.

    Raises
    ------
    ValueError
        If ``valid`` has another form.
    """
    if valid is None or isinstance(valid, str):
        return valid, None
    if isinstance(valid, tuple) and len(valid) == 2 and isinstance(valid[0], str):
        column, accepted = valid
        if isinstance(accepted, (str, numbers.Number)):
            accepted = [accepted]
        try:
            accepted = list(accepted)
        except TypeError:
            accepted = []
        if accepted:
            return column, accepted
    raise ValueError(
        "valid must be a file column name, or a tuple (column name, values that "
        f"mean valid) with at least one value; got {valid!r}."
    )


# ---------------------------------------------------------------------------
# reading the file and looking up columns
# ---------------------------------------------------------------------------
def _read_table(path, kind):
    """Read the file into a DataFrame.

    Parameters
    ----------
    path : pathlib.Path
        File to read.
    kind : {"csv", "parquet"}
        File type.

    Returns
    -------
    frame : pandas.DataFrame

    Raises
    ------
    ImportError
        If a Parquet file is read without a Parquet engine installed.
    """
    if kind == "csv":
        return pd.read_csv(path)
    try:
        return pd.read_parquet(path)
    except ImportError as exc:
        raise ImportError(
            f"Reading the Parquet file {str(path)!r} needs pyarrow: "
            f"pip install pyarrow  (or: pip install 'skcath[parquet]'). ({exc})"
        ) from exc


def _source_columns(frame, mapping, path):
    """Find the file column of every skcath name present in the file.

    Parameters
    ----------
    frame : pandas.DataFrame
        File contents.
    mapping : dict of str to str
        Explicit mapping from :func:`_check_columns_arg`.
    path : pathlib.Path
        File, for messages.

    Returns
    -------
    source : dict of str to str
        skcath name -> file column, for every skcath name found.

    Raises
    ------
    ValueError
        If an explicitly mapped column is not in the file.
    """
    present = set(frame.columns)
    source = {}
    for name in _SINGLE_NAMES:
        if name in mapping:
            file_column = mapping[name]
            if file_column not in present:
                raise ValueError(
                    f"{path.name}: columns maps {name!r} to the file column "
                    f"{file_column!r}, which the file does not have; file columns: "
                    f"{list(frame.columns)}."
                )
            source[name] = file_column
        elif name in present:
            source[name] = name
    return source


def _describe(name, source):
    """Describe a skcath column and its file column for error messages."""
    file_column = source.get(name)
    if file_column is None or file_column == name:
        return f"column {name!r}"
    return f"file column {file_column!r} (skcath column {name!r})"


def _numeric(frame, name, source, path):
    """Read one skcath column from the file as float64.

    Parameters
    ----------
    frame : pandas.DataFrame
        File contents.
    name : str
        skcath name of the column.
    source : dict of str to str
        skcath name -> file column.
    path : pathlib.Path
        File, for messages.

    Returns
    -------
    values : ndarray of shape (n_rows,), dtype float64
        A new array; empty cells are NaN.

    Raises
    ------
    ValueError
        If the column holds values that are not numbers.
    """
    series = frame[source[name]]
    if isinstance(series, pd.DataFrame):
        raise ValueError(
            f"{path.name}: the file has several columns named {source[name]!r}; "
            "column names must be unique."
        )
    if pdt.is_bool_dtype(series.dtype) or pdt.is_datetime64_any_dtype(series.dtype):
        raise ValueError(
            f"{path.name}: {_describe(name, source)} must hold numbers; got dtype "
            f"{series.dtype}."
        )
    if pdt.is_numeric_dtype(series.dtype) and not pdt.is_complex_dtype(series.dtype):
        return series.to_numpy(dtype=np.float64, na_value=np.nan, copy=True)
    parsed = pd.to_numeric(series, errors="coerce")
    values = parsed.to_numpy(dtype=np.float64, na_value=np.nan, copy=True)
    bad = np.flatnonzero(np.isnan(values) & series.notna().to_numpy(dtype=bool))
    if bad.size:
        raise ValueError(
            f"{path.name}: {_describe(name, source)} must hold numbers; "
            f"{bad.size} value(s) are not numeric, first {series.iloc[bad[0]]!r} "
            f"at row {int(bad[0])}."
        )
    return values


# ---------------------------------------------------------------------------
# building the long-format columns
# ---------------------------------------------------------------------------
def _id_values(frame, source, arguments, default_run, path):
    """Id columns: from the file, or broadcast from the arguments.

    Parameters
    ----------
    frame : pandas.DataFrame
        File contents.
    source : dict of str to str
        skcath name -> file column.
    arguments : dict
        ``{"catheter": ..., "setting": ..., "run": ...}`` given by the caller.
    default_run : str
        Run id used when neither the file nor ``run`` gives one.
    path : pathlib.Path
        File, for messages.

    Returns
    -------
    ids : dict of str to pandas.Series
        One series per id column, index ``range(n_rows)``.

    Raises
    ------
    ValueError
        If an id is given both in the file and as an argument, is missing, or
        the file column has empty cells.
    """
    n = len(frame)
    ids = {}
    for name in ID_COLUMNS:
        value = arguments[name]
        if name in source:
            if value is not None:
                raise ValueError(
                    f"{path.name}: {name}={value!r} was given, but the file already "
                    f"has {_describe(name, source)}; give one or the other."
                )
            series = frame[source[name]].reset_index(drop=True)
            empty = np.flatnonzero(series.isna().to_numpy(dtype=bool))
            if empty.size:
                raise ValueError(
                    f"{path.name}: {_describe(name, source)} has {empty.size} empty "
                    f"cell(s), first at row {int(empty[0])}; every row needs an id."
                )
            ids[name] = series
            continue
        if value is None and name == RUN:
            value = default_run
        if value is None:
            raise ValueError(
                f"{path.name}: the file has no {name!r} column; pass {name}=... to "
                f"read_recording or map the file column with columns={{{name!r}: ...}}."
            )
        ids[name] = pd.Series([value] * n)
    return ids


def _time_values(frame, source, numeric, run_ids, rate_hz, path):
    """Time (s): from the file, or sample index within the run / ``rate_hz``.

    Parameters
    ----------
    frame : pandas.DataFrame
        File contents.
    source : dict of str to str
        skcath name -> file column.
    numeric : callable
        ``numeric(name)`` reads a scaled numeric column.
    run_ids : pandas.Series
        Run id of every row.
    rate_hz : float or None
        Sampling rate (Hz).
    path : pathlib.Path
        File, for messages.

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
                f"{path.name}: rate_hz was given, but the file already has "
                f"{_describe(TIME, source)}; give one or the other."
            )
        return numeric(TIME)
    if rate_hz is None:
        raise ValueError(
            f"{path.name}: the file has no time column {TIME!r}; pass rate_hz "
            f"(sampling rate, Hz) or map the time column with columns={{{TIME!r}: ...}}."
        )
    index = run_ids.groupby(run_ids, sort=False).cumcount().to_numpy()
    return index / float(rate_hz)


def _phase_values(frame, source, run_ids, phase, n_sweep, path):
    """Phase of every row: from the file, ``phase`` or ``n_sweep``.

    Parameters
    ----------
    frame : pandas.DataFrame
        File contents.
    source : dict of str to str
        skcath name -> file column.
    run_ids : pandas.Series
        Run id of every row.
    phase : {"sweep", "motion"} or None
        Phase of every row.
    n_sweep : int or None
        Number of sweep samples at the start of each run.
    path : pathlib.Path
        File, for messages.

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
    n = len(frame)
    if PHASE in source:
        if phase is not None or n_sweep is not None:
            given = "phase" if phase is not None else "n_sweep"
            raise ValueError(
                f"{path.name}: {given} was given, but the file already has "
                f"{_describe(PHASE, source)}; give one or the other."
            )
        raw = frame[source[PHASE]]
        cleaned = _clean_text(raw)
        bad = np.flatnonzero(~cleaned.isin(PHASES).to_numpy(dtype=bool))
        if bad.size:
            raise ValueError(
                f"{path.name}: {_describe(PHASE, source)} must hold {list(PHASES)}; "
                f"first other value {raw.iloc[bad[0]]!r} at row {int(bad[0])}."
            )
        return cleaned.to_numpy(dtype=object)
    if phase is not None:
        return np.array([phase] * n, dtype=object)
    if n_sweep is None:
        raise ValueError(
            f"{path.name}: the file has no {PHASE!r} column; pass n_sweep (the first "
            f"n_sweep samples of each run are the sweep), phase={SWEEP!r} or "
            f"phase={MOTION!r}, or map the column with columns={{{PHASE!r}: ...}}."
        )
    sizes = run_ids.groupby(run_ids, sort=False).size()
    short = sizes[sizes < n_sweep]
    if len(short):
        raise ValueError(
            f"{path.name}: n_sweep={n_sweep} but run {short.index[0]!r} has only "
            f"{int(short.iloc[0])} samples; n_sweep must not exceed the length of a run."
        )
    index = run_ids.groupby(run_ids, sort=False).cumcount().to_numpy()
    return np.where(index < n_sweep, SWEEP, MOTION).astype(object)


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


def _valid_mask(frame, column, accepted, path):
    """Boolean mask of valid rows from a status column.

    Parameters
    ----------
    frame : pandas.DataFrame
        File contents.
    column : str
        File column holding the status.
    accepted : list or None
        Values meaning valid; None for the default rules (see
        :func:`read_recording`).
    path : pathlib.Path
        File, for messages.

    Returns
    -------
    valid : ndarray of bool, shape (n_rows,)

    Raises
    ------
    ValueError
        If the column is not in the file.
    """
    if column not in frame.columns:
        raise ValueError(
            f"{path.name}: valid names the status column {column!r}, which the file "
            f"does not have; file columns: {list(frame.columns)}."
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


def _target_values(numeric, source, tip_offset, invalid, path):
    """Tip position in the base frame (mm): from sensor poses or ``p_*`` columns.

    Parameters
    ----------
    numeric : callable
        ``numeric(name)`` reads a scaled numeric column.
    source : dict of str to str
        skcath name -> file column.
    tip_offset : array-like of shape (3,) or None
        Offset of the tip from the tip sensor, tip sensor frame (mm).
    invalid : ndarray of bool
        Rows whose poses are masked before the computation.
    path : pathlib.Path
        File, for messages.

    Returns
    -------
    y : ndarray of shape (n_rows, 3)

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
            block = np.column_stack([numeric(name) for name in SENSOR_POSE_COLUMNS[group]])
            block[invalid] = np.nan
            arrays[group] = block
        try:
            return tip_in_base_frame(
                arrays["tip_position"],
                arrays["base_position"],
                arrays["base_orientation"],
                quat_order="wxyz",
                tip_offset=tip_offset,
                tip_orientation=arrays.get("tip_orientation"),
            )
        except ValueError as exc:
            used = {g: [source[n] for n in SENSOR_POSE_COLUMNS[g]] for g in groups}
            raise ValueError(
                f"{path.name}: cannot compute the tip in the base frame from the "
                f"sensor-pose file columns {used}: {exc}"
            ) from None

    missing_target = [name for name in TARGET_NAMES if name not in source]
    if tip_offset is not None:
        raise ValueError(
            f"{path.name}: tip_offset needs the sensor-pose columns, but the file "
            f"lacks {missing_pose}; map them with columns=... or drop tip_offset."
        )
    if missing_target:
        raise ValueError(
            f"{path.name}: no target found. The file needs either the sensor-pose "
            f"columns (missing: {missing_pose}) or the base-frame tip columns "
            f"{list(TARGET_NAMES)} (missing: {missing_target}); map them with columns=..."
        )
    y = np.column_stack([numeric(name) for name in TARGET_NAMES])
    y[invalid] = np.nan
    return y


def _reference_values(numeric, source, y, sweep, invalid, path):
    """Reference tip (mm): from the file, or the target on sweep rows.

    Parameters
    ----------
    numeric : callable
        ``numeric(name)`` reads a scaled numeric column.
    source : dict of str to str
        skcath name -> file column.
    y : ndarray of shape (n_rows, 3)
        Target, already masked.
    sweep : ndarray of bool
        Sweep rows.
    invalid : ndarray of bool
        Rows to mask.
    path : pathlib.Path
        File, for messages.

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
            f"{path.name}: the file has the reference column(s) {found} but not "
            f"{missing}; give all three or none (then they are taken from the "
            "target on sweep rows)."
        )
    if found:
        ref = np.column_stack([numeric(name) for name in REFERENCE_COLUMNS])
    else:
        ref = np.where(sweep[:, None], y, np.nan)
    ref[invalid] = np.nan
    return ref


def _channel(numeric, source, constants, name, path):
    """A motor or torque channel: from the file or from ``constants``.

    Parameters
    ----------
    numeric : callable
        ``numeric(name)`` reads a scaled numeric column.
    source : dict of str to str
        skcath name -> file column.
    constants : dict of str to float
        Constant channels.
    name : str
        skcath name.
    path : pathlib.Path
        File, for messages.

    Returns
    -------
    values : ndarray of shape (n_rows,) or float

    Raises
    ------
    ValueError
        If the channel is both in the file and in ``constants``, or in neither.
    """
    if name in source:
        if name in constants:
            raise ValueError(
                f"{path.name}: constants sets {name!r}, but the file already has "
                f"{_describe(name, source)}; give one or the other."
            )
        return numeric(name)
    if name in constants:
        return constants[name]
    raise ValueError(
        f"{path.name}: the file has no {name!r} column; map it with "
        f"columns={{{name!r}: ...}} or set it with constants={{{name!r}: value}}."
    )


# ---------------------------------------------------------------------------
# public entry point
# ---------------------------------------------------------------------------
def read_recording(
    path,
    *,
    columns=None,
    quat_order="wxyz",
    catheter=None,
    setting=None,
    run=None,
    rate_hz=None,
    constants=None,
    scale=None,
    phase=None,
    n_sweep=None,
    valid=None,
    tip_offset=None,
):
    """Read a recording exported by another tool into the long format.

    Parameters
    ----------
    path : str or path-like
        A ``.csv`` file (also ``.csv.gz``, ``.csv.bz2``, ``.csv.xz``,
        ``.csv.zip``) read with :func:`pandas.read_csv`, or a ``.parquet``
        file read with :func:`pandas.read_parquet` (needs the optional
        dependency pyarrow).
    columns : mapping, default=None
        skcath name -> file column name, for the columns whose names differ
        (all other skcath names are looked up under their own name). Keys:
        the long-format names ``catheter, setting, run, t, phase, q1, q2,
        tau1, tau2, ref_x, ref_y, ref_z``, the base-frame tip ``p_x, p_y,
        p_z`` (mm) and the sensor-pose names ``tip_px ... base_qz``.
        Quaternion components are mapped by name (``tip_qw`` -> the file's w
        column). A whole sensor may be mapped at once with the group keys
        ``tip_position`` / ``base_position`` (3 file columns x, y, z) and
        ``tip_orientation`` / ``base_orientation`` (4 file columns listed in
        the order ``quat_order``).
    quat_order : {"wxyz", "xyzw"}, default="wxyz"
        Component order of the 4 file columns given for an orientation group
        in ``columns``. Quaternions mapped component by component do not
        depend on it.
    catheter, setting, run : str or int, default=None
        Id of all rows, for files without that column (giving an id that the
        file also has is an error). ``run`` defaults to the file name without
        its suffix: one file is one run.
    rate_hz : float, default=None
        Sampling rate (Hz) for files without a time column: ``t`` is the
        sample index within the run divided by ``rate_hz`` (s), starting at 0.
    constants : mapping, default=None
        Values of channels the file lacks, e.g. ``{"q2": 0.0, "tau2": 0.0}``
        for a one-motor rig. Keys: ``q1, q2`` (degrees), ``tau1, tau2``;
        values must be finite.
    scale : mapping, default=None
        skcath column -> multiplicative factor applied to the values read from
        the file, e.g. encoder counts to degrees or m to mm. Keys: ``t``,
        motor, torque, reference, ``p_*`` and sensor position columns (or the
        groups ``tip_position`` / ``base_position``); the column must be read
        from the file. Not applied to ``constants``.
    phase : {"sweep", "motion"}, default=None
        Phase of every row, for files without a phase column. Alternative to
        ``n_sweep``.
    n_sweep : int, default=None
        For files without a phase column: the first ``n_sweep`` samples (in
        file order) of each run are the sweep, the rest motion.
    valid : str or tuple (str, values), default=None
        File column holding a tracker status per row. Rows that are not valid
        keep their place, but their target and reference are set to NaN
        (masked, never imputed, never dropped). With a column name alone:

        - boolean column: True is valid;
        - numeric column: an error code, 0 is valid and anything else (or an
          empty cell) invalid;
        - text column: valid where the stripped, lower-cased text is one of
          :data:`VALID_STRINGS` (``"ok"``, ``"valid"``, ``"true"``,
          ``"yes"``), anything else invalid (e.g. ``"MISSING"``, ``"Out of
          volume"``).

        With ``(column, values)``, exactly the listed values are valid (e.g.
        ``("flag", [1])`` for a 0/1 flag where 1 means valid).
    tip_offset : array-like of shape (3,), default=None
        Offset of the real tip from the tip sensor in the tip sensor frame
        (mm); needs the tip orientation columns. See
        :func:`skcath.frames.tip_in_base_frame`.

    Returns
    -------
    X : pandas.DataFrame
        Exactly the long-format columns, in the standard order ``catheter,
        setting, run, t, phase, q1, q2, tau1, tau2, ref_x, ref_y, ref_z``
        (other file columns are not kept); index ``range(n_rows)``, rows in
        file order. Ids keep the type they have in the file (or as given);
        numeric columns are float64. Where the file has no reference columns,
        ``ref_*`` equal the target on sweep rows and are NaN on motion rows.
    y : ndarray of shape (n_rows, 3)
        Tip position in the base frame (mm), ``p_x, p_y, p_z``. Computed with
        :func:`skcath.frames.tip_in_base_frame` when the file has the
        sensor-pose columns (they take precedence), otherwise read from the
        ``p_*`` columns. NaN where the tracker dropped out or ``valid`` marks
        the row invalid.

    Raises
    ------
    ValueError
        On an unsupported file suffix or an invalid argument, and for every
        problem with the file: a mapped column that is missing, a channel that
        is neither in the file nor in ``constants``, non-numeric values, an
        unknown phase value, no target columns, conflicting information (an
        id, time, phase or constant given both in the file and as an
        argument). The message names the file column and the skcath column.
        The result is finally checked with
        :func:`skcath._validation.check_recordings` (time strictly increasing
        within a run, finite motor and torque channels, a sweep before the
        motion rows, ...).
    ImportError
        For a Parquet file when pyarrow is not installed.

    Notes
    -----
    The returned recording is checked with
    :func:`skcath._validation.check_recordings`. Every run must then contain
    a calibration sweep, except when the caller explicitly chose
    ``phase="motion"`` or ``n_sweep=0`` (a recording without sweep, which
    estimators that calibrate on the sweep will reject).

    Examples
    --------
    A one-motor rig exported as CSV with scalar-last quaternions and no time
    column::

        X, y = read_recording(
            "acq1.csv",
            columns={"q1": "motor_position", "tau1": "current",
                     "tip_position": ["tx", "ty", "tz"],
                     "tip_orientation": ["tqx", "tqy", "tqz", "tqw"],
                     "base_position": ["bx", "by", "bz"],
                     "base_orientation": ["bqx", "bqy", "bqz", "bqw"]},
            quat_order="xyzw", constants={"q2": 0.0, "tau2": 0.0},
            catheter="probe", setting="default", rate_hz=10.0, n_sweep=200,
        )
    """
    path = Path(path)
    kind, stem = _file_kind(path)
    options = _check_options(
        columns=columns,
        quat_order=quat_order,
        catheter=catheter,
        setting=setting,
        run=run,
        rate_hz=rate_hz,
        constants=constants,
        scale=scale,
        phase=phase,
        n_sweep=n_sweep,
        valid=valid,
        tip_offset=tip_offset,
    )
    frame = _read_table(path, kind)
    return _recording_from_frame(frame, path.name, stem, options)


def _check_options(
    *,
    columns,
    quat_order,
    catheter,
    setting,
    run,
    rate_hz,
    constants,
    scale,
    phase,
    n_sweep,
    valid,
    tip_offset,
):
    """Validate the reading options of :func:`read_recording`.

    Parameters
    ----------
    columns, quat_order, catheter, setting, run, rate_hz, constants, scale, \
phase, n_sweep, valid, tip_offset
        As in :func:`read_recording`; all required (the defaults are those of
        :func:`read_recording`, see ``_OPTION_DEFAULTS``).

    Returns
    -------
    options : dict
        Checked options, passed to :func:`_recording_from_frame`.

    Raises
    ------
    ValueError
        On an invalid option.
    """
    quat_order = check_quat_order(quat_order)
    mapping = _check_columns_arg(columns, quat_order)
    constants = _check_number_map(constants, "constants", _CONSTANT_NAMES, finite=True)
    scale = _check_number_map(
        _expand_scale(scale), "scale", _SCALABLE_NAMES, finite=True, nonzero=True
    )
    arguments = {
        CATHETER: _check_id_arg(catheter, "catheter"),
        SETTING: _check_id_arg(setting, "setting"),
        RUN: _check_id_arg(run, "run"),
    }
    _check_rate(rate_hz)
    _check_phase_args(phase, n_sweep)
    valid_column, accepted = _check_valid_arg(valid)
    return {
        "mapping": mapping,
        "constants": constants,
        "scale": scale,
        "arguments": arguments,
        "rate_hz": rate_hz,
        "phase": phase,
        "n_sweep": n_sweep,
        "valid_column": valid_column,
        "accepted": accepted,
        "tip_offset": tip_offset,
    }


#: Keyword options of :func:`read_recording` that the other readers pass on,
#: with their defaults, taken from its signature (the single place they are set).
_OPTION_DEFAULTS = {
    name: parameter.default
    for name, parameter in inspect.signature(read_recording).parameters.items()
    if parameter.kind is inspect.Parameter.KEYWORD_ONLY
}
_OPTION_NAMES = tuple(_OPTION_DEFAULTS)


def _options_from_kwargs(kwargs, caller):
    """Check the :func:`read_recording` options passed on by another reader.

    Parameters
    ----------
    kwargs : dict
        Keyword arguments given to ``caller``.
    caller : str
        Name of the reader, for messages.

    Returns
    -------
    options : dict
        Output of :func:`_check_options`.

    Raises
    ------
    TypeError
        On a keyword that is not an option of :func:`read_recording`.
    ValueError
        On an invalid option value.
    """
    unknown = sorted(set(kwargs) - set(_OPTION_NAMES))
    if unknown:
        raise TypeError(
            f"{caller}() got the unknown keyword argument(s) {unknown}; the reading "
            f"options are {list(_OPTION_NAMES)}."
        )
    return _check_options(**{**_OPTION_DEFAULTS, **kwargs})


def _recording_from_frame(frame, name, stem, options):
    """Convert a table in file column names into ``(X, y)``.

    Shared by :func:`read_recording` and the other readers of
    :mod:`skcath.io`, which first build such a table from their source.

    Parameters
    ----------
    frame : pandas.DataFrame
        Source table (not modified).
    name : str
        Name of the source, used at the start of error messages.
    stem : str
        Default run id.
    options : dict
        Output of :func:`_check_options`.

    Returns
    -------
    X : pandas.DataFrame
    y : ndarray of shape (n_rows, 3)
        As in :func:`read_recording`.

    Raises
    ------
    ValueError
        As in :func:`read_recording`.
    """
    path = PurePath(name.replace("/", "_"))
    mapping = options["mapping"]
    constants = options["constants"]
    scale = options["scale"]
    arguments = options["arguments"]
    rate_hz = options["rate_hz"]
    phase = options["phase"]
    n_sweep = options["n_sweep"]
    valid_column = options["valid_column"]
    accepted = options["accepted"]
    tip_offset = options["tip_offset"]

    if len(frame) == 0:
        raise ValueError(f"{path.name}: the file has no rows; a recording needs samples.")
    source = _source_columns(frame, mapping, path)
    for name in scale:
        if name not in source:
            raise ValueError(
                f"{path.name}: scale has a factor for {name!r}, which is not read "
                "from the file (the file has no such column after mapping)."
            )

    def numeric(name):
        return _numeric(frame, name, source, path) * scale.get(name, 1.0)

    ids = _id_values(frame, source, arguments, stem, path)
    invalid = np.zeros(len(frame), dtype=bool)
    if valid_column is not None:
        invalid = ~_valid_mask(frame, valid_column, accepted, path)

    t = _time_values(frame, source, numeric, ids[RUN], rate_hz, path)
    phases = _phase_values(frame, source, ids[RUN], phase, n_sweep, path)
    channels = {
        name: _channel(numeric, source, constants, name, path)
        for name in (*MOTOR_COLUMNS, *TORQUE_COLUMNS)
    }
    y = _target_values(numeric, source, tip_offset, invalid, path)
    ref = _reference_values(numeric, source, y, phases == SWEEP, invalid, path)

    data = dict(ids)
    data[TIME] = t
    data[PHASE] = phases
    for name, values in channels.items():
        data[name] = np.full(len(frame), values, dtype=np.float64)
    for j, name in enumerate(REFERENCE_COLUMNS):
        data[name] = ref[:, j]
    X = pd.DataFrame(data, index=pd.RangeIndex(len(frame)), columns=list(REQUIRED_COLUMNS))

    # Final check of the assembled recording (single call site).
    from .._validation import check_recordings

    require_sweep = not (phase == MOTION or n_sweep == 0)
    try:
        return check_recordings(X, y, require_sweep=require_sweep)
    except ValueError as exc:
        raise ValueError(f"{path.name}: the recording read is not valid: {exc}") from None
