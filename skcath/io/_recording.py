"""Read one recording file (CSV or Parquet) into the long recording format.

:func:`read_recording` reads one CSV or Parquet file, renames its columns to
the skcath names, fills the channels the file lacks from arguments, computes
the target (tip position in the base frame, mm) from raw EM sensor poses when
needed, and returns ``(X, y)`` in the long format described in
``docs/data_format.rst``. The options are checked by
:class:`~skcath.io._options.ReadingOptions` and the columns derived by
:func:`~skcath.io._convert.recording_from_table`.
"""

import io
from pathlib import Path

import pandas as pd

from ._convert import recording_from_table
from ._csv import read_csv_text
from ._errors import naming_the_file
from ._options import ReadingOptions
from ._quat import check_read_quat_order

__all__ = [
    "CSV_SUFFIXES",
    "PARQUET_SUFFIXES",
    "file_kind",
    "read_recording",
    "read_table",
    "read_with_poses",
]

#: File name endings read as CSV (compressed CSV included) and as Parquet.
CSV_SUFFIXES = (".csv", ".csv.gz", ".csv.bz2", ".csv.xz", ".csv.zip")
PARQUET_SUFFIXES = (".parquet",)


def file_kind(path):
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
    for kind, suffixes in (("csv", CSV_SUFFIXES), ("parquet", PARQUET_SUFFIXES)):
        for suffix in suffixes:
            if name.endswith(suffix) and len(name) > len(suffix):
                return kind, path.name[: -len(suffix)]
    raise ValueError(
        f"path must name a CSV ({', '.join(CSV_SUFFIXES)}) or Parquet "
        f"({', '.join(PARQUET_SUFFIXES)}) file; got {str(path)!r}."
    )


def read_table(path, kind):
    """Read the file into a DataFrame.

    A CSV file is read with the delimiter and decimal mark found in its text,
    without a cut last line (see :func:`~skcath.io._csv.read_csv_text`).

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
    ValueError
        If the file cannot be read as its type; the message names the file.
    ImportError
        If a Parquet file is read without a Parquet engine installed.

    Warns
    -----
    skcath.exceptions.TruncatedFileWarning
        When the last line of a CSV file looks cut; it is dropped.
    """
    if kind == "csv":
        found = read_csv_text(path)
        with naming_the_file(path, "CSV"):
            return pd.read_csv(io.StringIO(found.text), sep=found.sep, decimal=found.decimal)
    try:
        with naming_the_file(path, "Parquet"):
            return pd.read_parquet(path)
    except ImportError as exc:
        raise ImportError(
            f"Reading the Parquet file {str(path)!r} needs pyarrow: "
            f"pip install pyarrow  (or: pip install 'skcath[parquet]'). ({exc})"
        ) from exc


