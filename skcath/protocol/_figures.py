"""Figures of the evaluation protocol, drawn from its summary tables.

Every function takes one of the summary tables that the protocol computes (a
pandas DataFrame with fixed column names, described in each docstring) and
returns a :class:`matplotlib.figure.Figure`. :func:`write_figures` draws all the
figures whose tables are available and saves them as PNG files with fixed
names.

matplotlib is an optional dependency (``pip install "skcath[plot]"``); it is
imported only when a figure is drawn. The figures are built as standalone
:class:`~matplotlib.figure.Figure` objects attached to the Agg canvas, without
the global state of :mod:`matplotlib.pyplot`, so that drawing works headless
and from several threads at once. The input tables are never modified.

Methods are identified by their label in the ``method`` column (``"PCC"``,
``"PDL"``, ``"PDL+GRU"``, ...). Each method of the protocol keeps the colour
that :data:`~skcath.protocol.METHODS` gives it in every figure.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Iterable, Mapping
from numbers import Integral, Real
from pathlib import Path

import numpy as np
import pandas as pd
from pandas.api import types as pdt
from sklearn.utils._param_validation import Interval, validate_params

from ._methods import LOCO_VARIANT, MAIN_METHODS, METHODS, PROPOSED_METHOD, methods_with_role

__all__ = [
    "CONDITIONING_METHODS",
    "FIGURE_FILES",
    "NEW_CATHETER_METHODS",
    "RESIDUAL_METHODS",
    "TABLE_COLUMNS",
    "cdf_fraction_at",
    "plot_error_by_magnitude",
    "plot_error_cdf",
    "plot_error_over_time",
    "plot_motion_example",
    "plot_paired_reductions",
    "plot_rmse_boxes",
    "write_figures",
]

#: The two residual learners on top of the PDL backbone.
RESIDUAL_METHODS = methods_with_role("residual_learners")
#: Within-catheter training against training on the other catheters only.
NEW_CATHETER_METHODS = methods_with_role("new_catheter")
#: The GRU residual with and without its torque and context inputs.
CONDITIONING_METHODS = methods_with_role("conditioning")

#: Columns of each summary table, keyed by the table name used by
#: :func:`write_figures`.
TABLE_COLUMNS = {
    "run_rmse": ("method", "catheter", "setting", "run", "rmse_mm"),
    "cdf": ("method", "error_mm", "fraction"),
    "magnitude_bins": ("method", "run", "bin_left", "bin_right", "rmse_mm"),
    "time_bins": ("method", "run", "bin_left", "bin_right", "rmse_mm"),
    "paired": (
        "comparison",
        "scope",
        "reduction_mm",
        "ci_low_mm",
        "ci_high_mm",
        "reduction_pct",
        "fraction_improved",
    ),
    "example": ("t", "p_x", "p_y", "p_z", "phat_x", "phat_y", "phat_z"),
}

#: File names written by :func:`write_figures`, in the order they are written.
FIGURE_FILES = (
    "rmse_boxes.png",
    "residual_learners.png",
    "new_catheter.png",
    "conditioning.png",
    "error_cdf.png",
    "error_by_magnitude.png",
    "error_over_time.png",
    "motion_example.png",
    "paired_reductions.png",
)

#: Scope label of the group (box plots) or row (forest plot) over all catheters.
POOLED = "pooled"

_FIGSIZE = (8.0, 4.5)
_MARK_LABEL_FORMAT = "{:.1f}%"
_SPARE_COLOURS = ("tab:cyan", "tab:gray", "#1b3a6b", "#8c5a00", "#006d5b", "#7a1f5c")
_COMPARISON_COLOURS = (
    "tab:green",
    "tab:blue",
    "tab:purple",
    "tab:brown",
    "tab:red",
    "tab:olive",
    "tab:cyan",
    "tab:orange",
)
_MAX_SPARSE_BOXES = 8
#: Box-plot figures written by :func:`write_figures`: file name -> (methods,
#: how many of them the table must hold, title). The conditioning figure
#: counts only the ablated variants.
_BOX_FIGURES = {
    "rmse_boxes.png": (MAIN_METHODS, 1, None),
    "residual_learners.png": (
        RESIDUAL_METHODS,
        len(RESIDUAL_METHODS),
        "Residual learners on the {backbone} backbone: {learners}".format(
            backbone=METHODS[RESIDUAL_METHODS[0]].backbone.upper(),
            learners=" and ".join(METHODS[m].learner.upper() for m in RESIDUAL_METHODS),
        ),
    ),
    "new_catheter.png": (
        NEW_CATHETER_METHODS,
        len(NEW_CATHETER_METHODS),
        f"{LOCO_VARIANT} trained on the test catheter and on the other catheters (LOCO)",
    ),
    "conditioning.png": (
        CONDITIONING_METHODS,
        1,
        f"{PROPOSED_METHOD} with and without its torque and context inputs",
    ),
}


# ---------------------------------------------------------------------------
# shared helpers
# ---------------------------------------------------------------------------
def _new_figure(figsize=_FIGSIZE):
    """Create a standalone figure on the Agg canvas with constrained layout.

    Parameters
    ----------
    figsize : tuple of float
        Width and height in inches.

    Returns
    -------
    figure : matplotlib.figure.Figure

    Raises
    ------
    ImportError
        If matplotlib is not installed.
    """
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError as exc:
        raise ImportError(
            'Drawing the protocol figures needs matplotlib: pip install "skcath[plot]"'
        ) from exc
    figure = Figure(figsize=figsize, layout="constrained")
    FigureCanvasAgg(figure)
    return figure


def _check_table(table, name, *, numeric=(), finite=(), no_inf=()):
    """Check that ``table`` is a non-empty DataFrame with the columns of ``name``.

    Parameters
    ----------
    table : object
        The table to check.
    name : str
        Key of the table in :data:`TABLE_COLUMNS`, used in the messages.
    numeric : sequence of str
        Columns that must hold numbers.
    finite : sequence of str
        Numeric columns that must be finite on every row.
    no_inf : sequence of str
        Numeric columns that may hold NaN but never +-inf.

    Raises
    ------
    ValueError
        If ``table`` is not a DataFrame, is empty, lacks a column, or holds a
        value of the wrong kind; the message names the table and the column.
    """
    expected = TABLE_COLUMNS[name]
    listed = ", ".join(expected)
    if not isinstance(table, pd.DataFrame):
        raise ValueError(
            f"The {name!r} table must be a pandas DataFrame with the columns {listed}; "
            f"got {type(table).__name__}."
        )
    missing = ", ".join(repr(column) for column in expected if column not in table.columns)
    if missing:
        raise ValueError(f"The {name!r} table lacks the column(s) {missing}; expected the columns {listed}.")
    if len(table) == 0:
        raise ValueError(f"The {name!r} table is empty; expected at least one row.")
    for column in (*numeric, *finite, *no_inf):
        values = table[column]
        if not pdt.is_numeric_dtype(values) or pdt.is_bool_dtype(values):
            raise ValueError(
                f"Column {column!r} of the {name!r} table must hold numbers; "
                f"got dtype {values.dtype}."
            )
    for column in finite:
        values = table[column].to_numpy(dtype=float)
        if not np.isfinite(values).all():
            raise ValueError(
                f"Column {column!r} of the {name!r} table must be finite on every row; "
                f"found {int((~np.isfinite(values)).sum())} NaN or infinite value(s)."
            )
    for column in no_inf:
        values = table[column].to_numpy(dtype=float)
        if np.isinf(values).any():
            raise ValueError(
                f"Column {column!r} of the {name!r} table must not hold infinite values "
                f"(NaN marks a missing value)."
            )


def _as_labels(values, argument):
    """Turn ``values`` (one label or an iterable of labels) into a tuple without repeats."""
    if isinstance(values, str):
        values = (values,)
    if not isinstance(values, Iterable):
        raise ValueError(f"{argument} must be a label or a sequence of labels; got {values!r}.")
    labels = tuple(dict.fromkeys(values))
    if not labels:
        raise ValueError(f"{argument} must name at least one label; got an empty sequence.")
    return labels


def _select(table, column, requested, name, argument):
    """The requested labels present in ``table[column]``, in the requested order.

    Absent labels are skipped; a ValueError is raised if none is present.
    """
    requested = _as_labels(requested, argument)
    available = list(pd.unique(table[column]))
    present = [label for label in requested if label in set(available)]
    if not present:
        raise ValueError(
            f"None of the requested {argument} {list(requested)!r} is in column {column!r} "
            f"of the {name!r} table; it holds {available!r}."
        )
    return present


def _method_colours(methods):
    """Colour of every method: fixed for the known methods, spare colours otherwise."""
    colours = {}
    spare = iter(_SPARE_COLOURS * (1 + len(methods) // len(_SPARE_COLOURS)))
    for method in methods:
        colours[method] = METHODS[method].colour if method in METHODS else next(spare)
    return colours


def _natural_key(label):
    """Sort key that orders "C2" before "C10"."""
    parts = re.split(r"(\d+)", str(label))
    return tuple(int(part) if index % 2 else part for index, part in enumerate(parts))


def _offsets(n_items, total_width):
    """Centre offsets and width of ``n_items`` boxes side by side in ``total_width``."""
    width = total_width / n_items
    offsets = (np.arange(n_items) - (n_items - 1) / 2.0) * width
    return offsets, width


def _draw_boxes(ax, data, positions, width, colour, *, showfliers):
    """Draw one method's box plots (median line, quartile box, 1.5 IQR whiskers)."""
    from matplotlib.colors import to_rgba

    if not data:
        return None
    return ax.boxplot(
        data,
        positions=positions,
        widths=width,
        patch_artist=True,
        manage_ticks=False,
        showfliers=showfliers,
        boxprops={"facecolor": to_rgba(colour, 0.55), "edgecolor": colour, "linewidth": 1.2},
        medianprops={"color": "black", "linewidth": 1.4},
        whiskerprops={"color": colour, "linewidth": 1.1},
        capprops={"color": colour, "linewidth": 1.1},
        flierprops={
            "marker": "o",
            "markersize": 3.0,
            "markerfacecolor": to_rgba(colour, 0.6),
            "markeredgecolor": colour,
            "linestyle": "none",
        },
    )


