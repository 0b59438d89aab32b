"""The quaternion order of the files read, checked against the data.

:func:`skcath.io.read_recordings` keeps, for every file whose target it
computed from raw sensor poses, the poses of the neutral rows of the sweeps
(:func:`skcath.frames.neutral_rows`), and hands them to
:func:`check_quat_orders` once all files are read: there the runs of a
catheter tell, through :func:`skcath.frames.fit_quat_order`, whether the base
quaternions fit the order they were read in or the other one.
"""

from dataclasses import dataclass

import numpy as np
import pandas as pd

from .._quat_order import MIN_SPREAD_RATIO, fit_quat_order, neutral_rows

__all__ = [
    "NeutralPoses",
    "check_quat_orders",
    "check_read_quat_order",
    "declared_order",
    "neutral_poses",
]

_BY_NAME = ("base_qw", "base_qx", "base_qy", "base_qz")


@dataclass(frozen=True)
class NeutralPoses:
    """The raw poses of the neutral rows of one file.

    Attributes
    ----------
    declared : {"wxyz", "xyzw"} or None
        ``quat_order`` of a ``base_orientation`` group mapped in ``columns``;
        None when the components were read by name.
    file_columns : list of str
        File columns read as ``base_qw, base_qx, base_qy, base_qz``.
    X : pandas.DataFrame
        The neutral rows of the recording read.
    tip, base : ndarray of shape (m, 3)
        Tip and base sensor positions in the tracker frame (mm).
    quats : ndarray of shape (m, 4)
        Base quaternions, ``w, x, y, z`` by the names they were read under.
    """

    declared: object
    file_columns: list
    X: pd.DataFrame
    tip: np.ndarray
    base: np.ndarray
    quats: np.ndarray


def declared_order(options):
    """``quat_order`` when ``columns`` maps the ``base_orientation`` group, else None."""
    columns = options.get("columns") or {}
    if hasattr(columns, "keys") and "base_orientation" in columns:
        return options.get("quat_order")
    return None


def neutral_poses(X, poses, declared):
    """The :class:`NeutralPoses` of a recording read, or None without sensor poses."""
    if poses is None:
        return None
    rows = neutral_rows(X)
    return NeutralPoses(
        declared=declared,
        file_columns=list(poses["file_columns"]),
        X=X.loc[rows].reset_index(drop=True),
        tip=poses["tip_position"][rows],
        base=poses["base_position"][rows],
        quats=poses["base_orientation"][rows],
    )


def _as_stored(part):
    """The base quaternions and their file columns in the declared order, and that order."""
    order = part.declared or "wxyz"
    index = ["wxyz".index(c) for c in order]
    return part.quats[:, index], [part.file_columns[i] for i in index], order


def _message(order, fit, file_columns, by_name):
    """The error for files whose quaternions fit the other order than ``order``."""
    other = fit.fitting
    listed = ", ".join(f"{c}" for c in other)
    if by_name:
        read_as = f"the columns read as {', '.join(_BY_NAME)} (file columns {file_columns})"
        fix = (
            f"they hold {listed} in that order: map them with "
            f"columns={{'base_orientation': {file_columns!r}}} and quat_order={other!r}"
        )
    else:
        read_as = f"quat_order={order!r} for the base orientation columns {file_columns}"
        fix = f"they hold {listed} in that order: pass quat_order={other!r}"
    return (
        f"The base sensor's quaternions do not fit {read_as}. Read as {other!r}, each "
        f"catheter's neutral tip points the same way in the base frame in every run "
        f"(spread {fit.spread[other]:.2f} deg over {fit.n_runs} runs); read as {order!r} it "
        f"scatters by {fit.spread[order]:.2f} deg (ratio {fit.ratio:.1f}, at least "
        f"{MIN_SPREAD_RATIO:g} tells): {fix}. To skip this check on a rig where a "
        "catheter's neutral tip does not keep its direction across runs, pass "
        "quat_check=False."
    )


def check_quat_orders(parts):
    """Raise when the base quaternions fit the other order than they were read in.

    Files are checked in groups of the same declared order (or read by name).
    A group whose runs cannot tell the orders apart passes.

    Parameters
    ----------
    parts : list of NeutralPoses
        One per file with sensor poses.

    Raises
    ------
    ValueError
        Naming the order read, the order that fits, the spreads and their ratio.
    """
    groups = {}
    for part in parts:
        groups.setdefault(part.declared, []).append(part)
    for declared, members in groups.items():
        stored = [_as_stored(part) for part in members]
        file_columns, order = stored[0][1:]
        fit = fit_quat_order(
            pd.concat([part.X for part in members], ignore_index=True),
            np.concatenate([part.tip for part in members]),
            np.concatenate([part.base for part in members]),
            np.concatenate([quats for quats, _, _ in stored]),
        )
        if fit.fitting is not None and fit.fitting != order:
            raise ValueError(_message(order, fit, file_columns, declared is None))


def check_read_quat_order(X, poses, options):
    """Raise when the base quaternions of one recording read fit the other order.

    The check of :func:`skcath.io.read_recording` (``quat_check``), shared by
    the readers of one source (a file, aligned streams).

    Parameters
    ----------
    X : pandas.DataFrame
        The recording read (long format).
    poses : dict or None
        Its raw sensor poses
        (:func:`~skcath.io._convert.recording_from_table` with
        ``with_poses=True``); None when the target was read from ``p_*``
        columns, which passes.
    options : mapping
        The reading options as given (``columns`` and ``quat_order`` are
        read).

    Raises
    ------
    ValueError
        As :func:`check_quat_orders`.
    """
    if poses is not None:
        check_quat_orders([neutral_poses(X, poses, declared_order(options))])
