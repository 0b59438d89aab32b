"""The long recording format and per-run arrays, converted both ways.

The long format holds one row per time sample; the rows of different runs may
be interleaved, and within a run they are in time order (see
``docs/data_format.rst``). Whatever needs the rows of one run takes them from
here:

- :func:`run_codes`: the run of every row, as integer codes in order of first
  appearance;
- :func:`group_positions`, :func:`run_positions`: the rows of every run, in
  row order;
- :func:`run_steps`: the index of every row within its run;
- :func:`run_differences`: the difference of every row to the previous row of
  its run;
- :func:`to_padded`, :func:`from_padded`: the runs as zero-padded arrays
  (:class:`PaddedRuns`) and back, for sequence models.

All conversions are vectorised (one stable sort of the run codes, one gather
or scatter over all rows). The input checks come from :mod:`skcath._validation`,
which imports nothing from here (it orders the rows of a run itself, to check
them); :mod:`skcath.sequences` is the public home of the padded converters.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ._format import PHASE, PHASES, RUN, TIME
from ._validation_columns import _check_columns_present, _check_frame, _column_as_float, factorize_ids
from ._validation_runs import _check_time_order
from ._validation_target import check_target

__all__ = [
    "PaddedRuns",
    "from_padded",
    "group_positions",
    "run_codes",
    "run_differences",
    "run_positions",
    "run_steps",
    "to_padded",
]


# ---------------------------------------------------------------------------
# rows of every run
# ---------------------------------------------------------------------------
def run_codes(X: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """Integer run code of every row and the run ids in order of first appearance.

    Parameters
    ----------
    X : pandas.DataFrame
        Recordings in the long format; only the ``run`` column is used.

    Returns
    -------
    codes : ndarray of shape (n_rows,), dtype intp
        ``codes[i]`` is the index into ``runs`` of the run of row ``i``.
    runs : ndarray of shape (n_runs,), dtype object
        Run ids, in order of first appearance in ``X``.

    Raises
    ------
    TypeError
        If ``X`` is not a DataFrame.
    ValueError
        If the ``run`` column is missing or contains missing ids.
    """
    _check_frame(X, caller="run_codes")
    _check_columns_present(X, (RUN,))
    return factorize_ids(X, RUN)


def group_positions(
    codes: np.ndarray, n_groups: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Row positions sorted by group, keeping row order within each group.

    Parameters
    ----------
    codes : array-like of int, shape (n_rows,)
        Non-negative group code of every row (e.g. from :func:`run_codes`).
    n_groups : int, optional
        Number of groups; defaults to ``codes.max() + 1``. Groups without rows
        get an empty slice.

    Returns
    -------
    order : ndarray of shape (n_rows,), dtype intp
        Row positions; the rows of group ``k`` are
        ``order[bounds[k]:bounds[k + 1]]``, in their original row order.
    bounds : ndarray of shape (n_groups + 1,), dtype intp
        Slice boundaries into ``order``.
    """
    codes = np.asarray(codes)
    if codes.ndim != 1 or not np.issubdtype(codes.dtype, np.integer):
        raise ValueError(
            f"codes must be a 1-D integer array, got shape {codes.shape} and "
            f"dtype {codes.dtype}."
        )
    if codes.size and codes.min() < 0:
        raise ValueError("codes must be non-negative.")
    if n_groups is None:
        n_groups = int(codes.max()) + 1 if codes.size else 0
    counts = np.bincount(codes, minlength=n_groups)
    if counts.size != n_groups:
        raise ValueError(f"codes go up to {counts.size - 1}, but n_groups={n_groups}.")
    bounds = np.zeros(n_groups + 1, dtype=np.intp)
    np.cumsum(counts, out=bounds[1:])
    if codes.size < 2 or np.all(codes[1:] >= codes[:-1]):
        order = np.arange(codes.size, dtype=np.intp)
    else:
        # A stable sort keeps row order within a group; small integer types
        # let numpy use its radix sort.
        small = np.min_scalar_type(max(n_groups - 1, 0))
        order = np.argsort(codes.astype(small, copy=False), kind="stable").astype(
            np.intp, copy=False
        )
    return order, bounds