def _legend_columns(labels, width_chars=100):
    """How many legend columns fit across an 8 in wide figure for these labels."""
    n_columns = len(labels)
    while n_columns > 1 and sum(len(label) + 5 for label in labels[:n_columns]) > width_chars:
        n_columns -= 1
    return max(n_columns, 1)


def _figure_legend(figure, handles, labels, *, title=None):
    """Put the legend below the axes, outside them."""
    return figure.legend(
        handles,
        labels,
        loc="outside lower center",
        ncols=_legend_columns(labels),
        frameon=False,
        fontsize="small",
        title=title,
        title_fontsize="small",
    )


# ---------------------------------------------------------------------------
# per-run RMSE box plots
# ---------------------------------------------------------------------------
def plot_rmse_boxes(run_rmse, methods=MAIN_METHODS, *, title=None):
    """Box plots of the per-run tip RMSE, grouped by catheter and pooled.

    One group of boxes per catheter, in natural order (``"C2"`` before
    ``"C10"``), then a ``"pooled"`` group over all runs; within a group, one
    box per method, in the order of ``methods``. A box spans the quartiles of
    the runs' RMSE with a black line at the median; the whiskers reach the
    furthest run within 1.5 interquartile ranges and the runs beyond are
    drawn as points.

    Parameters
    ----------
    run_rmse : pandas.DataFrame
        One row per (method, test run), with the columns ``method``,
        ``catheter``, ``setting``, ``run`` and ``rmse_mm`` (tip RMSE of the run
        in mm, already averaged over seeds). Rows with a NaN RMSE are ignored.
    methods : sequence of str, default ("PCC", "PDL", "PDL+GRU")
        Methods to draw, in this order. Methods absent from the table are
        skipped.
    title : str, optional
        Figure title; a generic one by default.

    Returns
    -------
    figure : matplotlib.figure.Figure
        One axes; its box patches are the only patches of the axes.

    Raises
    ------
    ValueError
        If the table lacks a column, holds an infinite RMSE or several rows
        for one (method, catheter, setting, run), or if none of ``methods`` is
        in the table.
    ImportError
        If matplotlib is not installed.

    See Also
    --------
    write_figures : Draws this figure for the main methods, the residual
        learners, the held-out catheter and the conditioning variants.
    """
    _check_table(run_rmse, "run_rmse", no_inf=("rmse_mm",))
    present = _select(run_rmse, "method", methods, "run_rmse", "methods")
    table = run_rmse.loc[run_rmse["method"].isin(present), list(TABLE_COLUMNS["run_rmse"])]
    key = ["method", "catheter", "setting", "run"]
    duplicated = table.duplicated(subset=key, keep=False)
    if duplicated.any():
        first = table.loc[duplicated, key].iloc[0].tolist()
        raise ValueError(
            f"The 'run_rmse' table must hold one row per (method, catheter, setting, run); "
            f"found {int(duplicated.sum())} rows sharing a key, e.g. {first!r}. "
            "Average the RMSE over seeds first."
        )
    table = table[np.isfinite(table["rmse_mm"].to_numpy(dtype=float))]

    catheters = sorted(pd.unique(table["catheter"]), key=_natural_key)
    groups = [*catheters, POOLED]
    colours = _method_colours(present)
    offsets, width = _offsets(len(present), 0.8)

    figure = _new_figure()
    ax = figure.add_subplot()
    handles = []
    for method, offset in zip(present, offsets):
        rows = table[table["method"] == method]
        data, positions = [], []
        for index, group in enumerate(groups):
            in_group = rows if group == POOLED else rows[rows["catheter"] == group]
            values = in_group["rmse_mm"].to_numpy(dtype=float)
            if values.size:
                data.append(values)
                positions.append(index + offset)
        _draw_boxes(ax, data, positions, width * 0.9, colours[method], showfliers=True)
        handles.append(_legend_patch(colours[method]))

    ax.set_xticks(np.arange(len(groups)))
    ax.set_xticklabels([str(group) for group in groups])
    ax.set_xlim(-0.6, len(groups) - 0.4)
    ax.axvline(len(groups) - 1.5, color="0.6", linestyle=":", linewidth=1.0)
    ax.set_ylim(bottom=0.0)
    ax.set_xlabel("Catheter (pooled: all test runs)")
    ax.set_ylabel("Tip RMSE per run (mm)")
    ax.grid(axis="y", alpha=0.3)
    figure.suptitle(title or "Per-run tip RMSE by catheter")
    _figure_legend(figure, handles, list(present))
    return figure


