"""Read NDI Aurora / Track CSV exports into a tracker stream.

NDI tools write one of two CSV layouts:

- *wide*: one row per frame, the tools side by side, each tool a block of
  columns such as ``Port, State, Q0, Qx, Qy, Qz, Tx, Ty, Tz, Error`` (the
  block names repeat for every tool);
- *long*: one row per tool per frame, with a tool column (``Port``,
  ``ToolHandle``, ...) that says which tool the row belongs to.

:func:`read_ndi_csv` accepts both and returns the tip and base poses in the
raw sensor-pose columns of skcath (``tip_px ... base_qz``), one row per frame.
"""

import csv
import io
import numbers
import re
from pathlib import Path

import numpy as np
import pandas as pd

from .._format import SENSOR_POSE_COLUMNS
from .._validation import check_quat_order
from ._csv import read_csv_text
from ._errors import naming_the_file

__all__ = ["read_ndi_csv"]

#: Header names (lower case, without spaces, ``#`` and ``_``) of each role.
_FRAME_NAMES = frozenset({"frame", "frame#", "framenumber", "frameno"})
_TIME_NAMES = frozenset({"timestamp", "time", "t", "times", "hosttime", "systemtime"})
_TOOL_NAMES = frozenset(
    {"port", "porthandle", "porthandles", "toolhandle", "handle", "tool", "toolname",
     "name", "toolid"}
)
_STATUS_NAMES = frozenset({"state", "status", "toolstatus", "toolstate"})
_QUAT_NAMES = frozenset({"q0", "qw", "qx", "qy", "qz", "q1", "q2", "q3", "q4"})
_POSITION_NAMES = (("tx", "ty", "tz"), ("x", "y", "z"))
#: Cell texts written by NDI software in place of numbers for a lost pose.
_DROPOUT_TEXTS = frozenset(
    {"missing", "disabled", "outofvolume", "partiallyoutofvolume", "invalid",
     "nan", "none", ""}
)


def _key(name):
    """Normalise a header name: lower case without spaces, ``#`` kept, ``_`` dropped."""
    return re.sub(r"[\s_]+", "", str(name)).lower()


def _read_rows(path):
    """Read the header and the rows of a CSV file as text, rows padded.

    The file is read by :func:`~skcath.io._csv.read_csv_text`: its delimiter
    and decimal mark are found in the text (decimal commas become points),
    and a cut last line is dropped with a warning.

    Parameters
    ----------
    path : pathlib.Path
        CSV file.

    Returns
    -------
    header : list of str
    rows : list of list of str
        Every row has ``len(header)`` cells (rows with marker data longer
        than the header are cut, short rows padded with empty cells).

    Raises
    ------
    ValueError
        If the file cannot be read, is empty or has no rows; the message
        names the file.
    """
    found = read_csv_text(path, wider_rows=True)
    with naming_the_file(path, "CSV"):
        reader = csv.reader(io.StringIO(found.text, newline=""), delimiter=found.sep)
        header = [cell.strip() for cell in next(reader)]
        n = len(header)
        rows = [(row + [""] * n)[:n] for row in reader if any(c.strip() for c in row)]
    if found.decimal == ",":
        rows = [[cell.replace(",", ".") for cell in row] for row in rows]
    if not rows:
        raise ValueError(f"{path.name}: the file has a header but no rows.")
    return header, rows