def read_recording(
    path,
    *,
    columns=None,
    quat_order=None,
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
    torques=True,
    quat_check=True,
):
    """Read a recording exported by another tool into the long format.

    Parameters
    ----------
    path : str or path-like
        A ``.csv`` file (also ``.csv.gz``, ``.csv.bz2``, ``.csv.xz``,
        ``.csv.zip``), read as UTF-8 text with the delimiter (``,``, ``;`` or
        tab) and decimal mark (``.`` or, in a ``;`` or tab file, ``,``) found
        in the file, or a ``.parquet`` file read with
        :func:`pandas.read_parquet` (needs the optional dependency pyarrow).
    columns : mapping, default=None
        skcath name -> file column name, for the columns whose names differ
        (all other skcath names are looked up under their own name). Keys:
        the long-format names ``catheter, setting, run, t, phase, q1 .. qN,
        tau1 .. tauN, ref_x, ref_y, ref_z``, the base-frame tip ``p_x, p_y,
        p_z`` (mm) and the sensor-pose names ``tip_px ... base_qz``.
        Quaternion components are mapped by name (``tip_qw`` -> the file's w
        column). A whole sensor may be mapped at once with the group keys
        ``tip_position`` / ``base_position`` (3 file columns x, y, z) and
        ``tip_orientation`` / ``base_orientation`` (4 file columns listed in
        the order ``quat_order``).
    quat_order : {"wxyz", "xyzw"}, default=None
        Component order of the 4 file columns given for an orientation group
        in ``columns``: ``"wxyz"`` (scalar first) or ``"xyzw"`` (scalar
        last). Required when ``columns`` maps an orientation group, since
        skcath never guesses it; quaternions read under their skcath names
        (``tip_qw, ...``) or mapped component by component do not depend on
        it.
    catheter, setting, run : str or int, default=None
        Id of all rows, for files without that column (giving an id that the
        file also has is an error). ``run`` defaults to the file name without
        its suffix: one file is one run.
    rate_hz : float, default=None
        Sampling rate (Hz) for files without a time column: ``t`` is the
        sample index within the run divided by ``rate_hz`` (s), starting at 0.
    constants : mapping, default=None
        Values of channels the file lacks, e.g. ``{"q2": 0.0, "tau2": 0.0}``
        to read a one-motor rig as a two-motor one. Keys: motor angles
        ``qk`` (degrees), torques ``tauk``; values must be finite. The
        number of motors ``N`` is the largest ``k`` of a channel ``qk`` or
        ``tauk`` in the file (after ``columns``) or in ``constants``; every
        channel up to ``N`` must then be in one of them.
    scale : mapping, default=None
        skcath column -> multiplicative factor applied to the values read from
        the file, e.g. encoder counts to degrees or m to mm. Keys: ``t``,
        motor, torque, reference, ``p_*`` and sensor position columns (or the
        groups ``tip_position`` / ``base_position``); the column must be read
        from the file. Not applied to ``constants``.
    phase : {"sweep", "motion"}, default=None
        Phase of every row, for files without a phase column. Alternative to
        ``n_sweep``.
    n_sweep : int or "auto", default=None
        For files without a phase column: the first ``n_sweep`` samples (in
        file order) of each run are the sweep, the rest motion. ``"auto"``
        finds where each run's sweep ends from its motor angles and times
        (:func:`skcath.sweep.find_sweep_end`; ``docs/sweep_recording.rst``
        says what the robot must run), and raises an error naming the file
        and the run when the start of a run is not a sweep. A given number is
        kept in ``X.attrs["n_sweep"]`` (run id -> n_sweep), so that the error
        of a backbone that cannot find the rays in such a sweep names
        ``n_sweep`` and the sweep end found from the motor angles.
    valid : str or tuple (str, values), default=None
        File column holding a tracker status per row. Rows that are not valid
        keep their place, but their target and reference are set to NaN
        (masked, never imputed, never dropped). With a column name alone:

        - boolean column: True is valid;
        - numeric column: an error code, 0 is valid and anything else (or an
          empty cell) invalid;
        - text column: valid where the stripped, lower-cased text is one of
          :data:`skcath.io.VALID_STRINGS` (``"ok"``, ``"valid"``, ``"true"``,
          ``"yes"``), anything else invalid (e.g. ``"MISSING"``, ``"Out of
          volume"``).

        With ``(column, values)``, exactly the listed values are valid (e.g.
        ``("flag", [1])`` for a 0/1 flag where 1 means valid).
    tip_offset : array-like of shape (3,), default=None
        Offset of the real tip from the tip sensor in the tip sensor frame
        (mm); needs the tip orientation columns. See
        :func:`skcath.frames.tip_in_base_frame`.
    torques : bool, default=True
        Whether the file has drive torques: ``tau1 .. tauN`` are read (a
        missing one is an error). False for a rig without torque sensing:
        no torque is read, and ``X`` has no torque column (learners then
        need ``use_torque=False``).
    quat_check : bool, default=True
        When the file holds several runs of a catheter and the target is
        computed from raw sensor poses, check the quaternion order against
        the data as :func:`skcath.io.read_recordings` does (a ValueError
        names the order that fits). One run cannot tell the orders apart,
        so a file of one run passes. False skips the check.

    Returns
    -------
    X : pandas.DataFrame
        Exactly the long-format columns, in the standard order ``catheter,
        setting, run, t, phase, q1 .. qN, tau1 .. tauN, ref_x, ref_y, ref_z``
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
        On an unsupported file suffix or an invalid argument (an orientation
        group in ``columns`` without ``quat_order`` included), and for every
        problem with the file: a file that cannot be read (cut short
        compressed data, bytes that are not UTF-8 text, an empty file, a
        damaged Parquet file, a CSV line with more fields than the header; the
        message starts with the file name and chains the parser's error), a
        mapped column that is missing (the message lists the file's columns),
        a channel that
        is neither in the file nor in ``constants``, non-numeric values, an
        unknown phase value, no target columns, conflicting information (an
        id, time, phase or constant given both in the file and as an
        argument). The message names the file column and the skcath column.
        The result is finally checked with
        :func:`skcath._validation.check_recordings` (time strictly increasing
        within a run, finite motor and torque channels, a sweep before the
        motion rows, ...). With ``quat_check``, also when the base
        quaternions of a file of several runs fit the other order.
    ImportError
        For a Parquet file when pyarrow is not installed.
    FileNotFoundError
        If ``path`` does not exist.

    Warns
    -----
    skcath.exceptions.TruncatedFileWarning
        When the last line of a CSV file looks cut (no final line break, or
        fewer fields than the header and the line before it), as a recording
        interrupted while the file was written leaves it; that line is
        dropped.

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
            quat_order="xyzw", catheter="probe", setting="default", rate_hz=10.0,
            n_sweep=200,
        )

    ``X`` then has the columns ``q1``, ``tau1`` of one motor.
    """
    X, y, poses = read_with_poses(
        path,
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
        torques=torques,
    )
    if quat_check:
        check_read_quat_order(X, poses, {"columns": columns, "quat_order": quat_order})
    return X, y


def read_with_poses(path, *, with_poses=True, **options):
    """:func:`read_recording`, also returning the raw sensor poses when asked.

    Parameters
    ----------
    path : str or path-like
        File to read.
    with_poses : bool, default=True
        Return ``(X, y, poses)`` as
        :func:`~skcath.io._convert.recording_from_table` does, instead of
        ``(X, y)``.
    **options
        Reading options of :func:`read_recording`.
    """
    path = Path(path)
    kind, stem = file_kind(path)
    checked = ReadingOptions(**options)  # before the file is read
    table = read_table(path, kind)
    return recording_from_table(table, path.name, stem, checked, with_poses=with_poses)