def _legend_patch(colour):
    """A legend handle that looks like one of the boxes."""
    from matplotlib.colors import to_rgba
    from matplotlib.patches import Patch

    return Patch(facecolor=to_rgba(colour, 0.55), edgecolor=colour, linewidth=1.2)


# ---------------------------------------------------------------------------
# error CDF
# ---------------------------------------------------------------------------
def _cdf_curves(cdf, methods):
    """Error grid (mm) and fraction of every method, averaged over repeated grid points."""
    curves = {}
    for method in methods:
        rows = cdf[cdf["method"] == method]
        curve = rows.groupby("error_mm", sort=True)["fraction"].mean()
        curves[method] = (curve.index.to_numpy(dtype=float), curve.to_numpy(dtype=float))
    return curves


def cdf_fraction_at(cdf, method, error_mm):
    """Fraction of samples with a tip error up to ``error_mm``, read off the CDF table.

    The fraction is interpolated linearly between the grid points of the
    method's curve; below the first and above the last grid point it is the
    curve's first and last value.

    Parameters
    ----------
    cdf : pandas.DataFrame
        Error CDF with the columns ``method``, ``error_mm`` (mm) and
        ``fraction`` (between 0 and 1).
    method : str
        Method whose curve is read.
    error_mm : float
        Tip error (mm).

    Returns
    -------
    fraction : float
        Fraction of samples (between 0 and 1).

    Raises
    ------
    ValueError
        If the table is malformed or does not hold ``method``.
    """
    _check_cdf(cdf)
    _select(cdf, "method", (method,), "cdf", "methods")
    errors, fractions = _cdf_curves(cdf, (method,))[method]
    return float(np.interp(float(error_mm), errors, fractions))