def _tool_blocks(header, path):
    """Locate the column blocks of the tools in the header.

    Parameters
    ----------
    header : list of str
        Header of the file.
    path : pathlib.Path
        File, for messages.

    Returns
    -------
    blocks : list of dict
        One per tool block, with the column indices ``quat`` (4 indices in
        file order), ``position`` (3), and ``tool``, ``status`` (index or
        None).

    Raises
    ------
    ValueError
        If no quaternion block or no position columns are found.
    """
    keys = [_key(name) for name in header]
    starts = []
    i = 0
    while i <= len(keys) - 4:
        if all(k in _QUAT_NAMES for k in keys[i : i + 4]):
            starts.append(i)
            i += 4
        else:
            i += 1
    if not starts:
        raise ValueError(
            f"{path.name}: no quaternion columns found; expected four adjacent "
            f"columns such as Q0, Qx, Qy, Qz. Header: {header}."
        )
    blocks = []
    for k, start in enumerate(starts):
        lower = starts[k - 1] + 4 if k else 0
        upper = starts[k + 1] if k + 1 < len(starts) else len(keys)

        def last_before(names):
            for j in range(start - 1, lower - 1, -1):
                if keys[j] in names:
                    return j
            return None

        position = None
        for j in range(start + 4, upper):
            for triple in _POSITION_NAMES:
                if tuple(keys[j : j + 3]) == triple:
                    position = [j, j + 1, j + 2]
                    break
            if position is not None:
                break
        if position is None:
            raise ValueError(
                f"{path.name}: the quaternion columns {header[start : start + 4]} "
                f"are not followed by position columns (Tx, Ty, Tz or x, y, z). "
                f"Header: {header}."
            )
        blocks.append(
            {
                "quat": list(range(start, start + 4)),
                "position": position,
                "tool": last_before(_TOOL_NAMES),
                "status": last_before(_STATUS_NAMES),
            }
        )
    return blocks


def _first(keys, names):
    """Index of the first header key in ``names``, or None."""
    for j, key in enumerate(keys):
        if key in names:
            return j
    return None


def _pose_numbers(rows, index, header, path, dropout):
    """Parse one pose column; dropout words and invalid rows become NaN.

    Parameters
    ----------
    rows : list of list of str
        File rows.
    index : int
        Column index.
    header : list of str
        Header, for messages.
    path : pathlib.Path
        File, for messages.
    dropout : ndarray of bool
        Rows whose status marks the tool as not tracked.

    Returns
    -------
    values : ndarray of shape (n_rows,)

    Raises
    ------
    ValueError
        If a tracked row holds text that is neither a number nor a dropout word.
    """
    text = pd.Series([row[index] for row in rows], dtype=object)
    values = pd.to_numeric(text, errors="coerce").to_numpy(dtype=np.float64, copy=True)
    bad = np.isnan(values) & ~dropout
    bad &= ~text.map(lambda s: _key(s) in _DROPOUT_TEXTS).to_numpy(dtype=bool)
    bad_rows = np.flatnonzero(bad)
    if bad_rows.size:
        r = int(bad_rows[0])
        raise ValueError(
            f"{path.name}: column {header[index]!r} (column {index}) must hold numbers; "
            f"got {rows[r][index]!r} at data row {r}."
        )
    values[dropout] = np.nan
    return values


def _tool_value(value):
    """Tool ids are compared as stripped, upper-case text (``"10a"`` == ``"10A"``)."""
    if isinstance(value, numbers.Integral) and not isinstance(value, bool):
        return str(int(value))
    if isinstance(value, str) and value.strip():
        return value.strip().upper()
    raise ValueError(
        f"a tool must be given by its port handle, port or name (str or int); got {value!r}."
    )


def _check_tools(tip, base, valid_states):
    """Tool ids of the tip and base sensors, and the accepted status keys.

    Raises
    ------
    ValueError
        If a tool is not a str or int, both name the same tool, or
        ``valid_states`` is not a sequence of strings.
    """
    tip_id = _tool_value(tip)
    base_id = None if base is None else _tool_value(base)
    if base_id is not None and base_id == tip_id:
        raise ValueError(f"tip and base name the same tool {tip!r}; give two tools.")
    if isinstance(valid_states, str) or not all(isinstance(s, str) for s in valid_states):
        raise ValueError(
            f"valid_states must be a sequence of status strings; got {valid_states!r}."
        )
    return tip_id, base_id, {_key(s) for s in valid_states}


