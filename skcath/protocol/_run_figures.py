"""Figures of the per-run tip RMSE: box plots by catheter and the forest plot of paired reductions.

:func:`plot_rmse_boxes` draws the ``run_rmse`` table and
:func:`plot_paired_reductions` the ``paired`` table (see
:data:`~skcath.protocol._figure_tools.TABLE_COLUMNS`).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ._figure_tools import (
    POOLED,
    TABLE_COLUMNS,
    _check_table,
    _draw_boxes,
    _figure_legend,
    _legend_patch,
    _method_colours,
    _natural_key,
    _new_figure,
    _offsets,
    _select,
)
from ._methods import MAIN_METHODS

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