def _check_cdf(cdf):
    _check_table(cdf, "cdf", finite=("error_mm", "fraction"))
    fractions = cdf["fraction"].to_numpy(dtype=float)
    if (fractions < 0).any() or (fractions > 1).any():
        raise ValueError(
            "Column 'fraction' of the 'cdf' table must lie between 0 and 1; "
            f"got values from {fractions.min():g} to {fractions.max():g}."
        )


@validate_params(
    {
        "cdf": "no_validation",
        "methods": "no_validation",
        "mark_mm": [Interval(Real, 0, None, closed="left"), None],
        "title": [str, None],
    },
    prefer_skip_nested_validation=True,
)
def plot_error_cdf(cdf, methods=MAIN_METHODS, mark_mm=5.0, *, title=None):
    """Cumulative distribution of the tip error, one curve per method.

    A vertical dashed line marks ``mark_mm``; the legend gives each method's
    fraction of samples with an error up to ``mark_mm`` (interpolated on the
    grid, see :func:`cdf_fraction_at`). Repeated grid points of one method
    (for example one curve per run) are averaged. The error axis stops where
    every curve has reached 0.99, or at the end of the grid.

    Parameters
    ----------
    cdf : pandas.DataFrame
        Columns ``method``, ``error_mm`` (tip error, mm) and ``fraction``
        (fraction of samples with an error up to ``error_mm``, between 0 and 1).
    methods : sequence of str, default ("PCC", "PDL", "PDL+GRU")
        Methods to draw, in this order; absent ones are skipped.
    mark_mm : float or None, default 5.0
        Error (mm) to mark; None draws no marker.
    title : str, optional
        Figure title; a generic one by default.

    Returns
    -------
    figure : matplotlib.figure.Figure
        One axes with one line per method (plus the marker line).

    Raises
    ------
    ValueError
        If the table lacks a column, holds a non-finite value or a fraction
        outside [0, 1], if ``mark_mm`` is not a finite non-negative number, or
        if none of ``methods`` is in the table.
    ImportError
        If matplotlib is not installed.
    """
    _check_cdf(cdf)
    if mark_mm is not None:
        mark_mm = float(mark_mm)
    present = _select(cdf, "method", methods, "cdf", "methods")
    curves = _cdf_curves(cdf, present)
    colours = _method_colours(present)

    figure = _new_figure()
    ax = figure.add_subplot()
    x_stop = 0.0
    for method in present:
        errors, fractions = curves[method]
        label = method
        if mark_mm is not None:
            fraction = float(np.interp(mark_mm, errors, fractions))
            label = f"{method}: {_MARK_LABEL_FORMAT.format(100.0 * fraction)} within {mark_mm:g} mm"
            ax.plot([mark_mm], [fraction], "o", color=colours[method], markersize=5, zorder=3)
        ax.plot(errors, fractions, color=colours[method], linewidth=1.8, label=label)
        reached = np.flatnonzero(fractions >= 0.99)
        x_stop = max(x_stop, errors[reached[0]] if reached.size else errors[-1])
    grid_min = min(curves[method][0][0] for method in present)
    grid_max = max(curves[method][0][-1] for method in present)
    if mark_mm is not None:
        ax.axvline(mark_mm, color="0.35", linestyle="--", linewidth=1.0)
        x_stop = max(x_stop, 1.5 * mark_mm)
    x_stop = min(1.1 * x_stop, grid_max) if x_stop > 0 else grid_max
    ax.set_xlim(min(0.0, grid_min), max(x_stop, grid_min + 1e-9))
    ax.set_ylim(0.0, 1.02)
    ax.set_xlabel("Tip error (mm)")
    ax.set_ylabel("Fraction of samples with error \u2264 x")
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right", fontsize="small")
    figure.suptitle(title or "Cumulative distribution of the tip error")
    return figure


# ---------------------------------------------------------------------------
# binned errors (motor-input magnitude, motion time)
# ---------------------------------------------------------------------------
def _check_bins(table, name):
    _check_table(table, name, finite=("bin_left", "bin_right"), no_inf=("rmse_mm",))
    left = table["bin_left"].to_numpy(dtype=float)
    right = table["bin_right"].to_numpy(dtype=float)
    if (right <= left).any():
        raise ValueError(
            f"Every bin of the {name!r} table must have bin_right > bin_left; "
            f"found {int((right <= left).sum())} row(s) that do not."
        )


#: How each binned table is drawn: statistic over runs, x-axis label, bin unit, default title.
_BINNED = {
    "magnitude_bins": ("median", "Motor-input magnitude (deg)", "deg", "Tip error by motor-input magnitude"),
    "time_bins": ("mean", "Motion time (s)", "s", "Tip error over the motion"),
}