def _block_poses(rows, header, blocks, accepted, quat_order, path):
    """Every tool block as one long table: row index, tool id, pose.

    Returns
    -------
    poses : pandas.DataFrame
        Columns ``row``, ``tool`` and ``qw, qx, qy, qz, px, py, pz``; one
        row per file row and block, rows without a tool id left out.
    """
    n = len(rows)
    parts = []
    for number, block in enumerate(blocks, start=1):
        if block["tool"] is None:
            tools = np.full(n, str(number), dtype=object)
        else:
            tools = np.array([row[block["tool"]].strip().upper() for row in rows], dtype=object)
        if block["status"] is None:
            dropout = np.zeros(n, dtype=bool)
        else:
            dropout = np.array(
                [_key(row[block["status"]]) not in accepted for row in rows], dtype=bool
            )
        quat = [_pose_numbers(rows, j, header, path, dropout) for j in block["quat"]]
        pose = {f"q{c}": quat[quat_order.index(c)] for c in "wxyz"}
        for c, j in zip("xyz", block["position"]):
            pose[f"p{c}"] = _pose_numbers(rows, j, header, path, dropout)
        part = pd.DataFrame(pose)
        part.insert(0, "tool", tools)
        part.insert(0, "row", np.arange(n))
        parts.append(part)
    poses = pd.concat(parts, ignore_index=True)
    return poses[poses["tool"] != ""]


def _frame_meta(rows, header, path):
    """Frame number and timestamp of every file row, where the file has them.

    Returns
    -------
    meta : pandas.DataFrame
        Column ``row`` and, if found, ``frame`` (integers when whole) and
        ``t`` (the file's unit).

    Raises
    ------
    ValueError
        If a frame or time cell is not a number.
    """
    keys = [_key(name) for name in header]
    meta = pd.DataFrame({"row": np.arange(len(rows))})
    for name, col in (("frame", _first(keys, _FRAME_NAMES)), ("t", _first(keys, _TIME_NAMES))):
        if col is None:
            continue
        text = pd.Series([row[col] for row in rows], dtype=object)
        values = pd.to_numeric(text, errors="coerce")
        bad = np.flatnonzero(values.isna().to_numpy())
        if bad.size:
            raise ValueError(
                f"{path.name}: column {header[col]!r} must hold numbers; got "
                f"{rows[int(bad[0])][col]!r} at data row {int(bad[0])}."
            )
        values = values.to_numpy(dtype=np.float64)
        if name == "frame" and np.all(values == np.round(values)):
            values = values.astype(np.int64)
        meta[name] = values
    return meta


def _frame_key(wide, meta, header, path):
    """Columns that identify a frame: the file row (wide), else frame number or time."""
    if wide:
        return ["row"]
    if "frame" in meta:
        return ["frame"]
    if "t" in meta:
        return ["t"]
    raise ValueError(
        f"{path.name}: one row per tool but neither a frame number nor a "
        f"timestamp column to match the tools of one frame. Header: {header}."
    )


def _sensor_pose(poses, key, sensor, tool, path):
    """The pose of one tool in every frame, in the skcath sensor-pose column names.

    Raises
    ------
    ValueError
        If the tool is not in the file (the message lists the tools present)
        or appears twice in one frame.
    """
    chosen = poses[poses["tool"] == tool]
    if chosen.empty:
        present = sorted(poses["tool"].unique().tolist())
        raise ValueError(
            f"{path.name}: {sensor}={tool!r} is not a tool of this file; tools "
            f"present: {present}."
        )
    duplicated = chosen.duplicated(subset=key)
    if duplicated.any():
        at = chosen.loc[duplicated, key[0]].iloc[0]
        raise ValueError(
            f"{path.name}: tool {tool!r} appears more than once in one frame "
            f"({key[0]} = {at!r})."
        )
    names = {
        **{f"p{c}": n for c, n in zip("xyz", SENSOR_POSE_COLUMNS[f"{sensor}_position"])},
        **{f"q{n[-1]}": n for n in SENSOR_POSE_COLUMNS[f"{sensor}_orientation"]},
    }
    return chosen[key + list(names)].rename(columns=names)