def run_positions(X: pd.DataFrame, *, rows=None) -> list[np.ndarray]:
    """Row positions of every run, in row order.

    Parameters
    ----------
    X : pandas.DataFrame
        Recordings in the long format; only the ``run`` column is used.
    rows : array-like of bool, shape (n_rows,), optional
        Restrict to the rows where ``rows`` is True (e.g. sweep rows). Runs
        without selected rows get an empty array, so the list always has one
        entry per run.

    Returns
    -------
    positions : list of ndarray of int
        ``positions[k]`` holds the integer row positions (for ``X.iloc``) of
        the ``k``-th run in order of first appearance (see :func:`run_codes`).
    """
    codes, runs = run_codes(X)
    selected = np.arange(len(X), dtype=np.intp)
    if rows is not None:
        rows = np.asarray(rows)
        if rows.shape != (len(X),) or rows.dtype != bool:
            raise ValueError(
                f"rows must be a boolean mask of shape ({len(X)},), got shape "
                f"{rows.shape} and dtype {rows.dtype}."
            )
        selected = selected[rows]
    order, bounds = group_positions(codes[selected], len(runs))
    ordered = selected[order]
    return [ordered[bounds[k] : bounds[k + 1]] for k in range(len(runs))]


def run_steps(codes: np.ndarray, n_groups: int | None = None) -> np.ndarray:
    """Index of every row within its group, counting the group's rows in row order.

    Parameters
    ----------
    codes, n_groups
        Group code of every row and number of groups, as in
        :func:`group_positions`.

    Returns
    -------
    steps : ndarray of shape (n_rows,), dtype intp
        0 on the first row of every group, 1 on its second row, and so on;
        with one row per sample in time order, the sample index within the
        run.
    """
    order, bounds = group_positions(codes, n_groups)
    steps = np.empty(order.size, dtype=np.intp)
    steps[order] = np.arange(order.size, dtype=np.intp) - np.repeat(
        bounds[:-1], np.diff(bounds)
    )
    return steps


def run_differences(values: np.ndarray, codes: np.ndarray, n_groups: int | None = None):
    """Difference of every row to the previous row of its group.

    Parameters
    ----------
    values : ndarray of shape (n_rows, ...)
        Values of every row (e.g. motor angles in degrees), rows of a group in
        time order (groups may interleave).
    codes, n_groups
        Group code of every row and number of groups, as in
        :func:`group_positions`.

    Returns
    -------
    differences : ndarray of the shape and dtype of ``values``
        ``values[i] - values[j]`` with ``j`` the previous row of the group of
        row ``i``; 0 on the first row of every group.
    """
    order, bounds = group_positions(codes, n_groups)
    ordered = values[order]
    step = np.zeros_like(ordered)
    step[1:] = ordered[1:] - ordered[:-1]
    step[bounds[:-1][np.diff(bounds) > 0]] = 0.0  # first row of every group
    differences = np.empty_like(step)
    differences[order] = step
    return differences


# ---------------------------------------------------------------------------
# runs as padded arrays
# ---------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class PaddedRuns:
    """Runs of a long-format frame as zero-padded arrays.

    Produced by :func:`to_padded`; pass it to :func:`from_padded` to map
    per-step outputs back to the rows of the frame.

    Attributes
    ----------
    values : ndarray of shape (n_runs, T_max, n_features)
        Feature values; step ``s`` of run ``k`` is the ``s``-th selected row of
        that run in row order. Padding steps are 0.
    mask : ndarray of bool, shape (n_runs, T_max)
        True on real steps, False on padding.
    target : ndarray of shape (n_runs, T_max, 3) or None
        Tip position (mm) when ``y`` was given. Steps with any non-finite
        coordinate (tracker dropouts) and padding are set to 0 in all three
        coordinates, so a loss never sees NaN; use ``target_mask``.
    target_mask : ndarray of bool, shape (n_runs, T_max) or None
        ``mask`` and all three target coordinates finite.
    runs : ndarray of shape (n_runs,), dtype object
        Run ids in order of first appearance in the frame. Runs without
        selected rows are kept, with length 0, so the run order does not
        depend on the phase selection.
    positions : ndarray of int64, shape (n_runs, T_max)
        Integer row position (for ``X.iloc``) of every step; -1 on padding.
    lengths : ndarray of int64, shape (n_runs,)
        Number of real steps of every run.
    columns : tuple of str
        Feature names, in the order of the last axis of ``values``.
    n_rows : int
        Number of rows of the frame (``len(X)``).
    """

    values: np.ndarray
    mask: np.ndarray
    target: np.ndarray | None
    target_mask: np.ndarray | None
    runs: np.ndarray
    positions: np.ndarray
    lengths: np.ndarray
    columns: tuple
    n_rows: int

    @property
    def n_runs(self) -> int:
        """Number of runs (first axis)."""
        return int(self.positions.shape[0])

    @property
    def max_length(self) -> int:
        """Padded sequence length ``T_max`` (second axis)."""
        return int(self.positions.shape[1])

    def __repr__(self) -> str:
        target = "None" if self.target is None else f"shape {self.target.shape}"
        return (
            f"PaddedRuns(n_runs={self.n_runs}, max_length={self.max_length}, "
            f"columns={self.columns!r}, values dtype={self.values.dtype}, "
            f"target={target}, n_rows={self.n_rows})"
        )