def _plot_binned(table, name, methods, *, box_every, title):
    """Line of a per-bin statistic over runs plus sparse between-run box plots."""
    statistic, x_label, unit, default_title = _BINNED[name]
    title = title or default_title
    _check_bins(table, name)
    present = _select(table, "method", methods, name, "methods")
    rows = table.loc[table["method"].isin(present), ["method", "bin_left", "bin_right", "rmse_mm"]]
    rows = rows[np.isfinite(rows["rmse_mm"].to_numpy(dtype=float))]
    bins = rows[["bin_left", "bin_right"]].drop_duplicates().sort_values(["bin_left", "bin_right"])
    lefts = bins["bin_left"].to_numpy(dtype=float)
    rights = bins["bin_right"].to_numpy(dtype=float)
    centres = (lefts + rights) / 2.0
    if box_every is None:
        box_every = max(1, math.ceil(len(centres) / _MAX_SPARSE_BOXES))
    boxed = set(range(0, len(centres), box_every))
    bin_width = float(np.median(rights - lefts)) if len(centres) else 1.0
    offsets, width = _offsets(len(present), 0.85 * bin_width * min(box_every, 2))
    colours = _method_colours(present)

    figure = _new_figure()
    ax = figure.add_subplot()
    handles = []
    for method, offset in zip(present, offsets):
        method_rows = rows[rows["method"] == method]
        grouped = method_rows.groupby(["bin_left", "bin_right"], sort=True)["rmse_mm"]
        values = {key: group.to_numpy(dtype=float) for key, group in grouped}
        line_x, line_y, box_data, box_x = [], [], [], []
        for index, key in enumerate(zip(lefts, rights)):
            if key not in values:
                continue
            line_x.append(centres[index])
            line_y.append(np.median(values[key]) if statistic == "median" else np.mean(values[key]))
            if index in boxed:
                box_data.append(values[key])
                box_x.append(centres[index] + offset)
        (line,) = ax.plot(
            line_x,
            line_y,
            color=colours[method],
            marker="o",
            markersize=3.5,
            linewidth=1.6,
            zorder=3,
        )
        _draw_boxes(ax, box_data, box_x, width * 0.85, colours[method], showfliers=False)
        handles.append(line)
    ax.set_ylim(bottom=0.0)
    if len(centres):
        # room for the first and last groups of boxes, which may reach past the bins
        reach = abs(offsets[0]) + width / 2.0
        x_low = min(lefts.min(), centres[min(boxed)] - reach)
        x_high = max(rights.max(), centres[max(boxed)] + reach)
        ax.set_xlim(x_low, x_high)
    ax.set_xlabel(x_label)
    ax.set_ylabel("Tip RMSE per run and bin (mm)")
    ax.grid(alpha=0.3)
    figure.suptitle(title)
    legend_title = (
        f"line: {statistic} over runs per {bin_width:g} {unit} bin; "
        "boxes: between-run quartiles and median"
    )
    _figure_legend(figure, handles, list(present), title=legend_title)
    return figure


# The Returns and Raises sections of plot_error_by_magnitude and
# plot_error_over_time, put in place of ``{binned_returns}`` by _binned_doc.
_BINNED_RETURNS_DOC = """Returns
    -------
    figure : matplotlib.figure.Figure
        One axes with one line per method.

    Raises
    ------
    ValueError
        If the table lacks a column, holds non-finite bin edges, an empty bin
        or an infinite RMSE, or if none of ``methods`` is in the table.
    ImportError
        If matplotlib is not installed."""


#: Parameters of plot_error_by_magnitude and plot_error_over_time; the tables
#: and methods are checked by _plot_binned, with messages naming the column.
_BINNED_PARAMETERS = {
    "magnitude_bins": "no_validation",
    "time_bins": "no_validation",
    "methods": "no_validation",
    "box_every": [Interval(Integral, 1, None, closed="left"), None],
    "title": [str, None],
}


def _binned_doc(func):
    """Decorator: fill the ``{binned_returns}`` placeholder of ``func``'s docstring."""
    if func.__doc__:  # None under python -OO
        func.__doc__ = func.__doc__.replace("{binned_returns}", _BINNED_RETURNS_DOC)
    return func


@validate_params(_BINNED_PARAMETERS, prefer_skip_nested_validation=True)
@_binned_doc
def plot_error_by_magnitude(magnitude_bins, methods=MAIN_METHODS, *, box_every=None, title=None):
    """Tip error against the magnitude of the motor input.

    For every method, a line joins the median over runs of the run-bin RMSE
    at the bin centres; box plots of the between-run spread (quartiles,
    median, whiskers to 1.5 interquartile ranges, no outlier points) are
    drawn at every ``box_every``-th bin, side by side for the methods.

    Parameters
    ----------
    magnitude_bins : pandas.DataFrame
        One row per (method, run, bin), with the columns ``method``, ``run``,
        ``bin_left`` and ``bin_right`` (bin edges of the motor-input
        magnitude, degrees) and ``rmse_mm`` (tip RMSE of the run's samples in
        the bin, mm; NaN rows are ignored).
    methods : sequence of str, default ("PCC", "PDL", "PDL+GRU")
        Methods to draw, in this order; absent ones are skipped.
    box_every : int, optional
        Draw boxes at every ``box_every``-th bin, starting with the first;
        by default often enough for about 8 box positions.
    title : str, optional
        Figure title; a generic one by default.

    {binned_returns}
    """
    return _plot_binned(magnitude_bins, "magnitude_bins", methods, box_every=box_every, title=title)


@validate_params(_BINNED_PARAMETERS, prefer_skip_nested_validation=True)
@_binned_doc
def plot_error_over_time(time_bins, methods=MAIN_METHODS, *, box_every=None, title=None):
    """Tip error over the motion time of the runs.

    For every method, a line joins the mean over runs of the run-bin RMSE at
    the bin centres; box plots of the between-run spread (quartiles, median,
    whiskers to 1.5 interquartile ranges, no outlier points) are drawn at
    every ``box_every``-th bin, side by side for the methods.

    Parameters
    ----------
    time_bins : pandas.DataFrame
        One row per (method, run, bin), with the columns ``method``, ``run``,
        ``bin_left`` and ``bin_right`` (bin edges of the motion time, s) and
        ``rmse_mm`` (tip RMSE of the run's samples in the bin, mm; NaN rows are
        ignored).
    methods : sequence of str, default ("PCC", "PDL", "PDL+GRU")
        Methods to draw, in this order; absent ones are skipped.
    box_every : int, optional
        Draw boxes at every ``box_every``-th bin, starting with the first;
        by default often enough for about 8 box positions (every 4th bin of a
        300 s motion in 10 s bins).
    title : str, optional
        Figure title; a generic one by default.

    {binned_returns}
    """
    return _plot_binned(time_bins, "time_bins", methods, box_every=box_every, title=title)


