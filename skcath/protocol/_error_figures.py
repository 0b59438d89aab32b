"""Figures of the tip error of the samples: its CDF, its RMSE by bins of magnitude or time, one run.

:func:`plot_error_cdf` and :func:`cdf_fraction_at` read the ``cdf`` table,
:func:`plot_error_by_magnitude` and :func:`plot_error_over_time` the
``magnitude_bins`` and ``time_bins`` tables, and :func:`plot_motion_example`
the ``example`` table (see
:data:`~skcath.protocol._figure_tools.TABLE_COLUMNS`).
"""

from __future__ import annotations

import math
from numbers import Integral, Real

import numpy as np
from sklearn.utils._param_validation import Interval, validate_params

from ._figure_tools import (
    _check_table,
    _draw_boxes,
    _figure_legend,
    _method_colours,
    _new_figure,
    _offsets,
    _select,
)
from ._methods import MAIN_METHODS

_MARK_LABEL_FORMAT = "{:.1f}%"
_MAX_SPARSE_BOXES = 8


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