def _as_column_tuple(columns) -> tuple:
    """Normalise ``columns`` (a name or a sequence of names) to a tuple."""
    if isinstance(columns, str):
        return (columns,)
    if not isinstance(columns, Sequence) and not isinstance(columns, pd.Index):
        raise TypeError(
            f"columns must be a column name or a sequence of column names, got "
            f"{type(columns).__name__}."
        )
    return tuple(columns)


def _selected_rows(X: pd.DataFrame, phase) -> np.ndarray:
    """Row positions of the selected phase (all rows when ``phase`` is None)."""
    if phase is None:
        return np.arange(len(X), dtype=np.intp)
    if not isinstance(phase, str) or phase not in PHASES:
        raise ValueError(f"phase must be None or one of {list(PHASES)}, got {phase!r}.")
    _check_columns_present(X, (PHASE,))
    selected = (X[PHASE] == phase).to_numpy(dtype=bool, na_value=False)
    return np.flatnonzero(selected)


def _feature_matrix(X: pd.DataFrame, columns: tuple, dtype) -> np.ndarray:
    """Stack ``columns`` of ``X`` into an (n_rows, n_features) array of ``dtype``."""
    features = np.empty((len(X), len(columns)), dtype=dtype)
    for j, column in enumerate(columns):
        features[:, j] = _column_as_float(X, column)
    return features