# ---------------------------------------------------------------------------
# one motion run
# ---------------------------------------------------------------------------
def plot_motion_example(example, *, title=None):
    """Measured and estimated tip trajectory of one motion run, and its errors.

    Panel (a) shows the measured and estimated tip positions in the x-y and
    x-z projections, on equal metric scales (same mm per inch on every axis
    of both projections). Panel (b) shows the signed coordinate errors
    ``phat - p`` of x, y and z over time.

    Parameters
    ----------
    example : pandas.DataFrame
        One row per sample with the columns ``t`` (time, s), ``p_x``,
        ``p_y``, ``p_z`` (measured tip position, mm; NaN where the tracker
        dropped out) and ``phat_x``, ``phat_y``, ``phat_z`` (estimated tip
        position, mm). ``example.attrs`` may hold ``run``, ``method`` and
        ``rmse_mm`` for the title; a missing ``rmse_mm`` is computed from the
        rows.
    title : str, optional
        Figure title; built from ``example.attrs`` by default.

    Returns
    -------
    figure : matplotlib.figure.Figure
        Three axes: the x-y projection, the x-z projection and the errors.

    Raises
    ------
    ValueError
        If the table lacks a column, holds a non-finite time or estimate or
        an infinite measurement, or has no sample with a measured position.
    ImportError
        If matplotlib is not installed.
    """
    measured = ("p_x", "p_y", "p_z")
    estimated = ("phat_x", "phat_y", "phat_z")
    _check_table(example, "example", finite=("t", *estimated), no_inf=measured)
    rows = example.sort_values("t", kind="stable")
    t = rows["t"].to_numpy(dtype=float)
    p = rows[list(measured)].to_numpy(dtype=float)
    phat = rows[list(estimated)].to_numpy(dtype=float)
    observed = np.isfinite(p).all(axis=1)
    if not observed.any():
        raise ValueError(
            "The 'example' table has no row with a measured tip position (p_x, p_y, p_z all NaN)."
        )
    errors = phat - p

    attrs = dict(example.attrs)
    rmse = attrs.get("rmse_mm")
    if rmse is None:
        rmse = float(np.sqrt(np.mean(np.sum(errors[observed] ** 2, axis=1))))
    if title is None:
        parts = []
        if attrs.get("method") is not None:
            parts.append(str(attrs["method"]))
        if attrs.get("run") is not None:
            parts.append(f"run {attrs['run']}")
        head = ", ".join(parts) if parts else "Example motion run"
        title = f"{head}: tip RMSE {float(rmse):.2f} mm"

    figure = _new_figure(figsize=(9.0, 4.5))
    grid = figure.add_gridspec(1, 3, width_ratios=(1.0, 1.0, 1.25))
    ax_xy = figure.add_subplot(grid[0, 0])
    ax_xz = figure.add_subplot(grid[0, 1])
    ax_err = figure.add_subplot(grid[0, 2])

    both = np.vstack([p[observed], phat])
    low, high = both.min(axis=0), both.max(axis=0)
    centre = (low + high) / 2.0
    half = max(float((high - low).max()) / 2.0 * 1.08, 1.0)
    for ax, (i, j), panel in ((ax_xy, (0, 1), "x\u2013y"), (ax_xz, (0, 2), "x\u2013z")):
        names = "xyz"
        ax.plot(p[:, i], p[:, j], color="black", linewidth=1.4, label="measured")
        ax.plot(phat[:, i], phat[:, j], "--", color="tab:red", linewidth=1.1, label="estimated")
        ax.set_xlim(centre[i] - half, centre[i] + half)
        ax.set_ylim(centre[j] - half, centre[j] + half)
        ax.set_aspect("equal", adjustable="box")
        ax.set_xlabel(f"{names[i]} (mm)")
        ax.set_ylabel(f"{names[j]} (mm)")
        ax.set_title(f"(a) {panel} projection", fontsize="medium")
        ax.grid(alpha=0.3)
    ax_xy.legend(loc="best", fontsize="small")

    for k, (name, colour) in enumerate(zip("xyz", ("tab:blue", "tab:orange", "tab:green"))):
        ax_err.plot(t, errors[:, k], color=colour, linewidth=1.1, label=name)
    ax_err.axhline(0.0, color="0.3", linewidth=0.8)
    ax_err.set_xlim(t.min(), t.max() if t.max() > t.min() else t.min() + 1.0)
    ax_err.set_xlabel("Time (s)")
    ax_err.set_ylabel("Estimated \u2212 measured (mm)")
    ax_err.set_title("(b) Signed coordinate errors", fontsize="medium")
    ax_err.grid(alpha=0.3)
    ax_err.legend(loc="best", fontsize="small", ncols=3)
    figure.suptitle(title)
    return figure