def read_ndi_csv(
    path,
    *,
    tip,
    base=None,
    quat_order="wxyz",
    valid_states=("OK", "Enabled", "Valid"),
):
    """Read an NDI Aurora / Track CSV export into a tracker stream.

    Parameters
    ----------
    path : str or path-like
        CSV file written by NDI ToolBox / Track (or in the same layout):
        either one row per frame with the tools side by side (*wide*), each
        tool a block ``[Port|ToolHandle], [State|Status], Q0, Qx, Qy, Qz,
        Tx, Ty, Tz[, Error]``, or one row per tool per frame (*long*) with a
        tool column. Header names are matched case-insensitively, ignoring
        spaces and underscores. Columns that follow the block (markers, ...)
        are ignored. The delimiter and decimal mark are found in the file,
        and a cut last line is dropped with a warning, as in
        :func:`skcath.io.read_recording`.
    tip : str or int
        Tool carrying the tip sensor: the value of its tool column (port
        handle such as ``"0A"`` or ``10``, port, or tool name, compared as
        case-insensitive text). In a file without tool column, the tool
        blocks are numbered 1, 2, ... from left to right.
    base : str or int, default=None
        Tool carrying the base sensor, identified like ``tip``. None reads the
        tip only (then the base pose must come from elsewhere).
    quat_order : {"wxyz", "xyzw"}, default="wxyz"
        Order of the four quaternion columns of a block, from left to right.
        NDI writes scalar first (``Q0, Qx, Qy, Qz``).
    valid_states : sequence of str, default=("OK", "Enabled", "Valid")
        Values of the status column that mark a pose as tracked (compared
        case-insensitively). Any other status (``"Missing"``,
        ``"Disabled"``, ``"Out of Volume"``, ...) makes the pose NaN.

    Returns
    -------
    stream : pandas.DataFrame
        One row per frame, in file order, with the columns ``frame`` (the
        frame number, if the file has one), ``t`` (the file's timestamp
        column, in the file's unit, if it has one), ``tip_px, tip_py,
        tip_pz`` (mm), ``tip_qw, tip_qx, tip_qy, tip_qz`` and, with
        ``base``, the same for ``base_``. A pose that was not tracked (bad
        status, a ``"Missing"`` cell, an empty cell, or no row for that tool
        in that frame) is NaN: a dropout, which stays in the stream. Pass the
        stream to :func:`skcath.io.align_streams` with a motor log.

    Raises
    ------
    ValueError
        If the file cannot be read (the message starts with the file name),
        has no quaternion/position block (the message shows the header), a
        tool is not found (the message lists the tools present), a tool
        appears twice in one frame, or a tracked pose cell is not a number.

    Warns
    -----
    skcath.exceptions.TruncatedFileWarning
        When the last line looks cut; it is dropped.

    Notes
    -----
    In the long layout frames are matched by frame number (NDI recommends
    trusting the frame number over the host clock) or, without one, by the
    timestamp. In the wide layout both tools come from the same row.

    Examples
    --------
    ::

        tracker = read_ndi_csv("aurora.csv", tip="0A", base="0B")
    """
    path = Path(path)
    quat_order = check_quat_order(quat_order)
    tip_id, base_id, accepted = _check_tools(tip, base, valid_states)

    header, rows = _read_rows(path)
    blocks = _tool_blocks(header, path)
    poses = _block_poses(rows, header, blocks, accepted, quat_order, path)
    meta = _frame_meta(rows, header, path)
    key = _frame_key(len(blocks) > 1 or poses["tool"].nunique() <= 1, meta, header, path)
    poses = poses.merge(meta, on="row", how="left")
    frames = meta.drop_duplicates(subset=key, keep="first") if key != ["row"] else meta

    stream = frames.reset_index(drop=True)
    for sensor, tool in (("tip", tip_id), ("base", base_id)):
        if tool is not None:
            stream = stream.merge(_sensor_pose(poses, key, sensor, tool, path), on=key, how="left")
    stream = stream.drop(columns="row")
    # the left merge keeps the order of ``frames``: file order
    return stream.reset_index(drop=True)