def _pad(source: np.ndarray, positions: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Gather ``source[positions]`` into a padded array, 0 where ``mask`` is False."""
    padded = np.zeros(positions.shape + source.shape[1:], dtype=source.dtype)
    padded[mask] = source[positions[mask]]
    return padded


def to_padded(
    X: pd.DataFrame,
    columns,
    *,
    y=None,
    phase: str | None = None,
    dtype=np.float32,
) -> PaddedRuns:
    """Gather the rows of every run into zero-padded arrays.

    Parameters
    ----------
    X : pandas.DataFrame
        Recordings in the long format (see ``docs/data_format.rst``), usually
        the output of :func:`skcath.check_recordings`. Rows of different runs
        may be interleaved; within a run, rows must be in time order (checked
        when the ``t`` column is present).
    columns : str or sequence of str
        Numeric feature columns, in the order of the last axis of ``values``.
        Values are copied as they are: NaN in a feature stays NaN.
    y : array-like or pandas.DataFrame of shape (n_rows, 3), optional
        Tip position in the base frame (mm), matched to ``X`` by row position;
        NaN rows (tracker dropouts) are allowed.
    phase : {None, "sweep", "motion"}, default None
        Keep only the rows of this phase (None keeps all rows).
    dtype : numpy dtype, default numpy.float32
        Floating dtype of ``values`` and ``target``.

    Returns
    -------
    PaddedRuns
        ``values`` (n_runs, T_max, n_features), ``mask``, ``target`` and
        ``target_mask`` (when ``y`` is given), ``runs``, ``positions``,
        ``lengths``, ``columns`` and ``n_rows``. Runs are in order of first
        appearance in ``X``; a run without rows of the selected phase is kept
        with length 0 (all-False mask). ``T_max`` is the longest selected run
        (0 if no row is selected).

    Raises
    ------
    TypeError
        If ``X`` is not a DataFrame or ``columns`` is not a name or sequence.
    ValueError
        If a column is missing or non-numeric, ``phase`` is invalid, a run id
        is missing, time decreases within a run, or ``y`` is malformed.

    Notes
    -----
    Convert to torch with ``torch.from_numpy(padded.values)``; for a
    PyTorch ``pack_padded_sequence``, ``lengths`` holds the sequence lengths.
    """
    _check_frame(X, caller="to_padded")
    columns = _as_column_tuple(columns)
    dtype = np.dtype(dtype)
    if dtype.kind != "f":
        raise ValueError(f"dtype must be a floating dtype, got {dtype}.")
    _check_columns_present(X, columns)

    codes, runs = factorize_ids(X, RUN)
    if TIME in X.columns:
        order, _ = group_positions(codes, len(runs))
        _check_time_order(X, _column_as_float(X, TIME), codes, runs, order)

    selected = _selected_rows(X, phase)
    run_of_row = codes[selected]
    lengths = np.bincount(run_of_row, minlength=len(runs)).astype(np.int64)
    max_length = int(lengths.max()) if lengths.size else 0
    positions = np.full((len(runs), max_length), -1, dtype=np.int64)
    positions[run_of_row, run_steps(run_of_row, len(runs))] = selected
    mask = positions >= 0

    values = _pad(_feature_matrix(X, columns, dtype), positions, mask)

    target = target_mask = None
    if y is not None:
        y_checked = check_target(y, len(X))
        finite = np.isfinite(y_checked).all(axis=1)
        target_mask = mask.copy()
        target_mask[mask] = finite[positions[mask]]
        target = np.zeros(positions.shape + (3,), dtype=dtype)
        target[target_mask] = y_checked[positions[target_mask]]

    return PaddedRuns(
        values=values,
        mask=mask,
        target=target,
        target_mask=target_mask,
        runs=runs,
        positions=positions,
        lengths=lengths,
        columns=columns,
        n_rows=len(X),
    )


def from_padded(values, padded: PaddedRuns) -> np.ndarray:
    """Scatter per-step values back to the rows of the original frame.

    Parameters
    ----------
    values : ndarray of shape (n_runs, T_max, ...)
        Per-step outputs aligned with ``padded`` (e.g. a model's predictions of
        shape ``(n_runs, T_max, k)``). numpy only: convert a torch tensor with
        ``tensor.detach().cpu().numpy()``. Values on padding steps are ignored.
    padded : PaddedRuns
        The result of :func:`to_padded` the outputs were computed from.

    Returns
    -------
    out : ndarray of float64, shape (n_rows, ...)
        ``out[i]`` is the value of the step of row ``i``; rows that were not
        selected (other phase) are NaN. With ``values`` of shape
        ``(n_runs, T_max, k)`` the result has shape ``(n_rows, k)``.

    Raises
    ------
    TypeError
        If ``values`` is a torch tensor or ``padded`` is not a PaddedRuns.
    ValueError
        If the leading shape of ``values`` is not ``(n_runs, T_max)``.
    """
    if not isinstance(padded, PaddedRuns):
        raise TypeError(
            f"padded must be the PaddedRuns returned by to_padded, got "
            f"{type(padded).__name__}."
        )
    if hasattr(values, "detach") and not isinstance(values, np.ndarray):
        raise TypeError(
            "from_padded expects a numpy array; convert a torch tensor with "
            "tensor.detach().cpu().numpy()."
        )
    values = np.asarray(values)
    expected = padded.positions.shape
    if values.ndim < 2 or values.shape[:2] != expected:
        raise ValueError(
            f"values must have shape (n_runs, T_max, ...) = ({expected[0]}, "
            f"{expected[1]}, ...) to match the padded runs; got shape {values.shape}."
        )
    if values.dtype.kind not in "biuf":
        raise ValueError(f"values must be real numbers, got dtype {values.dtype}.")
    out = np.full((padded.n_rows,) + values.shape[2:], np.nan, dtype=np.float64)
    out[padded.positions[padded.mask]] = values[padded.mask]
    return out