# ---------------------------------------------------------------------------
# paired reductions (forest plot)
# ---------------------------------------------------------------------------
def plot_paired_reductions(paired, comparisons=None, *, title=None):
    """Forest plot of the paired per-run RMSE reductions with confidence intervals.

    One row per (comparison, scope): a point at the mean reduction and a
    horizontal bar over its confidence interval. The rows of one comparison
    share a colour, with the catheters in natural order and the pooled row
    last, drawn larger and labelled in bold. A column on the right gives the
    relative reduction and the fraction of runs improved. Positive values
    mean a lower error for the second method of the comparison.

    Parameters
    ----------
    paired : pandas.DataFrame
        One row per (comparison, scope) with the columns ``comparison``,
        ``scope`` (a catheter or ``"pooled"``), ``reduction_mm``,
        ``ci_low_mm`` and ``ci_high_mm`` (mean reduction of the per-run RMSE
        and its confidence interval, mm; NaN bounds draw no bar),
        ``reduction_pct`` (mean reduction, % of the first method's RMSE) and
        ``fraction_improved`` (fraction of runs improved, between 0 and 1).
    comparisons : sequence of str, optional
        Comparisons to draw, in this order; absent ones are skipped. By
        default all of them, in the order of the table.
    title : str, optional
        Figure title; a generic one by default.

    Returns
    -------
    figure : matplotlib.figure.Figure
        One axes with one y tick per drawn row.

    Raises
    ------
    ValueError
        If the table lacks a column, holds a non-finite reduction, an
        interval with ``ci_low_mm > ci_high_mm``, a fraction outside [0, 1]
        or several rows for one (comparison, scope), or if none of
        ``comparisons`` is in the table.
    ImportError
        If matplotlib is not installed.
    """
    _check_paired(paired)
    if comparisons is None:
        present = list(pd.unique(paired["comparison"]))
    else:
        present = _select(paired, "comparison", comparisons, "paired", "comparisons")
    layout, groups = _forest_layout(paired, present)

    figure = _new_figure(figsize=(8.0, max(4.5, 1.4 + 0.22 * len(layout))))
    ax = figure.add_subplot()
    from matplotlib.lines import Line2D
    from matplotlib.transforms import blended_transform_factory

    side = blended_transform_factory(ax.transAxes, ax.transData)
    for y_row, row, colour, pooled in layout:
        _draw_forest_row(ax, side, y_row, row, colour, pooled)
    ax.text(1.02, 1.0, "reduction | runs\nimproved", transform=ax.transAxes, va="bottom",
            ha="left", fontsize="x-small")
    ax.axvline(0.0, color="0.25", linewidth=1.0, linestyle="--")
    for top, _, _ in groups[1:]:
        ax.axhline(top + 0.8, color="0.8", linewidth=0.8)
    ax.set_yticks([entry[0] for entry in layout])
    labels = ax.set_yticklabels([str(entry[1]["scope"]) for entry in layout], fontsize="small")
    for label, entry in zip(labels, layout):
        if entry[3]:
            label.set_fontweight("bold")
    ax.set_ylim(min(entry[0] for entry in layout) - 0.7, 0.7)
    ax.set_xlabel("Reduction of the per-run tip RMSE (mm; > 0: second method better)")
    ax.grid(axis="x", alpha=0.3)
    handles = [
        Line2D([], [], color=colour, marker="D", markeredgecolor="black", linewidth=2.5)
        for _, _, colour in groups
    ]
    figure.suptitle(
        title or "Paired reductions of the per-run tip RMSE (mean and confidence interval)"
    )
    _figure_legend(figure, handles, [comparison for _, comparison, _ in groups])
    return figure


def _check_paired(paired):
    """Check the columns, intervals, fractions and keys of the 'paired' table."""
    _check_table(
        paired,
        "paired",
        finite=("reduction_mm",),
        no_inf=("ci_low_mm", "ci_high_mm", "reduction_pct", "fraction_improved"),
    )
    low = paired["ci_low_mm"].to_numpy(dtype=float)
    high = paired["ci_high_mm"].to_numpy(dtype=float)
    if (low > high).any():
        raise ValueError(
            "Every row of the 'paired' table must have ci_low_mm <= ci_high_mm; "
            f"found {int((low > high).sum())} row(s) that do not."
        )
    fractions = paired["fraction_improved"].to_numpy(dtype=float)
    if ((fractions < 0) | (fractions > 1)).any():
        raise ValueError(
            "Column 'fraction_improved' of the 'paired' table must lie between 0 and 1."
        )
    duplicated = paired.duplicated(subset=["comparison", "scope"], keep=False)
    if duplicated.any():
        raise ValueError(
            "The 'paired' table must hold one row per (comparison, scope); "
            f"found {int(duplicated.sum())} rows sharing a key."
        )


def _forest_layout(paired, comparisons):
    """Rows of the forest plot, top to bottom, and the top of every comparison's group.

    Returns a list of (y, table row, colour, is_pooled) and a list of (y,
    comparison, colour): within a comparison, the catheters in natural order
    and the pooled row last; a gap between comparisons.
    """
    layout, groups = [], []
    y = 0.0
    for number, comparison in enumerate(comparisons):
        rows = paired[paired["comparison"] == comparison]
        scopes = sorted((s for s in pd.unique(rows["scope"]) if s != POOLED), key=_natural_key)
        if (rows["scope"] == POOLED).any():
            scopes.append(POOLED)
        colour = _COMPARISON_COLOURS[number % len(_COMPARISON_COLOURS)]
        groups.append((y, comparison, colour))
        for scope in scopes:
            layout.append((y, rows[rows["scope"] == scope].iloc[0], colour, scope == POOLED))
            y -= 1.0
        y -= 0.6
    return layout, groups


def _percent(value, scale=1.0):
    """``value`` (times ``scale``) as a whole percentage, or n/a when not finite."""
    return format(scale * value, ".0f") + "%" if np.isfinite(value) else "n/a"


def _draw_forest_row(ax, side, y, row, colour, pooled):
    """One row of the forest plot: interval bar, mean marker and the note on the right."""
    if np.isfinite(row["ci_low_mm"]) and np.isfinite(row["ci_high_mm"]):
        ax.hlines(y, row["ci_low_mm"], row["ci_high_mm"], color=colour,
                  linewidth=3.0 if pooled else 1.4)
    ax.plot(
        [row["reduction_mm"]],
        [y],
        marker="D" if pooled else "o",
        markersize=8.0 if pooled else 5.0,
        color=colour,
        markeredgecolor="black" if pooled else colour,
        linestyle="none",
        zorder=3,
    )
    note = f"{_percent(row['reduction_pct'])} | {_percent(row['fraction_improved'], 100)}"
    ax.text(1.02, y, note, transform=side, va="center", ha="left", fontsize="x-small",
            fontweight="bold" if pooled else "normal")


# ---------------------------------------------------------------------------
# all figures to files
# ---------------------------------------------------------------------------
def _box_plans(run_rmse):
    """(file name, drawing function) of every box-plot figure whose methods were run."""
    plans = []
    for file_name, (methods, needed, title) in _BOX_FIGURES.items():
        found = _has_methods(run_rmse, methods)
        if file_name == "conditioning.png":  # the full model alone is no ablation
            found = [m for m in found if not (METHODS[m].use_torque and METHODS[m].use_context)]
        if len(found) >= needed:
            plans.append((file_name, lambda m=methods, t=title: plot_rmse_boxes(run_rmse, m, title=t)))
    return plans


def _has_methods(table, methods):
    """Which of ``methods`` appear in the method column of ``table``."""
    available = set(pd.unique(table["method"]))
    return [method for method in methods if method in available]


@validate_params(
    {
        "tables": [Mapping],
        "out_dir": [str, os.PathLike],
        "dpi": [Interval(Real, 0, None, closed="neither")],
    },
    prefer_skip_nested_validation=True,
)
def write_figures(tables: Mapping[str, pd.DataFrame], out_dir, *, dpi: float = 150) -> list[Path]:
    """Draw the protocol figures from its summary tables and save them as PNG.

    The figures whose tables are given are written to ``out_dir`` (created if
    needed) under fixed names, in this order:

    ``rmse_boxes.png``
        :func:`plot_rmse_boxes` of PCC, PDL and PDL+GRU (``run_rmse``).
    ``residual_learners.png``
        PDL+MLP against PDL+GRU, if both are in ``run_rmse``.
    ``new_catheter.png``
        PDL+GRU against PDL+GRU (LOCO), if both are in ``run_rmse``.
    ``conditioning.png``
        The GRU residual with and without torque and context inputs, if
        ``run_rmse`` holds at least one of the ablated variants.
    ``error_cdf.png``
        :func:`plot_error_cdf` (``cdf``).
    ``error_by_magnitude.png``
        :func:`plot_error_by_magnitude` (``magnitude_bins``).
    ``error_over_time.png``
        :func:`plot_error_over_time` (``time_bins``).
    ``motion_example.png``
        :func:`plot_motion_example` (``example``).
    ``paired_reductions.png``
        :func:`plot_paired_reductions` (``paired``).

    A figure of the main methods is skipped when its table holds none of
    PCC, PDL and PDL+GRU.

    Parameters
    ----------
    tables : mapping of str to pandas.DataFrame
        Any of the keys ``run_rmse``, ``cdf``, ``magnitude_bins``,
        ``time_bins``, ``paired`` and ``example`` (see the plotting functions
        for their columns). A missing key or a None value skips its figures.
    out_dir : str or os.PathLike
        Folder of the PNG files.
    dpi : float, default 150
        Resolution of the PNG files (dots per inch).

    Returns
    -------
    paths : list of pathlib.Path
        The written files, in the order above.

    Raises
    ------
    ValueError
        If ``tables`` holds an unknown key, if ``dpi`` is not a positive
        number, or if a table is malformed (see the plotting functions).
    ImportError
        If matplotlib is not installed.
    """
    unknown = [key for key in tables if key not in TABLE_COLUMNS]
    if unknown:
        raise ValueError(
            f"Unknown table name(s) {unknown!r}; expected any of {', '.join(TABLE_COLUMNS)}."
        )
    given = {key: table for key, table in tables.items() if table is not None}
    for key, table in given.items():
        _check_table(table, key)

    plans = _box_plans(given["run_rmse"]) if given.get("run_rmse") is not None else []
    for key, file_name, plot in (
        ("cdf", "error_cdf.png", plot_error_cdf),
        ("magnitude_bins", "error_by_magnitude.png", plot_error_by_magnitude),
        ("time_bins", "error_over_time.png", plot_error_over_time),
    ):
        table = given.get(key)
        if table is not None and _has_methods(table, MAIN_METHODS):
            plans.append((file_name, lambda plot=plot, table=table: plot(table, MAIN_METHODS)))
    if given.get("example") is not None:
        plans.append(("motion_example.png", lambda: plot_motion_example(given["example"])))
    if given.get("paired") is not None:
        plans.append(("paired_reductions.png", lambda: plot_paired_reductions(given["paired"])))

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for file_name, draw in plans:
        figure = draw()
        path = out_dir / file_name
        figure.savefig(path, dpi=dpi)
        figure.clear()
        written.append(path)
    return written
